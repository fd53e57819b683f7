"""A py_trees tree its user built in py_trees, as an agent's control tree (spec/protocol.md 4.4).

The robot's own behaviours are plain py_trees behaviours that log into the blackboard; a
``LiveTree`` of ``examples/sar_control.sbt`` over the same registry is the reference:
both get
the same inputs each tick and must give the same status, calls and halts.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import Any

import py_trees
import pytest
from py_trees.common import Status as Pt

import ktbt_proto as kp
from ktbt_proto.control import ControlTree
from ktbt_proto.errors import ErrorCode
from ktbt_proto.exchange.agent import Agent, Timing
from ktbt_proto.exchange.knowledge import KnowledgeBase
from ktbt_proto.interop import to_py_trees
from ktbt_proto.interop.pytrees_control import PyTreesControl, py_trees_control
from ktbt_proto.transport.memory import MemoryNetwork
from tests.door_robot import FLAT as DOOR_FLAT
from tests.door_robot import MEMORY as DOOR_MEMORY
from tests.door_robot import SEQUENCE as DOOR_SEQUENCE
from tests.door_robot import Degrees, Side, door_blackboard, door_registry

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
FLAGS = ("_collisionDetectedF", "_waitF", "_treasureOnBoardF", "_inZoneF")
C, W, T, Z = FLAGS
ACTIONS = (
    "CollisionAvoidance",
    "StopWalk",
    "PlaceTreasure",
    "WalkToCollection",
    "RandomWalk",
    "PickTreasure",
    "AssignCollectionPoint",
)
DEFAULT = {
    "CollisionAvoidance": kp.RUNNING,
    "StopWalk": kp.RUNNING,
    "PlaceTreasure": kp.SUCCESS,
    "WalkToCollection": kp.RUNNING,
    "RandomWalk": kp.RUNNING,
    "PickTreasure": kp.SUCCESS,
    "AssignCollectionPoint": kp.SUCCESS,
}
TO_PT = {kp.SUCCESS: Pt.SUCCESS, kp.FAILURE: Pt.FAILURE, kp.RUNNING: Pt.RUNNING}
LEARNED = "<sq><a>(PickTreasure)<a>(AssignCollectionPoint, colour=2)<e>"
SEEN_2 = ["TargetSeen(colour=2)"]


def _shown(name: str, args: dict[str, Any]) -> str:
    return name + "".join(f" {v}" for v in args.values())


def outcome(bb: kp.Blackboard, name: str) -> kp.Status:
    """What action ``name`` returns this tick: the script's, else its default."""
    status: kp.Status = bb.get("outcomes", {}).get(name, DEFAULT[name])
    return status


def sar_vocabulary() -> kp.Registry:
    """The robot's capabilities, what received knowledge is checked against (and what a
    LiveTree's leaves call)."""
    reg = kp.Registry()
    reg.flags(*FLAGS)

    @reg.condition("TargetSeen")
    def target_seen(bb: kp.Blackboard, colour: int) -> bool:
        return bool(bb.get("target") == colour)

    for name in ACTIONS:

        def act(bb: kp.Blackboard, name: str = name, **args: Any) -> kp.Status:
            bb["log"].append(_shown(name, args))
            return outcome(bb, name)

        def halt(bb: kp.Blackboard, name: str = name, **args: Any) -> None:
            bb["log"].append("~" + _shown(name, args))

        if name == "AssignCollectionPoint":

            def assign(bb: kp.Blackboard, colour: int) -> kp.Status:
                return act(bb, colour=colour)

            def unassign(bb: kp.Blackboard, colour: int) -> None:
                halt(bb, colour=colour)

            reg.add_action(name, assign, halt=unassign)
        else:
            reg.add_action(name, act, halt=halt)
    return reg


# -- the robot's own py_trees behaviours ------------------------------------------------------


