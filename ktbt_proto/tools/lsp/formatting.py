"""Edits that change a document's text but never what it means: formatting and certain fixes.

**Formatting** writes the pretty form (spec/stringbt.md section 7) with
``formatter.format_tree``, comments kept. The formatter guarantees ``parse(format(t)) == t``;
the edits are checked against it all the same (the edited text must parse to the same tree
with the same comments), and a text that does not parse is left as it is. The edits are the
changed runs of lines, not one replacement of the whole text, so an editor keeps its marks and
folds in the lines that did not change; a range formats the runs it touches.

**Fixes** (code actions) are offered only where the fix is certain, and each is checked on the
fixed text before it is offered:

- the re-run trap (``SBT502``, section 4.1): the actions after the item's leading conditions
  are put in one ``<msq>...<e>``, the memory form, so each runs once; the warning must be gone;
- an input that ends inside open nodes (``SBT104``): the missing ``<e>`` are added at the end,
  one a line at each node's indentation; the text must then parse.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass

from ktbt_proto.errors import ErrorCode, StringBTError
from ktbt_proto.formatter import INDENT, format_tree
from ktbt_proto.items import actions_rerun
from ktbt_proto.syntax import parse
from ktbt_proto.tools.lsp.diagnostics import offset_of
from ktbt_proto.tools.lsp.outline import Node, Outline, read
from ktbt_proto.tree import Action, Condition, Container, SequenceNode, Wait, WaitTimer, walk
from ktbt_proto.tree import Node as TreeNode


@dataclass(frozen=True)
class Edit:
    """Replace the text from ``start`` to ``end`` (offsets) with ``new``."""

    start: int
    end: int
    new: str


def apply(text: str, edits: list[Edit]) -> str:
    """The text with non-overlapping edits applied."""
    out, at = [], 0
    for edit in sorted(edits, key=lambda e: e.start):
        out += [text[at : edit.start], edit.new]
        at = edit.end
    out.append(text[at:])
    return "".join(out)


def _same(text: str, original: str) -> bool:
    """Whether ``text`` means what ``original`` means: the same tree and the same comments."""
    try:
        return format_tree(parse(text)) == format_tree(parse(original))
    except StringBTError:
        return False


def _lines(text: str) -> list[str]:
    """The text's lines, each with its LF (stringBT's only line break, spec/stringbt.md section
    1: a CR or a U+2028 inside a line is not one)."""
    lines = text.split("\n")
    last = lines.pop()
    return [line + "\n" for line in lines] + ([last] if last else [])


def format_edits(text: str, lines: tuple[int, int] | None = None) -> list[Edit]:
    """The edits that make ``text`` its pretty form: all of them, or those touching the lines
    ``lines`` (first and last, 0-based at LF); none when the text does not parse."""
    try:
        pretty = format_tree(parse(text))
    except StringBTError:
        return []
    if pretty == text:
        return []
    old, new = _lines(text), _lines(pretty)
    starts = [0]
    for line in old:
        starts.append(starts[-1] + len(line))
    edits = []
    matcher = difflib.SequenceMatcher(None, old, new, autojunk=False)
    for tag, i1, i2, j1, j2 in matcher.get_opcodes():
        if tag == "equal":
            continue
        if lines is not None and (i2 <= lines[0] or i1 > lines[1]) and i1 != i2:
            continue
        if lines is not None and i1 == i2 and not lines[0] <= i1 <= lines[1] + 1:
            continue
        edits.append(Edit(starts[i1], starts[i2], "".join(new[j1:j2])))
    if lines is not None and not _same(apply(text, edits), text):
        # The runs in the range do not stand alone here: format it all, which always does.
        return format_edits(text)
    return edits


# -- fixes --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Fix:
    """A certain fix: its title, the problem it fixes and its edits."""

    title: str
    code: ErrorCode
    edits: list[Edit]


def _line_indent(text: str, offset: int) -> str:
    start = text.rfind("\n", 0, offset) + 1
    line = text[start:offset]
    return line[: len(line) - len(line.lstrip(" \t"))]


def close_open_nodes(text: str, outline: Outline | None = None) -> Fix | None:
    """The ``<e>`` an input that ends inside open nodes lacks, added at its end (``SBT104``)."""
    outline = outline or read(text)
    if not outline.open_at_end:
        return None
    tail = "" if text.endswith("\n") or not text else "\n"
    closing = "".join(
        f"{_line_indent(text, node.start)}<e>\n" for node in reversed(outline.open_at_end)
    )
    fix = Fix("Close the open nodes with <e>", ErrorCode.UNEXPECTED_END, [])
    edit = Edit(len(text), len(text), tail + closing)
    try:
        parse(apply(text, [edit]))
    except StringBTError:
        return None
    return Fix(fix.title, fix.code, [edit])


def _first(node: TreeNode, kinds: tuple[type[TreeNode], ...]) -> TreeNode | None:
    return next((n for n, _ in walk(node) if isinstance(n, kinds)), None)


def _trap(sequence: SequenceNode) -> Action | None:
    """The action a reactive sequence runs again while a later child may run (the test of
    ``items.actions_rerun``, section 4.1), or None."""
    first: TreeNode | None = None
    for child in sequence.children:
        if first is not None and _first(child, (Action, Wait, WaitTimer)) is not None:
            return first if isinstance(first, Action) else None
        if first is None:
            first = _first(child, (Action,))
    return None


def memory_form(text: str, warning: StringBTError, outline: Outline | None = None) -> Fix | None:
    """The memory form for the item a ``SBT502`` warning is about: the children after the
    reactive sequence's leading conditions in one ``<msq>...<e>`` (a sequence with no leading
    condition becomes ``<msq>`` itself)."""
    try:
        tree = parse(text)
    except StringBTError:
        return None
    outline = outline or read(text)
    at = (warning.line, warning.column)
    for node, _ in walk(tree.root):
        if not isinstance(node, SequenceNode) or node.memory:
            continue
        action = _trap(node)
        if action is None or action.pos != at:
            continue
        fix = _wrap(text, node, outline)
        if fix is None:
            continue
        fixed = apply(text, fix)
        if (warning.line, warning.column) in {(w.line, w.column) for w in _warnings(fixed)}:
            continue
        if not _parses(fixed):
            continue
        return Fix("Run the actions once: the memory form (<msq>)", ErrorCode.ACTIONS_RERUN, fix)
    return None


def _warnings(text: str) -> list[StringBTError]:
    try:
        return actions_rerun(parse(text))
    except StringBTError:
        return []


def _parses(text: str) -> bool:
    try:
        parse(text)
    except StringBTError:
        return False
    return True


def _written(outline: Outline, node: TreeNode, text: str) -> Node | None:
    if node.pos is None:
        return None
    line, column = node.pos
    return outline.by_start.get(offset_of(text, line, column))


def _wrap(text: str, sequence: SequenceNode, outline: Outline) -> list[Edit] | None:
    written = _written(outline, sequence, text)
    if written is None or not written.closed:
        return None
    n = 0
    while n < len(sequence.children) and isinstance(sequence.children[n], Condition):
        n += 1
    if n == 0:  # no condition guards it: the sequence itself takes the memory
        return [Edit(written.start, written.start + len("<sq>"), "<msq>")]
    rest = [_written(outline, child, text) for child in sequence.children[n:]]
    first, last = rest[0], rest[-1]
    if first is None or last is None or not isinstance(sequence, Container):
        return None
    inner = _line_indent(text, first.start)
    start = text.rfind("\n", 0, first.start) + 1
    end_line = text.find("\n", last.end)
    end = len(text) if end_line < 0 else end_line
    after = text[last.end : end].strip()
    if text[start : first.start].strip() or (after and not after.startswith("#")):
        # Not one node a line: wrap in place.
        return [Edit(first.start, first.start, "<msq>"), Edit(last.end, last.end, "<e>")]
    # One node a line: the actions go one level deeper, between <msq> and <e> lines.
    body = text[start:end]
    deeper = "\n".join(INDENT + line if line.strip() else line for line in body.split("\n"))
    return [Edit(start, end, f"{inner}<msq>\n{deeper}\n{inner}<e>")]
