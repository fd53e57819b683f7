"""A document's problems as an editor shows them: what ``ktbt check`` reports, with ranges.

The parser, the validator (against the robot's vocabulary when there is one) and the warnings
of ``items.find_warnings`` are the same calls ``ktbt check`` makes (spec/stringbt.md sections
5, 9 and 4.1), so the editor and the command line never disagree. Each problem's position is
where its token or node starts; the range is that token (an unknown character, a tag, the end
of the input), a leaf's or container's head (``<a>(TurnHandle, degrees=600)``), or the name a
problem is about (an unknown action's name). ``SBT5xx`` are warnings, every other code an
error. Only the problem's own head is read to place it, never the whole text again.
"""

from __future__ import annotations

from dataclasses import dataclass

from ktbt_proto.errors import ErrorCode, StringBTError
from ktbt_proto.items import find_warnings
from ktbt_proto.syntax import parse
from ktbt_proto.tools.lsp.outline import head_at, token_at
from ktbt_proto.tree import Tree
from ktbt_proto.validate import SupportsNames, find_problems

MAX_PROBLEMS = 1_000
"""Problems shown at most, the first in document order: past a thousand, a list of problems
helps no one, and would cost the editor more than the text itself."""
_ON_NAME = frozenset(
    (ErrorCode.UNKNOWN_CONDITION, ErrorCode.UNKNOWN_ACTION, ErrorCode.INVALID_NAME)
)


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
class Checked:
    """What checking a text gives: its tree when it parses, and its problems in order."""

    tree: Tree | None
    problems: list[Problem]


def check(text: str, registry: SupportsNames | None = None) -> Checked:
    """Parse, validate and look for warnings, as ``ktbt check`` does; never raises for any
    text (the library's own promise: a ``StringBTError`` or a tree)."""
    try:
        tree = parse(text)
    except StringBTError as error:
        return Checked(None, [_placed(text, error, node_problem=False)])
    found = find_problems(tree, registry)
    warnings = find_warnings(tree)
    ordered = sorted([*found, *warnings], key=lambda p: (p.line, p.column))
    if len(ordered) > MAX_PROBLEMS:
        ordered = ordered[:MAX_PROBLEMS]
    starts = line_starts(text) if ordered else []
    return Checked(tree, [_placed(text, p, node_problem=True, starts=starts) for p in ordered])


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