class Flag(py_trees.behaviour.Behaviour):
    def __init__(self, bb: kp.Blackboard, key: str, negated: bool = False) -> None:
        super().__init__(("!" if negated else "") + key)
        self.bb, self.key, self.negated = bb, key, negated

    def update(self) -> Pt:
        return Pt.SUCCESS if bool(self.bb.get(self.key)) != self.negated else Pt.FAILURE


class TargetSeen(py_trees.behaviour.Behaviour):
    def __init__(self, bb: kp.Blackboard, colour: int) -> None:
        super().__init__(f"TargetSeen {colour}")
        self.bb, self.colour = bb, colour

    def update(self) -> Pt:
        return Pt.SUCCESS if self.bb.get("target") == self.colour else Pt.FAILURE


class Act(py_trees.behaviour.Behaviour):
    """An action as a py_trees robot writes one: ``update`` works, ``terminate`` cleans up
    after an interruption."""

    def __init__(self, bb: kp.Blackboard, name: str, **args: Any) -> None:
        super().__init__(_shown(name, args))
        self.bb, self.action = bb, name
        self.started = 0

    def initialise(self) -> None:
        self.started += 1

    def update(self) -> Pt:
        self.bb["log"].append(self.name)
        return TO_PT[outcome(self.bb, self.action)]

    def terminate(self, new_status: Pt) -> None:
        if new_status == Pt.INVALID and self.status == Pt.RUNNING:
            self.bb["log"].append("~" + self.name)


def behaviours(bb: kp.Blackboard) -> dict[str, Any]:
    """The factories the learner builds learned leaves with: its own behaviours."""
    made: dict[str, Any] = {"TargetSeen": lambda colour: TargetSeen(bb, colour)}
    for name in ACTIONS:
        made[name] = lambda name=name, **args: Act(bb, name, **args)
    return made


def seq(name: str, *children: py_trees.behaviour.Behaviour) -> py_trees.composites.Sequence:
    return py_trees.composites.Sequence(name, memory=False, children=list(children))


def sel(name: str, *children: py_trees.behaviour.Behaviour) -> py_trees.composites.Selector:
    return py_trees.composites.Selector(name, memory=False, children=list(children))


def py_trees_sar(bb: kp.Blackboard, reg: kp.Registry) -> py_trees.trees.BehaviourTree:
    """``examples/sar_control.sbt`` as its user would write it in py_trees:
    placeholders are ``k:NAME`` selectors; the prior knowledge was built from stringBT (so it can
    be taught)."""
    prior = to_py_trees(
        "<sq><c>(TargetSeen, colour=1)<a>(PickTreasure)<a>(AssignCollectionPoint, colour=1)<e>",
        reg,
        bb,
        behaviours=behaviours(bb),
    )
    root = sel(
        "Root",
        seq("Collision", Flag(bb, C), Act(bb, "CollisionAvoidance")),
        seq("Wait", Flag(bb, W), Act(bb, "StopWalk")),
        sel(
            "k:common",
            seq(
                "Carry",
                Flag(bb, T),
                sel(
                    "Zone",
                    seq("Place", Flag(bb, Z), Act(bb, "PlaceTreasure")),
                    seq("Walk", Flag(bb, Z, True), Act(bb, "WalkToCollection")),
                ),
            ),
        ),
        sel("k:prior", prior),
        sel("k:new"),
        Act(bb, "RandomWalk"),
    )
    return py_trees.trees.BehaviourTree(root)


class Twin:
    """One robot's control tree with its own blackboard, fed the same inputs as its twin."""

    def __init__(self, control: ControlTree, bb: kp.Blackboard) -> None:
        self.control, self.bb = control, bb

    def tick(
        self, target: int | None = None, outcomes: dict[str, kp.Status] | None = None, **flags: bool
    ) -> tuple[kp.Status, list[str]]:
        log: list[str] = self.bb["log"]
        mark = len(log)
        self.bb.update({name: flags.get(name, False) for name in FLAGS})
        self.bb["target"], self.bb["outcomes"] = target, outcomes or {}
        return self.control.tick(), log[mark:]

    def halt(self) -> list[str]:
        log: list[str] = self.bb["log"]
        mark = len(log)
        self.control.halt()
        return log[mark:]


