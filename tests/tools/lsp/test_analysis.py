"""The language server's functions of a document's text, without a client: positions in the
three ways of counting (spec/stringbt.md section 1 against LSP's UTF-16), the outline of text
being typed, problems with their ranges, formatting that keeps meaning, completion, hover, the
project's settings, and the fuzzer's corpus through every feature without an exception.

The same features over a real client are tests/tools/lsp/test_server.py's."""

from __future__ import annotations

import json
import os
import random
import sys
from pathlib import Path

import pytest
from lsprotocol import types as lsp

from ktbt_proto.errors import StringBTError
from ktbt_proto.formatter import format_tree
from ktbt_proto.syntax import parse
from ktbt_proto.tools import fuzz
from ktbt_proto.tools.lsp import assist, navigation
from ktbt_proto.tools.lsp.diagnostics import MAX_PROBLEMS, Checked, check
from ktbt_proto.tools.lsp.document import UTF8, UTF16, UTF32, Document
from ktbt_proto.tools.lsp.formatting import apply, close_open_nodes, format_edits, memory_form
from ktbt_proto.tools.lsp.outline import read
from ktbt_proto.tools.lsp.vocabularies import Known, Vocabularies
from ktbt_proto.tools.project import ProjectError, find_project
from ktbt_proto.tools.vocabulary import parse_vocabulary, read_vocabulary
from tests.door_robot import FLAT, MEMORY, VOCABULARY, door_registry

ROOT = Path(__file__).resolve().parents[3]
DOOR = Known(parse_vocabulary(VOCABULARY), "door.toml")


def test_positions_count_utf16_units_where_stringbt_counts_code_points() -> None:
    # "é" is one code point and one UTF-16 unit; the emoji one code point and two units.
    text = '<sq>\n    <a>(Say, text="é😀") <zz>\n<e>\n'
    (problem,) = check(text).problems
    assert problem.error.code.value == "SBT102"
    assert (problem.error.line, problem.error.column) == (2, 25)  # code points, 1-based
    document = Document("file:///t.sbt", text)
    start = document.position_at(problem.start)
    assert (start.line, start.character) == (1, 25)  # 24 code points before it, one is two units
    assert document.offset_at(start) == problem.start
    for encoding, character in ((UTF8, 28), (UTF32, 24)):
        other = Document("file:///t.sbt", text, encoding=encoding)
        assert other.position_at(problem.start).character == character
        assert other.offset_at(lsp.Position(1, character)) == problem.start
    # Half a surrogate pair is not a place: it rounds down to before the emoji.
    emoji = text.index("😀")
    assert document.offset_at(lsp.Position(1, document.position_at(emoji).character + 1)) == emoji


def test_lsp_lines_break_at_a_lone_cr_and_stringbt_lines_do_not() -> None:
    text = "<sq> # a\rb\n  <zz>\n<e>"
    (problem,) = check(text).problems
    assert (problem.error.line, problem.error.column) == (2, 3)
    position = Document("file:///t.sbt", text).position_at(problem.start)
    assert (position.line, position.character) == (2, 2)


def test_incremental_changes_apply_in_order_whatever_the_line_breaks() -> None:
    document = Document("file:///t.sbt", '<sq>\n  <a>(Say, text="a\u2028b")\n<e>\n')
    change = lsp.TextDocumentContentChangePartial(
        range=lsp.Range(start=lsp.Position(2, 0), end=lsp.Position(2, 3)), text="<e> # done"
    )
    whole = lsp.TextDocumentContentChangeWholeDocument(text="<a>(X)")
    document.apply([change], 2)
    assert document.text.endswith("<e> # done\n") and document.version == 2
    document.apply([whole, change], 3)
    assert document.text == "<a>(X)<e> # done"  # past the last line: the end, as LSP says


