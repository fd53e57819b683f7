"""A document's problems as an editor shows them: what ``ktbt check`` reports, with ranges.

The parser, the validator (against the robot's vocabulary when there is one) and the warnings
of ``items.find_warnings`` are the same calls ``ktbt check`` makes (spec/stringbt.md sections
5, 9 and 4.1), so the editor and the command line never disagree. Each problem's position is
where its token or node starts; the range is that token (an unknown character, a tag, the end
of the input), a leaf's or container's head (``<a>(TurnHandle, degrees=600)``), or the name a
problem is about (an unknown action's name). ``SBT5xx`` are warnings, every other code an
error. Only the problem's own head is read to place it, never the whole text again.

**After an edit that leaves the text's tokens as they were, but for one leaf, one tag, blanks
or a comment's text**, the server does not read the whole text again: given the previous check
and how much of the text's start and end the edit left alone, :func:`check` reuses the previous
tree. Each way gives the same tree (positions and comments included) and the same problems as
checking the whole text, for the reasons below; ``tests/tools/lsp/test_analysis.py`` holds
the ways of checking to the same result on chained random edits. Common to all four: no ``#``
is added or removed, the text has no byte order mark, the previous check reached no limit (a
limit is a whole-tree matter) and the parser reads, around the edit, the same tokens as before
(spec/stringbt.md section 2: blanks and comments may stand between any two tokens).

- **Inside one leaf's tag or parentheses** (typing ``MoveTo`` letter by letter, ``degrees=60``
  into ``degrees=600``, ``<c>`` into ``<a>``): that leaf's token is read again, put in the tree
  in place of the old one and validated alone. The old token (found by its own reading,
  strings whole) reads alone as the very leaf the tree holds there, and the new one as one
  leaf, without a comment in it; no line comes or goes, and the nodes after the edit on its line
  move by the change of length (their problems found again when one has some); what
  ``find_problems`` says of a leaf depends on that leaf alone (its name, arguments and the
  vocabulary); warnings (``SBT501``, ``SBT502``) are only about knowledge items: a tree with no
  placeholder and a root that is no item has none, whatever its leaves hold (whether the root
  is an item is found again when a leaf changes kind); otherwise they are looked for again in
  the new tree.
- **Inside a container's tag** (``<sq>`` to ``<sl>``, ``<msq>``, ``<pl>``, ``<neg>``...): when
  the old and the new token are both tags that make a container's whole head (``<sq>``,
  ``<msq>``, ``<sl>``, ``<msl>``, ``<pl>``, ``<neg>``), the old one reads alone as the very
  container the tree holds at its position (so not ``<pl>(2)``, whose threshold would follow a
  ``<sq>``), the container is replaced by one of the new kind with the same children, position
  and comments, the nodes after the tag on its line move by the change of length, and the tree
  is validated again whole and its warnings looked for (the checks of a container depend on
  its kind and children, and whether the root is a knowledge item on the root's kind), which
  costs a third of reading the text.
- **In blanks** (spaces, tabs and line breaks, typed or deleted): the edit is blanks for blanks,
  in a run of blanks or just after a token, read from the start of its line (only blanks span
  lines, so the tokens read from there are the text's): never in a string or a comment (blanks
  typed after a comment's end are stripped from its text). Nodes' positions are where their
  tags start, so the tree is the same but for the nodes after the edit, which move: on its last
  line with its end, on later lines by the lines it adds or removes. A comment's place (trailing
  a node, or leading the next) depends on whether a token stands before it on its line, so a
  line may come or go only when no ``#`` stands on the edit's lines. The problems of nodes that
  moved are found again (the tree validated again when one has a problem), the others stay.

- **In a comment's text** (after its ``#``, no line broken): the comment is the same token to
  the end of its line, so it stays where the parser put it, with its new text. Which comment of
  the tree it is: when the text holds as many ``#`` as the tree holds comments, each ``#``
  starts one of them (none in a string, none dropped), so the one comment held with the old
  text, when only one is, is the one edited. Problems and positions stay.

Any other edit (a ``#`` typed or deleted, a ``<e>``, a line broken beside a comment...), a text
that did not parse, or another vocabulary, and the whole text is checked, exactly as ``ktbt
check`` does.
"""

