"""A document's problems as an editor shows them: what ``ktbt check`` reports, with ranges.

The parser, the validator (against the robot's vocabulary when there is one) and the warnings
of ``items.find_warnings`` are the same calls ``ktbt check`` makes (spec/stringbt.md sections
5, 9 and 4.1), so the editor and the command line never disagree. Each problem's position is
where its token or node starts; the range is that token (an unknown character, a tag, the end
of the input), a leaf's or container's head (``<a>(TurnHandle, degrees=600)``), or the name a
problem is about (an unknown action's name). ``SBT5xx`` are warnings, every other code an
error. Only the problem's own head is read to place it, never the whole text again.

**After an edit inside one leaf's parentheses** (typing ``MoveTo`` letter by letter, or
``degrees=60`` into ``degrees=600``), the server does not read the whole text again: given the
previous check and how much of the text's start and end the edit left alone, :func:`check`
reads that one leaf's token again, puts the leaf in the previous tree in place of the old one
and validates it alone. This gives the same tree and the same problems as checking the whole
text, for these reasons, each tested for (``tests/tools/lsp/test_analysis.py`` holds the two
ways of checking to the same result on chained random edits):

- the text before the leaf's token and after its ``)`` is unchanged, the old token (found by
  its own reading, strings whole) reads alone as the very leaf the tree holds there, and the new
  one reads alone as one leaf of the same kind, without a comment in it: the parser reads the
  same tokens around it, and this leaf among them (spec/stringbt.md section 2);
- no line break is added or removed, and when the length changes no other node starts after
  the edit on its line, so every other node keeps its position;
- what ``find_problems`` says of a leaf depends on that leaf alone (its name, arguments and the
  vocabulary), once no limit was reached (a limit is a whole-tree matter: no reuse then);
- warnings (``SBT501``, ``SBT502``) are only about knowledge items: a tree with no placeholder
  and a root that is no item has none, whatever its leaves hold; otherwise they are looked for
  again in the new tree.

Any other edit, a text that did not parse, or another vocabulary, and the whole text is
checked, exactly as ``ktbt check`` does.
"""

from __future__ import annotations

from bisect import bisect_left
from dataclasses import dataclass, field
from typing import cast

from ktbt_proto.errors import ErrorCode, LimitError, StringBTError
from ktbt_proto.items import find_warnings, split_item
from ktbt_proto.limits import DEFAULT_LIMITS
from ktbt_proto.syntax import parse
from ktbt_proto.tools.lsp.outline import head_at, leaf_end, token_at
from ktbt_proto.tree import (
    Action,
    Condition,
    Container,
    Node,
    Placeholder,
    Tree,
    Wait,
    with_children,
)
from ktbt_proto.validate import SupportsNames, find_problems

MAX_PROBLEMS = 1_000
"""Problems shown at most, the first in document order: past a thousand, a list of problems
helps no one, and would cost the editor more than the text itself."""
_ON_NAME = frozenset(
    (ErrorCode.UNKNOWN_CONDITION, ErrorCode.UNKNOWN_ACTION, ErrorCode.INVALID_NAME)
)
_LEAF_HEADS = ("<a>(", "<c>(", "<w>(", "<wt>(")
"""How a leaf's token starts when its parentheses follow its tag at once (the usual way)."""
_LEAVES = (Action, Condition, Wait)


@dataclass(frozen=True)
class Problem:
    """A problem placed in the text: ``start`` and ``end`` are offsets (code points)."""

    error: StringBTError
    start: int
    end: int

    @property
    def warning(self) -> bool:
        return self.error.code.value.startswith("SBT5")