@pytest.mark.parametrize(
    ("text", "code", "underlined"),
    [
        ("<sq><a>(Fly)<e>", "SBT306", "Fly"),
        ("<sq><c>(!Hovering)<a>(Push)<e>", "SBT305", "Hovering"),
        ("<sq><a>(TurnHandle, degrees=600)<e>", "SBT310", "<a>(TurnHandle, degrees=600)"),
        ("<sq><a>(Push, force=1)<e>", "SBT311", "<a>(Push, force=1)"),
        ("<sq><e>", "SBT302", "<sq>"),
        ("<sq><a>(Push)<e><e>", "SBT105", "<e>"),
        ("<sq><a>(Push)", "SBT104", ""),
        ("<sq><a>(Push)<e> <a>(Push)", "SBT106", "<a>"),
        ("<sq> & <e>", "SBT101", "&"),
        ("<sq><k>(a)<e><k>(a)<e><e>", "SBT304", "<k>(a)"),
        ("<neg><a>(Push)<a>(Push)<e>", "SBT301", "<neg>"),
    ],
)
def test_each_problem_underlines_its_token_head_or_name(
    text: str, code: str, underlined: str
) -> None:
    problems = [p for p in check(text, DOOR.registry).problems if p.error.code.value == code]
    assert problems, check(text, DOOR.registry).problems
    problem = problems[-1]
    assert text[problem.start : problem.end] == underlined
    assert not problem.warning


def test_a_thousand_problems_at_most_each_placed_in_constant_time() -> None:
    # 50,000 unknown actions on 50,000 lines: placing each by walking the lines from the
    # start would take minutes; the editor gets the first thousand at once.
    text = "<sq>\n" + "<a>(Fly)\n" * 50_000 + "<e>\n"
    problems = check(text, DOOR.registry).problems
    assert len(problems) == MAX_PROBLEMS
    assert [text[p.start : p.end] for p in problems[-2:]] == ["Fly", "Fly"]
    assert Document("file:///t.sbt", text).position_at(problems[-1].start).line == MAX_PROBLEMS


def test_the_rerun_trap_is_a_warning_at_the_action_that_runs_again() -> None:
    (problem,) = check(FLAT, DOOR.registry).problems
    assert problem.error.code.value == "SBT502" and problem.warning
    assert FLAT[problem.start : problem.end] == "<a>(GraspHandle)"


def test_formatting_gives_the_pretty_form_in_runs_of_lines_and_keeps_comments() -> None:
    text = "<sl>  # the root\n<sq><c>(A) <a>B<e>\n    <a>(C)\n# the end\n<e>"
    edits = format_edits(text)
    formatted = apply(text, edits)
    assert formatted == format_tree(parse(text))
    assert "# the root" in formatted and "# the end" in formatted
    assert format_edits(formatted) == []
    assert format_edits("<sq><a>(") == []  # a text that does not parse is left as it is
    # A range formats the runs of lines it touches, and only those.
    in_range = apply(text, format_edits(text, (1, 1)))
    assert in_range.splitlines()[0] == "<sl>  # the root"
    assert "    <sq>\n        <c>(A)\n        <a>(B)\n    <e>\n" in in_range
    assert format_tree(parse(in_range)) == formatted


def test_the_memory_form_fix_wraps_the_actions_and_removes_the_warning() -> None:
    (problem,) = check(FLAT, DOOR.registry).problems
    fix = memory_form(FLAT, problem.error)
    assert fix is not None and apply(FLAT, fix.edits) == MEMORY
    pretty = format_tree(parse(FLAT))
    (problem,) = check(pretty, DOOR.registry).problems
    fix = memory_form(pretty, problem.error)
    assert fix is not None
    fixed = apply(pretty, fix.edits)
    assert fixed == format_tree(parse(MEMORY))  # one node a line, still
    assert check(fixed, DOOR.registry).problems == []


def test_the_missing_e_fix_closes_every_open_node_at_its_indentation() -> None:
    text = "<sl>\n    <sq>\n        <a>(Push)"
    fix = close_open_nodes(text)
    assert fix is not None
    assert apply(text, fix.edits) == "<sl>\n    <sq>\n        <a>(Push)\n    <e>\n<e>\n"
    assert close_open_nodes("<sq><a>(Push") is None  # no <e> makes that parse: no fix


def _complete(text: str, known: Known | None = DOOR) -> list[tuple[str, str, str]]:
    items = assist.complete(text, read(text), len(text), known)
    return [(i.label, i.insert, text[i.start : i.end]) for i in items]


