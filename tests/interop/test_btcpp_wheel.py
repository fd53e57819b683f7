"""BehaviorTree.CPP 4.8.2 (the ``behaviortreepy`` wheel) runs what ``ktbt convert`` writes as
``LiveTree`` runs the stringBT tree: the port-less part of the differential tests, in
``make test``. The wheel registers leaves by name only, so trees here have no arguments and no
``KTBT_`` nodes; ``tests/interop/test_btcpp_engine.py`` (``make interop``) covers the rest
against BT.CPP built from source.
"""

from __future__ import annotations

import pytest
from hypothesis import given, settings

import ktbt_proto as kp
from ktbt_proto.interop import from_xml, to_xml
from ktbt_proto.tree import Node
from tests.btcpp.cases import ACTIONS, CONDITIONS, SAR_SCRIPTS, example, outcomes, trees
from tests.btcpp.trace import compact, live_trace, script_for, wheel_trace

pytest.importorskip("behaviortreepy", reason="pip install 'ktbt[btcpp]'")

TICKS = 8


def both(tree: kp.Tree, script: dict[str, str], ticks: int = TICKS) -> tuple[list[str], list[str]]:
    xml = to_xml(tree)
    plan = script_for(xml, script, ticks)
    return live_trace(tree, plan), wheel_trace(xml, plan)


@pytest.mark.parametrize("situation", sorted(SAR_SCRIPTS))
def test_paper_control_tree_ticks_the_same(situation: str) -> None:
    live, engine = both(example("paper_control.sbt"), SAR_SCRIPTS[situation])
    assert engine == live
    assert any(line.startswith("call ") for line in live)


def test_the_traces_can_differ() -> None:
    # The comparison sees a wrong export: a reactive sequence written as BT.CPP's Sequence.
    tree = kp.parse("<sq><c>(C0)<a>(A0)<e>")
    script = script_for(to_xml(tree), {"C0": "SF", "A0": "R"}, 3)
    wrong = to_xml(tree).replace("ReactiveSequence", "Sequence")
    assert wheel_trace(wrong, script) != live_trace(tree, script)


@settings(max_examples=40, deadline=None)
@given(outcomes(CONDITIONS[:2], ACTIONS[:3]))
def test_paper_shaped_random_outcomes(script: dict[str, str]) -> None:
    tree = kp.parse("<sl><sq><c>(C0)<a>(A0)<e><msq><c>(!C1)<a>(A1)<a>(A2)<e><k>(new)<e><a>(A0)<e>")
    live, engine = both(tree, script)
    assert engine == live


@settings(max_examples=60, deadline=None)
@given(trees(with_ports=False, ticks=False), outcomes(CONDITIONS, ACTIONS))
def test_random_port_less_trees(root: Node, script: dict[str, str]) -> None:
    tree = kp.Tree(root)
    live, engine = both(tree, script)
    assert engine == live


# The one node whose semantics differ (spec/stringbt.md section 12): BT.CPP's Parallel does not
# tick again a child that finished earlier in the same activation, and decides as soon as its
# count is reached, without ticking the children to the right.
PARALLEL_CASES = {
    "a finished child is not ticked again": (
        "<pl><a>(A0)<a>(A1)<e>",
        {"A0": "S", "A1": "RRS"},
        "call A0, call A1, status RUNNING; call A0, call A1, status RUNNING; "
        "call A0, call A1, status SUCCESS",
        "call A0, call A1, status RUNNING; call A1, status RUNNING; call A1, status SUCCESS",
    ),
    "decided before the last child": (
        "<pl>(1)<a>(A0)<a>(A1)<e>",
        {"A0": "S", "A1": "R"},
        "call A0, call A1, halt A1, status SUCCESS; " * 2
        + "call A0, call A1, halt A1, status SUCCESS",
        "call A0, status SUCCESS; call A0, status SUCCESS; call A0, status SUCCESS",
    ),
}


@pytest.mark.parametrize("case", sorted(PARALLEL_CASES))
def test_parallel_differs_as_the_spec_says(case: str) -> None:
    text, script, in_stringbt, in_btcpp = PARALLEL_CASES[case]
    live, engine = both(kp.parse(text), script, ticks=3)
    assert compact(live) == in_stringbt
    assert compact(engine) == in_btcpp


# The other way: trees written for BT.CPP with its built-in nodes, imported and ticked alike.
WRITTEN_FOR_BTCPP = """\
<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <ReactiveFallback>
      <ReactiveSequence>
        <C0/>
        <Inverter><C1/></Inverter>
        <A0/>
      </ReactiveSequence>
      <Sequence>
        <A1/>
        <Fallback><C2/><A2/></Fallback>
      </Sequence>
      <Inverter><A0/></Inverter>
    </ReactiveFallback>
  </BehaviorTree>
  <TreeNodesModel>
    <Condition ID="C0"/><Condition ID="C1"/><Condition ID="C2"/>
    <Action ID="A0"/><Action ID="A1"/><Action ID="A2"/>
  </TreeNodesModel>
</root>
"""


@settings(max_examples=30, deadline=None)
@given(outcomes(CONDITIONS[:3], ACTIONS[:3]))
def test_a_tree_written_for_btcpp_imports_and_ticks_the_same(script: dict[str, str]) -> None:
    tree = from_xml(WRITTEN_FOR_BTCPP)
    plan = script_for(WRITTEN_FOR_BTCPP, script, TICKS)
    assert wheel_trace(WRITTEN_FOR_BTCPP, plan) == live_trace(tree, plan)
