"""A document's problems as an editor shows them: what ``ktbt check`` reports, with ranges.

The parser, the validator (against the robot's vocabulary when there is one) and the warnings
of ``items.find_warnings`` are the same calls ``ktbt check`` makes (spec/stringbt.md sections
5, 9 and 4.1), so the editor and the command line never disagree. Each problem's position is
where its token or node starts; the range is that token (an unknown character, a tag, the end
of the input), a leaf's or container's head (``<a>(TurnHandle, degrees=600)``), or the name a
problem is about (an unknown action's name). ``SBT5xx`` are warnings, every other code an
error. Only the problem's own head is read to place it, never the whole text again.

**After an edit inside one leaf's name** (typing ``MoveTo`` letter by letter), the server does
not read the whole text again: given the previous check and how much of the text's start and
end the edit left alone, :func:`check` renames that one leaf in the previous tree and validates
it alone. This gives the same tree and the same problems as checking the whole text, for
these reasons, each tested for (``tests/tools/lsp/test_analysis.py`` holds the two ways of
checking to the same result on edited texts):

- the text before the leaf's token and after its name is unchanged, and the new name is a
  whole stringBT name (spec/stringbt.md section 2) followed by what followed the old one, so
  the parser reads the same tokens, the leaf with its new name among them;
- no line break is added or removed, and when the name's length changes no other node starts
  on the edited line, so every other node keeps its position;
- what ``find_problems`` says of a leaf depends on that leaf alone (its name, arguments and the
  vocabulary), once no limit was reached (a limit is a whole-tree matter: no reuse then);
- warnings (``SBT501``, ``SBT502``) are only about knowledge items: a tree with no placeholder
  and a root that is no item has none, whatever its leaves are called; otherwise they are
  looked for again in the new tree.

Any other edit, a text that did not parse, or another vocabulary, and the whole text is
checked, exactly as ``ktbt check`` does.
"""

from __future__ import annotations

from bisect import bisect_right
from dataclasses import dataclass, field
from typing import cast

from ktbt_proto.errors import ErrorCode, LimitError, StringBTError
from ktbt_proto.items import find_warnings, split_item
from ktbt_proto.limits import DEFAULT_LIMITS
from ktbt_proto.syntax import NAME_RE, parse
from ktbt_proto.tools.lsp.outline import head_at, token_at
from ktbt_proto.tree import Action, Condition, Container, Node, Placeholder, Tree, with_children
from ktbt_proto.validate import SupportsNames, find_problems

MAX_PROBLEMS = 1_000
"""Problems shown at most, the first in document order: past a thousand, a list of problems
helps no one, and would cost the editor more than the text itself."""
_ON_NAME = frozenset(
    (ErrorCode.UNKNOWN_CONDITION, ErrorCode.UNKNOWN_ACTION, ErrorCode.INVALID_NAME)
)
_NAME_CHARS = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_.")
_AFTER_NAME = frozenset(" \t\r\n#,)")
"""What may follow a leaf's name in its token: a blank, a comment, its arguments or its end."""


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
    """Where a tree's nodes are: their positions in document order, the path (child indices
    from the root) to each, and whether the tree can hold a warning at all (it has a
    placeholder, or its root is a knowledge item)."""

    positions: list[tuple[int, int]]
    paths: list[tuple[int, ...]]
    warns: bool

    @classmethod
    def of(cls, tree: Tree) -> Nodes | None:
        """None when a node has no position (a tree that was not parsed)."""
        positions: list[tuple[int, int]] = []
        paths: list[tuple[int, ...]] = []
        warns = split_item(tree.root) is not None
        stack: list[tuple[Node, tuple[int, ...]]] = [(tree.root, ())]
        while stack:
            node, path = stack.pop()
            if node.pos is None:
                return None
            positions.append(node.pos)
            paths.append(path)
            if isinstance(node, Container):
                warns = warns or isinstance(node, Placeholder)
                children = node.children
                stack.extend((children[i], (*path, i)) for i in range(len(children) - 1, -1, -1))
        return cls(positions, paths, warns)


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
    leaf's name (see the module's docstring); None when it does not."""
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
    if old.startswith("\ufeff") or any(isinstance(p, LimitError) for p in previous.found):
        return None
    start, old_end = prefix, len(old) - suffix
    word = start
    while word and old[word - 1] in _NAME_CHARS and start - word <= DEFAULT_LIMITS.max_literal:
        word -= 1
    if old[word - 1 : word] not in ("(", "!"):
        return None  # not in a leaf's name (a tag, a blank, an argument): read it all
    nodes = previous.nodes()
    if nodes is None:
        return None
    line_start = old.rfind("\n", 0, start) + 1
    line = old.count("\n", 0, line_start) + 1
    at = bisect_right(nodes.positions, (line, start - line_start + 1)) - 1
    if at < 0 or nodes.positions[at][0] != line:
        return None
    path = nodes.paths[at]
    leaf = tree.root
    for i in path:
        leaf = leaf.children[i]  # type: ignore[attr-defined]
    kind = type(leaf)
    if kind is not Condition and kind is not Action:
        return None
    name: str = leaf.name  # type: ignore[attr-defined]
    pos = nodes.positions[at]
    head = ("<c>(!" if leaf.negated else "<c>(") if kind is Condition else "<a>("  # type: ignore[attr-defined]
    name_start = line_start + pos[1] - 1 + len(head)
    name_end = name_start + len(name)
    if not (
        name_start <= start
        and old_end <= name_end
        and old.startswith(head, name_start - len(head))
        and old.startswith(name, name_start)
        and old[name_end : name_end + 1] in _AFTER_NAME
    ):
        return None
    delta = len(text) - len(old)
    renamed = text[name_start : name_end + delta]
    if (
        NAME_RE.fullmatch(renamed) is None
        or renamed in ("true", "false")
        or len(renamed) > DEFAULT_LIMITS.max_literal
    ):
        return None
    if delta and at + 1 < len(nodes.positions) and nodes.positions[at + 1][0] == line:
        return None  # the nodes after it on this line would move
    new: Node = object.__new__(kind)
    new.__dict__.update(leaf.__dict__)
    new.__dict__["name"] = renamed
    root = _replaced(tree.root, path, new)
    renamed_tree = Tree(root, footer=tree.footer)
    found = [p for p in previous.found if (p.line, p.column) != pos]
    found.extend(find_problems(new, registry))
    found.sort(key=lambda p: (p.line, p.column))
    warnings = find_warnings(renamed_tree) if nodes.warns else []
    return _checked(text, registry, renamed_tree, found, warnings, nodes)


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