def test_completion_offers_what_may_stand_where_the_cursor_is() -> None:
    tags = _complete("<sl>\n    <sq>\n        <c>(DoorClosed)\n        <")
    assert tags[0] == ("<e>", "<e>", "<")  # a container is open: its <e> first
    assert {"<sq>", "<msq>", "<k>", "<tt1>"} <= {label for label, _, _ in tags}
    assert "<e>" not in {label for label, _, _ in _complete("<sq><a>(Push)<e>\n")}
    assert _complete("<sq><a>(") == [
        ("GraspHandle", "GraspHandle", ""),
        ("Push", "Push", ""),
        ("TurnHandle", "TurnHandle", ""),
    ]
    # Every name, over the word typed: the client filters them by it.
    assert ("HandleSeen", "HandleSeen", "Han") in _complete("<sq><c>(!Han")
    assert ("DoorClosed", "(DoorClosed)", "") in _complete("<sq><c>")
    assert _complete("<sq><a>(TurnHandle, ") == [("degrees", "degrees=", "")]
    assert _complete('<sq><c>(HandleSeen, side="l') == [
        ('"left"', '"left"', '"l'),
        ('"right"', '"right"', '"l'),
    ]
    assert _complete("<sq> # <") == []
    assert _complete("<sq><a>(", known=None) == []  # no vocabulary: no names to offer
    (argument,) = assist.complete("<a>(TurnHandle, ", read("<a>(TurnHandle, "), 16, DOOR)
    assert argument.detail == "degrees: int, 1 <= degrees <= 90"


def test_hover_says_what_a_word_means() -> None:
    text = (
        '<sl>\n  <k>(new)\n    <sq><c>(HandleSeen, side="left")<a>(TurnHandle, degrees=3)<e>\n'
        "  <e>\n<e>"
    )
    outline = read(text)

    def said(word: str, known: Known | None = DOOR) -> str:
        found = assist.hover(text, outline, text.index(word) + 1, known)
        assert found is not None, word
        return found.markdown

    assert "Selector (fallback), reactive" in said("<sl>")
    assert "segment of knowledge learned from other robots" in said("new")
    assert "1 sequence now" in said("new")
    turn = said("TurnHandle")
    assert "action TurnHandle(degrees: int, 1 <= degrees <= 90)" in turn
    assert "30 degrees a tick" in turn
    assert said("degrees") == "argument `degrees: int, 1 <= degrees <= 90`"
    assert "no vocabulary is configured" in said("TurnHandle", known=None)


def test_outline_folds_and_tokens_follow_a_text_being_typed() -> None:
    text = '<sl>\n  <k>(new)\n    <sq><c>(HandleSeen, side="left")\n      <a>(Push)'
    document = Document("file:///t.sbt", text)
    outline = read(text)
    (root,) = navigation.symbols(document, outline)
    assert root.name == "<sl>" and root.children is not None
    (placeholder,) = root.children
    assert placeholder.detail == "placeholder, 1 item"
    assert placeholder.children is not None and placeholder.children[0].name == "item HandleSeen"
    closed = text + "\n    <e>\n  <e>\n<e>\n"
    folds = navigation.folding_ranges(Document("file:///t.sbt", closed), read(closed))
    assert [(f.start_line, f.end_line) for f in folds] == [(0, 6), (1, 5), (2, 4)]
    data = navigation.semantic_tokens(document, outline)
    assert data is not None
    kinds = [navigation.TOKEN_TYPES[data[i + 3]] for i in range(0, len(data), 5)]
    assert kinds == [
        "keyword", "keyword", "namespace", "keyword", "keyword", "variable", "parameter",
        "string", "keyword", "function",
    ]  # fmt: skip


def test_definitions_lead_to_the_vocabulary_file_or_the_python_code(tmp_path: Path) -> None:
    vocabulary = tmp_path / "door.toml"
    vocabulary.write_text(VOCABULARY, encoding="utf-8")
    from_file = Known(read_vocabulary(vocabulary), "door.toml", vocabulary)
    assert from_file.definition("action", "TurnHandle") == (vocabulary, 16)
    assert VOCABULARY.splitlines()[16] == "[actions.TurnHandle]"
    path, line = Known(door_registry(), "door").definition("action", "TurnHandle") or (None, 0)
    assert path == ROOT / "tests" / "door_robot.py"
    assert "class TurnHandle" in path.read_text().splitlines()[line]
    assert from_file.definition("action", "Fly") is None


