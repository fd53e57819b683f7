"""Merging knowledge into placeholders: where it lands, deduplication, conflicts, sharing."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ktbt_proto as kp
from ktbt_proto.errors import ErrorCode
from ktbt_proto.items import read_sequence
from ktbt_proto.merge import find_placeholder
from ktbt_proto.tree import Node, Placeholder, Selector, walk
from tests.strategies import names, trees
from tests.tools.test_cli import ktbt

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
CONTROL = kp.parse((EXAMPLES / "sar_control.sbt").read_text())
SKILL = kp.parse("<sq><a>(PickTreasure)<a>(AssignCollectionPoint, colour=2)<e>")


def slot(tree: kp.Tree, name: str) -> Placeholder:
    path = find_placeholder(tree, name)
    assert path is not None
    node: Node = tree.root
    for i in path:
        node = node.children[i]  # type: ignore[attr-defined]
    assert isinstance(node, Placeholder)
    return node


def test_item_is_sequence_of_conditions_then_subtree_appended_last() -> None:
    first = kp.merge(CONTROL, SKILL, "new", when=["TargetSeen(colour=2)"])
    second = kp.merge(first, kp.parse("<a>(PickTreasure)"), "new", when=["TargetSeen(colour=3)"])
    items = slot(second, "new").children
    assert items == (
        kp.SequenceNode((kp.Condition("TargetSeen", args=(("colour", 2),)), SKILL.root)),
        kp.SequenceNode(
            (kp.Condition("TargetSeen", args=(("colour", 3),)), kp.Action("PickTreasure"))
        ),
    )
    kp.validate(second)


def test_merge_shares_untouched_subtrees_and_leaves_the_original_alone() -> None:
    before = kp.format_tree(CONTROL, "compact")
    merged = kp.merge(CONTROL, SKILL, "new", when=["X"])
    assert kp.format_tree(CONTROL, "compact") == before
    old_root, new_root = CONTROL.root, merged.root
    assert isinstance(old_root, Selector) and isinstance(new_root, Selector)
    same = [a is b for a, b in zip(old_root.children, new_root.children, strict=True)]
    assert same == [True, True, True, True, False, True]
    assert merged.root.children[0].comments == CONTROL.root.children[0].comments  # type: ignore[attr-defined]


def test_same_knowledge_twice_changes_nothing() -> None:
    once = kp.merge(CONTROL, SKILL, "new", when=["TargetSeen(colour=2)"])
    assert kp.merge(once, SKILL, "new", when=["TargetSeen(colour=2)"]) is once


def test_conflicting_answer_is_refused() -> None:
    once = kp.merge(CONTROL, SKILL, "new", when=["TargetSeen(colour=2)"])
    with pytest.raises(kp.MergeError) as info:
        kp.merge(once, kp.parse("<a>(RandomWalk)"), "new", when=["TargetSeen(colour=2)"])
    assert info.value.code is ErrorCode.KNOWLEDGE_CONFLICT


def test_unknown_slot() -> None:
    with pytest.raises(kp.MergeError) as info:
        kp.merge(CONTROL, SKILL, "learned")
    assert info.value.code is ErrorCode.UNKNOWN_SLOT


def test_without_when_the_subtree_is_the_item() -> None:
    item = kp.parse("<sq><c>(A)<a>(B)<e>")
    merged = kp.merge(CONTROL, item, "prior")
    assert slot(merged, "prior").children[-1] == item.root


def test_conditions_from_text() -> None:
    assert read_sequence('A, !B,C(x=1, s="a,b"), D( y = true )') == (
        kp.Condition("A"),
        kp.Condition("B", negated=True),
        kp.Condition("C", args=(("x", 1), ("s", "a,b"))),
        kp.Condition("D", args=(("y", True),)),
    )
    with pytest.raises(kp.StringBTError):
        read_sequence(["A B"])


@st.composite
def control_trees(draw: st.DrawFn) -> kp.Tree:
    body = draw(st.lists(trees(valid=True), min_size=0, max_size=3))
    existing = draw(st.lists(trees(valid=True), max_size=3))
    return kp.Tree(Selector((*body, Placeholder(tuple(existing), name="new"))))


@pytest.mark.slow
@settings(max_examples=150, deadline=None)
@given(control_trees(), trees(valid=True), st.lists(names, min_size=1, max_size=3))
def test_merge_properties(control: kp.Tree, subtree: Node, when: list[str]) -> None:
    try:
        merged = kp.merge(control, subtree, "new", when=when)
    except kp.MergeError as err:
        assert err.code is ErrorCode.KNOWLEDGE_CONFLICT
        return
    item = kp.SequenceNode((*(kp.Condition(n) for n in when), subtree))
    assert item in slot(merged, "new").children
    # Idempotent: merging again is the same tree, compared by canonical form.
    again = kp.merge(merged, subtree, "new", when=when)
    assert kp.format_tree(again, "compact") == kp.format_tree(merged, "compact")
    # Nothing else changed: removing the item gives back the original.
    count = sum(1 for _ in walk(merged.root)) - sum(1 for _ in walk(control.root))
    assert count in (0, sum(1 for _ in walk(item)))


@pytest.mark.network
def test_cli_merge(tmp_path: Path) -> None:
    skill = tmp_path / "skill.sbt"
    skill.write_text("<sq><a>(PickTreasure)<a>(AssignCollectionPoint, colour=2)<e>\n")
    out = tmp_path / "merged.sbt"
    code, stdout, _ = ktbt(
        "merge",
        str(EXAMPLES / "sar_control.sbt"),
        str(skill),
        "--slot",
        "new",
        "--when",
        "TargetSeen(colour=2),!_inZoneF",
        "-o",
        str(out),
    )
    assert (code, stdout) == (0, "")
    merged = kp.parse(out.read_text())
    assert slot(merged, "new").children[0] == kp.SequenceNode(
        (
            kp.Condition("TargetSeen", args=(("colour", 2),)),
            kp.Condition("_inZoneF", True),
            SKILL.root,
        )
    )
    assert "# New knowledge: subtrees learned from other robots are merged here." in out.read_text()
    code, stdout, _ = ktbt(
        "merge", str(EXAMPLES / "sar_control.sbt"), "-", "--compact", stdin=b"<a>(RandomWalk)"
    )
    assert code == 0 and stdout.endswith("<k>(new)<a>(RandomWalk)<e><a>(RandomWalk)<e>\n")
    code, _, err = ktbt("merge", str(EXAMPLES / "sar_control.sbt"), str(skill), "--slot", "nope")
    assert code == 1 and "SBT401" in err
    code, _, err = ktbt("merge", str(EXAMPLES / "sar_control.sbt"), str(skill), "--when", "A B")
    # A mistake in --when is a usage error (exit 2), shown in what the user typed.
    assert code == 2 and "Traceback" not in err
    assert err.splitlines() == [
        "error: --when 'A B': SBT103 expected '(' or ',' after the condition name",
        "    A B",
        "      ^",
    ]


def test_when_as_one_string_is_one_condition() -> None:
    merged = kp.merge(CONTROL, SKILL, "new", when="TargetSeen(colour=2)")
    assert slot(merged, "new").children[0].children[0] == kp.Condition(  # type: ignore[attr-defined]
        "TargetSeen", args=(("colour", 2),)
    )
    with pytest.raises(kp.StringBTError) as raised:
        kp.merge(CONTROL, SKILL, "new", when=[5])  # type: ignore[list-item]
    assert raised.value.code is ErrorCode.UNEXPECTED_TOKEN
