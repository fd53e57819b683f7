"""Completion and hover: what may be written where the cursor is, and what a word means.

Both read the text as it is being typed (:mod:`.outline`), never only a text that parses:

- where a tag can start, the tags of spec/stringbt.md section 3, with the closing ``<e>`` first
  while a container is open;
- where a leaf names a condition or an action (``<c>(``, ``<a>(``, or just after the tag), the
  vocabulary's names of that kind (section 5.1), each with its signature and doc;
- after a leaf's name and a comma, the arguments it takes and has not been given, each with its
  type and range; after ``key=``, the values its choices allow (or ``true``/``false``);
- hover on a tag gives its meaning (section 3), on a leaf's name its signature and doc from the
  vocabulary, on an argument its type and range, on a placeholder's name its role (section 4).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Literal

from ktbt_proto.formatter import format_value
from ktbt_proto.tools.lsp.outline import Node, Outline
from ktbt_proto.tools.lsp.vocabularies import Entry, Known

TAG_MEANING: dict[str, str] = {
    "<sq>": "Sequence, reactive: ticks its children left to right while they succeed; every "
    "tick starts again at the first child.",
    "<msq>": "Sequence with memory: as `<sq>`, but resumes at the running child.",
    "<sl>": "Selector (fallback), reactive: ticks its children left to right until one does "
    "not fail.",
    "<msl>": "Selector with memory: as `<sl>`, but resumes at the running child.",
    "<pl>": "Parallel: ticks every child each tick; `<pl>(M)` succeeds when M succeed (all when "
    "M is omitted).",
    "<neg>": "Inverter: swaps SUCCESS and FAILURE of its one child; RUNNING passes through.",
    "<tt1>": "TT1, wait timer: `<tt1>(N)` is RUNNING for N ticks, then its child's status.",
    "<tt2>": "TT2, run timer: `<tt2>(N)` is its child's status for up to N ticks, then FAILURE.",
    "<k>": "Knowledge placeholder: `<k>(name)` is where learned knowledge is merged; a reactive "
    "selector over its items, FAILURE when empty.",
    "<c>": "Condition: `<c>(X)` is SUCCESS if X holds (`<c>(!X)`: if it does not), else FAILURE.",
    "<a>": "Action: `<a>(X)` runs the robot's action X, which returns SUCCESS, FAILURE or RUNNING.",
    "<w>": "Wait, in ticks: `<w>(N)` is RUNNING for N ticks, then SUCCESS.",
    "<wt>": "Wait, in seconds: `<wt>(S)` is RUNNING until S seconds have passed, then SUCCESS.",
    "<e>": "Closes the innermost open container.",
    "<Root>": "Optional marker before the root node; it carries no meaning.",
}
"""Each tag's meaning, from the table of spec/stringbt.md section 3."""

_SECTION = {"<k>": "4", "<e>": "3", "<Root>": "3"}

PLACEHOLDER_ROLE = {
    "common": "knowledge every robot has",
    "prior": "knowledge this robot was built with",
    "new": "knowledge learned from other robots",
}
"""The three segments of the KT-BT control tree, in priority order (spec/stringbt.md section 4)."""

_TAG_ORDER = [
    "<sq>", "<sl>", "<c>", "<a>", "<k>", "<msq>", "<msl>", "<pl>", "<neg>", "<tt1>", "<tt2>",
    "<w>", "<wt>",
]  # fmt: skip
_TYPED_TAG = re.compile(r"<[A-Za-z0-9_]*$")

ItemKind = Literal["tag", "close", "condition", "action", "argument", "value", "placeholder"]


@dataclass(frozen=True)
class Item:
    """A completion: its label, what it inserts over the offsets ``start``..``end``, and what it
    says of itself."""

    label: str
    kind: ItemKind
    insert: str
    start: int
    end: int
    detail: str = ""
    doc: str = ""
    order: str = field(default="5")