def test_project_settings_are_found_upward_and_refused_in_one_line(tmp_path: Path) -> None:
    (tmp_path / "door.toml").write_text(VOCABULARY, encoding="utf-8")
    (tmp_path / "ktbt.toml").write_text('vocabulary = "door.toml"\n', encoding="utf-8")
    trees = tmp_path / "trees" / "deep"
    trees.mkdir(parents=True)
    project = find_project(trees / "a.sbt")
    assert project is not None and project.vocabulary_file() == tmp_path / "door.toml"
    known, reason = Vocabularies().for_path(trees / "a.sbt")
    assert reason is None and known is not None and known.entry("action", "Push") is not None
    py = tmp_path / "py"
    py.mkdir()
    (py / "pyproject.toml").write_text('[tool.ktbt]\nvocabulary = "gone.toml"\n', "utf-8")
    known, reason = Vocabularies().for_path(py / "a.sbt")
    assert known is None and reason is not None
    assert reason.startswith(f"{py / 'pyproject.toml'} [tool.ktbt]: vocabulary: ")
    (py / "pyproject.toml").write_text("[tool.ktbt]\nvocabulary = 1\ncontrol = 2\n", "utf-8")
    with pytest.raises(ProjectError, match=r"unknown keys \['control'\]"):
        find_project(py)


def test_one_servers_vocabularies_follow_the_files_as_they_change(tmp_path: Path) -> None:
    # What a running server sees: the folders above a document are found once, but every
    # check looks at the files again, so a settings file written nearer, settings changed and a
    # vocabulary changed are all seen at the next keystroke.
    (tmp_path / "door.toml").write_text(VOCABULARY, encoding="utf-8")
    (tmp_path / "ktbt.toml").write_text('vocabulary = "door.toml"\n', encoding="utf-8")
    deep = tmp_path / "trees"
    deep.mkdir()
    vocabularies = Vocabularies()
    first, _ = vocabularies.for_path(deep / "a.sbt")
    assert first is not None and first.entry("action", "Push") is not None
    assert vocabularies.for_path(deep / "a.sbt")[0] is first  # nothing changed: not read again
    (deep / "small.toml").write_text('actions = ["Fly"]\n', encoding="utf-8")
    (deep / "ktbt.toml").write_text('vocabulary = "small.toml"\n', encoding="utf-8")
    nearer, _ = vocabularies.for_path(deep / "a.sbt")
    assert nearer is not None and nearer.entry("action", "Fly") is not None
    assert nearer.entry("action", "Push") is None
    (deep / "small.toml").write_text('actions = ["Hop"]\n', encoding="utf-8")
    os.utime(deep / "small.toml", ns=(1, 1))  # another modification time, however fast
    changed, _ = vocabularies.for_path(deep / "a.sbt")
    assert changed is not None and changed.entry("action", "Hop") is not None
    (deep / "ktbt.toml").unlink()
    assert vocabularies.for_path(deep / "a.sbt")[0] is first  # back to the project's own


def _seen(checked: Checked) -> tuple[object, ...]:
    """All a check says, positions and comments included (which nodes' equality leaves out)."""
    tree = checked.tree
    nodes = [] if tree is None else [(n, n.pos, n.comments) for n, _ in tree.walk()]
    footer = None if tree is None else tree.footer
    problems = [(_said(p.error), p.start, p.end) for p in checked.problems]
    return nodes, footer, problems, [*map(_said, checked.found)], [*map(_said, checked.warnings)]


def _said(error: StringBTError) -> tuple[object, ...]:
    return type(error), error.code, error.message, error.line, error.column


BARE_TAGS = ("<sq>", "<msq>", "<sl>", "<msl>", "<pl>", "<neg>")


