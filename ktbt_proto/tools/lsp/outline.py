"""The shape of a document's text, read even when it does not parse: tokens and nodes.

An editor asks about text that is being typed, so most of the time the text is not stringBT
yet. The parser (``syntax.parse``) rightly stops at the first problem; this module reads on.
:func:`tokens` splits any text into the tokens of spec/stringbt.md section 1 (a character that
starts none is an ``error`` token, an unterminated string runs to the end of its line), in
linear time and without raising; :func:`read` builds from them the nodes the text holds, each
with its tag, its head (the tag with its parenthesised part: what a diagnostic underlines) and
its extent (to its ``<e>``, or to the end of the text when it is never closed). Completion,
hover, folding, the outline and semantic tokens all read this; the diagnostics come from the
parser and validator themselves, placed with it.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Literal

from ktbt_proto.syntax import LEAF_TAGS, NAME_PATTERN, OPEN_TAGS

Kind = Literal["ws", "comment", "tag", "string", "bool", "name", "number", "punct", "error"]

_TOKEN = re.compile(
    r"(?P<ws>[ \t\r\n]+)"
    r"|(?P<comment>#[^\n]*)"
    r"|(?P<tag><[A-Za-z0-9_]*>)"
    r'|(?P<string>"(?:[^"\\\x00-\x1f]|\\["\\/bfnrt]|\\u[0-9a-fA-F]{4})*"|"[^"\n]*)'
    r"|(?P<bool>(?:true|false)(?![A-Za-z0-9_.]))"
    rf"|(?P<name>{NAME_PATTERN})"
    r"|(?P<number>-?[0-9]+(?:\.[0-9]+)?(?:[eE][+-]?[0-9]+)?)"
    r"|(?P<punct>[(),=!])"
    r"|(?P<error>[\s\S])"
)

TAGS = frozenset((*OPEN_TAGS, *LEAF_TAGS, "<e>", "<Root>"))
"""Every tag of the language (spec/stringbt.md section 1)."""


@dataclass(frozen=True, slots=True)
class Token:
    kind: Kind
    start: int
    end: int
    text: str


def tokens(text: str) -> Iterator[Token]:
    """Every token of ``text``, whitespace and comments included, in order; never raises."""
    for match in _TOKEN.finditer(text):
        kind = match.lastgroup
        yield Token(kind, match.start(), match.end(), match.group())  # type: ignore[arg-type]


@dataclass(eq=False)
class Node:
    """A node as written: ``tag`` (``<sq>``, ``<c>``...), where its head starts and ends, where
    the whole node ends (after its ``<e>``; the end of the text when unclosed), and what its
    head names: a leaf's ``name`` (and ``negated``) with its arguments' ``keys`` and their values'
    tokens, a placeholder's ``name``. ``children`` are the nodes inside a container."""

    tag: str
    start: int
    head_end: int
    end: int = -1
    name: Token | None = None
    negated: bool = False
    keys: list[Token] = field(default_factory=list)
    values: list[Token | None] = field(default_factory=list)
    paren: tuple[int, int] | None = None
    """The offsets of the head's ``(`` and of its ``)`` (-1 while it is not typed yet)."""
    children: list[Node] = field(default_factory=list)
    closed: bool = False
    parent: Node | None = field(default=None, repr=False)

    @property
    def is_container(self) -> bool:
        return self.tag in OPEN_TAGS

    @property
    def kind(self) -> Literal["condition", "action"] | None:
        return "condition" if self.tag == "<c>" else "action" if self.tag == "<a>" else None


@dataclass
class Outline:
    """What :func:`read` finds: the significant tokens, the top-level nodes, every node by the
    offset of its tag, the containers still open at the end, and the comment tokens."""

    tokens: list[Token]
    roots: list[Node]
    by_start: dict[int, Node]
    open_at_end: list[Node]
    comments: list[Token]

    def token_at(self, offset: int) -> int:
        """The index of the last significant token starting at or before ``offset`` (-1)."""
        lo, hi = 0, len(self.tokens)
        while lo < hi:
            mid = (lo + hi) // 2
            if self.tokens[mid].start <= offset:
                lo = mid + 1
            else:
                hi = mid
        return lo - 1

    def node_at(self, offset: int) -> Node | None:
        """The innermost node whose extent holds ``offset``."""
        found = None
        level = self.roots
        while True:
            inner = next((n for n in level if n.start <= offset < max(n.end, n.head_end)), None)
            if inner is None:
                return found
            found, level = inner, inner.children

    def walk(self) -> Iterator[tuple[Node, int]]:
        """Every node with its depth (a root is at 1), in document order, without recursion."""
        stack = [(n, 1) for n in reversed(self.roots)]
        while stack:
            node, depth = stack.pop()
            yield node, depth
            stack.extend((c, depth + 1) for c in reversed(node.children))


