"""py_trees export: the same tree ticks the same way in LiveTree and in py_trees.

Both runtimes get the same registry and their own blackboard; every leaf logs into its blackboard,
so a test compares, tick by tick, the root's status and the exact calls and halts.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import py_trees
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ktbt_proto as kp
from ktbt_proto.exchange.knowledge import KnowledgeBase
from ktbt_proto.interop import to_py_trees
from ktbt_proto.interop.pytrees import from_py_trees_status, origin
from ktbt_proto.interop.pytrees_control import PyTreesControl
from ktbt_proto.tree import Node, walk
from tests.interop.test_btcpp import unique_placeholders
from tests.strategies import trees

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
FLAGS = ("_collisionDetectedF", "_waitF", "_treasureOnBoardF", "_inZoneF")
Trace = list[tuple[kp.Status, list[str]]]


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


class Runner:
    """One tree in one runtime, with its own blackboard, log and clock."""

    def __init__(self, tree: kp.Tree, registry: kp.Registry, engine: str, **bb: Any) -> None:
        self.bb = kp.Blackboard(log=[], tick=0, **bb)
        self.clock = Clock()
        self.tick_root: Callable[[], kp.Status]
        if engine == "live":
            live = kp.LiveTree(tree, registry, self.bb, clock=self.clock)
            self.tick_root, self.halt_root = live.tick, live.halt
        else:
            root = to_py_trees(tree, registry, self.bb, clock=self.clock)
            bt = py_trees.trees.BehaviourTree(root)

            def tick() -> kp.Status:
                bt.tick()
                return from_py_trees_status(root.status)

            self.tick_root = tick
            self.halt_root = lambda: root.stop(py_trees.common.Status.INVALID)

    def tick(self, **flags: bool) -> tuple[kp.Status, list[str]]:
        log: list[str] = self.bb["log"]
        mark = len(log)
        self.bb.update({name: flags.get(name, False) for name in FLAGS})
        self.bb["tick"] += 1
        self.clock.now += 0.5
        status = self.tick_root()
        return status, log[mark:]

    def halt(self) -> list[str]:
        log: list[str] = self.bb["log"]
        mark = len(log)
        self.halt_root()
        return log[mark:]


# -- the paper's SAR control tree -----------------------------------------------------------


class CollisionAvoidance:
    """Runs for two ticks, then succeeds; a halt restarts it."""

    def __init__(self, bb: kp.Blackboard) -> None:
        self.bb, self.ticks = bb, 0

    def tick(self) -> kp.Status:
        self.bb["log"].append("CollisionAvoidance")
        self.ticks += 1
        if self.ticks < 3:
            return kp.RUNNING
        self.ticks = 0
        return kp.SUCCESS

    def halt(self) -> None:
        self.bb["log"].append("~CollisionAvoidance")
        self.ticks = 0


def sar_vocabulary() -> kp.Registry:
    reg = kp.Registry()
    reg.flags(*FLAGS)
    reg.add_action("CollisionAvoidance", CollisionAvoidance)
    script = {
        "StopWalk": kp.RUNNING,
        "RandomWalk": kp.RUNNING,
        "WalkToCollection": kp.RUNNING,
        "PlaceTreasure": kp.SUCCESS,
        "PickTreasure": kp.SUCCESS,
    }
    for name, status in script.items():
        reg.add_action(
            name,
            lambda bb, name=name, status=status: (bb["log"].append(name), status)[1],
            halt=lambda bb, name=name: bb["log"].append(f"~{name}"),
        )

    @reg.condition("TargetSeen")
    def target_seen(bb: kp.Blackboard, colour: int) -> bool:
        return bool(bb.get("target") == colour)

    @reg.action("AssignCollectionPoint")
    def assign(bb: kp.Blackboard, colour: int) -> bool:
        bb["log"].append(f"Assign {colour}")
        return True  # a bool, converted to SUCCESS by both runtimes

    return reg


C, W, T, Z = FLAGS
SCENARIO: list[tuple[dict[str, bool], kp.Status, list[str]]] = [
    ({}, kp.RUNNING, ["RandomWalk"]),
    ({}, kp.RUNNING, ["RandomWalk"]),
    # A collision: avoidance preempts the walk, which is halted on the same tick.
    ({C: True}, kp.RUNNING, ["CollisionAvoidance", "~RandomWalk"]),
    ({C: True}, kp.RUNNING, ["CollisionAvoidance"]),
    ({C: True}, kp.SUCCESS, ["CollisionAvoidance"]),
    ({C: True}, kp.RUNNING, ["CollisionAvoidance"]),
    # The collision is over: back to the walk, avoidance halted.
    ({}, kp.RUNNING, ["~CollisionAvoidance", "RandomWalk"]),
    # Carrying a target: walk to its zone, then place it.
    ({T: True}, kp.RUNNING, ["WalkToCollection", "~RandomWalk"]),
    ({T: True}, kp.RUNNING, ["WalkToCollection"]),
    ({T: True, Z: True}, kp.SUCCESS, ["PlaceTreasure", "~WalkToCollection"]),
    # Critical subtrees first, even while carrying.
    ({T: True, C: True}, kp.RUNNING, ["CollisionAvoidance"]),
    ({W: True, T: True}, kp.RUNNING, ["~CollisionAvoidance", "StopWalk"]),
    # Nothing sensed: the fallback.
    ({}, kp.RUNNING, ["~StopWalk", "RandomWalk"]),
]


def test_sar_scenario_ticks_identically() -> None:
    tree = kp.parse((EXAMPLES / "sar_control.sbt").read_text())
    reg = sar_vocabulary()
    runs = [Runner(tree, reg, engine) for engine in ("live", "py_trees")]
    for flags, status, calls in SCENARIO:
        assert [run.tick(**flags) for run in runs] == [(status, calls)] * 2, flags
    # Prior knowledge: a red target is picked up and assigned to its zone.
    for run in runs:
        run.bb["target"] = 1
    assert [run.tick() for run in runs] == [
        (kp.SUCCESS, ["PickTreasure", "Assign 1", "~RandomWalk"])
    ] * 2
    assert [run.tick() for run in runs] == [(kp.SUCCESS, ["PickTreasure", "Assign 1"])] * 2
    for run in runs:
        run.bb["target"] = None
    assert [run.tick(**{C: True}) for run in runs] == [(kp.RUNNING, ["CollisionAvoidance"])] * 2
    assert [run.halt() for run in runs] == [["~CollisionAvoidance"]] * 2


def test_py_trees_structure() -> None:
    tree = kp.parse((EXAMPLES / "teach_learn.sbt").read_text())
    root = to_py_trees(tree, _anything(tree))
    assert isinstance(root, py_trees.composites.Parallel)
    teach = root.children[0]
    assert isinstance(teach, py_trees.composites.Sequence) and not teach.memory
    names = ["QueryReceived", "!_coolDownF", "RespondWithKnowledge", "TT1(1000)"]
    assert [child.name for child in teach.children] == names


# -- random trees, random scripts ---------------------------------------------------------

STATUSES = (kp.RUNNING, kp.SUCCESS, kp.FAILURE, kp.RUNNING)


def _pick(bb: kp.Blackboard, name: str, n: int) -> int:
    """A deterministic choice per (seed, leaf name, tick, call within the tick)."""
    key = (name, bb["tick"])
    calls = bb.setdefault("calls", {})
    calls[key] = calls.get(key, 0) + 1
    return zlib.crc32(f"{bb['seed']}|{name}|{key[1]}|{calls[key]}".encode()) % n


def _condition(name: str) -> Callable[..., bool]:
    def holds(bb: kp.Blackboard, /, **kw: Any) -> bool:  # any argument name, "bb" too
        bb["log"].append(f"{name}?")
        return _pick(bb, name, 2) == 0

    return holds


def _action(name: str) -> tuple[Callable[..., kp.Status], Callable[..., None]]:
    def act(bb: kp.Blackboard, /, **kw: Any) -> kp.Status:
        bb["log"].append(name)
        return STATUSES[_pick(bb, "a " + name, len(STATUSES))]

    def halt(bb: kp.Blackboard, /, **kw: Any) -> None:
        bb["log"].append(f"~{name}")

    return act, halt


def _anything(tree: kp.Tree) -> kp.Registry:
    """Every condition and action of the tree, taking any arguments, scripted by ``_pick``."""
    reg = kp.Registry()
    for node, _ in walk(tree.root):
        if isinstance(node, kp.Condition):
            reg.add_condition(node.name, _condition(node.name))
        elif isinstance(node, kp.Action):
            act, halt = _action(node.name)
            reg.add_action(node.name, act, halt=halt)
    return reg


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(trees(valid=True), st.integers(0, 2**32), st.integers(1, 12))
def test_random_trees_tick_identically(root: Node, seed: int, ticks: int) -> None:
    tree = kp.Tree(unique_placeholders(root))
    reg = _anything(tree)
    runs = [Runner(tree, reg, engine, seed=seed) for engine in ("live", "py_trees")]
    live, pyt = runs
    for _ in range(ticks):
        assert live.tick() == pyt.tick()
    assert live.halt() == pyt.halt()


# -- the user's own behaviours for leaves, and reading a built tree back ---------------------


class _UserCondition(py_trees.behaviour.Behaviour):
    """A condition as a py_trees user writes it, scripted as ``_condition`` is."""

    def __init__(self, bb: kp.Blackboard, name: str) -> None:
        super().__init__(name)
        self.bb, self.leaf = bb, name

    def update(self) -> py_trees.common.Status:
        self.bb["log"].append(f"{self.leaf}?")
        ok = _pick(self.bb, self.leaf, 2) == 0
        return py_trees.common.Status.SUCCESS if ok else py_trees.common.Status.FAILURE


class _UserAction(py_trees.behaviour.Behaviour):
    """An action as a py_trees user writes it, scripted as ``_action`` is."""

    def __init__(self, bb: kp.Blackboard, name: str) -> None:
        super().__init__(name)
        self.bb, self.leaf = bb, name

    def update(self) -> py_trees.common.Status:
        self.bb["log"].append(self.leaf)
        status = STATUSES[_pick(self.bb, "a " + self.leaf, len(STATUSES))]
        return py_trees.common.Status[status.name]

    def terminate(self, new_status: py_trees.common.Status) -> None:
        if new_status == py_trees.common.Status.INVALID and self.status.name == "RUNNING":
            self.bb["log"].append(f"~{self.leaf}")


@settings(max_examples=100, deadline=None)
@given(trees(valid=True), st.integers(0, 2**32), st.integers(1, 8))
def test_the_users_own_leaves_tick_as_the_registrys(root: Node, seed: int, ticks: int) -> None:
    tree = kp.Tree(unique_placeholders(root))
    reg = _anything(tree)
    live = Runner(tree, reg, "live", seed=seed)
    mine = Runner(tree, reg, "live", seed=seed)  # replaced below: same blackboard, clock, log
    own: dict[str, Callable[..., py_trees.behaviour.Behaviour]] = {}
    for node, _ in walk(tree.root):
        if isinstance(node, kp.Condition):
            own[node.name] = lambda name=node.name, **_: _UserCondition(mine.bb, name)
        elif isinstance(node, kp.Action):
            own[node.name] = lambda name=node.name, **_: _UserAction(mine.bb, name)
    for both in reg.conditions & reg.actions:  # factories go by name: these stay the registry's
        del own[both]
    built = to_py_trees(tree, reg, mine.bb, clock=mine.clock, behaviours=own)
    bt = py_trees.trees.BehaviourTree(built)

    def tick() -> kp.Status:
        bt.tick()
        return from_py_trees_status(built.status)

    mine.tick_root, mine.halt_root = tick, lambda: built.stop(py_trees.common.Status.INVALID)
    for _ in range(ticks):
        assert live.tick() == mine.tick()
    assert live.halt() == mine.halt()


@settings(max_examples=150, deadline=None)
@given(trees(valid=True))
def test_a_built_tree_reads_back_as_itself(root: Node) -> None:
    tree = kp.Tree(unique_placeholders(root))
    reg = _anything(tree)
    built = to_py_trees(tree, reg)
    assert origin(built) == tree.root
    control = PyTreesControl(py_trees.trees.BehaviourTree(built), reg)
    assert control.tree == tree
    assert KnowledgeBase.from_tree(control.tree).keys() == KnowledgeBase.from_tree(tree).keys()