def twins() -> tuple[Twin, Twin]:
    reg = sar_vocabulary()
    live_bb, py_bb = kp.Blackboard(log=[]), kp.Blackboard(log=[])
    text = (EXAMPLES / "sar_control.sbt").read_text()
    live = kp.LiveTree(text, reg, live_bb)
    pyt = PyTreesControl(py_trees_sar(py_bb, reg), reg, py_bb, behaviours=behaviours(py_bb))
    return Twin(live, live_bb), Twin(pyt, py_bb)


def both(pair: tuple[Twin, Twin], **inputs: Any) -> tuple[kp.Status, list[str]]:
    a, b = (twin.tick(**inputs) for twin in pair)
    assert a == b, inputs
    return a


# -- merging and forgetting ----------------------------------------------------------------------


def test_the_py_trees_tree_reads_as_its_stringbt_twin() -> None:
    live, pyt = twins()
    assert isinstance(pyt.control, PyTreesControl)
    kb = KnowledgeBase.from_tree(pyt.control.tree)
    assert kb.keys() == ["<c>(TargetSeen,colour=1)"]  # the prior built from stringBT
    assert pyt.control.knows("prior", ["TargetSeen(colour=1)"])
    assert not pyt.control.knows("new", SEEN_2) and not pyt.control.knows("nowhere", SEEN_2)
    assert not live.control.knows("nowhere", SEEN_2)
    assert not kp.LiveTree("<a>(RandomWalk)", sar_vocabulary()).knows("new", SEEN_2)
    text = kp.format_tree(pyt.control.tree, "compact")
    assert "<k>(new)<e>" in text and "<k>(common)<sq><a>(_treasureOnBoardF)" in text


def test_merge_takes_effect_between_ticks_and_ticks_as_livetree() -> None:
    pair = twins()
    assert both(pair) == (kp.RUNNING, ["RandomWalk"])
    for twin in pair:
        assert twin.control.merge(LEARNED, "new", when=SEEN_2)
        assert twin.control.knows("new", SEEN_2)
        assert twin.control.last_used("new", SEEN_2) is None  # not in force yet
        assert not twin.control.merge(LEARNED, "new", when=SEEN_2)  # the same item: no change
    assert both(pair, target=2) == (
        kp.SUCCESS,
        ["PickTreasure", "AssignCollectionPoint 2", "~RandomWalk"],
    )
    assert [t.control.last_used("new", SEEN_2) for t in pair] == [2, 2]
    assert both(pair, target=2, outcomes={"PickTreasure": kp.RUNNING}) == (
        kp.RUNNING,
        ["PickTreasure"],
    )
    assert both(pair, target=1) == (
        kp.SUCCESS,
        ["PickTreasure", "AssignCollectionPoint 1", "~PickTreasure"],
    )
    assert both(pair) == (kp.RUNNING, ["RandomWalk"])
    assert [t.control.last_used("new", SEEN_2) for t in pair] == [3, 3]
    assert kp.format_tree(pair[1].control.tree) == kp.format_tree(
        kp.merge(kp.parse(kp.format_tree(pair[1].control.tree)), kp.parse(LEARNED), "new", SEEN_2)
    )