def test_a_check_after_an_edit_says_what_checking_the_whole_text_says() -> None:
    # Edits typed into names (where the previous check is reused), into tags (a container's
    # kind swapped), into blanks (the nodes after them moved), into comments, around them and
    # anywhere, one or
    # several per change, chained as an editor sends them: each check from the one before gives
    # the tree, positions, comments and problems that checking the whole new text gives, and
    # the document's lines are those of its new text.
    corpus = fuzz.load_corpus()
    rng = random.Random(1)
    seeds = [FLAT, MEMORY, "<sq>\r\n  <a>(Push) # go\r\n  <c>(!DoorClosed)\r<a>(P)\n<e>\n"]
    seeds += [t for t in corpus.texts + corpus.pieces if len(t) < 3_000]
    seeds += [format_tree(parse(FLAT)), "<k>(door)\n    " + MEMORY + "\n    <a>(Push)\n<e>\n"]
    typed = 'abzAZ_09.!<>(),="# \n\ré😀'
    reused: dict[str, int] = {}
    flat_tree = format_tree(parse(FLAT), "compact")
    for seed, start, end, new in (  # edits inside a leaf, a tag, blanks, and beside them
        ("<sq><a>(trux)<e>", 11, 12, "e"),  # a word that is no name: SBT103
        ("<sq><a>(Push)<e>", 12, 12, "."),
        ("<sq><a>(Push)<e>", 8, 8, "9"),
        ("<sq><c>(!Door)<a>(Push)<e>", 13, 13, "s"),  # the next node moves
        ("<sq><a>(Push)<a>(X)<e>", 11, 11, "x"),  # ... with its problem (SBT306)
        ("<sq><a>(Pus)<a>(X)<e>", 11, 11, "h"),
        ("<sq>\r<a>(Push)\n<e>", 14, 14, "x"),
        ("<sq><a>(Push)<e>", 8, 12, ""),
        (FLAT, FLAT.index("60"), FLAT.index("60") + 1, "9"),  # an argument's value
        (FLAT, FLAT.index("60") + 2, FLAT.index("60") + 2, "0"),  # out of range: SBT310
        (FLAT, FLAT.index("left") + 4, FLAT.index("left") + 4, ")<a>(X"),  # in a string
        (FLAT, FLAT.index("side"), FLAT.index("side") + 1, ""),  # an argument's name
        (FLAT, FLAT.index("(DoorClosed)") + 1, FLAT.index("(DoorClosed)") + 1, "!"),
        ("<sq><c>(!Door, on=true)<e>", 8, 9, ""),
        ("<sq><c>(!Door, on=true)<e>", 21, 22, ""),  # "tru" is no value: SBT103
        ("<sq><w>(5)<a>(Push)<e>", 9, 9, "0"),
        ("<sq><a>(Push, x=1)<e>", 17, 17, ", y=2"),
        ("<sq><a>(Push, x=1)<e>", 17, 17, ") <a>(Y"),  # two leaves now
        ("<sq>\n<a>(Push\n)<e>", 13, 13, "#c"),  # a comment in it: it moves to the next node
        ("<sq><a>(Push)<c>(DoorClosed)<e>", 14, 15, "a"),  # a condition becomes an action
        ("<sq><c>(Push)<a>(DoorClosed)<e>", 5, 6, "a"),  # ... which the vocabulary lacks
        ("<sl><a>(DoorClosed)<a>(Push)<e>", 5, 6, "c"),  # the root is still no item
        ("<sq><a>(DoorClosed)<a>(Push)<e>", 5, 6, "c"),  # it becomes one
        ("<sq><c>(DoorClosed)<a>(Push)<e>", 5, 6, "a"),  # it is no longer one
        ("<sq><a>(DoorClosed)" + FLAT[19:], 5, 6, "c"),  # ... one with the SBT502 trap
        (FLAT, 5, 6, "a"),
        ("<sq><c>(!DoorClosed)<a>(Push)<e>", 5, 6, "a"),  # an action is never negated
        ("<sq><w>(5)<a>(Push)<e>", 6, 6, "t"),  # seconds: the leaf after it would move
        ("<sq><w>(5)\n<a>(Push)<e>", 6, 6, "t"),
        ("<sq><a>(Push)<e>", 5, 6, "k"),  # SBT102
        ("<sq><a>(Push)<e>", 2, 3, "l"),  # a sequence becomes a selector
        ("<sq><a>(Push)<e>", 1, 1, "m"),  # ... a memory sequence, the leaf after it moves
        ("<sq><a>(Push)<e>", 1, 3, "neg"),  # ... an inverter: one child, so still valid
        ("<sq><a>(Push)<a>(Pull)<e>", 1, 3, "neg"),  # SBT301
        ("<sl><c>(DoorClosed)<a>(Push)<e>", 2, 3, "q"),  # the root becomes an item
        ("<sl>" + FLAT[4:], 2, 3, "q"),  # ... with the SBT502 trap
        (FLAT, 2, 3, "l"),  # ... and is no longer one
        ("<sq><c>(DoorClosed)<msl><a>(Push)<e><e>", 20, 21, ""),  # flat: the SBT502 trap
        ("<pl>(1)<a>(Push)<e>", 1, 3, "sq"),  # a threshold after a sequence: SBT103
        ("<pl> (1)<a>(Push)<e>", 2, 3, "x"),  # SBT102
        ("<sq><a>(Push)<e>", 14, 15, "k"),  # the <e>: not a container's tag
        ("<Root><sq><a>(Push)<e>", 8, 9, "l"),
        ("<sq>\t<a>(Push) # go\n<e>", 4, 4, " "),  # blanks: the leaf moves, not its comment
        ("<sq> <a>(Push)  <a>(X) # go\n<e>", 15, 16, ""),  # SBT306 moves
        ("<sq> <a>(Push) <a>(X) # go\n<e>", 14, 15, ""),  # a run of blanks gone
        ("<sq> <a>(Push) <a>(X)\n<e>", 4, 4, "  "),  # at a token's end: the run grows
        ("<sq> <a>(Push)\n  <a>(X)\n<e>", 15, 15, "\t"),  # at the line's start
        ("<sq> <a>(Push)\n  <a>(X)\n<e>", 15, 17, ""),  # the indentation gone
        ("<sq> <a>(Push)\n  <a>(X)\n<e>", 16, 17, "   "),
        ('<sq><a>(Push, s="a b")<e>', 18, 18, " "),  # in a string: the leaf's
        ('<sq><a>(Push, s="a b")<a>(X)<e>', 18, 18, " "),  # the leaf after it moves
        ('<sq><a>(Push, s="a b")<a>(X)<e>', 18, 19, ""),
        ("<sq><a>(Push) # a b\n<e>", 17, 17, " "),  # in a comment
        ("<sq><a>(Push) # a b\n<e>", 17, 18, ""),
        ("<sq><a>(Push) # a  b\n<e>", 17, 18, ""),
        ("<sq><a>(Push) #  b\n<e>", 15, 16, ""),  # one blank after the "#" is not its text
        ("<sq><a>(Push) # a \n<e>", 18, 18, " "),  # at a comment's end
        ("<sq><a>(Push) <e>", 13, 13, " "),  # between two tokens
        ("<sq><a>Push <e>", 11, 11, " "),
        ("<sq><a>Push<e>", 11, 11, " "),
        ("<sq><c> !Door<e>", 7, 8, ""),
        ("<sq><w> 5<e>", 7, 8, ""),
        ("<sq> <a>(Push) <a>(X) # go\n<e>", 14, 14, "\n"),  # the comment would lead the <e>
        ("<sq> <a>(Push)\n<a>(X) # go\n<e>", 14, 15, " "),
        ("<sq> <a>(Push)\n# go\n<a>(X)\n<e>", 14, 15, ""),  # ... would trail the leaf
        ("<sq> <a>(Push) # go\n<a>(X)\n<e>", 19, 20, ""),  # ... would hide the leaf
        ("<sq> <a>(Push)\n\n  <a>(X)\n<e>", 14, 16, " "),  # lines joined
        ("<sq> <a>(Push)  <a>(X)\n<e>", 15, 15, "\n"),  # a line broken, SBT306 moves
        ("<sq> <a>(Push,  x=1)<a>(Y)\n<e>", 15, 15, "\r\n"),  # in a leaf, which spans lines
        ("<sq>\n# go\n  <a>(Push)\n<e>", 10, 10, "\n  "),  # an empty line under the comment
        ("<sq><a>(Push)<e>\n# end\n", 16, 16, "\n"),  # before the footer
        (flat_tree, flat_tree.index("<a>"), flat_tree.index("<a>"), "\n"),
        (flat_tree, 0, 0, " "),
        ("# a\n<sq> # b\n  # c\n  <a>(Push) # d\n  # e\n<e> # f\n# g\n", 2, 3, "x"),  # leading
        ("# a\n<sq> # b\n  # c\n  <a>(Push) # d\n  # e\n<e> # f\n# g\n", 11, 11, "x"),
        ("# a\n<sq> # b\n  # c\n  <a>(Push) # d\n  # e\n<e> # f\n# g\n", 16, 17, "xy"),
        ("# a\n<sq> # b\n  # c\n  <a>(Push) # d\n  # e\n<e> # f\n# g\n", 33, 34, ""),
        ("# a\n<sq> # b\n  # c\n  <a>(Push) # d\n  # e\n<e> # f\n# g\n", 39, 40, "e e"),
        ("# a\n<sq> # b\n  # c\n  <a>(Push) # d\n  # e\n<e> # f\n# g\n", 47, 47, "f"),
        ("# a\n<sq> # b\n  # c\n  <a>(Push) # d\n  # e\n<e> # f\n# g\n", 51, 52, "h"),  # footer
        ("# a\n<sq> # b\n  # c\n  <a>(Push) # d\n  # e\n<e> # f\n# g\n", 1, 1, " "),
        ("<sq> # b\n<a>(Push) # b\n<e>", 7, 7, "x"),  # two alike: which one?
        ("<sq> # b\n<a>(Push) # b\n<e>", 21, 21, "x"),
        ("<Root> # b\n<sq> # b\n<a>(Push)\n<e>", 9, 9, "x"),  # ... the tree drops one
        ("<sq> # b\n<a>(Push)\n<e>\n# c\n", 23, 23, "x"),  # typed before a comment
        ('<sq> # b\n<a>(Push, s="#") # c\n<e>', 7, 7, "x"),  # a "#" in a string
        ("<Root> # r\n<sq> # b\n<a>(Push)\n<e>", 9, 10, "s"),  # a comment the tree drops
        ("<Root> # r\n<sq> # b\n<a>(Push)\n<e>", 18, 18, "s"),
        ("<sq><a>(Push, # in\n x=1)<a>(X)\n<e>", 17, 18, "out"),  # it leads the next leaf
        ("<sq> # b # c\n<a>(Push)\n<e>", 7, 7, "x"),
        ("<sq> # b\n<a>(Push)\n<e>", 6, 8, ""),  # no text left
        ("<sq> # b\n<a>(Push)\n<e>", 5, 6, ""),  # the "#" gone: all read
        (flat_tree, 4, 4, "\t "),
    ):
        document = Document("file:///t.sbt", seed)
        previous = check(seed, DOOR.registry, None, document.take_edits())
        where = lsp.Range(start=document.position_at(start), end=document.position_at(end))
        document.apply([lsp.TextDocumentContentChangePartial(range=where, text=new)], 1)
        checked = check(document.text, DOOR.registry, previous, document.take_edits())
        assert _seen(checked) == _seen(check(document.text, DOOR.registry)), document.text
        reused[checked.by] = reused.get(checked.by, 0) + 1
    for seed in seeds:
        for registry in (DOOR.registry, None):
            document = Document("file:///t.sbt", seed)
            previous = check(seed, registry, None, document.take_edits())
            for _ in range(12):
                changes = []
                for _ in range(rng.choice((1, 1, 1, 2))):
                    text = document.text
                    names = [i for i, ch in enumerate(text) if ch.isalnum() or ch == "_"]
                    tags = [i for i in range(len(text)) if text.startswith(BARE_TAGS, i)]
                    blanks = [i for i, ch in enumerate(text) if ch in " \t\n"]
                    roll = rng.random()
                    if tags and roll < 0.15:  # a tag changed, a letter of it or all of it
                        start = rng.choice(tags)
                        end = text.index(">", start) + 1
                        new = rng.choice(BARE_TAGS)
                        if rng.random() < 0.5:
                            start, end = start + 1, end - 1
                            new = new[1:-1]
                    elif blanks and roll < 0.35:  # blanks typed or deleted beside blanks
                        start = rng.choice(blanks) + rng.choice((-1, 0, 0, 1))
                        start = min(max(start, 0), len(text))
                        end = min(len(text), start + rng.choice((0, 0, 1, 2)))
                        size = rng.choice((0, 1, 1, 3))
                        new = "".join(rng.choice(" \t \n\r") for _ in range(size))
                    elif "#" in text and roll < 0.5:  # a letter typed into a comment or deleted
                        start = text.index("#", rng.randrange(text.index("#") + 1))
                        start = min(len(text), start + rng.choice((1, 2, 3, 5)))
                        end = start + rng.choice((0, 1)) if start < len(text) else start
                        new = (
                            rng.choice(typed[:9] + " ")
                            if start == end or rng.random() < 0.6
                            else ""
                        )
                    elif names and roll < 0.75:  # a letter typed, changed or deleted
                        start = rng.choice(names) + rng.choice((0, 1))
                        end = start + rng.choice((0, 1)) if start < len(text) else start
                        new = rng.choice(typed[:9]) if start == end or rng.random() < 0.7 else ""
                    else:  # anything anywhere
                        start = rng.randrange(len(text) + 1)
                        end = min(len(text), start + rng.choice((0, 1, 2)))
                        new = "".join(rng.choice(typed) for _ in range(rng.choice((0, 1, 2))))
                    first, last = document.position_at(start), document.position_at(end)
                    changes.append(
                        lsp.TextDocumentContentChangePartial(
                            range=lsp.Range(start=first, end=last), text=new
                        )
                    )
                    document.apply(changes[-1:], document.version + 1)
                fresh = Document("file:///t.sbt", document.text)
                assert [fresh.line_text(i) for i in range(fresh.line_count)] == [
                    document.line_text(i) for i in range(document.line_count)
                ]
                for offset in range(0, len(document.text) + 1, 7):
                    position = document.position_at(offset)
                    assert position == fresh.position_at(offset)
                    assert document.offset_at(position) == fresh.offset_at(position)
                checked = check(document.text, registry, previous, document.take_edits())
                whole = check(document.text, registry)
                assert _seen(checked) == _seen(whole), (seed, document.text)
                reused[checked.by] = reused.get(checked.by, 0) + 1
                previous = checked
                if checked.tree is None:  # start again from the seed, which parses
                    document = Document("file:///t.sbt", seed)
                    previous = check(seed, registry, None, document.take_edits())
    # Typing into a comment, letter by letter, reuses the check before each time.
    text = "<sq> # b\n  <a>(Push)\n<e> # e\n"
    document = Document("file:///t.sbt", text)
    previous = check(text, DOOR.registry, None, document.take_edits())
    for letter in "abc":
        at = document.position_at(document.text.index(" # e") + 4)
        change = lsp.TextDocumentContentChangePartial(
            range=lsp.Range(start=at, end=at), text=letter
        )
        document.apply([change], document.version + 1)
        previous = check(document.text, DOOR.registry, previous, document.take_edits())
        assert previous.by == "comment"
        assert _seen(previous) == _seen(check(document.text, DOOR.registry))
    # Each way of reusing the check before was taken, many times.
    assert min(reused.get(by, 0) for by in ("leaf", "tag", "blanks", "comment")) > 150, reused


