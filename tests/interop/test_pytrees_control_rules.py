"""The py_trees learner's rules beside LiveTree's (spec/protocol.md 4.4): node counts through
nested merges and forgets, setup and shutdown of what a merge inserts and a forget prunes,
refusals that leave every count as it was, the stringBT a user's own py_trees tree reads as,
merges from another thread, and its tick against ``BehaviourTree.tick``.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any

import py_trees
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from py_trees.common import ParallelPolicy
from py_trees.common import Status as Pt

import ktbt_proto as kp
from ktbt_proto.errors import ErrorCode
from ktbt_proto.exchange.agent import Agent
from ktbt_proto.interop import to_py_trees
from ktbt_proto.interop.pytrees import from_py_trees_status
from ktbt_proto.interop.pytrees_control import PyTreesControl, py_trees_control
from ktbt_proto.transport.memory import MemoryNetwork
from ktbt_proto.tree import Node
from tests.interop.test_btcpp import unique_placeholders
from tests.interop.test_pytrees import _anything
from tests.interop.test_pytrees_control import (
    FLAGS,
    LEARNED,
    SEEN_2,
    Act,
    Twin,
    behaviours,
    py_trees_sar,
    sar_vocabulary,
    sel,
    twins,
)
from tests.strategies import trees

C, W, T, Z = FLAGS
OUTER = "<sq><k>(inner)<e><a>(PickTreasure)<e>"
DEEPER = "<sq><k>(deeper)<e><a>(StopWalk)<e>"


def counts(control: Any) -> int:
    nodes: int = control._nodes
    return nodes


def same_counts(pair: tuple[Twin, Twin]) -> int:
    live, pyt = (counts(twin.control) for twin in pair)
    assert live == pyt
    return live


# -- node counts: what a merge adds and a forget takes back, nested placeholders included ------


def test_forgetting_an_outer_item_with_a_pending_inner_merge_takes_both_back() -> None:
    pair = twins()
    start = same_counts(pair)
    for twin in pair:
        twin.control.merge(OUTER, "new", when=[Z])
        twin.tick()
        twin.control.merge(LEARNED, "inner", when=SEEN_2)  # pending: no tick since
        assert twin.control.forget("new", [Z])
        assert not twin.control.knows("inner", SEEN_2)
    assert same_counts(pair) == start
    assert pair[1].tick(target=2, _inZoneF=True) == (kp.RUNNING, ["RandomWalk"])
    assert same_counts(pair) == start


def test_forgetting_a_running_inner_item_then_its_outer_counts_each_once() -> None:
    pair = twins()
    start = same_counts(pair)
    for twin in pair:
        twin.control.merge(OUTER, "new", when=[Z])
        twin.control.merge(LEARNED, "inner", when=SEEN_2)
    running = {"PickTreasure": kp.RUNNING}
    assert pair[0].tick(target=2, outcomes=running, **{Z: True}) == pair[1].tick(
        target=2, outcomes=running, **{Z: True}
    )
    for twin in pair:
        assert twin.control.forget("inner", SEEN_2)  # running: stays until it stops
        assert twin.control.forget("new", [Z])
    assert same_counts(pair) == start
    for _ in range(2):
        assert pair[0].tick() == pair[1].tick()
    assert same_counts(pair) == start


SLOTS = st.sampled_from(["new", "inner", "deeper"])
WHEN = st.sampled_from([[Z], SEEN_2])
OPS = st.lists(
    st.one_of(
        st.tuples(st.just("merge"), SLOTS, st.sampled_from([OUTER, DEEPER, LEARNED]), WHEN),
        st.tuples(st.just("forget"), SLOTS, WHEN),
        st.tuples(st.just("tick"), st.sampled_from([None, 2]), st.booleans(), st.booleans()),
    ),
    max_size=25,
)


@settings(max_examples=120, deadline=None, database=None)
@given(OPS)
def test_node_counts_and_knowledge_follow_livetree(ops: list[tuple[Any, ...]]) -> None:
    pair = twins()
    for op in ops:
        if op[0] == "tick":
            _, target, zone, busy = op
            outcomes = {"PickTreasure": kp.RUNNING, "StopWalk": kp.RUNNING} if busy else {}
            inputs = {"target": target, "outcomes": outcomes, Z: zone}
            assert pair[0].tick(**inputs) == pair[1].tick(**inputs)
            continue
        results: list[object] = []
        for twin in pair:
            try:
                if op[0] == "merge":
                    results.append(twin.control.merge(op[2], op[1], when=op[3]))
                else:
                    results.append(twin.control.forget(op[1], op[2]))
            except kp.StringBTError as err:
                results.append(err.code)
        assert results[0] == results[1], op
        same_counts(pair)
        for slot in ("new", "inner", "deeper"):
            for when in ([Z], SEEN_2):
                assert pair[0].control.knows(slot, when) == pair[1].control.knows(slot, when)
    for twin in pair:
        twin.control.tick()
    same_counts(pair)


# -- refusals: nothing changes, counts and placeholders included ------------------------------


def _state(control: PyTreesControl) -> tuple[Any, ...]:
    slots = {
        name: (slot.depth, slot.fixed, [(k, h.nodes, h.inner) for k, h in slot.items.items()])
        for name, slot in control._slots.items()
    }
    shape = [(b.name, id(b)) for b in control.bt.root.iterate()]
    return shape, kp.format_tree(control.tree), slots, control._nodes, control._adds, control._drops


@pytest.mark.parametrize(
    ("subtree", "slot", "when", "code"),
    [
        (LEARNED, "nowhere", SEEN_2, ErrorCode.UNKNOWN_SLOT),
        ("<a>(Fly)", "new", SEEN_2, ErrorCode.UNKNOWN_ACTION),
        ("<a>(AssignCollectionPoint, colour=true)", "new", SEEN_2, ErrorCode.INVALID_VALUE),
        ("<a>(PickTreasure)", "new", ["Levitating"], ErrorCode.UNKNOWN_CONDITION),
        ("<a>(PickTreasure)", "prior", ["TargetSeen(colour=1)"], ErrorCode.KNOWLEDGE_CONFLICT),
        ("<sq><k>(prior)<e><a>(PickTreasure)<e>", "new", SEEN_2,
         ErrorCode.DUPLICATE_PLACEHOLDER),
        ("<sq><k>(inner)<e><a>(PickTreasure)<e>", "new", SEEN_2,
         ErrorCode.DUPLICATE_PLACEHOLDER),
        ("<sq><a>(PickTreasure)", "new", SEEN_2, ErrorCode.UNEXPECTED_END),
        ("<a>(PickTreasure)", "new", None, ErrorCode.NOT_KNOWLEDGE),
        ("<a>(StopWalk)", "inner", [Z], ErrorCode.KNOWLEDGE_CONFLICT),
        ("<a>(Broken)", "inner", SEEN_2, ErrorCode.BEHAVIOUR_FAILED),
    ],
)  # fmt: skip
def test_refusals_change_nothing(subtree: str, slot: str, when: Any, code: ErrorCode) -> None:
    bb, reg = kp.Blackboard(log=[]), sar_vocabulary()
    reg.add_action("Broken", lambda bb: kp.SUCCESS)

    def broken() -> py_trees.behaviour.Behaviour:
        raise RuntimeError("no such motor")

    control = PyTreesControl(
        py_trees_sar(bb, reg), reg, bb, behaviours={**behaviours(bb), "Broken": broken}
    )
    control.merge(OUTER, "new", when=["TargetSeen(colour=3)"])
    control.tick()
    control.merge("<a>(PickTreasure)", "inner", when=[Z])  # pending when refused
    before = _state(control)
    with pytest.raises(kp.StringBTError) as caught:
        control.merge(subtree, slot, when=when)
    assert caught.value.code == code
    assert _state(control) == before
    bb["log"].clear()
    assert Twin(control, bb).tick(target=3, _inZoneF=True) == (
        kp.SUCCESS,
        ["PickTreasure", "PickTreasure", "~RandomWalk"],
    )


# -- factories that fail: at a merge, at resume ------------------------------------------------


def test_an_agent_resumes_past_saved_knowledge_its_behaviours_cannot_build(
    tmp_path: Path,
) -> None:
    saved = tmp_path / "learned.json"
    item = {"sequence": "<c>(TargetSeen,colour=2)", "subtree": LEARNED.replace(" ", "")}
    saved.write_text(json.dumps({"version": 1, "knowledge": [{**item, "segment": "new",
                                 "source": "t", "learned_at": 3}]}))  # fmt: skip
    bb, reg = kp.Blackboard(log=[]), sar_vocabulary()

    def no_gripper() -> py_trees.behaviour.Behaviour:
        raise RuntimeError("no gripper on this robot")

    bt = py_trees_sar(bb, reg)
    agent = Agent(
        "l", py_trees_control(bt, behaviours={"PickTreasure": no_gripper}), reg,
        MemoryNetwork().join("l"), blackboard=bb, knowledge_path=saved,
    )  # fmt: skip
    assert not agent.knows(SEEN_2) and agent.metrics.refused == 1
    assert "SBT403" in agent.metrics.refusals[0][1] and "no gripper" in agent.metrics.refusals[0][1]
    assert bt.root.children[4].children == [] and not agent.control.knows("new", SEEN_2)
    assert agent.tick() is kp.RUNNING


def test_a_livetree_refuses_what_its_registry_cannot_build_too() -> None:
    reg = sar_vocabulary()

    class Gripper:
        def __init__(self, bb: kp.Blackboard) -> None:
            raise RuntimeError("no gripper on this robot")

        def tick(self) -> kp.Status:
            return kp.SUCCESS

    reg.add_action("Grip", Gripper)
    live = kp.LiveTree("<sl><k>(new)<e><a>(RandomWalk)<e>", reg, kp.Blackboard(log=[]))
    before = kp.format_tree(live.tree), counts(live)
    with pytest.raises(kp.MergeError) as caught:
        live.merge("<a>(Grip)", when=SEEN_2)
    assert caught.value.code == ErrorCode.BEHAVIOUR_FAILED
    assert (kp.format_tree(live.tree), counts(live)) == before and not live.knows("new", SEEN_2)
    assert live.tick() is kp.RUNNING


def test_an_agent_takes_a_factory_not_a_built_backend() -> None:
    reg, net = sar_vocabulary(), MemoryNetwork()
    bb = kp.Blackboard(log=[])
    built: list[Any] = [
        PyTreesControl(py_trees_sar(bb, reg), reg, bb),
        kp.LiveTree("<sl><k>(new)<e><a>(RandomWalk)<e>", reg),
    ]
    for k, control in enumerate(built):
        with pytest.raises(TypeError, match="factory such as py_trees_control"):
            Agent(f"a{k}", control, reg, net.join(f"a{k}"))


def test_one_tree_is_wrapped_once() -> None:
    bb, reg = kp.Blackboard(log=[]), sar_vocabulary()
    bt = py_trees_sar(bb, reg)
    PyTreesControl(bt, reg, bb)
    with pytest.raises(ValueError, match="once"):
        PyTreesControl(bt, reg, bb)
    assert len(bt.pre_tick_handlers) == 1


# -- setup and shutdown ------------------------------------------------------------------------


class Device(py_trees.behaviour.Behaviour):
    """A behaviour that needs its setup (a py_trees_ros action client, say)."""

    def __init__(self, journal: list[Any], name: str, fail: bool = False) -> None:
        super().__init__(name)
        self.journal, self.fail, self.ready = journal, fail, False

    def setup(self, **kwargs: Any) -> None:
        if self.fail:
            raise TimeoutError(f"{self.name}: no action server")
        self.journal.append(("setup", self.name, kwargs))
        self.ready = True

    def update(self) -> Pt:
        assert self.ready, "ticked before setup"
        return Pt.SUCCESS

    def shutdown(self) -> None:
        self.journal.append(("shutdown", self.name))


def test_merged_behaviours_are_set_up_and_pruned_ones_shut_down() -> None:
    journal: list[Any] = []
    bb, reg = kp.Blackboard(log=[]), sar_vocabulary()
    own: dict[str, Any] = {
        "PickTreasure": lambda: Device(journal, "Pick"),
        "AssignCollectionPoint": lambda colour: Device(journal, f"Assign {colour}"),
        "StopWalk": lambda: Device(journal, "Stop", fail=True),
    }
    control = PyTreesControl(
        py_trees_sar(bb, reg), reg, bb, behaviours=own, setup_kwargs={"node": "ros", "timeout": 2}
    )
    control.merge(LEARNED, "new", when=SEEN_2)
    kw = {"node": "ros", "timeout": 2}
    assert journal == [("setup", "Pick", kw), ("setup", "Assign 2", kw)]  # before any tick
    assert Twin(control, bb).tick(target=2)[0] is kp.SUCCESS
    journal.clear()
    assert control.forget("new", SEEN_2)
    assert journal == []  # pruned between ticks, not now
    control.tick()
    assert ("shutdown", "Pick") in journal and ("shutdown", "Assign 2") in journal

    journal.clear()  # merged and forgotten before a tick: set up, then shut down
    control.merge(LEARNED, "new", when=SEEN_2)
    control.forget("new", SEEN_2)
    assert [e[:2] for e in journal if e[1] == "Pick"] == [("setup", "Pick"), ("shutdown", "Pick")]

    journal.clear()  # a setup that fails: refused, those set up already shut down again
    before = _state(control)
    with pytest.raises(kp.MergeError) as caught:
        control.merge("<sq><a>(PickTreasure)<a>(StopWalk)<e>", "new", when=SEEN_2)
    assert caught.value.code == ErrorCode.BEHAVIOUR_FAILED
    assert "no action server" in caught.value.message
    assert _state(control) == before and not control.knows("new", SEEN_2)
    assert [e[:2] for e in journal if e[1] == "Pick"] == [("setup", "Pick"), ("shutdown", "Pick")]


# -- what a user's own py_trees tree reads as ---------------------------------------------------


def test_the_users_own_composites_read_as_the_spec_maps_them() -> None:
    def leaf(name: str) -> py_trees.behaviour.Behaviour:
        return py_trees.behaviours.Running(name)

    root = py_trees.composites.Selector("Root", memory=False, children=[
        py_trees.composites.Sequence("S", memory=True, children=[leaf("a"), leaf("b")]),
        py_trees.composites.Selector("k:my_slot", memory=False, children=[leaf("c")]),
        py_trees.composites.Selector("k:not.a.placeholder", memory=True, children=[leaf("d")]),
        py_trees.composites.Parallel("P", ParallelPolicy.SuccessOnOne(), [leaf("e"), leaf("f")]),
        py_trees.composites.Parallel("Q", ParallelPolicy.SuccessOnAll(), [leaf("g")]),
        py_trees.decorators.Inverter("I", leaf("h")),
        py_trees.decorators.Timeout("T", leaf("i"), duration=1.0),
        leaf("1st-move"),
        leaf("true"),
        leaf("Go.To"),
    ])  # fmt: skip
    tree = PyTreesControl(py_trees.trees.BehaviourTree(root), kp.Registry()).tree
    assert kp.format_tree(tree, "compact") == (
        "<sl><msq><a>(a)<a>(b)<e><k>(my_slot)<a>(c)<e><msl><a>(d)<e><pl>(1)<a>(e)<a>(f)<e>"
        "<pl><a>(g)<e><neg><a>(h)<e><a>(i)<a>(_1st_move)<a>(_true)<a>(Go.To)<e>"
    )
    assert kp.parse(kp.format_tree(tree)) == tree


@pytest.mark.parametrize("name", ["k:my slot", "k:", "k:1st", "k:true", "k:a..b"])
def test_a_placeholder_name_stringbt_cannot_write_is_refused(name: str) -> None:
    bt = py_trees.trees.BehaviourTree(sel("Root", sel(name), py_trees.behaviours.Running("W")))
    with pytest.raises(kp.ValidationError) as caught:
        PyTreesControl(bt, kp.Registry())
    assert caught.value.code == ErrorCode.INVALID_NAME
    assert bt.pre_tick_handlers == []


LEAF_NAMES = st.text(st.characters(codec="utf-8", exclude_categories=["Cs"]), max_size=8)


def _user_trees() -> st.SearchStrategy[py_trees.behaviour.Behaviour]:
    counter = iter(range(10**9))
    leaf = LEAF_NAMES.map(lambda name: py_trees.behaviours.Success(name or "x"))

    def grow(kids: st.SearchStrategy[list[Any]]) -> st.SearchStrategy[Any]:
        composite = st.tuples(st.sampled_from(range(7)), st.booleans(), kids)

        def make(spec: tuple[int, bool, list[Any]]) -> py_trees.behaviour.Behaviour:
            kind, memory, children = spec
            if kind == 0:
                return py_trees.composites.Sequence("S", memory, children)
            if kind == 1:
                return py_trees.composites.Selector("L", memory, children)
            if kind == 2:
                return py_trees.composites.Selector(f"k:slot{next(counter)}", False, children)
            if kind in (3, 4):
                policy = (
                    ParallelPolicy.SuccessOnOne() if kind == 3 else ParallelPolicy.SuccessOnAll()
                )
                return py_trees.composites.Parallel("P", policy, children)
            child = children[0] if children else py_trees.behaviours.Failure("f")
            if kind == 5:
                return py_trees.decorators.Inverter("I", child)
            return py_trees.decorators.SuccessIsRunning("D", child)

        return composite.map(make)

    return st.recursive(leaf, lambda kids: grow(st.lists(kids, max_size=3)), max_leaves=12)


@settings(max_examples=150, deadline=None)
@given(_user_trees())
def test_any_tree_a_user_builds_reads_as_stringbt_that_parses(
    root: py_trees.behaviour.Behaviour,
) -> None:
    control = PyTreesControl(py_trees.trees.BehaviourTree(root), kp.Registry())
    tree = control.tree
    assert kp.parse(kp.format_tree(tree)) == tree
    assert kp.parse(kp.format_tree(tree, "compact")) == tree


# -- merges from another thread -----------------------------------------------------------------


def test_merges_from_another_thread_while_the_tree_ticks() -> None:
    reg = sar_vocabulary()
    colours = list(range(3, 43))
    bb = kp.Blackboard(log=[])
    walker = Act(bb, "RandomWalk")
    root = sel("Root", sel("k:new"), walker)
    control = PyTreesControl(py_trees.trees.BehaviourTree(root), reg, bb)
    twin = Twin(control, bb)
    stop = threading.Event()
    errors: list[BaseException] = []

    def ticker() -> None:
        try:
            while not stop.is_set():
                control.tick()
                control.tree  # noqa: B018 - read while merges land, as a teacher does
        except BaseException as exc:  # surfaced below
            errors.append(exc)

    bb.update(target=None, outcomes={})
    thread = threading.Thread(target=ticker)
    thread.start()
    try:
        for colour in colours:
            assert control.merge(
                f"<a>(AssignCollectionPoint, colour={colour})",
                when=[f"TargetSeen(colour={colour})"],
            )
    finally:
        stop.set()
        thread.join(timeout=30)
    assert not thread.is_alive() and errors == []
    assert walker.started == 1 and walker.status == Pt.RUNNING  # never stopped meanwhile
    control.tick()
    new = root.children[0]
    assert [child.name for child in new.children] == [
        f"TargetSeen(colour={c})" for c in colours
    ]  # merged in order
    assert counts(control) == 3 + 3 * len(colours)
    assert twin.tick(target=7) == (kp.SUCCESS, ["AssignCollectionPoint 7", "~RandomWalk"])


# -- the learner's tick is BehaviourTree.tick ---------------------------------------------------


@settings(max_examples=100, deadline=None)
@given(trees(valid=True), st.integers(0, 2**32), st.integers(1, 10))
def test_the_learners_tick_is_behaviour_tree_tick(root: Node, seed: int, ticks: int) -> None:
    tree = kp.Tree(unique_placeholders(root))
    reg = _anything(tree)
    runs = []
    for _ in range(2):
        bb = kp.Blackboard(log=[], tick=0, seed=seed)
        bt = py_trees.trees.BehaviourTree(to_py_trees(tree, reg, bb, clock=lambda: 0.0))
        runs.append((bb, bt, PyTreesControl(bt, reg, bb)))
    (bb_a, bt_a, fast), (bb_b, bt_b, _) = runs
    for _ in range(ticks):
        for bb in (bb_a, bb_b):
            bb["tick"] += 1
        status = fast.tick()
        bt_b.tick()  # what py_trees does, visitors' walk included
        assert status == from_py_trees_status(bt_b.root.status)
        assert bb_a["log"] == bb_b["log"] and bt_a.count == bt_b.count
        assert [n.status for n in bt_a.root.iterate()] == [n.status for n in bt_b.root.iterate()]