@dataclass(frozen=True)
class Nodes:
    """Where a tree's nodes are: their positions in document order, each one's parent (its
    index here, -1 for the root) and place among the parent's children, and whether the tree
    can hold a warning at all (it has a placeholder, or its root is a knowledge item)."""

    positions: list[tuple[int, int]]
    parents: list[int]
    places: list[int]
    warns: bool

    @classmethod
    def of(cls, tree: Tree) -> Nodes | None:
        """None when a node has no position (a tree that was not parsed)."""
        positions: list[tuple[int, int]] = []
        parents: list[int] = []
        places: list[int] = []
        warns = split_item(tree.root) is not None
        stack: list[tuple[Node, int, int]] = [(tree.root, -1, 0)]
        while stack:
            node, parent, place = stack.pop()
            if node.pos is None:
                return None
            here = len(positions)
            positions.append(node.pos)
            parents.append(parent)
            places.append(place)
            if isinstance(node, Container):
                warns = warns or isinstance(node, Placeholder)
                children = node.children
                stack.extend((children[i], here, i) for i in range(len(children) - 1, -1, -1))
        return cls(positions, parents, places, warns)

    def path(self, at: int) -> tuple[int, ...]:
        """The child indices from the root to node ``at``."""
        path = []
        while self.parents[at] >= 0:
            path.append(self.places[at])
            at = self.parents[at]
        return tuple(reversed(path))


@dataclass
class Checked:
    """What checking a text gives: its tree when it parses, and its problems in order; and,
    for the next check of an edit of this text, the text itself, the vocabulary it was checked
    against, the validator's problems and the warnings apart, and where the tree's nodes are
    (found when first asked for)."""

    tree: Tree | None
    problems: list[Problem]
    text: str = ""
    registry: SupportsNames | None = None
    found: list[StringBTError] = field(default_factory=list)
    warnings: list[StringBTError] = field(default_factory=list)
    _nodes: Nodes | None = field(default=None, repr=False, compare=False)

    def nodes(self) -> Nodes | None:
        if self._nodes is None and self.tree is not None:
            self._nodes = Nodes.of(self.tree)
        return self._nodes


def check(
    text: str,
    registry: SupportsNames | None = None,
    previous: Checked | None = None,
    same: tuple[int, int] | None = None,
) -> Checked:
    """Parse, validate and look for warnings, as ``ktbt check`` does; never raises for any
    text (the library's own promise: a ``StringBTError`` or a tree).

    ``previous`` and ``same``: the check of the text this one was edited from, and how many
    code points at the start and at the end of the two texts the edits left unchanged (see
    the module's docstring for when that spares reading the whole text)."""
    if previous is not None and same is not None:
        again = _recheck(previous, text, registry, *same)
        if again is not None:
            return again
    try:
        tree = parse(text)
    except StringBTError as error:
        return Checked(None, [_placed(text, error, node_problem=False)], text, registry)
    return _checked(text, registry, tree, find_problems(tree, registry), find_warnings(tree))


def _checked(
    text: str,
    registry: SupportsNames | None,
    tree: Tree,
    found: list[StringBTError],
    warnings: list[StringBTError],
    nodes: Nodes | None = None,
) -> Checked:
    ordered = sorted([*found, *warnings], key=lambda p: (p.line, p.column))
    if len(ordered) > MAX_PROBLEMS:
        ordered = ordered[:MAX_PROBLEMS]
    starts = line_starts(text) if ordered else []
    problems = [_placed(text, p, node_problem=True, starts=starts) for p in ordered]
    return Checked(tree, problems, text, registry, found, warnings, nodes)


