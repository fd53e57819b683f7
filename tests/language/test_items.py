"""Knowledge items written the paper's way (flat) and nested, the sequence syntax people type and
read, and `ktbt check`'s warning about placeholder children that are not knowledge
(spec/stringbt.md, section 4; spec/protocol.md, section 1)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ktbt_proto as kp
from ktbt_proto.errors import ErrorCode
from ktbt_proto.exchange.agent import Agent, Timing
from ktbt_proto.exchange.knowledge import KnowledgeBase
from ktbt_proto.interop.knowledge_file import load_knowledge
from ktbt_proto.items import (
    actions_rerun,
    find_warnings,
    read_sequence,
    sequence_key,
    show_sequence,
    split_item,
    stray_nodes,
)
from ktbt_proto.transport import MemoryNetwork
from tests.door_robot import FLAT as DOOR_FLAT
from tests.door_robot import MEMORY as DOOR_MEMORY
from tests.door_robot import door_blackboard, door_registry
from tests.runtime_helpers import Harness
from tests.strategies import names, values

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
VECTORS = json.loads((ROOT / "spec" / "vectors" / "knowledge.json").read_text(encoding="utf-8"))

FLAT = "<sq><c>(TargetSeen, colour=1)<a>(PickTreasure)<a>(AssignCollectionPoint, colour=1)<e>"
NESTED = (
    "<sq><c>(TargetSeen, colour=1)<sq><a>(PickTreasure)<a>(AssignCollectionPoint, colour=1)<e><e>"
)


@pytest.mark.parametrize("case", VECTORS, ids=[c["name"] for c in VECTORS])
def test_knowledge_vectors(case: dict[str, Any]) -> None:
    tree = kp.parse(case["input"])
    items = [
        [k.segment, k.key, kp.format_tree(k.subtree, "compact")]
        for k in KnowledgeBase.from_tree(tree)
    ]
    assert items == case["items"]
    assert [[w.code.value, w.line, w.column] for w in find_warnings(tree)] == case["warnings"]


def test_flat_and_nested_are_the_same_item_but_written_as_they_are() -> None:
    flat, nested = split_item(kp.parse(FLAT).root), split_item(kp.parse(NESTED).root)
    assert flat is not None and flat == nested
    # The canonical form keeps the author's form: fmt never rewrites one into the other.
    assert kp.format_tree(kp.parse(FLAT), "compact") == FLAT.replace(", ", ",")
    assert kp.format_tree(kp.parse(NESTED), "compact") == NESTED.replace(", ", ",")


def test_merge_treats_flat_and_nested_as_one_item() -> None:
    control = kp.parse(f"<sl><k>(new){FLAT}<e><a>(W)<e>")
    same = kp.merge(control, kp.parse(NESTED), "new")
    assert same == control  # unchanged: the placeholder already holds this item
    learned = kp.parse("<sq><a>(PickTreasure)<a>(AssignCollectionPoint, colour=1)<e>")
    assert kp.merge(control, learned, "new", when=["TargetSeen(colour=1)"]) == control
    other = kp.parse("<sq><c>(TargetSeen, colour=1)<a>(PickTreasure)<a>(Drop)<e>")
    with pytest.raises(kp.MergeError) as info:
        kp.merge(control, other, "new")
    assert info.value.code is ErrorCode.KNOWLEDGE_CONFLICT


SCRIPTS = st.lists(st.sampled_from([kp.SUCCESS, kp.FAILURE, kp.RUNNING]), min_size=1, max_size=4)


@settings(max_examples=60, deadline=None)
@given(
    a=SCRIPTS,
    b=SCRIPTS,
    c=SCRIPTS,
    flags=st.lists(st.booleans(), min_size=8, max_size=8),
)
def test_flat_and_nested_tick_alike(
    a: list[kp.Status], b: list[kp.Status], c: list[kp.Status], flags: list[bool]
) -> None:
    """Both sequences are reactive, so the flat item and its nested twin give the same status
    and tick and halt the same leaves, tick after tick (the paper's meaning of the flat form)."""
    runs = []
    for text in (
        "<sl><k>(k)<sq><c>(G)<a>(A)<a>(B)<a>(C)<e><e><a>(W)<e>",
        "<sl><k>(k)<sq><c>(G)<sq><a>(A)<a>(B)<a>(C)<e><e><e><a>(W)<e>",
    ):
        h = Harness()
        h.action("A", *a)
        h.action("B", *b)
        h.action("C", *c)
        h.action("W", kp.RUNNING)
        h.condition("G")
        live = h.live(text)
        steps = []
        for flag in flags:
            h.bb["G"] = flag
            steps.append(h.tick(live))
        runs.append(steps)
    assert runs[0] == runs[1]


def run_door(text: str) -> list[str]:
    """The log of the door robot's item, ticked until it finishes."""
    bb = door_blackboard()
    live = kp.LiveTree(text, door_registry(), bb)
    for _ in range(5):
        if live.tick() is not kp.RUNNING:
            break
    return list(bb["log"])


def test_the_flat_form_runs_earlier_actions_again_and_is_warned_about() -> None:
    """The re-run trap (spec/stringbt.md, section 4.1): while TurnHandle runs, the reactive
    item starts again at its first child, so the handle is grasped twice; the memory form
    grasps once. The warning is given for the one and not for the other."""
    assert run_door(DOOR_FLAT) == ["grasp", "turn 30/60", "grasp", "turn 60/60", "push"]
    assert run_door(DOOR_MEMORY) == ["grasp", "turn 30/60", "turn 60/60", "push"]
    [warning] = actions_rerun(kp.parse(f"<k>(new){DOOR_FLAT}<e>"))
    assert (warning.code, warning.line, warning.column) == (ErrorCode.ACTIONS_RERUN, 1, 56)
    assert warning.message == (
        "<a>(GraspHandle) runs again on every tick while <a>(TurnHandle,degrees=60) is "
        "RUNNING: if it must run once, put the actions in one <msq>...<e> (the memory form)"
    )
    assert [w.column for w in actions_rerun(kp.parse(DOOR_FLAT))] == [48]  # a root item
    assert actions_rerun(kp.parse(f"<k>(new){DOOR_MEMORY}<e>")) == []
    # A warning, not a problem: the flat item stays valid for a peer.
    assert kp.find_problems(kp.parse(DOOR_FLAT), door_registry()) == []


@pytest.mark.parametrize(
    ("text", "columns"),
    [
        ("<k>(k)<sq><c>(A)<a>(X)<e><e>", []),  # one action
        ("<k>(k)<sq><c>(A)<a>(X)<w>(3)<e><e>", [17]),  # a wait may return RUNNING
        ("<k>(k)<sq><c>(A)<a>(X)<tt1>(3)<c>(B)<e><e><e>", [17]),  # so may TT1
        ("<k>(k)<sq><c>(A)<a>(X)<c>(B)<e><e>", []),  # a condition never runs
        ("<k>(k)<sq><c>(A)<sl><a>(X)<a>(Y)<e><e><e>", []),  # a selector's children are not rerun
        ("<k>(k)<sq><c>(A)<sq><a>(X)<a>(Y)<e><e><e>", [21]),  # the nested form ticks the same
        ("<k>(k)<sq><c>(A)<msq><a>(X)<a>(Y)<e><a>(Z)<e><e>", [22]),  # a finished <msq> restarts
        ("<sq><c>(A)<a>(X)<a>(Y)<e>", [11]),  # a root item
        ("<sl><sq><c>(A)<a>(X)<a>(Y)<e><e>", []),  # not knowledge: the control tree's own
        ("<k>(k)<sq><c>(A)<k>(in)<sq><c>(B)<a>(X)<a>(Y)<e><e><e><e>", [34]),  # once, inside
    ],
)
def test_the_rerun_warning_looks_at_what_may_run(text: str, columns: list[int]) -> None:
    assert [w.column for w in actions_rerun(kp.parse(text))] == columns


def sar_vocabulary() -> kp.Registry:
    """The example control tree's vocabulary, with actions that record what they did."""
    reg = kp.Registry()
    reg.flags("_collisionDetectedF", "_waitF", "_treasureOnBoardF", "_inZoneF")

    @reg.condition("TargetSeen")
    def target_seen(bb: kp.Blackboard, colour: int) -> bool:
        return bool(bb.get("target") == colour)

    @reg.action("AssignCollectionPoint")
    def assign(bb: kp.Blackboard, colour: int) -> kp.Status:
        bb["zone"] = colour
        return kp.SUCCESS

    for name in (
        "CollisionAvoidance",
        "StopWalk",
        "PlaceTreasure",
        "WalkToCollection",
        "PickTreasure",
        "RandomWalk",
    ):
        reg.add_action(name, lambda bb: kp.SUCCESS)
    return reg


def test_an_agent_built_on_the_example_knows_red_and_asks_only_for_green() -> None:
    control = (EXAMPLES / "sar_control.sbt").read_text(encoding="utf-8")
    net = MemoryNetwork()
    robot = Agent("r1", control, sar_vocabulary(), net.join("r1"), timing=Timing(wait=5))
    assert robot.knows(["TargetSeen(colour=1)"])
    robot.blackboard["target"] = 1
    robot.encounter(["TargetSeen(colour=1)"])
    for _ in range(3):
        net.step()
        robot.tick()
    assert robot.metrics.queries_sent == 0
    assert robot.blackboard.get("zone") == 1  # the prior skill ran
    robot.encounter(["TargetSeen(colour=2)"])
    net.step()
    robot.tick()
    assert robot.metrics.queries_sent == 1


def test_every_example_knowledge_item_is_served() -> None:
    served = {k.key: k.segment for k in load_knowledge(EXAMPLES / "sar_control.sbt")}
    assert served == {"<c>(_treasureOnBoardF)": "common", "<c>(TargetSeen,colour=1)": "prior"}
    colours = load_knowledge(EXAMPLES / "knowledge" / "colours.sbt")
    assert [show_sequence(k.conditions) for k in colours] == [
        f"TargetSeen(colour={c})" for c in (1, 2, 3, 4)
    ]
    for item in colours:
        assert kp.format_tree(item.subtree, "compact") == (
            f"<sq><a>(PickTreasure)<a>(AssignCollectionPoint,colour={item.key[-2]})<e>"
        )


@pytest.mark.parametrize("path", sorted(EXAMPLES.rglob("*.sbt")), ids=lambda p: p.name)
def test_every_example_checks_clean_without_warnings(path: Path) -> None:
    """Against its own robot's vocabulary (the ``.toml`` of the same name beside it), else the
    search-and-rescue robot's."""
    own = path.with_suffix(".toml")
    vocabulary = own if own.exists() else EXAMPLES / "sar_vocabulary.toml"
    tree = kp.parse(path.read_bytes())
    assert kp.find_problems(tree, kp.load_vocabulary(vocabulary)) == []
    assert stray_nodes(tree) == []


# -- the sequence syntax ---------------------------------------------------------------------

conditions = st.builds(
    kp.Condition,
    names,
    st.booleans(),
    st.lists(st.tuples(names, values), max_size=3, unique_by=lambda kv: kv[0]).map(tuple),
)


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(st.lists(conditions, min_size=1, max_size=4))
def test_show_and_read_sequence_round_trip(conds: list[kp.Condition]) -> None:
    shown = show_sequence(conds)
    assert read_sequence(shown) == tuple(conds)
    key = sequence_key(conds)
    assert read_sequence(key) == tuple(conds)  # the wire form is read as well
    assert show_sequence(key) == shown


@pytest.mark.parametrize(
    ("text", "code", "column"),
    [
        ("TargetSeen(colour=2", "SBT104", 20),
        ("TargetSeen(colour=)", "SBT103", 19),
        ("TargetSeen(colour=2), !_inZoneF x", "SBT103", 33),
        ("A,,B", "SBT103", 3),
        ("A, 3x", "SBT103", 4),
        ("A, ?", "SBT101", 4),
        ("", "SBT107", 1),
        ("<c>(A)<c>(B", "SBT104", 12),
    ],
)
def test_sequence_errors_point_at_what_was_typed(text: str, code: str, column: int) -> None:
    with pytest.raises(kp.StringBTError) as info:
        read_sequence(text)
    err = info.value
    assert (err.code.value, err.line, err.column) == (code, 1, column)
    assert err.excerpt.splitlines()[0].strip() == text.strip()


def ktbt(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ktbt_proto", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=120,
    )


@pytest.mark.network
def test_check_warns_about_placeholder_children_that_are_not_knowledge(tmp_path: Path) -> None:
    tree = tmp_path / "stray.sbt"
    tree.write_text("<sl>\n    <k>(prior)\n        <a>(X)\n        <sq><c>(A)<a>(B)<e><e><e>")
    done = ktbt("check", str(tree))
    assert done.returncode == 0  # a warning, not a problem
    assert done.stdout == (
        f"{tree}:3:9: SBT501 warning: <k>(prior) holds a node that is not a knowledge item "
        "(<sq>, its conditions, then its actions): it is never taught\n"
    )
    broken = tmp_path / "broken.sbt"
    broken.write_text("<k>(prior)\n<a>(X)\n<sq><e>\n<e>\n")
    done = ktbt("check", str(broken))
    assert done.returncode == 1
    assert [line.split(": ")[1].split()[0] for line in done.stdout.splitlines()] == [
        "SBT501",
        "SBT302",
        "SBT501",
    ]


@pytest.mark.network
def test_check_of_nothing_is_an_error(tmp_path: Path) -> None:
    done = ktbt("check", str(tmp_path))
    assert done.returncode == 2
    assert done.stderr == f"error: no .sbt file in {tmp_path}\n"
