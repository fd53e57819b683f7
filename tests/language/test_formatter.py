"""The formatter: canonical compact form, pretty form with comments, round trips."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ktbt_proto as kp
from ktbt_proto.tree import Comments, Node, Value, walk
from tests.language.test_syntax import PAPER, RELEASE
from tests.strategies import trees

PAPER_PRETTY = """\
<sl>
    <sq>
        <c>(_collisionDetectedF)
        <a>(CollisionAvoidance)
    <e>
    <sq>
        <c>(_waitF)
        <a>(StopWalk)
    <e>
    <sq>
        <c>(_treasureOnBoardF)
        <sl>
            <sq>
                <c>(_inZoneF)
                <a>(PlaceTreasure)
            <e>
            <sq>
                <c>(!_inZoneF)
                <a>(WalkToCollection)
            <e>
        <e>
    <e>
    <a>(RandomWalk)
<e>
"""


def test_paper_tree_compact_is_the_release_string() -> None:
    assert kp.format_tree(kp.parse(PAPER), "compact") == RELEASE


def test_paper_tree_pretty() -> None:
    assert kp.format_tree(kp.parse(PAPER)) == PAPER_PRETTY
    assert kp.format_tree(kp.parse(RELEASE), "pretty") == PAPER_PRETTY


def test_comments_kept_where_written() -> None:
    text = """\
# file header
<sl>  # the root
    #  indented note
    <sq>
        #before c
        <c>(X)  # why X
        <a>(Y, speed=2)
        # last in sq
    <e>  # after sq
    <k>(new)<e>  # learned skills land here
<e>
# footer
"""
    tree = kp.parse(text)
    assert kp.format_tree(tree) == text.replace("#before c", "# before c")
    assert tree.root.comments == Comments(("file header",), "the root")
    seq = tree.root.children[0]  # type: ignore[attr-defined]
    assert seq.comments == Comments((" indented note",), None, ("last in sq",), "after sq")
    assert tree.footer == ("footer",)


def test_comments_inside_parentheses_move_to_the_next_node() -> None:
    text = "<sq>\n<c>(X, # about a\n a=1)\n<a>(Y)<e>"
    assert (
        kp.format_tree(kp.parse(text)) == "<sq>\n    <c>(X, a=1)\n    # about a\n    <a>(Y)\n<e>\n"
    )


def test_compact_has_no_blanks_and_no_comments() -> None:
    text = kp.format_tree(kp.parse("# c\n<sq> <a>( Go , x = 1 ) # t\n<e>"), "compact")
    assert text == "<sq><a>(Go,x=1)<e>"


@pytest.mark.parametrize(
    ("value", "literal"),
    [
        (True, "true"),
        (False, "false"),
        (0, "0"),
        (-7, "-7"),
        (1.0, "1.0"),
        (-0.0, "-0.0"),
        (1e16, "1e+16"),
        (2.5e-7, "2.5e-07"),
        ('a"b\\c\n', '"a\\"b\\\\c\\n"'),
        ("ü", '"ü"'),
    ],
)
def test_value_literals(value: Value, literal: str) -> None:
    node = kp.Action("F", (("v", value),))
    assert kp.format_tree(node, "compact") == f"<a>(F,v={literal})"
    assert kp.parse(kp.format_tree(node, "compact")).root == node


def test_unrepresentable_values_are_refused() -> None:
    with pytest.raises(kp.ValidationError):
        kp.format_tree(kp.Action("F", (("v", float("nan")),)), "compact")
    with pytest.raises(ValueError):
        kp.format_tree(kp.Action("F"), "wide")  # type: ignore[arg-type]


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(trees(), st.sampled_from(["pretty", "compact"]))
def test_round_trip(tree: Node, style: str) -> None:
    text = kp.format_tree(tree, style)  # type: ignore[arg-type]
    assert kp.parse(text).root == tree
    if style == "compact":
        assert "\n" not in text


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(trees(with_comments=True), st.sampled_from(["pretty", "compact"]))
def test_idempotent(tree: Node, style: str) -> None:
    once = kp.format_tree(tree, style)  # type: ignore[arg-type]
    twice = kp.format_tree(kp.parse(once), style)  # type: ignore[arg-type]
    assert twice == once


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(trees(with_comments=True))
def test_pretty_keeps_every_comment(tree: Node) -> None:
    texts: list[str] = []
    for node, _ in walk(tree):
        c = node.comments
        if c is not None:
            texts += [*c.leading, *c.end]
            texts += [t for t in (c.trailing, c.end_trailing) if t is not None]
    reparsed = kp.parse(kp.format_tree(tree))
    found: list[str] = list(reparsed.footer)
    for node, _ in walk(reparsed.root):
        c = node.comments
        if c is not None:
            found += [*c.leading, *c.end]
            found += [t for t in (c.trailing, c.end_trailing) if t is not None]
    norm = sorted(t.strip() for t in texts)
    assert sorted(t.strip() for t in found) == norm


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(trees(), trees())
def test_compact_form_is_a_digest(a: Node, b: Node) -> None:
    assert (kp.format_tree(a, "compact") == kp.format_tree(b, "compact")) == (a == b)


def test_lone_surrogates_stay_escaped_in_the_canonical_form() -> None:
    tree = kp.parse('<a>(X, s="\\ud800")')
    text = kp.format_tree(tree, "compact")
    assert text == '<a>(X,s="\\ud800")'
    text.encode("utf-8")  # a digest can be taken
    assert kp.parse(text) == tree