def _open_container(outline: Outline, offset: int) -> Node | None:
    """The innermost container open at ``offset`` (started before it, not yet closed there)."""
    found = None
    level = outline.roots
    while True:
        inner = next(
            (n for n in level if n.start < offset and (offset < n.end or not n.closed)), None
        )
        if inner is None:
            return found
        if inner.is_container and offset >= inner.head_end:
            found = inner
        level = inner.children


def _head_around(outline: Outline, offset: int) -> Node | None:
    """The node whose parenthesised head holds ``offset`` (between its ``(`` and ``)``)."""
    index = outline.token_at(offset - 1)
    while index >= 0 and outline.tokens[index].kind != "tag":
        index -= 1
    if index < 0:
        return None
    node = outline.by_start.get(outline.tokens[index].start)
    if node is None or node.paren is None:
        return None
    opening, closing = node.paren
    if opening < offset and (closing < 0 or offset <= closing):
        return node
    return None


def _in_comment(outline: Outline, offset: int) -> bool:
    return any(c.start < offset <= c.end for c in outline.comments)


def complete(text: str, outline: Outline, offset: int, known: Known | None) -> list[Item]:
    """The completions at ``offset`` (see the module's docstring)."""
    if _in_comment(outline, offset):
        return []
    node = _head_around(outline, offset)
    if node is not None:
        return _in_head(text, outline, node, offset, known)
    index = outline.token_at(offset - 1)
    before = outline.tokens[index] if index >= 0 else None
    if before is not None and before.kind == "string" and before.start < offset < before.end:
        return []
    if before is not None and before.text in ("<c>", "<a>") and before.end == offset:
        leaf = outline.by_start.get(before.start)
        if leaf is not None and leaf.paren is None and leaf.name is None and known is not None:
            kind: Literal["condition", "action"] = "condition" if before.text == "<c>" else "action"
            return [_name_item(e, f"({e.name})", offset, offset) for e in known.names(kind)]
    line_start = text.rfind("\n", 0, offset) + 1
    typed = _TYPED_TAG.search(text, line_start, offset)
    if typed is not None:
        start = typed.start()
    elif before is None or before.end < offset or before.text.endswith((">", ")")):
        start = offset
    else:
        return []
    items = []
    container = _open_container(outline, offset)
    if container is not None:
        line = text.count("\n", 0, container.start) + 1
        items.append(
            Item(
                "<e>",
                "close",
                "<e>",
                start,
                offset,
                detail=f"close the {container.tag} of line {line}",
                doc=TAG_MEANING["<e>"],
                order="0",
            )
        )
    for rank, tag in enumerate(_TAG_ORDER):
        items.append(
            Item(tag, "tag", tag, start, offset, doc=TAG_MEANING[tag], order=f"1{rank:02d}")
        )
    return items


def _name_item(entry: Entry, insert: str, start: int, end: int) -> Item:
    return Item(entry.name, entry.kind, insert, start, end, detail=entry.signature(), doc=entry.doc)


def _typed_word(text: str, offset: int) -> int:
    """Where the word being typed at ``offset`` starts (``offset`` when none is); a string
    value being typed starts at its opening quote."""
    start = offset
    while start > 0 and (text[start - 1].isalnum() or text[start - 1] in "_.-"):
        start -= 1
    if start > 0 and text[start - 1] == '"':
        start -= 1
    return start


