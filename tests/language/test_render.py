from __future__ import annotations

import re

import pytest

from ktbt_proto.render import render
from ktbt_proto.syntax import parse
from ktbt_proto.tree import (
    Action,
    Condition,
    Inverter,
    Node,
    Parallel,
    Placeholder,
    RunTimer,
    Selector,
    SequenceNode,
    Wait,
    WaitTimer,
)

SMALL = "<sl><sq><c>(!a)<a>(B, x=1)<e><k>(new)<e><a>(C)<e>"

EVERY_KIND = (
    "<pl>(2)<msq><neg><tt1>(1000)<tt2>(500)<w>(5)<e><e><e><wt>(0.5)<e><msl><k>(prior)"
    '<c>(inZone, r=2.5)<e><a>(MoveTo, x=1, y="a")<e><pl><sl><sq><c>(_inZoneF)<e><e><e><e>'
)

EDGE = re.compile(r"^\s*n(\d+) -> n(\d+);$", re.MULTILINE)


def test_outline_of_a_small_tree() -> None:
    assert render(parse(SMALL)) == (
        "Selector\n"
        "├── Sequence\n"
        "│   ├── Condition NOT a\n"
        "│   └── Action B(x=1)\n"
        "├── Knowledge [new] (empty)\n"
        "└── Action C\n"
    )


def test_outline_labels_every_node_type() -> None:
    assert render(parse(EVERY_KIND), "outline") == (
        "Parallel (≥2)\n"
        "├── Sequence (memory)\n"
        "│   ├── Inverter\n"
        "│   │   └── TT1 wait 1000 ticks\n"
        "│   │       └── TT2 run 500 ticks\n"
        "│   │           └── Wait 5 ticks\n"
        "│   └── Wait 0.5 s\n"
        "├── Selector (memory)\n"
        "│   ├── Knowledge [prior]\n"
        "│   │   └── Condition inZone(r=2.5)\n"
        '│   └── Action MoveTo(x=1, y="a")\n'
        "└── Parallel (all)\n"
        "    └── Selector\n"
        "        └── Sequence\n"
        "            └── Condition _inZoneF\n"
    )


def test_renders_a_bare_node_as_well_as_a_tree() -> None:
    node = Action("Go", (("fast", True),))
    assert render(node) == "Action Go(fast=true)\n"
    assert render(parse("<a>(Go, fast=true)")) == render(node)


@pytest.mark.parametrize("fmt", ["outline", "dot", "mermaid"])
def test_every_label_appears_in_every_format(fmt: str) -> None:
    out = render(parse(EVERY_KIND), fmt)  # type: ignore[arg-type]
    labels = ["Parallel (≥2)", "Sequence (memory)", "Inverter", "TT1 wait 1000 ticks"]
    labels += ["TT2 run 500 ticks", "Wait 5 ticks", "Wait 0.5 s", "Knowledge [prior]"]
    labels += ["Condition inZone(r=2.5)", "Parallel (all)", "Condition _inZoneF"]
    for text in labels:
        assert text in out, (fmt, text)
    assert out.endswith("\n")


def _chain(depth: int) -> Node:
    node: Node = Action("Leaf")
    for _ in range(depth - 1):
        node = Inverter((node,))
    return node


def test_deep_chain_renders_in_every_format() -> None:
    depth = 5000
    root = _chain(depth)
    outline = render(root, "outline").splitlines()
    assert len(outline) == depth
    assert outline[0] == "Inverter"
    assert outline[-1] == " " * 4 * (depth - 2) + "└── Action Leaf"
    dot = render(root, "dot")
    assert len(EDGE.findall(dot)) == depth - 1
    assert f"n{depth - 2} -> n{depth - 1};" in dot
    mermaid = render(root, "mermaid")
    assert mermaid.count(" --> ") == depth - 1
    assert f'n{depth - 1}("Action Leaf")' in mermaid


def test_dot_has_one_edge_per_parent_child_pair_in_child_order() -> None:
    dot = render(parse(SMALL), "dot")
    assert dot.startswith("digraph stringbt {\n")
    assert dot.endswith("}\n")
    assert dot.count("{") == dot.count("}") == 1
    edges = [(int(a), int(b)) for a, b in EDGE.findall(dot)]
    assert edges == [(0, 1), (1, 2), (1, 3), (0, 4), (0, 5)]
    assert len(set(edges)) == len(edges)
    declared = re.findall(r"^\s*n(\d+) \[", dot, re.MULTILINE)
    assert declared == [str(i) for i in range(6)]


def test_dot_shapes_distinguish_kinds() -> None:
    dot = render(parse(SMALL), "dot")
    assert 'n0 [label="Selector", shape=box];' in dot
    assert 'n2 [label="Condition NOT a", shape=ellipse];' in dot
    assert 'n3 [label="Action B(x=1)", shape=box, style="rounded"];' in dot
    assert 'n4 [label="Knowledge [new] (empty)", shape=box, style="dashed"];' in dot


def test_shared_subtree_is_drawn_once_per_occurrence() -> None:
    shared = SequenceNode((Condition("ok"), Action("Go")))
    dot = render(Selector((shared, shared)), "dot")
    edges = [(int(a), int(b)) for a, b in EDGE.findall(dot)]
    assert edges == [(0, 1), (1, 2), (1, 3), (0, 4), (4, 5), (4, 6)]


def test_quotes_and_backslashes_are_escaped() -> None:
    node = Action("Say", (("text", 'he said "hi" \\o/'),))
    # format_value already writes the string as a JSON literal: "he said \"hi\" \\o/"
    dot = render(node, "dot")
    assert r'n0 [label="Action Say(text=\"he said \\\"hi\\\" \\\\o/\")"' in dot
    mermaid = render(node, "mermaid")
    assert mermaid == (
        'flowchart TD\n    n0("Action Say(text=#quot;he said \\#quot;hi\\#quot; \\\\o/#quot;)")\n'
    )


def test_mermaid_escapes_entity_and_html_characters() -> None:
    out = render(Condition("c", args=(("s", "#quot; <b> & x"),)), "mermaid")
    assert '"Condition c(s=#quot;#35;quot; #lt;b#gt; #amp; x#quot;)"' in out


def test_mermaid_small_tree() -> None:
    assert render(parse(SMALL), "mermaid") == (
        "flowchart TD\n"
        '    n0["Selector"]\n'
        '    n1["Sequence"]\n'
        '    n2(["Condition NOT a"])\n'
        '    n3("Action B(x=1)")\n'
        '    n4[/"Knowledge [new] (empty)"/]\n'
        '    n5("Action C")\n'
        "    n0 --> n1\n"
        "    n1 --> n2\n"
        "    n1 --> n3\n"
        "    n0 --> n4\n"
        "    n0 --> n5\n"
    )


def test_programmatic_nodes_match_parsed_labels() -> None:
    root = Parallel(
        (
            WaitTimer((RunTimer((Wait(3),), ticks=2),), ticks=1),
            Placeholder((), name="common"),
            Wait(1.5, "seconds"),
        ),
        threshold=1,
    )
    assert render(root) == (
        "Parallel (≥1)\n"
        "├── TT1 wait 1 ticks\n"
        "│   └── TT2 run 2 ticks\n"
        "│       └── Wait 3 ticks\n"
        "├── Knowledge [common] (empty)\n"
        "└── Wait 1.5 s\n"
    )


def test_unknown_format_raises() -> None:
    with pytest.raises(ValueError, match="svg"):
        render(parse(SMALL), "svg")  # type: ignore[arg-type]
