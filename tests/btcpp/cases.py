"""Trees and scripts both engines are run on: the paper's trees, random trees and outcomes."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

from hypothesis import strategies as st

import ktbt_proto as kp
from ktbt_proto.interop.btcpp import reference
from ktbt_proto.tree import (
    Args,
    Container,
    Inverter,
    Node,
    Placeholder,
    RunTimer,
    Selector,
    Wait,
    WaitTimer,
)

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
CONDITIONS = ("C0", "C1", "C2", "nav.Near")
ACTIONS = ("A0", "A1", "A2", "nav.Go")

condition_outcomes = st.text(alphabet="SF", min_size=1, max_size=5)
action_outcomes = st.text(alphabet="SFR", min_size=1, max_size=5)


@st.composite
def outcomes(
    draw: st.DrawFn, conditions: tuple[str, ...], actions: tuple[str, ...]
) -> dict[str, str]:
    """An outcome string per leaf name."""
    script = {name: draw(condition_outcomes) for name in conditions}
    script.update({name: draw(action_outcomes) for name in actions})
    return script


# Port values: ints within BT.CPP's 32-bit int; subnormal doubles on purpose (the export refuses
# them, BT.CPP cannot read them) next to the smallest normal one; braced strings such as "{x}"
# and " {x}", which BT.CPP would read as blackboard references were they not quoted. A string
# exported as a reference ("{x}" itself, spec/stringbt.md section 12) reads BT.CPP's blackboard,
# which LiveTree has not: those are tested apart (test_btcpp_engine.py), not compared here.
port_values = st.one_of(
    st.booleans(),
    st.integers(-(2**31), 2**31 - 1),
    st.floats(allow_nan=False, allow_infinity=False),
    st.sampled_from((5e-324, -1e-310, 2.2250738585072014e-308)),
    st.text(st.characters(codec="utf-8", exclude_categories=["Cs"]), max_size=8),
    st.text("{}x ", max_size=5),
).filter(lambda value: reference(value) is None)
port_names = st.sampled_from(("x", "goal", "nav.frame"))


def port_args(with_ports: bool) -> st.SearchStrategy[Args]:
    if not with_ports:
        return st.just(())
    pairs = st.lists(st.tuples(port_names, port_values), max_size=2, unique_by=lambda kv: kv[0])
    return pairs.map(tuple)


def leaves(with_ports: bool, ticks: bool) -> st.SearchStrategy[Node]:
    choices = [
        st.builds(kp.Condition, st.sampled_from(CONDITIONS), st.booleans(), port_args(with_ports)),
        st.builds(kp.Action, st.sampled_from(ACTIONS), port_args(with_ports)),
    ]
    if ticks:
        choices.append(st.builds(Wait, st.integers(0, 3), st.just("ticks")))
    return st.one_of(choices)


def trees(with_ports: bool = True, ticks: bool = True) -> st.SearchStrategy[Node]:
    """Random trees of every stringBT node both engines run alike: no ``<pl>`` (BT.CPP's
    Parallel differs, pinned apart) and no ``<wt>`` (wall-clock time). ``ticks``: with the
    three ``KTBT_`` nodes."""

    def extend(children: st.SearchStrategy[Node]) -> st.SearchStrategy[Node]:
        many = st.lists(children, min_size=1, max_size=4).map(tuple)
        one = children.map(lambda c: (c,))
        choices = [
            st.builds(kp.SequenceNode, many, st.booleans()),
            st.builds(Selector, many, st.booleans()),
            st.builds(Inverter, one),
            st.builds(Placeholder, st.lists(children, max_size=3).map(tuple), st.just("k")),
        ]
        if ticks:
            choices.append(st.builds(WaitTimer, one, st.integers(0, 3)))
            choices.append(st.builds(RunTimer, one, st.integers(0, 3)))
        return st.one_of(choices)

    return st.recursive(leaves(with_ports, ticks), extend, max_leaves=14).map(_unique)


def _unique(root: Node) -> Node:
    """Placeholder names made unique (a tree may hold each name once)."""
    counter = itertools.count()

    def go(node: Node) -> Node:
        if isinstance(node, Container):
            node = dataclasses.replace(node, children=tuple(go(c) for c in node.children))
            if isinstance(node, Placeholder):
                node = dataclasses.replace(node, name=f"k{next(counter)}")
        return node

    return go(root)


def example(name: str) -> kp.Tree:
    return kp.parse((EXAMPLES / name).read_text())


# Scripted runs of the paper's SAR tree: what happens when the robot meets each situation.
SAR_SCRIPTS = {
    "roams": {},
    "collides while walking": {"_collisionDetectedF": "FFSSF", "RandomWalk": "R"},
    "stops to wait": {"_waitF": "FSSF", "RandomWalk": "R", "StopWalk": "R"},
    "carries to the zone": {
        "_treasureOnBoardF": "SSSF",
        "_inZoneF": "FFS",
        "WalkToCollection": "R",
        "PlaceTreasure": "RS",
    },
    "picks a red target": {
        "TargetSeen": "SSF",
        "PickTreasure": "RRS",
        "AssignCollectionPoint": "R",
        "RandomWalk": "R",
    },
    "everything fails": {"RandomWalk": "F", "CollisionAvoidance": "F"},
}