def _in_head(
    text: str, outline: Outline, node: Node, offset: int, known: Known | None
) -> list[Item]:
    start = _typed_word(text, offset)
    if node.paren is None:
        return []
    first, last_index = outline.token_at(node.paren[0]) + 1, outline.token_at(start - 1) + 1
    inside = [t for t in outline.tokens[first:last_index] if t.end <= start]
    last = inside[-1].text if inside else "("
    if node.tag == "<k>":
        if inside:
            return []
        return [
            Item(name, "placeholder", name, start, offset, detail=role, order=str(rank))
            for rank, (name, role) in enumerate(PLACEHOLDER_ROLE.items())
        ]
    kind = node.kind
    if kind is None or known is None:
        return []
    if last in ("(", "!") and all(t.text == "!" for t in inside):
        return [_name_item(e, e.name, start, offset) for e in known.names(kind)]
    entry = known.entry(kind, node.name.text) if node.name is not None else None
    if entry is None:
        return []
    if last == ",":
        given = {k.text for k in node.keys if k.end <= start or k.start > offset}
        return [
            Item(
                a.name,
                "argument",
                f"{a.name}=",
                start,
                offset,
                detail=a.shown(),
                order=("0" if a.required else "1") + a.name,
            )
            for a in entry.arguments
            if a.name not in given
        ]
    if last == "=" and len(inside) >= 2 and inside[-2].kind == "name":
        argument = entry.argument(inside[-2].text)
        if argument is None:
            return []
        values = argument.choices or ([True, False] if argument.type == "bool" else [])
        shown = argument.shown()
        return [
            Item(format_value(v), "value", format_value(v), start, offset, detail=shown)
            for v in values
        ]
    return []


# -- hover --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Hover:
    """What a word means, in Markdown, over the offsets ``start``..``end``."""

    markdown: str
    start: int
    end: int


def hover(text: str, outline: Outline, offset: int, known: Known | None) -> Hover | None:
    """What the word at ``offset`` means (see the module's docstring)."""
    index = outline.token_at(offset)
    if index < 0:
        return None
    token = outline.tokens[index]
    if not token.start <= offset < token.end:
        return None
    if token.kind == "tag":
        meaning = TAG_MEANING.get(token.text)
        if meaning is None:
            return Hover(
                f"`{token.text}` is not a tag of stringBT (SBT102).", token.start, token.end
            )
        section = _SECTION.get(token.text, "3")
        return Hover(
            f"**{token.text}** {meaning}\n\n(spec/stringbt.md, section {section})",
            token.start,
            token.end,
        )
    if token.kind != "name":
        return None
    node = _head_around(outline, token.end)
    if node is None:  # the bare form: <c>X, <a>X
        tag_index = index - 1 - (outline.tokens[index - 1].text == "!" if index else 0)
        if tag_index < 0 or outline.tokens[tag_index].kind != "tag":
            return None
        node = outline.by_start.get(outline.tokens[tag_index].start)
        if node is None:
            return None
    if node.tag == "<k>" and node.name is token:
        return Hover(_placeholder(node), token.start, token.end)
    kind = node.kind
    if kind is None:
        return None
    if node.name is token:
        return Hover(_leaf(kind, token.text, known), token.start, token.end)
    if token in node.keys and known is not None and node.name is not None:
        entry = known.entry(kind, node.name.text)
        argument = entry.argument(token.text) if entry is not None else None
        if argument is not None:
            return Hover(f"argument `{argument.shown()}`", token.start, token.end)
    return None


def _leaf(kind: Literal["condition", "action"], name: str, known: Known | None) -> str:
    if known is None:
        return (
            f"{kind} `{name}`: no vocabulary is configured (`vocabulary` in ktbt.toml or "
            "pyproject.toml `[tool.ktbt]`, or `ktbt lsp --vocabulary`)"
        )
    entry = known.entry(kind, name)
    if entry is None:
        code = "SBT305" if kind == "condition" else "SBT306"
        return f"{kind} `{name}` is not in the vocabulary {known.spec} ({code})"
    doc = f"\n\n{entry.doc}" if entry.doc else ""
    return f"```\n{entry.signature()}\n```{doc}"


def _placeholder(node: Node) -> str:
    name = node.name.text if node.name is not None else ""
    role = PLACEHOLDER_ROLE.get(name)
    items = sum(1 for child in node.children if child.tag == "<sq>")
    said = f", the segment of {role}" if role else ""
    return (
        f"**<k>({name})**: a knowledge placeholder{said}. Learned items are merged here, "
        f"after the ones it holds ({items} sequence{'s' * (items != 1)} now); ticked, it is a "
        "reactive selector over them.\n\n(spec/stringbt.md, section 4)"
    )
