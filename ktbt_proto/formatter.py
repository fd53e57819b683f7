"""Writing stringBT: the canonical compact form (the wire form) and the pretty form (files).

Both are functions of the tree alone, so formatting is idempotent and ``parse(format(t)) == t``
holds in both styles (property-tested). The compact form has no whitespace and no comments:
equal trees give identical bytes, which is what makes it a knowledge digest. The pretty form puts
one node per line, indents four spaces per level and keeps every comment.
"""

from __future__ import annotations

import json
import math
import re
from typing import Literal

from ktbt_proto.errors import ErrorCode, ValidationError
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
    Value,
    Visitor,
    Wait,
    WaitTimer,
)

Style = Literal["pretty", "compact"]
_SURROGATE = re.compile("[\ud800-\udfff]")
INDENT = "    "


def format_value(value: Value) -> str:
    """The canonical literal of an argument value."""
    if value is True:
        return "true"
    if value is False:
        return "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValidationError(ErrorCode.INVALID_VALUE, f"{value} has no stringBT literal")
        return repr(value)
    if isinstance(value, str):
        text = json.dumps(value, ensure_ascii=False)
        # A lone surrogate (from a "\ud800" escape) cannot be UTF-8: keep it escaped.
        return _SURROGATE.sub(lambda m: f"\\u{ord(m.group()):04x}", text)
    raise ValidationError(
        ErrorCode.INVALID_VALUE, f"{type(value).__name__} values have no stringBT literal"
    )


class _Tags(Visitor[str]):
    """A node's tag: a container's opening tag with its arguments (``<tt1>(5)``, ``<k>(new)``),
    a leaf whole (its arguments separated by ``sep``)."""

    def __init__(self, sep: str = ",") -> None:
        self.sep = sep

    def sequence(self, node: SequenceNode) -> str:
        return "<msq>" if node.memory else "<sq>"

    def selector(self, node: Selector) -> str:
        return "<msl>" if node.memory else "<sl>"

    def parallel(self, node: Parallel) -> str:
        return "<pl>" if node.threshold is None else f"<pl>({format_value(node.threshold)})"

    def inverter(self, node: Inverter) -> str:
        return "<neg>"

    def wait_timer(self, node: WaitTimer) -> str:
        return f"<tt1>({format_value(node.ticks)})"

    def run_timer(self, node: RunTimer) -> str:
        return f"<tt2>({format_value(node.ticks)})"

    def placeholder(self, node: Placeholder) -> str:
        return f"<k>({node.name})"

    def condition(self, node: Condition) -> str:
        return self._call("<c>", ("!" if node.negated else "") + node.name, node.args)

    def action(self, node: Action) -> str:
        return self._call("<a>", node.name, node.args)

    def wait(self, node: Wait) -> str:
        tag = "<w>" if node.unit == "ticks" else "<wt>"
        return f"{tag}({format_value(node.duration)})"

    def _call(self, tag: str, head: str, args: Args) -> str:
        if not args:
            return f"{tag}({head})"
        return f"{tag}({head}{self.sep}{self.sep.join(f'{k}={format_value(v)}' for k, v in args)})"


_COMPACT, _SPACED = _Tags(","), _Tags(", ")


def format_tree(tree: Tree | Node, style: Style = "pretty") -> str:
    """Format a tree. ``compact``: one line, no trailing newline (the wire form);
    ``pretty``: one node per line, comments kept, ending with a newline (the file form)."""
    if style == "compact":
        return _compact(tree.root if isinstance(tree, Tree) else tree)
    if style == "pretty":
        return _pretty(tree)
    raise ValueError(f"unknown style {style!r}; use 'pretty' or 'compact'")


def _compact(root: Node) -> str:
    out: list[str] = []
    stack: list[Node | str] = [root]
    tag, other = _COMPACT.methods(), _COMPACT.other
    while stack:
        item = stack.pop()
        if isinstance(item, str):
            out.append(item)
        else:
            out.append(tag.get(type(item), other)(item))
            if isinstance(item, Container):
                stack.append("<e>")
                stack.extend(reversed(item.children))
    return "".join(out)


def _comment(text: str) -> str:
    # As black does: one space after the '#'; further indentation is the author's.
    text = text.rstrip()
    return "# " + text if text else "#"


def _pretty(tree: Tree | Node) -> str:
    root = tree.root if isinstance(tree, Tree) else tree
    lines: list[str] = []
    add = lines.append
    # Items: (node, depth) to open, or (str, depth) for a closing line already rendered.
    stack: list[tuple[Node | str, int]] = [(root, 0)]
    tag, other = _SPACED.methods(), _SPACED.other
    while stack:
        item, depth = stack.pop()
        indent = INDENT * depth
        if isinstance(item, str):
            add(indent + item)
            continue
        notes = item.comments
        if notes is not None:
            for text in notes.leading:
                add(indent + _comment(text))
        if isinstance(item, Container):
            head = indent + tag.get(type(item), other)(item)
            trailing = notes.trailing if notes is not None else None
            end_trailing = notes.end_trailing if notes is not None else None
            end = "<e>" if end_trailing is None else "<e>  " + _comment(end_trailing)
            if not item.children and trailing is None and (notes is None or not notes.end):
                add(head + end)
                continue
            if trailing is not None:
                head += "  " + _comment(trailing)
            add(head)
            closing: list[tuple[Node | str, int]] = [(end, depth)]
            if notes is not None:
                closing.extend((INDENT + _comment(t), depth) for t in reversed(notes.end))
            stack.extend(closing)
            stack.extend((child, depth + 1) for child in reversed(item.children))
        else:
            line = indent + tag.get(type(item), other)(item)
            if notes is not None and notes.trailing is not None:
                line += "  " + _comment(notes.trailing)
            add(line)
    if isinstance(tree, Tree):
        lines.extend(_comment(t) for t in tree.footer)
    lines.append("")
    return "\n".join(lines)