def _recheck(
    previous: Checked, text: str, registry: SupportsNames | None, prefix: int, suffix: int
) -> Checked | None:
    """The check of ``text`` from ``previous``'s, when the edit between them lies inside one
    leaf's parentheses (see the module's docstring); None when it does not."""
    old, tree = previous.text, previous.tree
    if tree is None or previous.registry is not registry or len(text) > DEFAULT_LIMITS.max_size:
        return None
    prefix = min(prefix, len(old), len(text))
    suffix = min(suffix, len(old) - prefix, len(text) - prefix)
    if not (
        text[:prefix] == old[:prefix] and text[len(text) - suffix :] == old[len(old) - suffix :]
    ):
        return None  # not the text previous checked, edited as said: read it all
    if prefix == len(old) == len(text):
        return previous  # the same text
    start, old_end, new_end = prefix, len(old) - suffix, len(text) - suffix
    removed, added = old[start:old_end], text[start:new_end]
    if "\n" in removed or "\n" in added or "#" in removed or "#" in added:
        return None  # a line or a comment comes or goes: read it all
    tag = old.rfind("<", 0, start)
    head = next((h for h in _LEAF_HEADS if old.startswith(h, tag)), None) if tag >= 0 else None
    if head is None or start < tag + len(head):
        return None  # not inside a leaf's parentheses (a tag, a blank...): read it all
    if old.startswith("\ufeff") or any(isinstance(p, LimitError) for p in previous.found):
        return None
    close = leaf_end(old, tag + len(head))
    if close is None or old_end >= close:
        return None
    nodes = previous.nodes()
    if nodes is None:
        return None
    line_start = old.rfind("\n", 0, tag) + 1
    line = old.count("\n", 0, line_start) + 1
    pos = (line, tag - line_start + 1)
    at = bisect_left(nodes.positions, pos)
    if at == len(nodes.positions) or nodes.positions[at] != pos:
        return None
    path = nodes.path(at)
    leaf = tree.root
    for i in path:
        leaf = leaf.children[i]  # type: ignore[attr-defined]
    kind = type(leaf)
    delta = new_end - old_end
    edited_line = line + old.count("\n", tag, start)
    if kind not in _LEAVES or (
        delta and at + 1 < len(nodes.positions) and nodes.positions[at + 1][0] == edited_line
    ):
        return None  # not a leaf, or the nodes after it on the edited line would move
    try:
        was, now = parse(old[tag:close]).root, parse(text[tag : close + delta]).root
    except StringBTError:
        return None  # the leaf is no longer one leaf: read it all
    if was != leaf or type(now) is not kind or now.comments is not None:
        return None
    now.__dict__["pos"], now.__dict__["comments"] = leaf.pos, leaf.comments
    renamed = Tree(_replaced(tree.root, path, now), footer=tree.footer)
    found = [p for p in previous.found if (p.line, p.column) != pos]
    found.extend(find_problems(now, registry))
    found.sort(key=lambda p: (p.line, p.column))
    warnings = find_warnings(renamed) if nodes.warns else []
    return _checked(text, registry, renamed, found, warnings, nodes)


def _replaced(node: Node, path: tuple[int, ...], new: Node) -> Node:
    """``node`` with the node at ``path`` (child indices) replaced by ``new``."""
    if not path:
        return new
    container = cast(Container, node)  # a path leads through containers
    children = list(container.children)
    children[path[0]] = _replaced(children[path[0]], path[1:], new)
    return with_children(container, tuple(children))


def line_starts(text: str) -> list[int]:
    """The offset where each stringBT line starts (lines end at LF)."""
    starts, at, find = [0], 0, text.find
    while (at := find("\n", at) + 1) > 0:
        starts.append(at)
    return starts


def offset_of(text: str, line: int, column: int, starts: list[int] | None = None) -> int:
    """The offset of a stringBT position (1-based line and column in code points, lines at
    LF); ``0:0`` (no position) is the start. ``starts``: the text's :func:`line_starts`, when
    many positions are placed in the same text."""
    if line < 1:
        return 0
    starts = line_starts(text) if starts is None else starts
    if line > len(starts):
        return len(text)
    at = starts[line - 1]
    end = starts[line] - 1 if line < len(starts) else len(text)
    return min(at + max(column - 1, 0), end)


def _placed(
    text: str, error: StringBTError, *, node_problem: bool, starts: list[int] | None = None
) -> Problem:
    start = offset_of(text, error.line, error.column, starts)
    code = error.code
    if code is ErrorCode.TOO_LARGE:  # the whole text: underline its first line
        end = text.find("\n")
        return Problem(error, 0, len(text) if end < 0 else end)
    node = head_at(text, start) if start < len(text) else None
    if node is not None and (
        node_problem or code in (ErrorCode.TOO_DEEP, ErrorCode.TOO_MANY_NODES)
    ):
        if code in _ON_NAME and node.name is not None:
            return Problem(error, node.name.start, node.name.end)
        return Problem(error, node.start, max(node.head_end, node.start + 1))
    token = token_at(text, start)
    if token is None or token.kind == "ws":  # the end of the input
        return Problem(error, start, start)
    return Problem(error, token.start, token.end)
