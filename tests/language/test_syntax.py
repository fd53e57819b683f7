"""The parser: the paper's and the release's texts, errors, limits, and agreement with the
reference (lark) parser over the normative grammar."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ktbt_proto as kp
from ktbt_proto.limits import DEFAULT_LIMITS
from ktbt_proto.syntax import _parse_fast, parse_reference
from ktbt_proto.tree import (
    Inverter,
    Node,
    Parallel,
    Placeholder,
    RunTimer,
    Selector,
    Wait,
    WaitTimer,
    walk,
)
from tests.strategies import SOUP_TOKENS, soup, trees

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

# The paper's algorithm "stringBT for T_Control in the SAR case study", LaTeX stripped, with its
# line breaks and indentation.
PAPER = """<Root>
<sl>
 <sq><c>(_collisionDetectedF)
      <a>(CollisionAvoidance)<e>
 <sq><c>(_waitF)
      <a>(StopWalk)<e>
 <sq><c>(_treasureOnBoardF)
      <sl><sq><c>(_inZoneF)
               <a>(PlaceTreasure)<e>
          <sq><c>(!_inZoneF)
               <a>(WalkToCollection)<e><e><e>
 <a>(RandomWalk)<e>
"""

# The authors' release: its base tree, whitespace removed, with no learned knowledge.
RELEASE = (
    "<sl><sq><c>(_collisionDetectedF)<a>(CollisionAvoidance)<e><sq><c>(_waitF)<a>(StopWalk)<e>"
    "<sq><c>(_treasureOnBoardF)<sl><sq><c>(_inZoneF)<a>(PlaceTreasure)<e><sq><c>(!_inZoneF)"
    "<a>(WalkToCollection)<e><e><e><a>(RandomWalk)<e>"
)


def errors_of(text: str | bytes, **kw: object) -> tuple[str, int, int]:
    with pytest.raises(kp.StringBTError) as info:
        kp.parse(text, **kw)  # type: ignore[arg-type]
    err = info.value
    return err.code.value, err.line, err.column


def test_paper_control_tree_verbatim() -> None:
    tree = kp.parse(PAPER)
    kp.validate(tree)
    root = tree.root
    assert isinstance(root, Selector) and not root.memory
    assert len(root.children) == 4
    collision = root.children[0]
    assert collision == kp.SequenceNode(
        (kp.Condition("_collisionDetectedF"), kp.Action("CollisionAvoidance"))
    )
    assert collision.pos == (3, 2)
    carry = root.children[2]
    assert isinstance(carry, kp.SequenceNode)
    inner = carry.children[1]
    assert isinstance(inner, Selector)
    negated = inner.children[1].children[0]  # type: ignore[attr-defined]
    assert negated == kp.Condition("_inZoneF", negated=True)
    assert root.children[3] == kp.Action("RandomWalk")
    # The release's base tree is the same tree.
    assert kp.parse(RELEASE) == tree


def test_paper_example_file_is_the_paper_tree() -> None:
    assert kp.parse((EXAMPLES / "paper_control.sbt").read_text()) == kp.parse(PAPER)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("<w>5", Wait(5)),
        ("<w>(5)", Wait(5)),
        ("<w> ( 5 )", Wait(5)),
        ("<wt>(0.5)", Wait(0.5, "seconds")),
        ("<wt>2", Wait(2, "seconds")),
        ("<neg><c>(X)<e>", Inverter((kp.Condition("X"),))),
        ("<c>X", kp.Condition("X")),
        ("<c>!X", kp.Condition("X", negated=True)),
        ("<c>( ! X )", kp.Condition("X", negated=True)),
        ("<a>RandomWalk", kp.Action("RandomWalk")),
        ("<pl><a>(A)<a>(B)<e>", Parallel((kp.Action("A"), kp.Action("B")))),
        ("<pl>(1)<a>(A)<a>(B)<e>", Parallel((kp.Action("A"), kp.Action("B")), threshold=1)),
        ("<msq><a>(A)<e>", kp.SequenceNode((kp.Action("A"),), memory=True)),
        ("<msl><a>(A)<e>", Selector((kp.Action("A"),), memory=True)),
        ("<tt1>(1000)<a>(A)<e>", WaitTimer((kp.Action("A"),), ticks=1000)),
        ("<tt2>(10)<a>(A)<e>", RunTimer((kp.Action("A"),), ticks=10)),
        ("<k>(new)<e>", Placeholder((), name="new")),
        (
            '<a>(MoveTo, x=1, y=-2.5e1, label="a\\"b", fast=true)',
            kp.Action("MoveTo", (("x", 1), ("y", -25.0), ("label", 'a"b'), ("fast", True))),
        ),
        ("<c>(ns.Seen, colour=2)", kp.Condition("ns.Seen", args=(("colour", 2),))),
        ("<Root><a>(A)", kp.Action("A")),
        ("# c\n<Root> # d\n<a>(A)", kp.Action("A")),
    ],
)
def test_node_spellings(text: str, expected: Node) -> None:
    assert kp.parse(text).root == expected
    assert parse_reference(text).root == expected


def test_values_keep_their_type() -> None:
    args = kp.parse("<a>(F, i=1, f=1.0, b=true)").root.args  # type: ignore[attr-defined]
    assert [type(v) for _, v in args] == [int, float, bool]
    assert kp.Action("F", (("x", 1),)) != kp.Action("F", (("x", 1.0),))
    assert kp.Action("F", (("x", 1),)) != kp.Action("F", (("x", True),))


def test_bytes_input_and_bad_utf8() -> None:
    assert kp.parse('<a>(Gehen, w="ü")'.encode()).root == kp.Action("Gehen", (("w", "ü"),))
    assert errors_of(b"<sq>\n  <a>(X)\xff<e>") == ("SBT100", 2, 9)


@pytest.mark.parametrize(
    ("text", "code", "line", "column"),
    [
        ("", "SBT107", 1, 1),
        ("  # only a comment\n", "SBT107", 2, 1),
        ("<sq><a>(X)", "SBT104", 1, 11),
        ("<Root>", "SBT104", 1, 7),
        ("<e>", "SBT105", 1, 1),
        ("<a>(X)\n<e>", "SBT105", 2, 1),
        ("<a>(X) <a>(Y)", "SBT106", 1, 8),
        ("<sq>\n  <foo>", "SBT102", 2, 3),
        ("<sq> $", "SBT101", 1, 6),
        ("<c>(true)", "SBT103", 1, 5),
        ("<c>(X <e>", "SBT103", 1, 7),
        ("<a>(X, y=)", "SBT103", 1, 10),
        ("<a>(X, y=1,)", "SBT103", 1, 12),
        ("<tt1><a>(X)<e>", "SBT103", 1, 6),
        ("<k>()<e>", "SBT103", 1, 5),
        ("<sq><Root><e>", "SBT103", 1, 5),
        ("<w>(x)", "SBT103", 1, 5),
    ],
)
def test_errors_have_code_and_position(text: str, code: str, line: int, column: int) -> None:
    assert errors_of(text) == (code, line, column)
    with pytest.raises(kp.StringBTError) as ref:
        parse_reference(text)
    assert (ref.value.code.value, ref.value.line, ref.value.column) == (code, line, column)


def test_error_message_has_caret_excerpt() -> None:
    with pytest.raises(kp.ParseError) as info:
        kp.parse("<sl>\n    <a>(X, y=)\n<e>")
    text = str(info.value)
    assert text.splitlines() == [
        "2:14: SBT103 unexpected ), expected a number, a string, true or false",
        "        <a>(X, y=)",
        "                 ^",
    ]


def test_unclosed_names_the_opener() -> None:
    with pytest.raises(kp.ParseError, match=r"inside <sq> opened at 2:5"):
        kp.parse("<sl>\n    <sq><a>(X)\n")


def test_hundred_thousand_nested_sequences_are_refused_quickly() -> None:
    text = "<sq>" * 100_000 + "<a>(X)" + "<e>" * 100_000
    started = time.perf_counter()
    assert errors_of(text) == ("SBT202", 1, 128 * 4 + 1)
    assert time.perf_counter() - started < 30  # a hang guard, not a benchmark


@pytest.mark.slow
def test_deep_trees_within_raised_limits_need_no_recursion() -> None:
    depth = 20_000
    limits = kp.Limits(max_depth=depth + 1)
    text = "<neg>" * depth + "<a>(X)" + "<e>" * depth
    tree = kp.parse(text, limits=limits)
    assert sum(1 for _ in walk(tree.root)) == depth + 1
    kp.validate(tree, limits=limits)
    assert kp.format_tree(tree, "compact") == text
    assert kp.format_tree(tree).count("\n") == 2 * depth + 1
    ref = parse_reference(text, limits=limits)
    assert kp.format_tree(ref, "compact") == text


@pytest.mark.parametrize(
    ("limits", "text", "code"),
    [
        (kp.Limits(max_size=10), "<a>(Xxxxxxxxxx)", "SBT201"),
        (kp.Limits(max_nodes=3), "<sq><a>(A)<a>(B)<a>(C)<e>", "SBT203"),
        (kp.Limits(max_literal=4), "<a>(Abcde)", "SBT204"),
        (kp.Limits(max_literal=4), '<a>(A, s="abcd")', "SBT204"),
        (kp.Limits(max_depth=2), "<sq><sq><a>(A)<e><e>", "SBT202"),
    ],
)
def test_limits(limits: kp.Limits, text: str, code: str) -> None:
    assert errors_of(text, limits=limits)[0] == code
    with pytest.raises(kp.LimitError):
        kp.parse(text, limits=limits)


def test_limits_come_before_syntax_errors() -> None:
    # Stage order: lexing, then limits, then syntax (spec, "Errors").
    assert errors_of("<sq><sq><sq> ) $", limits=kp.Limits(max_depth=2))[0] == "SBT101"
    assert errors_of("<sq><sq><sq> ) )", limits=kp.Limits(max_depth=2))[0] == "SBT202"


def test_pathological_blanks_do_not_backtrack() -> None:
    started = time.perf_counter()
    for text in ("<c>(" + " " * 200_000 + "!", "<a>(X" + "#" * 200_000, "<c>(X," + " \n" * 99_999):
        with pytest.raises(kp.ParseError):
            kp.parse(text)
    assert time.perf_counter() - started < 30  # a hang guard, not a benchmark


def _outcome(fn: object, text: str) -> object:
    try:
        return fn(text)  # type: ignore[operator]
    except kp.StringBTError as err:
        return (type(err).__name__, err.code, err.line, err.column)


@pytest.mark.slow
@settings(max_examples=400, deadline=None)
@given(soup())
def test_agrees_with_reference_on_token_soup(text: str) -> None:
    ours, ref = _outcome(kp.parse, text), _outcome(parse_reference, text)
    assert ours == ref
    if isinstance(ref, kp.Tree):
        assert _parse_fast(text, DEFAULT_LIMITS) is not None, "fast path refused valid text"


@st.composite
def mutated(draw: st.DrawFn) -> str:
    """A formatted random tree with one random edit: near-valid input, where parsers differ."""
    text = kp.format_tree(draw(trees()), draw(st.sampled_from(["pretty", "compact"])))
    at = draw(st.integers(0, len(text)))
    edit = draw(st.sampled_from(["delete", "insert", "replace"]))
    token = draw(st.sampled_from(SOUP_TOKENS))
    if edit == "delete":
        return text[:at] + text[at + draw(st.integers(1, 4)) :]
    if edit == "insert":
        return text[:at] + token + text[at:]
    return text[:at] + token + text[at + len(token) :]


@pytest.mark.slow
@settings(max_examples=400, deadline=None)
@given(mutated())
def test_agrees_with_reference_on_mutated_trees(text: str) -> None:
    ours, ref = _outcome(kp.parse, text), _outcome(parse_reference, text)
    assert ours == ref
    if isinstance(ref, kp.Tree):
        assert _parse_fast(text, DEFAULT_LIMITS) is not None, "fast path refused valid text"


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(trees(with_comments=True), st.sampled_from(["pretty", "compact"]))
def test_agrees_with_reference_on_formatted_trees(tree: Node, style: str) -> None:
    text = kp.format_tree(tree, style)  # type: ignore[arg-type]
    fast = _parse_fast(text, DEFAULT_LIMITS)
    assert fast is not None
    assert fast == parse_reference(text) == kp.Tree(tree)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("<a>(X, n=" + "9" * 5000 + ")", ("SBT204", 1, 10)),  # a literal over the limit
        ("<w>(" + "1" * 3000 + ")", ("SBT204", 1, 5)),
        ("\x00", ("SBT101", 1, 1)),
        ("<" * 1000, ("SBT101", 1, 1)),
        ("(" * 1000, ("SBT103", 1, 1)),
        ("<sq>" * 200 + "<e>" * 300, ("SBT202", 1, 128 * 4 + 1)),  # deeper than the depth limit
    ],
    ids=["long-number", "long-wait", "nul", "angles", "parens", "deep-nesting"],
)
def test_hostile_text_is_one_positioned_error(text: str, expected: tuple[str, int, int]) -> None:
    assert errors_of(text) == expected


LEAF_TAILS = [".", "..", ".5", ".1e", ". ", ".x", ".x.", ".e1", "5", "_", "x", "", ")", "(", "<e>"]


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("<c>true.5", ("SBT101", 1, 8)),
        ("<sq><c>true.5<e>", ("SBT101", 1, 12)),
        ("<a>false.1e", ("SBT101", 1, 9)),
        ("<a>true. ", ("SBT101", 1, 8)),
    ],
)
def test_a_bool_read_as_a_leaf_name_is_a_positioned_error(
    text: str, expected: tuple[str, int, int]
) -> None:
    """``true`` before a ``.`` is a name (the grammar's BOOL looks ahead), and what follows the
    name is then the error: the fast parser's leaf must see that context as its scanner did."""
    assert errors_of(text) == expected
    assert errors_of(text.encode()) == expected


@pytest.mark.parametrize("tag", ["<c>", "<c>!", "<a>", "<c> ", "<a>\n", "<w>", "<c>(", "<a>("])
def test_agrees_with_reference_next_to_a_bool_after_a_leaf_tag(tag: str) -> None:
    """Every leaf tag, then ``true`` or ``false``, then each tail, bare and in a container:
    the same tree or the same error as the grammar, and never an exception of another kind."""
    for word in ("true", "false", "trueX", "true_1"):
        for tail in LEAF_TAILS:
            leaf = tag + word + tail
            for text in (leaf, f"<sq>{leaf}<e>", f"<sq>{leaf}<a>(B)<e>"):
                assert _outcome(kp.parse, text) == _outcome(parse_reference, text), text


def test_a_lone_surrogate_escape_is_kept_escaped() -> None:
    assert kp.format_tree(kp.parse('<a>(X, s="\\ud800")'), "compact") == '<a>(X,s="\\ud800")'


def test_byte_order_mark_is_not_text() -> None:
    assert kp.parse("\ufeff<a>(X)").root == kp.Action("X")
    assert kp.parse(b"\xef\xbb\xbf<a>(X)").root == kp.Action("X")
    assert kp.parse(bytearray(b"<a>(X)")).root == kp.Action("X")  # type: ignore[arg-type]