from __future__ import annotations

import re
from bisect import bisect_left
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from typing import Any, cast

from ktbt_proto.errors import ErrorCode, LimitError, StringBTError
from ktbt_proto.items import find_warnings, split_item
from ktbt_proto.limits import DEFAULT_LIMITS
from ktbt_proto.syntax import comment_text, parse
from ktbt_proto.tools.lsp.outline import head_at, leaf_end, token_at, token_to
from ktbt_proto.tree import (
    Action,
    Comments,
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
_BARE_TAGS = {
    tag: cast(Container, parse(tag + "<e>").root)
    for tag in ("<sq>", "<msq>", "<sl>", "<msl>", "<pl>", "<neg>")
}
"""The containers whose head can be their tag alone (a parallel's threshold is optional), each
as the parser reads it with no child."""
_BLANKS = re.compile(r"[ \t\r\n]*")


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
    index here, -1 for the root), place among the parent's children and the index past its
    subtree's last node; whether the tree holds a placeholder and its root is a knowledge item
    (a tree can hold a warning only then); and every comment it holds, as the index of its node
    (-1 for the footer), its field of :class:`~ktbt_proto.tree.Comments`, its place in that
    field and its text."""

    positions: list[tuple[int, int]]
    parents: list[int]
    places: list[int]
    ends: list[int]
    placeholder: bool
    item: bool
    comments: list[tuple[int, str, int, str]]

    @property
    def warns(self) -> bool:
        return self.placeholder or self.item

    @classmethod
    def of(cls, tree: Tree) -> Nodes | None:
        """None when a node has no position (a tree that was not parsed)."""
        positions: list[tuple[int, int]] = []
        parents: list[int] = []
        places: list[int] = []
        placeholder = False
        comments = [(-1, "footer", k, text) for k, text in enumerate(tree.footer)]
        stack: list[tuple[Node, int, int]] = [(tree.root, -1, 0)]
        while stack:
            node, parent, place = stack.pop()
            if node.pos is None:
                return None
            here = len(positions)
            positions.append(node.pos)
            parents.append(parent)
            places.append(place)
            if node.comments is not None:
                comments.extend(_held(here, node.comments))
            if isinstance(node, Container):
                placeholder = placeholder or isinstance(node, Placeholder)
                children = node.children
                stack.extend((children[i], here, i) for i in range(len(children) - 1, -1, -1))
        ends = list(range(1, len(positions) + 1))
        for i in range(len(positions) - 1, 0, -1):  # a subtree ends where its last one does
            parent = parents[i]
            if ends[i] > ends[parent]:
                ends[parent] = ends[i]
        item = split_item(tree.root) is not None
        return cls(positions, parents, places, ends, placeholder, item, comments)

    def but(self, **changes: object) -> Nodes:
        return replace(self, **changes)  # type: ignore[arg-type]

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
    by: str = "text"
    """How it was made: ``text`` (the whole text read), ``leaf``, ``tag``, ``blanks`` or
    ``comment``."""

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
    by: str = "text",
) -> Checked:
    ordered = sorted([*found, *warnings], key=lambda p: (p.line, p.column))
    if len(ordered) > MAX_PROBLEMS:
        ordered = ordered[:MAX_PROBLEMS]
    starts = line_starts(text) if ordered else []
    problems = [_placed(text, p, node_problem=True, starts=starts) for p in ordered]
    return Checked(tree, problems, text, registry, found, warnings, nodes, by)


def _recheck(
    previous: Checked, text: str, registry: SupportsNames | None, prefix: int, suffix: int
) -> Checked | None:
    """The check of ``text`` from ``previous``'s, when the edit between them lies inside one
    leaf, inside one container's tag, in blanks or in a comment's text (see the module's
    docstring); None when it does not."""
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
    if "#" in old[start:old_end] or "#" in text[start:new_end]:
        return None  # a comment comes or goes: read it all
    if old.startswith("\ufeff") or any(isinstance(p, LimitError) for p in previous.found):
        return None
    edit = _Edit(previous, tree, text, registry, start, old_end, new_end)
    return edit.in_leaf() or edit.in_tag() or edit.in_blanks() or edit.in_comment()


@dataclass
class _Edit:
    """One edit of a checked text that parsed: where it is, and the four ways of checking the
    new text from the old check."""

    previous: Checked
    tree: Tree
    text: str
    registry: SupportsNames | None
    start: int
    old_end: int
    new_end: int

    def _node_at(self, nodes: Nodes, offset: int) -> tuple[int, int, int] | None:
        """The index in :class:`Nodes` of the node whose tag starts at ``offset`` of the old
        text, with its line and the offset where that line starts; None if none does."""
        old = self.previous.text
        line_start = old.rfind("\n", 0, offset) + 1
        line = old.count("\n", 0, line_start) + 1
        pos = (line, offset - line_start + 1)
        positions = nodes.positions
        at = bisect_left(positions, pos)
        if at == len(positions) or positions[at] != pos:
            return None
        return at, line, line_start

    def _node(self, nodes: Nodes, at: int) -> Node:
        node = self.tree.root
        for i in nodes.path(at):
            node = node.children[i]  # type: ignore[attr-defined]
        return node

    def _moved(self, nodes: Nodes) -> tuple[int, int, list[tuple[int, int]]]:
        """The indices ``lo`` to ``hi`` of the nodes that start after the edit and move with
        it, and every node's position in the new text: those on the edit's last line follow
        its end, those on later lines (all moved when a line comes or goes) change line."""
        old, text, old_end, new_end = self.previous.text, self.text, self.old_end, self.new_end
        positions = nodes.positions
        old_start = old.rfind("\n", 0, old_end) + 1  # the start of old_end's line
        line = old.count("\n", 0, old_start) + 1
        lines = text.count("\n", self.start, new_end) - old.count("\n", self.start, old_end)
        column = old_end - old_start + 1
        shift = new_end - (text.rfind("\n", 0, new_end) + 1) + 1 - column
        lo = bisect_left(positions, (line, column))
        hi = len(positions) if lines else bisect_left(positions, (line + 1, 0), lo)
        if lo == hi or not (lines or shift):
            return 0, 0, positions
        moved = positions[:lo]
        for i in range(lo, hi):
            at_line, at_column = positions[i]
            if at_line == line:
                moved.append((at_line + lines, at_column + shift))
            else:
                moved.append((at_line + lines, at_column))
        moved.extend(positions[hi:])
        return lo, hi, moved

    def in_leaf(self) -> Checked | None:
        """An edit inside one leaf's tag or parentheses: that leaf read again and validated
        alone."""
        old, text, start = self.previous.text, self.text, self.start
        if "\n" in old[start : self.old_end] or "\n" in text[start : self.new_end]:
            return None  # a line comes or goes
        tag = old.rfind("<", 0, start)
        head = next((h for h in _LEAF_HEADS if old.startswith(h, tag)), None) if tag >= 0 else None
        if head is None:
            return None  # not inside a leaf (a container's tag, a blank...)
        close = leaf_end(old, tag + len(head))
        if close is None or self.old_end >= close:
            return None
        nodes = self.previous.nodes()
        found_at = None if nodes is None else self._node_at(nodes, tag)
        if nodes is None or found_at is None:
            return None
        at = found_at[0]
        leaf = self._node(nodes, at)
        kind = type(leaf)
        delta = self.new_end - self.old_end
        if kind not in _LEAVES:
            return None
        try:
            was, now = parse(old[tag:close]).root, parse(text[tag : close + delta]).root
        except StringBTError:
            return None  # the leaf is no longer one leaf
        if was != leaf or type(now) not in _LEAVES or now.comments is not None:
            return None
        now.__dict__["pos"], now.__dict__["comments"] = leaf.pos, leaf.comments
        tree = self.tree
        lo, hi, positions = self._moved(nodes) if delta else (0, 0, nodes.positions)
        root = _copied(tree.root, 0, nodes.ends, at, now, lo, hi, positions)
        renamed = Tree(root, footer=tree.footer)
        pos = leaf.pos
        found = [p for p in self.previous.found if (p.line, p.column) != pos]
        found.extend(find_problems(now, self.registry))
        found.sort(key=lambda p: (p.line, p.column))
        if lo < hi:  # the nodes after it on its line moved, and their problems with them
            first, last = nodes.positions[lo], nodes.positions[hi - 1]
            if any(first <= (p.line, p.column) <= last for p in found):
                found = find_problems(renamed, self.registry)
            nodes = nodes.but(positions=positions)
        if type(now) is not kind:  # a condition that leads an item, or an action...
            nodes = nodes.but(item=split_item(root) is not None)
        warnings = find_warnings(renamed) if nodes.warns else []
        return _checked(text, self.registry, renamed, found, warnings, nodes, "leaf")

    def in_tag(self) -> Checked | None:
        """An edit inside a container's tag that leaves another tag standing alone: the
        container's kind swapped in the old tree, the tree validated again without reading."""
        old, text, start = self.previous.text, self.text, self.start
        tag = old.rfind("<", 0, start + 1)
        close = old.find(">", tag) + 1
        delta = self.new_end - self.old_end
        if tag < 0 or close == 0 or self.old_end > close:
            return None
        was_tag, now_tag = old[tag:close], text[tag : close + delta]
        if was_tag not in _BARE_TAGS or now_tag not in _BARE_TAGS:
            return None
        nodes = self.previous.nodes()
        found_at = None if nodes is None else self._node_at(nodes, tag)
        if nodes is None or found_at is None:
            return None
        container = self._node(nodes, found_at[0])
        if not isinstance(container, Container):
            return None
        was = _BARE_TAGS[was_tag]
        if with_children(was, container.children) != container:
            return None  # a parallel's threshold after its tag: no longer one
        now = with_children(_BARE_TAGS[now_tag], container.children)
        now.__dict__["pos"], now.__dict__["comments"] = container.pos, container.comments
        return self._rebuilt(nodes, found_at[0], now, *self._moved(nodes), "tag")

    def in_blanks(self) -> Checked | None:
        """Blanks (spaces, tabs, line breaks) typed, or deleted from a run of blanks, between
        two tokens: the same tree, its nodes after the edit moved."""
        old, start, old_end = self.previous.text, self.start, self.old_end
        if _BLANKS.fullmatch(self.text, start, self.new_end) is None:
            return None
        line_start = old.rfind("\n", 0, start) + 1
        if not start == line_start == old_end:  # blanks typed at a line's start are blanks
            token = token_to(old, line_start, old_end)
            if token is None or not (
                (token.kind == "ws" and token.start <= start)  # in a run of blanks
                or token.end == start  # typed after a token (a comment's end is stripped)
            ):
                return None  # in a token: a string's, a comment's, a name's...
        if "\n" in old[start:old_end] or "\n" in self.text[start : self.new_end]:
            # Lines come or go: whether a comment trails a node or leads the next depends on
            # the tokens before it on its line, so none may stand on the edit's lines.
            line_end = old.find("\n", old_end)
            rest = old[old_end:] if line_end < 0 else old[old_end:line_end]
            if "#" in old[line_start:start] or "#" in rest:
                return None
        nodes = self.previous.nodes()
        if nodes is None:
            return None
        return self._rebuilt(nodes, -1, None, *self._moved(nodes), "blanks")

    def in_comment(self) -> Checked | None:
        """An edit inside a comment's text (after its ``#``, no line broken): the same tree,
        with that comment's new text where the old one was."""
        old, text, start, old_end = self.previous.text, self.text, self.start, self.old_end
        if "\n" in text[start : self.new_end]:
            return None
        line_start = old.rfind("\n", 0, start) + 1
        token = token_to(old, line_start, old_end)
        if token is None or token.kind != "comment" or not token.start < start:
            return None
        delta = self.new_end - old_end
        was = comment_text(old[token.start + 1 : token.end])
        now = comment_text(text[token.start + 1 : token.end + delta])
        nodes = self.previous.nodes()
        if nodes is None:
            return None
        tree = self.tree
        if was != now:
            # Each "#" starts a comment the tree holds, so the one comment held with the old
            # text is the one edited.
            held = [i for i, c in enumerate(nodes.comments) if c[3] == was]
            if len(held) != 1 or old.count("#") != len(nodes.comments):
                return None
            at, where, k, _ = nodes.comments[held[0]]
            comments = nodes.comments[:]
            comments[held[0]] = (at, where, k, now)
            nodes = nodes.but(comments=comments)
            if at < 0:
                tree = Tree(tree.root, footer=_put(tree.footer, k, now))
            else:
                node = self._node(nodes, at)
                notes = cast(Comments, node.comments)
                texts = getattr(notes, where)
                texts = _put(texts, k, now) if isinstance(texts, tuple) else now
                copy = object.__new__(type(node))
                copy.__dict__.update(node.__dict__)
                changes: dict[str, Any] = {where: texts}
                copy.__dict__["comments"] = replace(notes, **changes)
                root = _copied(tree.root, 0, nodes.ends, at, copy, 0, 0, nodes.positions)
                tree = Tree(root, footer=tree.footer)
        previous = self.previous
        return _checked(
            text, self.registry, tree, previous.found, previous.warnings, nodes, "comment"
        )

    def _rebuilt(
        self,
        nodes: Nodes,
        at: int,
        new: Container | None,
        lo: int,
        hi: int,
        positions: list[tuple[int, int]],
        by: str,
    ) -> Checked:
        """The old tree with the node at index ``at`` replaced by ``new`` and the nodes
        ``lo`` to ``hi`` given their new ``positions``; validated again (and warnings looked
        for) when a node changed kind or a problem moved, its problems kept otherwise."""
        previous, tree = self.previous, self.tree
        root = _copied(tree.root, 0, nodes.ends, at, new, lo, hi, positions)
        item = nodes.item if new is None or at else split_item(root) is not None
        moved = nodes.but(positions=positions, item=item)
        renamed = Tree(root, footer=tree.footer)
        found, warnings = previous.found, previous.warnings
        if lo < hi and new is None:  # the problems of the nodes that moved move with them
            first, last = nodes.positions[lo], nodes.positions[hi - 1]
            stay = all(not first <= (p.line, p.column) <= last for p in (*found, *warnings))
        else:
            stay = new is None
        if not stay:
            found = find_problems(renamed, self.registry)
            warnings = find_warnings(renamed) if moved.warns else []
        return _checked(self.text, self.registry, renamed, found, warnings, moved, by)


