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


def _leaf(node: Node, sep: str) -> str:
    if isinstance(node, Condition):
        head = ("!" if node.negated else "") + node.name
        tag = "<c>"
    elif isinstance(node, Action):
        head, tag = node.name, "<a>"
    elif isinstance(node, Wait):
        tag = "<w>" if node.unit == "ticks" else "<wt>"
        return f"{tag}({format_value(node.duration)})"
    else:
        raise TypeError(f"not a stringBT node: {node!r}")
    if not node.args:
        return f"{tag}({head})"
    args = sep.join(f"{k}={format_value(v)}" for k, v in node.args)
    return f"{tag}({head}{sep}{args})"


def opening_tag(node: Container) -> str:
    """The text that opens a container, arguments included (``<tt1>(5)``, ``<k>(new)``...)."""
    if isinstance(node, SequenceNode):
        return "<msq>" if node.memory else "<sq>"
    if isinstance(node, Selector):
        return "<msl>" if node.memory else "<sl>"
    if isinstance(node, Parallel):
        return "<pl>" if node.threshold is None else f"<pl>({format_value(node.threshold)})"
    if isinstance(node, Inverter):
        return "<neg>"
    if isinstance(node, WaitTimer):
        return f"<tt1>({format_value(node.ticks)})"
    if isinstance(node, RunTimer):
        return f"<tt2>({format_value(node.ticks)})"
    if isinstance(node, Placeholder):
        return f"<k>({node.name})"
    raise TypeError(f"not a stringBT node: {node!r}")


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
    while stack:
        item = stack.pop()
        if isinstance(item, str):
            out.append(item)
        elif isinstance(item, Container):
            out.append(opening_tag(item))
            stack.append("<e>")
            stack.extend(reversed(item.children))
        else:
            out.append(_leaf(item, ","))
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
            head = indent + opening_tag(item)
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
            line = indent + _leaf(item, ", ")
            if notes is not None and notes.trailing is not None:
                line += "  " + _comment(notes.trailing)
            add(line)
    if isinstance(tree, Tree):
        lines.extend(_comment(t) for t in tree.footer)
    lines.append("")
    return "\n".join(lines)