def test_the_fuzzers_corpus_goes_through_every_feature_without_an_exception() -> None:
    found = json.loads((ROOT / "tests" / "data" / "fuzz" / "inputs.json").read_text("utf-8"))
    corpus = fuzz.load_corpus()
    rng = random.Random(0)
    texts = [case["input"] for case in found["texts"]]
    texts += [fuzz.next_text(rng, corpus) for _ in range(400)]
    texts += ["\ud800<sq>", "<sq>" * 300, "<" * 50, '"' * 7, "<c>(!", "<a>(X, =, ,)"]
    for text in texts:
        for encoding in (UTF16, UTF8):
            document = Document("file:///t.sbt", text, encoding=encoding)
            checked = check(text, DOOR.registry)
            for problem in checked.problems:
                document.range_of(problem.start, problem.end)
                memory_form(text, problem.error)
            outline = read(text)
            close_open_nodes(text, outline)
            format_edits(text, (0, 3))
            navigation.symbols(document, outline)
            navigation.folding_ranges(document, outline)
            navigation.semantic_tokens(document, outline)
            for offset in range(0, len(text) + 1, max(1, len(text) // 16)):
                assist.complete(text, outline, offset, DOOR)
                assist.hover(text, outline, offset, DOOR)
                navigation.definition(outline, offset, DOOR)


def test_ktbt_lsp_without_the_extra_says_in_one_line_how_to_get_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from typer.testing import CliRunner

    from ktbt_proto.tools.cli import app, load_plugins
    from ktbt_proto.tools.lsp.command import INSTALL

    assert "lsp" in load_plugins()
    monkeypatch.setitem(sys.modules, "ktbt_proto.tools.lsp.server", None)  # as if pygls were not
    result = CliRunner().invoke(app, ["lsp"])
    assert result.exit_code == 2
    assert result.output.strip() == INSTALL