def test_a_behaviour_running_outside_the_placeholder_keeps_running() -> None:
    bb = kp.Blackboard(log=[])
    reg = sar_vocabulary()
    walker = Act(bb, "RandomWalk")
    root = py_trees.composites.Parallel(
        "Root",
        py_trees.common.ParallelPolicy.SuccessOnAll(synchronise=False),
        [walker, sel("Side", sel("k:new"), Act(bb, "StopWalk"))],
    )
    control = PyTreesControl(py_trees.trees.BehaviourTree(root), reg, bb)
    twin = Twin(control, bb)
    assert twin.tick() == (kp.RUNNING, ["RandomWalk", "StopWalk"])
    control.merge(LEARNED, "new", when=SEEN_2)
    assert twin.tick(target=2) == (
        kp.RUNNING,
        ["RandomWalk", "PickTreasure", "AssignCollectionPoint 2", "~StopWalk"],
    )
    assert walker.status == Pt.RUNNING and walker.started == 1  # never stopped, never restarted
    assert control.forget("new", SEEN_2)
    assert twin.tick(target=2) == (kp.RUNNING, ["RandomWalk", "StopWalk"])
    assert walker.started == 1 and not control.knows("new", SEEN_2)
    assert twin.halt() == ["~RandomWalk", "~StopWalk"]


def test_forget_waits_while_the_item_runs() -> None:
    pair = twins()
    for twin in pair:
        twin.control.merge(LEARNED, "new", when=SEEN_2)
    running = {"PickTreasure": kp.RUNNING}
    assert both(pair, target=2, outcomes=running) == (kp.RUNNING, ["PickTreasure"])
    for twin in pair:
        assert twin.control.forget("new", SEEN_2)
        assert not twin.control.forget("new", SEEN_2)
    # Still running: it stays until it stops, and is not halted by forgetting.
    assert both(pair, target=2, outcomes=running) == (kp.RUNNING, ["PickTreasure"])
    assert both(pair, target=2) == (kp.SUCCESS, ["PickTreasure", "AssignCollectionPoint 2"])
    assert both(pair, target=2) == (kp.RUNNING, ["RandomWalk"])  # gone
    assert all("<k>(new)<e>" in kp.format_tree(t.control.tree, "compact") for t in pair)


def test_whoever_ticks_the_tree_gets_the_merge_at_the_next_tick() -> None:
    _, pyt = twins()
    control = pyt.control
    assert isinstance(control, PyTreesControl)
    updates: list[int] = []
    control.bt.tree_update_handler = lambda: updates.append(control.ticks)
    pyt.bb.update(target=2, outcomes={})
    control.merge(LEARNED, "new", when=SEEN_2)
    control.bt.tick()  # the user's own loop (tick_tock, a ROS timer), not the agent
    assert pyt.bb["log"] == ["PickTreasure", "AssignCollectionPoint 2"]
    assert control.bt.root.status == Pt.SUCCESS and updates == [1]
    assert control.last_used("new", SEEN_2) == 1
    control.forget("new", SEEN_2)
    control.bt.tick()
    assert updates == [1, 2] and pyt.bb["log"][-1] == "RandomWalk"


def test_the_trees_visitors_see_the_learned_item() -> None:
    pair = twins()
    control = pair[1].control
    assert isinstance(control, PyTreesControl)
    snapshot = py_trees.visitors.SnapshotVisitor()
    control.bt.add_visitor(snapshot)
    for twin in pair:
        twin.control.merge(LEARNED, "new", when=SEEN_2)
    assert both(pair, target=2) == (kp.SUCCESS, ["PickTreasure", "AssignCollectionPoint 2"])
    item = control.bt.root.children[4].children[0]
    assert snapshot.visited[item.id] == Pt.SUCCESS  # what a monitor (py_trees_ros) shows


def test_merged_then_forgotten_before_a_tick_is_never_inserted() -> None:
    _, pyt = twins()
    control = pyt.control
    assert isinstance(control, PyTreesControl)
    new = control.bt.root.children[4]
    control.merge(LEARNED, "new", when=SEEN_2)
    assert control.forget("new", SEEN_2)
    assert pyt.tick(target=2) == (kp.RUNNING, ["RandomWalk"])
    assert new.children == []


