"""The paper's SAR scenario: a py_trees robot learns over zenoh from a LiveTree robot, then ticks
its new knowledge exactly as its teacher does (spec/protocol.md section 4.4). And the
door-opening robot, a py_trees robot with its own behaviour classes and no stubs, learns its
skill over zenoh from a ``ktbt peer serve`` process (serving stringBT, or a BehaviorTree.CPP
robot's skills as XML) or a Python teacher, and runs it.

Real zenoh sessions on loopback. After the transfer, both control trees get the same inputs
every tick (sensed flags, the target in view, each action's outcome), scripted and then drawn by
hypothesis, and must give the same status, the same calls and the same halts, tick by tick.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ktbt_proto as kp
from ktbt_proto.exchange.agent import Agent, Timing
from ktbt_proto.interop.btcpp import to_xml
from ktbt_proto.interop.pytrees_control import PyTreesControl, py_trees_control
from ktbt_proto.transport.zenoh import ZenohTransport
from tests.door_robot import MEMORY as DOOR_MEMORY
from tests.door_robot import SEQUENCE as DOOR_SEQUENCE
from tests.door_robot import door_blackboard, door_registry
from tests.interop.test_pytrees_control import (
    ACTIONS,
    EXAMPLES,
    FLAGS,
    LEARNED,
    SEEN_2,
    Twin,
    behaviours,
    door_behaviours,
    door_conditions,
    door_tree,
    py_trees_sar,
    sar_vocabulary,
)
from tests.zenoh_helpers import endpoint, free_port, ktbt_process, see, wait_until
from tests.zenoh_helpers import settings as zenoh_settings

pytestmark = pytest.mark.network  # zenoh sessions on loopback

C, W, T, Z = FLAGS
STATUSES = st.sampled_from([kp.SUCCESS, kp.FAILURE, kp.RUNNING])
SOMETIMES = st.integers(0, 3).map(lambda n: n == 0)
"""A sensed flag, true one tick in four: the critical subtrees do not hide the rest."""
TICK = st.fixed_dictionaries(
    {
        "target": st.sampled_from([None, 1, 2, 2, 3]),
        "outcomes": st.dictionaries(st.sampled_from(ACTIONS), STATUSES, max_size=len(ACTIONS)),
        **{flag: SOMETIMES for flag in FLAGS},
    }
)


def test_a_py_trees_robot_learns_over_zenoh_and_ticks_as_its_teacher() -> None:
    reg = sar_vocabulary()
    sar = (EXAMPLES / "sar_control.sbt").read_text()
    knows_2 = sar.replace("<k>(new)<e>", f"<k>(new)<sq><c>(TargetSeen, colour=2){LEARNED}<e><e>")
    a, b = free_port(), free_port()
    with (
        ZenohTransport("teacher", zenoh_settings(a), query_timeout=2) as tt,
        ZenohTransport("learner", zenoh_settings(b, a), query_timeout=2) as tl,
    ):
        see(tl, "teacher")
        teacher_bb, learner_bb = kp.Blackboard(log=[]), kp.Blackboard(log=[])
        teacher = Agent("teacher", knows_2, reg, tt, timing=Timing(wait=400), blackboard=teacher_bb)
        bt = py_trees_sar(learner_bb, reg)
        learner = Agent(
            "learner",
            py_trees_control(bt, behaviours=behaviours(learner_bb)),
            reg,
            tl,
            timing=Timing(wait=400),
            blackboard=learner_bb,
        )
        assert isinstance(learner.control, PyTreesControl)
        learner.encounter(SEEN_2)

        def learned() -> bool:
            teacher.tick()
            learner.tick()
            return learner.knows(SEEN_2)

        assert wait_until(learned, 20), learner.metrics.refusals
        assert learner.metrics.learned["<c>(TargetSeen,colour=2)"][1] == "teacher"
        assert learner.metrics.refused == 0
        new = bt.root.children[4]
        assert new.children == []  # learned inside a tick: inserted before the next one

    # The two control trees, side by side: from the same state (nothing running) on.
    pair = (Twin(teacher.control, teacher_bb), Twin(learner.control, learner_bb))
    first = [twin.halt() for twin in pair]
    assert first[0] == first[1] == ["~RandomWalk"]

    def same(**inputs: Any) -> tuple[kp.Status, list[str]]:
        a, b = (twin.tick(**inputs) for twin in pair)
        assert a == b, inputs
        return a

    # Scripted: the learned rescue, interrupted and resumed, and the tree around it.
    assert same() == (kp.RUNNING, ["RandomWalk"])
    assert [child.name for child in new.children] == ["TargetSeen(colour=2)"]
    assert same(target=2, outcomes={"PickTreasure": kp.RUNNING}) == (
        kp.RUNNING,
        ["PickTreasure", "~RandomWalk"],
    )
    # The target is lost from view: the item's condition fails, its running action is halted.
    assert same(target=3) == (kp.RUNNING, ["~PickTreasure", "RandomWalk"])
    assert same(target=2, outcomes={"PickTreasure": kp.RUNNING}) == (
        kp.RUNNING,
        ["PickTreasure", "~RandomWalk"],
    )
    assert same(target=2, **{C: True}) == (
        kp.RUNNING,
        ["CollisionAvoidance", "~PickTreasure"],
    )
    assert same(target=2) == (
        kp.SUCCESS,
        ["~CollisionAvoidance", "PickTreasure", "AssignCollectionPoint 2"],
    )
    assert same(target=2, outcomes={"AssignCollectionPoint": kp.RUNNING}) == (
        kp.RUNNING,
        ["PickTreasure", "AssignCollectionPoint 2"],
    )
    assert same(target=2, outcomes={"PickTreasure": kp.FAILURE}) == (
        kp.RUNNING,
        ["PickTreasure", "~AssignCollectionPoint 2", "RandomWalk"],
    )
    assert same(target=2, **{T: True, Z: True}) == (
        kp.SUCCESS,
        ["PlaceTreasure", "~RandomWalk"],
    )
    assert same(target=3) == (kp.RUNNING, ["RandomWalk"])
    assert [twin.halt() for twin in pair] == [["~RandomWalk"]] * 2
    used = learner.control.last_used("new", SEEN_2)
    assert used == teacher.control.last_used("new", SEEN_2) == learner.now == teacher.now

    # Drawn: any inputs, any outcomes, each run ended by a halt.
    @settings(max_examples=150, deadline=None, database=None)
    @given(st.lists(TICK, min_size=1, max_size=12))
    def ticks_alike(script: list[dict[str, Any]]) -> None:
        for inputs in script:
            same(**inputs)
        halts = [twin.halt() for twin in pair]
        assert halts[0] == halts[1]

    ticks_alike()


@contextmanager
def door_teacher(kind: str, port: int, folder: Path) -> Iterator[None]:
    """A teacher of the door skill on ``port``: a ``ktbt peer serve`` process serving a
    knowledge file (stringBT, or a BehaviorTree.CPP robot's skills as XML, spec/stringbt.md
    section 12.1), or a Python agent that is never ticked (it answers from what it knows, in
    zenoh's callback, spec section 4.5)."""
    if kind in ("serve", "serve-btcpp-xml"):
        if kind == "serve":
            knowledge = folder / "door.sbt"
            knowledge.write_text(f"<sl><k>(prior){DOOR_MEMORY}<e><e>")
        else:
            knowledge = folder / "skills.xml"
            knowledge.write_text(to_xml(kp.parse(DOOR_MEMORY)))
        with ktbt_process(
            "peer", "serve", "--id", "teacher", "--knowledge", str(knowledge),
            "--listen", endpoint(port), ready="serving",
        ):  # fmt: skip
            yield
    else:
        with ZenohTransport("teacher", zenoh_settings(port)) as transport:
            Agent("teacher", f"<sl><k>(new){DOOR_MEMORY}<e><e>", door_registry(), transport)
            yield


@pytest.mark.parametrize("teacher", ["serve", "serve-btcpp-xml", "python"])
def test_the_door_robot_in_py_trees_learns_over_zenoh_and_runs_its_own_behaviours(
    teacher: str, tmp_path: Path
) -> None:
    """Only its conditions are registered: its actions are its py_trees behaviour classes,
    typed by their ``__init__`` (no stubs). It learns the memory form and ticks its own
    GraspHandle, TurnHandle and Push in order, each once."""
    pt, pl = free_port(), free_port()
    bb = door_blackboard()
    with (
        door_teacher(teacher, pt, tmp_path),
        ZenohTransport("door", zenoh_settings(pl, pt)) as transport,
    ):
        robot = Agent(
            "door", py_trees_control(door_tree(), behaviours=door_behaviours(bb)),
            door_conditions(), transport, timing=Timing(wait=500), blackboard=bb,
        )  # fmt: skip
        see(transport, "teacher")
        robot.encounter(DOOR_SEQUENCE)
        assert wait_until(lambda: robot.tick() is None or robot.knows(DOOR_SEQUENCE), 20), (
            robot.metrics.refusals
        )
        assert robot.metrics.refused == 0 and bb["log"] == []
        for _ in range(4):
            robot.tick()
    assert bb["log"] == ["grasp", "turn 30/60", "turn 60/60", "push"]
    assert bb["DoorClosed"] is False