def _held(at: int, comments: Comments) -> Iterator[tuple[int, str, int, str]]:
    """A node's comments, as :class:`Nodes` lists them."""
    for where in ("leading", "end"):
        for k, text in enumerate(getattr(comments, where)):
            yield at, where, k, text
    for where in ("trailing", "end_trailing"):
        text = getattr(comments, where)
        if text is not None:
            yield at, where, 0, text


def _put(texts: tuple[str, ...], k: int, text: str) -> tuple[str, ...]:
    return (*texts[:k], text, *texts[k + 1 :])


def _copied(
    node: Node,
    i: int,
    ends: list[int],
    at: int,
    new: Node | None,
    lo: int,
    hi: int,
    positions: list[tuple[int, int]],
) -> Node:
    """``node`` (index ``i``) with the node at index ``at`` replaced by ``new`` and the nodes
    ``lo`` to ``hi`` given their new ``positions``; every subtree that holds none of them is
    shared."""
    end = ends[i]
    if not (i <= at < end or (i < hi and end > lo)):
        return node
    if i == at and new is not None:
        node = copy = new
    else:
        copy = object.__new__(type(node))
        copy.__dict__.update(node.__dict__)
    if lo <= i < hi:
        copy.__dict__["pos"] = positions[i]
    if isinstance(node, Container):
        children, j = [], i + 1
        for child in node.children:
            children.append(_copied(child, j, ends, at, new, lo, hi, positions))
            j = ends[j]
        copy.__dict__["children"] = tuple(children)
    return copy


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