def test_nested_placeholders_merge_and_go_with_their_item() -> None:
    pair = twins()
    outer = "<sq><k>(inner)<e><a>(PickTreasure)<e>"
    for twin in pair:
        twin.control.merge(outer, "new", when=["_inZoneF"])
        twin.control.merge(LEARNED, "inner", when=SEEN_2)
    assert both(pair, target=2, _inZoneF=True) == (
        kp.SUCCESS,
        ["PickTreasure", "AssignCollectionPoint 2", "PickTreasure"],
    )
    assert [t.control.last_used("inner", SEEN_2) for t in pair] == [1, 1]
    for twin in pair:
        assert twin.control.forget("new", ["_inZoneF"])
        assert not twin.control.knows("inner", SEEN_2)
        with pytest.raises(kp.MergeError):
            twin.control.merge(LEARNED, "inner", when=SEEN_2)
    assert both(pair, target=2, _inZoneF=True) == (kp.RUNNING, ["RandomWalk"])


# -- refusals: a StringBTError, and the tree as it was ------------------------------------------


# (Every refusal, and what it leaves as it was: tests/interop/test_pytrees_control_rules.py.)


def test_limits_and_a_failing_factory_change_nothing() -> None:
    bb, reg = kp.Blackboard(log=[]), sar_vocabulary()
    tight = PyTreesControl(
        py_trees_sar(bb, reg), reg, bb, limits=kp.Limits(max_depth=4, max_nodes=10_000)
    )
    with pytest.raises(kp.LimitError):
        tight.merge("<sq><sq><a>(PickTreasure)<e><e>", "new", when=SEEN_2)
    assert not tight.knows("new", SEEN_2)

    def broken(**_: Any) -> py_trees.behaviour.Behaviour:
        raise RuntimeError("no such gripper")

    faulty = PyTreesControl(py_trees_sar(bb, reg), reg, bb, behaviours={"PickTreasure": broken})
    with pytest.raises(kp.MergeError) as caught:  # the application's failure, as a refusal
        faulty.merge(LEARNED, "new", when=SEEN_2)
    assert caught.value.code == ErrorCode.BEHAVIOUR_FAILED
    assert "no such gripper" in caught.value.message
    assert not faulty.knows("new", SEEN_2)
    assert faulty.tick() is kp.RUNNING and faulty.bt.root.children[4].children == []


def test_two_placeholders_with_one_name_are_refused() -> None:
    bt = py_trees.trees.BehaviourTree(sel("Root", sel("k:new"), sel("k:new")))
    with pytest.raises(kp.ValidationError) as caught:
        PyTreesControl(bt, sar_vocabulary())
    assert caught.value.code == ErrorCode.DUPLICATE_PLACEHOLDER


# -- an agent over a py_trees tree ------------------------------------------------------------


def test_an_agent_learns_into_and_teaches_from_a_py_trees_tree() -> None:
    net = MemoryNetwork()
    reg = sar_vocabulary()
    text = (EXAMPLES / "sar_control.sbt").read_text()
    teacher = Agent(
        "t", text.replace("<k>(new)<e>", f"<k>(new)<sq><c>(TargetSeen, colour=2){LEARNED}<e><e>"),
        reg, net.join("t"), timing=Timing(wait=20, cooldown=5), blackboard=kp.Blackboard(log=[]),
    )  # fmt: skip
    bb = kp.Blackboard(log=[])
    learner = Agent(
        "l", py_trees_control(py_trees_sar(bb, reg), behaviours=behaviours(bb)), reg,
        net.join("l"), timing=Timing(wait=20, cooldown=5), blackboard=bb,
    )  # fmt: skip
    assert isinstance(learner.control, PyTreesControl)
    assert learner.knows(["TargetSeen(colour=1)"])  # innate, read off the py_trees tree
    learner.encounter(SEEN_2)
    for _ in range(10):
        teacher.tick()
        learner.tick()
    assert learner.knows(SEEN_2) and learner.metrics.learned_direct == 1
    assert learner.control.knows("new", SEEN_2)
    # It teaches what it learned, and what it was built knowing, to a third robot.
    third = Agent(
        "x", "<sl><k>(new)<e><a>(RandomWalk)<e>", reg, net.join("x"), timing=Timing(wait=20,
        cooldown=5), blackboard=kp.Blackboard(log=[]),
    )  # fmt: skip
    for sequence in (SEEN_2, ["TargetSeen(colour=1)"]):
        third.encounter(sequence)
        for _ in range(30):
            learner.tick()
            third.tick()
            if third.knows(sequence):
                break
    assert {key: who for key, (_, who) in third.metrics.learned.items()} == {
        "<c>(TargetSeen,colour=2)": "l",
        "<c>(TargetSeen,colour=1)": "l",
    }
    assert learner.forget(SEEN_2) and not learner.control.knows("new", SEEN_2)


