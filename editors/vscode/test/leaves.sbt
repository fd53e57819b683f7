# SYNTAX TEST "source.stringbt" "conditions, actions and their arguments"
<sq><c>(!HandleSeen, side="left")<a>(TurnHandle, degrees=60, speed=-1.5e3, ok=true)<e>
#   ^^^ keyword.control.tag.stringbt
#       ^ keyword.operator.logical.stringbt
#        ^^^^^^^^^^ entity.name.function.stringbt
#                    ^^^^ variable.parameter.stringbt
#                         ^^^^^^ string.quoted.double.stringbt
#                                    ^^^^^^^^^^ entity.name.function.stringbt
#                                                ^^^^^^^ variable.parameter.stringbt
#                                                        ^^ constant.numeric.stringbt
#                                                                  ^^^^^^ constant.numeric.stringbt
#                                                                             ^^^^ constant.language.boolean.stringbt
<c>DoorClosed <a>(Say, text="a \"b\" \u00e9")
# <- keyword.control.tag.stringbt
#  ^^^^^^^^^^ entity.name.function.stringbt
#                           ^^^^^^^^^^^^^^^^ string.quoted.double.stringbt
#                              ^^ constant.character.escape.stringbt
#                                    ^^^^^^ constant.character.escape.stringbt