def read(text: str) -> Outline:
    """The nodes ``text`` holds, read as far as it goes (see the module's docstring)."""
    significant: list[Token] = []
    comments: list[Token] = []
    for token in tokens(text):
        if token.kind == "comment":
            comments.append(token)
        elif token.kind != "ws":
            significant.append(token)
    roots: list[Node] = []
    by_start: dict[int, Node] = {}
    stack: list[Node] = []
    i, n = 0, len(significant)
    while i < n:
        token = significant[i]
        i += 1
        if token.kind != "tag" or token.text == "<Root>":
            continue
        if token.text == "<e>":
            if stack:
                closing = stack.pop()
                closing.end, closing.closed = token.end, True
            continue
        node = Node(token.text, token.start, token.end)
        if token.text in LEAF_TAGS or token.text in ("<pl>", "<tt1>", "<tt2>", "<k>"):
            i = _head(node, significant, i)
        (stack[-1].children if stack else roots).append(node)
        if stack:
            node.parent = stack[-1]
        by_start[node.start] = node
        if token.text in OPEN_TAGS:
            stack.append(node)
        else:
            node.end = node.head_end
    for node in stack:
        node.end = len(text)
    return Outline(significant, roots, by_start, list(stack), comments)


def _head(node: Node, toks: list[Token], i: int) -> int:
    """Read what follows a tag that takes one (``(...)``, or a leaf's bare name or number) into
    ``node``; returns the index of the first token after the head. A head being typed (no
    ``)`` yet) ends before the next tag."""
    n = len(toks)
    if i < n and toks[i].text == "(":
        node.paren = (toks[i].start, -1)
        i += 1
        expect_key = False
        key: Token | None = None
        while i < n and toks[i].kind != "tag":
            tok = toks[i]
            i += 1
            node.head_end = tok.end
            if tok.text == ")":
                node.paren = (node.paren[0], tok.start)
                break
            if tok.text == "!" and node.name is None:
                node.negated = True
            elif tok.text == ",":
                expect_key, key = True, None
            elif tok.text == "=":
                continue
            elif expect_key and tok.kind == "name":
                key = tok
                node.keys.append(tok)
                node.values.append(None)
                expect_key = False
            elif key is not None and node.values and node.values[-1] is None:
                node.values[-1] = tok
            elif node.name is None and tok.kind in ("name", "number"):
                node.name = tok
        return i
    if node.tag in LEAF_TAGS:  # the bare form: <c>X, <c>!X, <a>X, <w>N
        if i < n and toks[i].text == "!" and node.tag == "<c>":
            node.negated = True
            node.head_end = toks[i].end
            i += 1
        if i < n and toks[i].kind in ("name", "number"):
            node.name = toks[i]
            node.head_end = toks[i].end
            i += 1
    return i


HEAD_TOKENS = 4096
"""How many tokens :func:`head_at` reads at most: a head longer than that (a leaf with thousands
of arguments) is underlined over its first ones."""


def head_at(text: str, offset: int) -> Node | None:
    """The node whose tag starts at ``offset``, its head read from there alone (what a
    diagnostic at a node's position underlines, without reading the rest of the text); None
    when no tag starts there."""
    significant: list[Token] = []
    for match in _TOKEN.finditer(text, offset):
        kind = match.lastgroup
        if kind in ("ws", "comment"):
            continue
        significant.append(Token(kind, match.start(), match.end(), match.group()))  # type: ignore[arg-type]
        if len(significant) > 1 and (kind == "tag" or significant[-1].text == ")"):
            break
        if len(significant) >= HEAD_TOKENS:
            break
    if not significant or significant[0].kind != "tag" or significant[0].start != offset:
        return None
    first = significant[0]
    node = Node(first.text, first.start, first.end)
    if first.text in LEAF_TAGS or first.text in ("<pl>", "<tt1>", "<tt2>", "<k>"):
        _head(node, significant, 1)
    return node


def leaf_end(text: str, at: int) -> int | None:
    """The offset just past the ``)`` that closes the leaf whose ``(`` ends at ``at``, strings
    read whole (a ``)`` in one is not it); None if a tag, a comment or a stray character comes
    first."""
    for match in _TOKEN.finditer(text, at):
        kind = match.lastgroup
        if kind == "punct" and match.group() == ")":
            return match.end()
        if kind in ("tag", "comment", "error"):
            return None
    return None


def token_to(text: str, line_start: int, offset: int) -> Token | None:
    """The first token that ends at or after ``offset`` (the one holding it, or the one just
    before it when tokens meet there), read from the start of its line, ``line_start``: only
    blanks span lines (a string or a comment stops at a line's end), so the tokens read from
    there are the text's. None when the text ends first."""
    for match in _TOKEN.finditer(text, line_start):
        if match.end() >= offset:
            return Token(match.lastgroup, match.start(), match.end(), match.group())  # type: ignore[arg-type]
    return None


def token_at(text: str, offset: int) -> Token | None:
    """The token that starts at ``offset`` (None at the end of the text)."""
    match = _TOKEN.match(text, offset)
    if match is None:
        return None
    return Token(match.lastgroup, match.start(), match.end(), match.group())  # type: ignore[arg-type]
