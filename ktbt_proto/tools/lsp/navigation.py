"""Finding one's way in a document: its outline, folds, definitions and semantic tokens.

- **Document symbols**: every node as written (:mod:`.outline`, so a text being typed still has
  one), placeholders and the knowledge items they hold named as spec/stringbt.md section 4
  names them (an item by its condition sequence);
- **folding ranges**: each container over several lines, from its tag to its ``<e>``, and each
  run of comment lines;
- **definition**: from a leaf's name to where the vocabulary defines it (its table in a
  vocabulary file, section 5.1, or the Python function or class of a ``module:callable``);
- **semantic tokens**: every token of section 1 by its role in the grammar of section 2 (a tag,
  a condition's or an action's name, a placeholder, an argument, a literal, a comment), so that
  highlighting follows the language itself.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from lsprotocol import types as lsp

from ktbt_proto.limits import DEFAULT_LIMITS
from ktbt_proto.tools.lsp.document import Document, units
from ktbt_proto.tools.lsp.outline import Node, Outline, tokens
from ktbt_proto.tools.lsp.vocabularies import Known

MAX_SYMBOLS = 20_000
"""Nodes shown in an outline at most (past them, a huge document's outline stops)."""
MAX_SYMBOL_DEPTH = DEFAULT_LIMITS.max_depth
"""Levels of an outline at most: the language's own depth limit (spec/stringbt.md section 8).
Deeper text is not stringBT, and a client reads nested symbols recursively: 100,000 levels
would break the client's reader, and the server's JSON writer, before any editor shows them."""
MAX_SEMANTIC_TOKENS = 250_000
"""Tokens highlighted at most; past them, a client keeps its own grammar's highlighting."""

TOKEN_TYPES = [
    "keyword",  # a tag
    "function",  # an action's name
    "variable",  # a condition's name
    "namespace",  # a placeholder's name
    "parameter",  # an argument's name
    "string",
    "number",
    "comment",
    "operator",  # ! before a condition
]
TOKEN_MODIFIERS = ["readonly"]  # a condition: it reads the blackboard, never writes it
LEGEND = lsp.SemanticTokensLegend(token_types=TOKEN_TYPES, token_modifiers=TOKEN_MODIFIERS)
_TYPE = {name: i for i, name in enumerate(TOKEN_TYPES)}

_CONTAINER_KIND = {
    "<sq>": lsp.SymbolKind.Array,
    "<msq>": lsp.SymbolKind.Array,
    "<sl>": lsp.SymbolKind.Enum,
    "<msl>": lsp.SymbolKind.Enum,
    "<pl>": lsp.SymbolKind.Struct,
    "<neg>": lsp.SymbolKind.Operator,
    "<tt1>": lsp.SymbolKind.Operator,
    "<tt2>": lsp.SymbolKind.Operator,
    "<k>": lsp.SymbolKind.Namespace,
}
_LEAF_KIND = {
    "<c>": lsp.SymbolKind.Boolean,
    "<a>": lsp.SymbolKind.Function,
    "<w>": lsp.SymbolKind.Event,
    "<wt>": lsp.SymbolKind.Event,
}


def _head_text(document: Document, node: Node) -> str:
    text = " ".join(document.text[node.start : node.head_end].split())
    return text if len(text) <= 80 else text[:77] + "..."


def _item_key(node: Node) -> list[Node] | None:
    """The leading conditions of a knowledge item (a reactive ``<sq>`` in a placeholder with
    conditions first and something after them), or None."""
    if node.tag != "<sq>" or node.parent is None or node.parent.tag != "<k>":
        return None
    conditions = []
    for child in node.children:
        if child.tag != "<c>":
            break
        conditions.append(child)
    if not conditions or len(conditions) == len(node.children):
        return None
    return conditions


def _symbol(document: Document, node: Node) -> lsp.DocumentSymbol:
    name = _head_text(document, node)
    detail = ""
    kind = _CONTAINER_KIND.get(node.tag) or _LEAF_KIND.get(node.tag, lsp.SymbolKind.Object)
    key = _item_key(node)
    if key is not None:
        shown = ", ".join(
            ("!" if c.negated else "") + (c.name.text if c.name else "?") for c in key
        )
        name, detail, kind = f"item {shown}", "knowledge item", lsp.SymbolKind.Class
    elif node.tag == "<k>":
        count = sum(1 for c in node.children if _item_key(c) is not None)
        detail = f"placeholder, {count} item{'s' * (count != 1)}"
    end = max(node.end, node.head_end)
    return lsp.DocumentSymbol(
        name=name or node.tag,
        detail=detail,
        kind=kind,
        range=document.range_of(node.start, end),
        selection_range=document.range_of(node.start, max(node.head_end, node.start)),
        children=[],
    )


def symbols(document: Document, outline: Outline) -> list[lsp.DocumentSymbol]:
    """The document's outline: a symbol for each node, nested as the nodes are."""
    roots: list[lsp.DocumentSymbol] = []
    stack: list[tuple[Node, list[lsp.DocumentSymbol], int]] = [
        (n, roots, 1) for n in reversed(outline.roots)
    ]
    count = 0
    while stack and count < MAX_SYMBOLS:
        node, into, depth = stack.pop()
        count += 1
        symbol = _symbol(document, node)
        into.append(symbol)
        if depth < MAX_SYMBOL_DEPTH:
            children: list[lsp.DocumentSymbol] = []
            symbol.children = children
            stack.extend((child, children, depth + 1) for child in reversed(node.children))
    return roots


def folding_ranges(document: Document, outline: Outline) -> list[lsp.FoldingRange]:
    """A fold for each container written over several lines, and each run of comment lines."""
    folds = []
    for node, _ in outline.walk():
        if node.is_container and node.closed:
            first = document.position_at(node.start).line
            last = document.position_at(node.end).line
            if last > first:
                folds.append(lsp.FoldingRange(start_line=first, end_line=last))
    run: list[int] = []
    for comment in outline.comments:
        line = document.position_at(comment.start).line
        if document.line_text(line).lstrip().startswith("#") and (not run or run[-1] == line - 1):
            run.append(line)
            continue
        if len(run) > 1:
            folds.append(
                lsp.FoldingRange(
                    start_line=run[0], end_line=run[-1], kind=lsp.FoldingRangeKind.Comment
                )
            )
        run = [line] if document.line_text(line).lstrip().startswith("#") else []
    if len(run) > 1:
        folds.append(
            lsp.FoldingRange(start_line=run[0], end_line=run[-1], kind=lsp.FoldingRangeKind.Comment)
        )
    return folds


def _leaf_named_at(outline: Outline, offset: int) -> Node | None:
    """The condition or action whose name is at ``offset``."""
    node = outline.node_at(offset)
    if node is None or node.kind is None or node.name is None:
        return None
    return node if node.name.start <= offset <= node.name.end else None


def definition(outline: Outline, offset: int, known: Known | None) -> tuple[Path, int] | None:
    """Where the vocabulary defines the condition or action named at ``offset``."""
    node = _leaf_named_at(outline, offset)
    if node is None or known is None or node.kind is None or node.name is None:
        return None
    return known.definition(node.kind, node.name.text)


@dataclass
class _Cursor:
    """Walks the text forward once, giving each token's LSP line and character: linear over
    the whole text, where converting each token's offset on its own would be quadratic on a
    long line."""

    document: Document
    line: int = 0
    offset: int = 0
    units: int = 0

    def at(self, offset: int) -> tuple[int, int]:
        doc = self.document
        position = None
        next_line = self.line + 1
        if next_line < doc.line_count and offset >= doc.offset_at(lsp.Position(next_line, 0)):
            position = doc.position_at(offset)
            self.line, self.units = position.line, position.character
        else:
            self.units += units(doc.text[self.offset : offset], doc.encoding)
        self.offset = offset
        return self.line, self.units


def semantic_tokens(
    document: Document, outline: Outline, start: int = 0, end: int | None = None
) -> list[int] | None:
    """The semantic tokens of the text from ``start`` to ``end``, encoded as LSP wants them
    (five integers a token, relative to the one before); None past ``MAX_SEMANTIC_TOKENS``."""
    role: dict[int, tuple[int, int]] = {}
    for node, _ in outline.walk():
        if node.name is not None:
            if node.tag == "<a>":
                role[node.name.start] = (_TYPE["function"], 0)
            elif node.tag == "<c>":
                role[node.name.start] = (_TYPE["variable"], 1)
            elif node.tag == "<k>":
                role[node.name.start] = (_TYPE["namespace"], 0)
        for key in node.keys:
            role[key.start] = (_TYPE["parameter"], 0)
    data: list[int] = []
    cursor = _Cursor(document)
    last_line = last_char = 0
    end = len(document.text) if end is None else end
    for token in tokens(document.text):
        if token.end <= start:
            continue
        if token.start >= end:
            break
        kind = token.kind
        if kind == "tag":
            typed = (_TYPE["keyword"], 0)
        elif kind in ("string", "number", "comment"):
            typed = (_TYPE[kind], 0)
        elif kind == "bool":
            typed = (_TYPE["keyword"], 0)
        elif token.text == "!":
            typed = (_TYPE["operator"], 0)
        elif token.start in role:
            typed = role[token.start]
        else:
            continue
        line, char = cursor.at(token.start)
        length = _length(document, token.start, token.end)
        if length <= 0:
            continue
        data += [
            line - last_line,
            char - last_char if line == last_line else char,
            length,
            typed[0],
            typed[1],
        ]
        last_line, last_char = line, char
        if len(data) > 5 * MAX_SEMANTIC_TOKENS:
            return None
    return data


def _length(document: Document, start: int, end: int) -> int:
    """A token's length in client units, cut at the end of its LSP line (a lone CR inside a
    comment ends an LSP line, not a stringBT one)."""
    text = document.text[start:end]
    cut = text.find("\r")
    return units(text if cut < 0 else text[:cut], document.encoding)
