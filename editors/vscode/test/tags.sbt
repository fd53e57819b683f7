# SYNTAX TEST "source.stringbt" "tags, placeholders and comments"
<sl>  # the control tree
# <- keyword.control.tag.stringbt
#     ^^^^^^^^^^^^^^^^^^ comment.line.number-sign.stringbt
    <k>(new)<e>
#   ^^^ keyword.control.tag.stringbt
#       ^^^ entity.name.namespace.stringbt
#           ^^^ keyword.control.tag.stringbt
    <tt1>(5)<w>3<e>
#   ^^^^^ keyword.control.tag.stringbt
#         ^ constant.numeric.stringbt
#            ^ keyword.control.tag.stringbt
    <zz>
#   ^^^^ invalid.illegal.tag.stringbt
<e>