def test_an_agent_refuses_what_its_py_trees_behaviours_cannot_build() -> None:
    net = MemoryNetwork()
    reg = sar_vocabulary()
    text = (EXAMPLES / "sar_control.sbt").read_text()
    teacher = Agent(
        "t", text.replace("<k>(new)<e>", f"<k>(new)<sq><c>(TargetSeen, colour=2){LEARNED}<e><e>"),
        reg, net.join("t"), timing=Timing(wait=20, cooldown=5), blackboard=kp.Blackboard(log=[]),
    )  # fmt: skip
    bb = kp.Blackboard(log=[])

    def no_gripper() -> py_trees.behaviour.Behaviour:
        raise RuntimeError("no gripper on this robot")

    bt = py_trees_sar(bb, reg)
    before = kp.format_tree(PyTreesControl(py_trees_sar(bb, reg), reg, bb).tree)
    learner = Agent(
        "l", py_trees_control(bt, behaviours={"PickTreasure": no_gripper}), reg, net.join("l"),
        timing=Timing(wait=20, cooldown=5), blackboard=bb,
    )  # fmt: skip
    learner.encounter(SEEN_2)
    for _ in range(10):
        teacher.tick()
        learner.tick()
    assert not learner.knows(SEEN_2) and learner.metrics.refused == 1
    assert "a behaviour failed to build" in learner.metrics.refusals[0][1]
    assert kp.format_tree(learner.control.tree) == before and bt.root.children[4].children == []


# -- a door-opening robot whose actions are its own py_trees behaviours -------------------------


class GraspHandle(py_trees.behaviour.Behaviour):
    """Close the gripper on the handle."""

    def __init__(self, *, bb: kp.Blackboard, name: str = "GraspHandle") -> None:
        super().__init__(name)
        self.bb = bb

    def update(self) -> Pt:
        self.bb["log"].append("grasp")
        return Pt.SUCCESS


class TurnHandle(py_trees.behaviour.Behaviour):
    """Turn the grasped handle, 30 degrees a tick."""

    def __init__(self, degrees: Degrees, *, bb: kp.Blackboard, name: str = "TurnHandle") -> None:
        super().__init__(name)
        self.bb, self.degrees, self.turned = bb, degrees, 0

    def initialise(self) -> None:
        self.turned = 0

    def update(self) -> Pt:
        self.turned += 30
        self.bb["log"].append(f"turn {self.turned}/{self.degrees}")
        return Pt.RUNNING if self.turned < self.degrees else Pt.SUCCESS


class Push(py_trees.behaviour.Behaviour):
    """Push the door open."""

    def __init__(self, *, bb: kp.Blackboard, name: str = "Push") -> None:
        super().__init__(name)
        self.bb = bb

    def update(self) -> Pt:
        self.bb["log"].append("push")
        self.bb["DoorClosed"] = False
        return Pt.SUCCESS


def door_conditions() -> kp.Registry:
    """What the py_trees robot registers: its two conditions, and no action at all."""
    reg = kp.Registry()
    reg.flags("DoorClosed")

    @reg.condition("HandleSeen")
    def handle_seen(bb: kp.Blackboard, side: Side) -> bool:
        return bool(bb.get("handle") == side)

    return reg


