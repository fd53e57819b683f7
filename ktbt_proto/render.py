"""Pictures of a tree for people: a terminal outline, Graphviz DOT and Mermaid.

stringBT is written for machines and diffs; these views are for reading a tree at a glance, in a
terminal, a notebook or a pull request. Every walk is iterative, because programmatically built
trees can be thousands of levels deeper than Python's recursion limit. Nodes are numbered per
occurrence, not per object, so a subtree shared by two parents is drawn twice, as it behaves.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Literal

from ktbt_proto.formatter import format_value
from ktbt_proto.tree import (
    Action,
    Args,
    Condition,
    Container,
    Inverter,
    Node,
    Parallel,
    Placeholder,
    RunTimer,
    Selector,
    SequenceNode,
    Tree,
    Visitor,
    Wait,
    WaitTimer,
    as_node,
)

Format = Literal["outline", "dot", "mermaid"]


def render(tree: Tree | Node, fmt: Format = "outline") -> str:
    """Draw a tree as ``outline`` (``tree``-style text), ``dot`` (Graphviz) or ``mermaid``.

    Every format ends with a newline, so the result can be written straight to a file.
    """
    root = as_node(tree)
    if fmt == "outline":
        return _outline(root)
    if fmt == "dot":
        return _dot(root)
    if fmt == "mermaid":
        return _mermaid(root)
    raise ValueError(f"unknown format {fmt!r}; use 'outline', 'dot' or 'mermaid'")


def call_text(name: str, args: Args) -> str:
    """A call as stringBT writes it: ``TargetSeen(colour=2)``, or the bare name."""
    if not args:
        return name
    return name + "(" + ", ".join(f"{k}={format_value(v)}" for k, v in args) + ")"


class _Labels(Visitor[str]):
    """A short human label: readers of a picture should not need to know stringBT tags."""

    def sequence(self, node: SequenceNode) -> str:
        return "Sequence (memory)" if node.memory else "Sequence"

    def selector(self, node: Selector) -> str:
        return "Selector (memory)" if node.memory else "Selector"

    def parallel(self, node: Parallel) -> str:
        return "Parallel (all)" if node.threshold is None else f"Parallel (≥{node.threshold})"

    def inverter(self, node: Inverter) -> str:
        return "Inverter"

    def wait_timer(self, node: WaitTimer) -> str:
        return f"TT1 wait {format_value(node.ticks)} ticks"

    def run_timer(self, node: RunTimer) -> str:
        return f"TT2 run {format_value(node.ticks)} ticks"

    def placeholder(self, node: Placeholder) -> str:
        return f"Knowledge [{node.name}]" + ("" if node.children else " (empty)")

    def condition(self, node: Condition) -> str:
        return "Condition " + ("NOT " if node.negated else "") + call_text(node.name, node.args)

    def action(self, node: Action) -> str:
        return "Action " + call_text(node.name, node.args)

    def wait(self, node: Wait) -> str:
        return f"Wait {format_value(node.duration)} " + ("ticks" if node.unit == "ticks" else "s")


_label = _Labels().visit


def _outline(root: Node) -> str:
    lines: list[str] = []
    # (node, text before its label, prefix for its children's lines)
    stack: list[tuple[Node, str, str]] = [(root, "", "")]
    while stack:
        node, head, indent = stack.pop()
        lines.append(head + _label(node))
        if isinstance(node, Container) and node.children:
            last = len(node.children) - 1
            for i in range(last, -1, -1):
                end = i == last
                stack.append(
                    (
                        node.children[i],
                        indent + ("└── " if end else "├── "),
                        indent + ("    " if end else "│   "),
                    )
                )
    lines.append("")
    return "\n".join(lines)


def _numbered(root: Node) -> Iterator[tuple[int, int | None, Node]]:
    """(id, parent id, node) in pre-order, so each parent's edges come out in child order."""
    stack: list[tuple[Node, int | None]] = [(root, None)]
    n = 0
    while stack:
        node, parent = stack.pop()
        yield n, parent, node
        if isinstance(node, Container):
            stack.extend((child, n) for child in reversed(node.children))
        n += 1


def _dot_attrs(node: Node) -> str:
    if isinstance(node, Condition):
        return "shape=ellipse"
    if isinstance(node, Action):
        return 'shape=box, style="rounded"'
    if isinstance(node, Wait):
        return 'shape=box, style="rounded,dotted"'
    if isinstance(node, Placeholder):
        return 'shape=box, style="dashed"'
    return "shape=box"


def _dot(root: Node) -> str:
    nodes: list[str] = []
    edges: list[str] = []
    for n, parent, node in _numbered(root):
        text = _label(node).replace("\\", "\\\\").replace('"', '\\"')
        nodes.append(f'    n{n} [label="{text}", {_dot_attrs(node)}];')
        if parent is not None:
            edges.append(f"    n{parent} -> n{n};")
    # ordering=out keeps children left to right, which is what a behaviour tree means.
    head = ["digraph stringbt {", "    graph [ordering=out];"]
    return "\n".join([*head, *nodes, *edges, "}", ""])


# Mermaid reads #name; as an entity and may treat < > & as HTML, so all of them are escaped.
_MERMAID_ESCAPES = str.maketrans(
    {"#": "#35;", '"': "#quot;", "&": "#amp;", "<": "#lt;", ">": "#gt;"}
)


def _mermaid_shape(node: Node) -> tuple[str, str]:
    if isinstance(node, Condition):
        return "([", "])"
    if isinstance(node, Action | Wait):
        return "(", ")"
    if isinstance(node, Placeholder):
        return "[/", "/]"
    return "[", "]"


def _mermaid(root: Node) -> str:
    lines = ["flowchart TD"]
    edges: list[str] = []
    for n, parent, node in _numbered(root):
        opening, closing = _mermaid_shape(node)
        text = _label(node).translate(_MERMAID_ESCAPES)
        lines.append(f'    n{n}{opening}"{text}"{closing}')
        if parent is not None:
            edges.append(f"    n{parent} --> n{n}")
    return "\n".join([*lines, *edges, ""])