def door_tree() -> py_trees.trees.BehaviourTree:
    idle = py_trees.behaviours.Running("Idle")
    return py_trees.trees.BehaviourTree(sel("Root", sel("k:new"), idle))


def door_behaviours(bb: kp.Blackboard) -> dict[str, Any]:
    return {cls.__name__: partial(cls, bb=bb) for cls in (GraspHandle, TurnHandle, Push)}


def test_a_py_trees_robot_learns_with_its_own_behaviours_and_no_stubs() -> None:
    """Its behaviours are its actions, typed by their classes' __init__: it learns the door
    skill on the in-memory network, runs it with its own classes, and refuses an answer whose
    argument its TurnHandle does not take (the same SBT310 a Python registry gives)."""
    net = MemoryNetwork()
    teacher = Agent(
        "t", f"<sl><k>(new){DOOR_FLAT}<e><e>", door_registry(), net.join("t"),
        timing=Timing(wait=20, cooldown=5), blackboard=door_blackboard(),
    )  # fmt: skip
    bb = door_blackboard()
    learner = Agent(
        "l", py_trees_control(door_tree(), behaviours=door_behaviours(bb)), door_conditions(),
        net.join("l"), timing=Timing(wait=20, cooldown=5), blackboard=bb,
    )  # fmt: skip
    learner.encounter(DOOR_SEQUENCE)
    for _ in range(10):
        teacher.tick()
        learner.tick()
        if learner.knows(DOOR_SEQUENCE):
            break
    assert learner.knows(DOOR_SEQUENCE) and learner.metrics.refused == 0
    for _ in range(4):
        learner.tick()
    assert bb["log"] == ["grasp", "turn 30/60", "grasp", "turn 60/60", "push"]  # the flat form
    assert learner.registry.has_action("TurnHandle")
    wide = kp.parse("<a>(TurnHandle, degrees=120)")
    [problem] = kp.find_problems(wide, learner.registry)
    assert str(problem) == str(kp.find_problems(wide, door_registry())[0])
    assert problem.code is ErrorCode.INVALID_VALUE


def test_registering_only_the_conditions_no_longer_refuses_every_answer() -> None:
    bb = door_blackboard()
    control = PyTreesControl(door_tree(), door_conditions(), bb, behaviours=door_behaviours(bb))
    assert control.merge(DOOR_MEMORY, "new")
    control.tick()
    control.tick()
    assert bb["log"] == ["grasp", "turn 30/60", "turn 60/60", "push"]  # the memory form
    with pytest.raises(kp.StringBTError) as info:
        control.merge("<sq><c>(DoorClosed)<a>(Fly)<e>", "new")
    assert info.value.code is ErrorCode.UNKNOWN_ACTION


def test_what_is_not_a_control_tree_is_refused_in_one_line() -> None:
    root = sel("Root", sel("k:new"))
    with pytest.raises(TypeError) as info:
        py_trees_control(root)  # type: ignore[arg-type]
    assert str(info.value) == (
        "a py_trees control tree is a py_trees.trees.BehaviourTree, not the behaviour 'Root': "
        "pass py_trees.trees.BehaviourTree(root)"
    )
    with pytest.raises(TypeError, match="not the behaviour 'Root'"):
        PyTreesControl(root, door_conditions())  # type: ignore[arg-type]
    bare = py_trees.trees.BehaviourTree(sel("Root", py_trees.behaviours.Running("Idle")))
    with pytest.raises(ValueError) as no_slot:
        py_trees_control(bare)
    assert str(no_slot.value) == (
        "the py_trees tree has no knowledge placeholder, so an agent could learn nothing into "
        "it: add py_trees.composites.Selector(name='k:new', memory=False, children=[]) where "
        "learned knowledge should run, before the fallback"
    )
