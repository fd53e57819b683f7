"""The knowledge base: known condition sequences (the paper's L_ks) and their action subtrees
(L_ka), keyed by the canonical form of the sequence, and persisted so a robot keeps what it
learned across a crash.
"""

from __future__ import annotations

import json
import os
import re
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path

from .errors import ErrorCode, ParseError, StringBTError
from .format import format as format_tree
from .format import format_value
from .limits import DEFAULT_LIMITS, Limits
from .syntax import parse
from .tree import Condition, Node, Placeholder, Sequence, Tree, as_node, walk

FORMAT_VERSION = 1


def sequence_key(conditions: Iterable[Condition]) -> str:
    """The canonical form of a condition sequence: how knowledge is looked up and asked for."""
    return "".join(format_tree(c, "compact") for c in conditions)


@lru_cache(maxsize=1024)
def parse_sequence(key: str, limits: Limits = DEFAULT_LIMITS) -> tuple[Condition, ...]:
    """The conditions of a sequence key (``<c>(A)<c>(!B)``); raises StringBTError. Cached:
    a robot asks and is asked about the same few sequences again and again."""
    root = parse(f"<sq>{key}<e>", limits=limits).root
    assert isinstance(root, Sequence)
    conds = root.children
    if not conds or not all(isinstance(c, Condition) for c in conds):
        raise ParseError(ErrorCode.UNEXPECTED_TOKEN, "a sequence holds conditions only")
    return tuple(c for c in conds if isinstance(c, Condition))


# -- the sequence as people type and read it (spec/protocol.md, section 1) ----------------------

_NAME = re.compile(r"\s*(!?\s*[A-Za-z0-9_.]+)\s*")


def show_sequence(sequence: str | Iterable[Condition]) -> str:
    """A condition sequence as the command line prints it and reads it back:
    ``TargetSeen(colour=2), !_inZoneF``. Takes conditions or a wire key (``<c>(...)...``)."""
    conds = parse_sequence(sequence) if isinstance(sequence, str) else tuple(sequence)
    parts = []
    for c in conds:
        head = ("!" if c.negated else "") + c.name
        if c.args:
            head += "(" + ", ".join(f"{k}={format_value(v)}" for k, v in c.args) + ")"
        parts.append(head)
    return ", ".join(parts)


def read_sequence(text: str) -> tuple[Condition, ...]:
    """Conditions from what a user types: ``TargetSeen(colour=2), !_inZoneF`` (what
    :func:`show_sequence` prints), or the wire form ``<c>(TargetSeen,colour=2)<c>(!_inZoneF)``.

    Raises :class:`ParseError` (or another StringBTError) positioned in ``text`` itself, with
    a caret under the offending character, never in an internal rewrite of it."""
    return _read_sequence(text)


@lru_cache(maxsize=1024)
def _read_sequence(text: str) -> tuple[Condition, ...]:
    if not text.strip():
        raise ParseError(ErrorCode.EMPTY, "the sequence names no condition", source=text)
    if text.lstrip().startswith("<"):
        try:
            return parse_sequence(text)
        except StringBTError as err:  # columns of "<sq>" + text + "<e>"
            column = max(1, err.column - 4) if err.line == 1 else err.column
            if err.line == 1 and column > len(text):  # at the "<e>" this function added
                raise ParseError(
                    ErrorCode.UNEXPECTED_END,
                    "the sequence ends inside a condition",
                    1,
                    column,
                    source=text,
                ) from None
            raise type(err)(err.code, err.message, err.line, column, source=text) from None
    conds = []
    for start, end in _top_level_spans(text):
        conds.append(_read_condition(text, start, end))
    return tuple(conds)


def _top_level_spans(text: str) -> list[tuple[int, int]]:
    """(start, end) of each comma-separated part, commas inside parentheses or strings kept."""
    spans: list[tuple[int, int]] = []
    depth, quoted, escaped, start = 0, False, False, 0
    for i, char in enumerate(text):
        if quoted:
            if escaped:
                escaped = False
            elif char == "\\":
                escaped = True
            elif char == '"':
                quoted = False
        elif char == '"':
            quoted = True
        elif char == "(":
            depth += 1
        elif char == ")":
            depth -= 1
        elif char == "," and depth == 0:
            spans.append((start, i))
            start = i + 1
    spans.append((start, len(text)))
    return spans


def _read_condition(text: str, start: int, end: int) -> Condition:
    def fail(code: ErrorCode, message: str, at: int) -> ParseError:
        return ParseError(code, message, 1, at + 1, source=text)

    part = text[start:end]
    if not part.strip():
        raise fail(
            ErrorCode.UNEXPECTED_TOKEN, "expected a condition before ','", min(end, len(text) - 1)
        )
    name = _NAME.match(text, start, end)
    if name is None:
        at = start + len(part) - len(part.lstrip())
        raise fail(ErrorCode.UNEXPECTED_CHARACTER, "expected a condition name", at)
    head = name.group(1)
    rest = name.end()
    if rest == end:
        args, open_at, close_at = "", -1, -1
    elif text[rest] == "(":
        open_at = rest
        close_at = len(text[:end].rstrip()) - 1
        if text[close_at] != ")" or close_at == open_at:
            raise fail(ErrorCode.UNEXPECTED_END, "missing ) to close the arguments", close_at + 1)
        args = text[open_at + 1 : close_at]
    else:
        raise fail(ErrorCode.UNEXPECTED_TOKEN, "expected '(' or ',' after the condition name", rest)
    rewrite = f"<c>({head}, {args})" if args.strip() else f"<c>({head})"
    try:
        node = parse(rewrite).root
    except StringBTError as err:
        raise type(err)(
            err.code,
            err.message,
            1,
            _user_column(err, head, name, args, open_at, close_at) + 1,
            source=text,
        ) from None
    if not isinstance(node, Condition):  # pragma: no cover - the grammar guarantees it
        raise fail(ErrorCode.UNEXPECTED_TOKEN, "not a condition", start)
    return replace(node, pos=None)


def _user_column(
    err: StringBTError, head: str, name: re.Match[str], args: str, open_at: int, close_at: int
) -> int:
    """Where in the user's text column ``err.column`` of ``<c>(HEAD, ARGS)`` came from."""
    r = err.column - 1 if err.line == 1 else len(head) + len(args) + 6
    if r < 4:
        return name.start(1)
    if r < 4 + len(head):
        return name.start(1) + r - 4
    if r < 6 + len(head):
        return open_at if open_at >= 0 else name.end(1)
    if r < 6 + len(head) + len(args):
        return open_at + 1 + r - 6 - len(head)
    return close_at if close_at >= 0 else name.end(1)


@dataclass(frozen=True)
class Knowledge:
    """One item: ``Sequence(conditions, subtree)``, where it lives, and where it came from.
    ``subtree`` of an item written flat (``<sq><c>(A)<a>(X)<a>(Y)<e>``) is ``Sequence(X, Y)``."""

    conditions: tuple[Condition, ...]
    subtree: Node
    segment: str = "new"
    source: str | None = None
    learned_at: float | None = None
    author: str | None = None
    """Provenance (``spec/protocol.md`` section 7): the author's public key and signature of
    the item, and when (UTC, ISO 8601) it was received from its teacher ``source``."""
    signature: str | None = None
    received_at: str | None = None

    @property
    def key(self) -> str:
        return sequence_key(self.conditions)

    def item(self) -> Sequence:
        return Sequence((*self.conditions, self.subtree))


def split_item(node: Node) -> tuple[tuple[Condition, ...], Node] | None:
    """A knowledge item's condition sequence and action subtree; None if ``node`` is not an item
    (spec/stringbt.md, section 4). An item is a reactive ``<sq>`` whose leading conditions are
    the key and whose remaining children (at least one) are the actions: one child is the
    subtree itself, several are ``Sequence(children)``. So the paper's flat form
    ``<sq><c>(A)<a>(X)<a>(Y)<e>`` and the nested ``<sq><c>(A)<sq><a>(X)<a>(Y)<e><e>`` are the
    same item, and tick the same way."""
    if not isinstance(node, Sequence) or node.memory:
        return None
    children = node.children
    n = 0
    while n < len(children) and isinstance(children[n], Condition):
        n += 1
    if n == 0 or n == len(children):
        return None
    conds = tuple(c for c in children[:n] if isinstance(c, Condition))
    rest = children[n:]
    return conds, rest[0] if len(rest) == 1 else Sequence(rest)


def stray_nodes(tree: Tree | Node) -> list[StringBTError]:
    """Warnings (``SBT501``) for every child of a placeholder that is not a knowledge item: it is
    ticked like any node, but never taught, looked up or counted as knowledge."""
    found = []
    for node, _ in walk(as_node(tree)):
        if isinstance(node, Placeholder):
            for child in node.children:
                if split_item(child) is None:
                    found.append(
                        StringBTError(
                            ErrorCode.NOT_KNOWLEDGE,
                            f"<k>({node.name}) holds a node that is not a knowledge item "
                            "(<sq>, its conditions, then its actions): it is never taught",
                            child.line,
                            child.column,
                        )
                    )
    return found


class KnowledgeBase:
    """Known sequences and their subtrees, first answer kept (a later one is not an update)."""

    def __init__(self, items: Iterable[Knowledge] = ()) -> None:
        self._items: dict[str, Knowledge] = {}
        for item in items:
            self.add(item)

    @classmethod
    def from_tree(cls, tree: Tree | Node) -> KnowledgeBase:
        """The knowledge already in a control tree's placeholders (priors, common knowledge)."""
        kb = cls()
        for node, _ in walk(as_node(tree)):
            if isinstance(node, Placeholder):
                for child in node.children:
                    split = split_item(child)
                    if split is not None:
                        kb.add(Knowledge(split[0], split[1], node.name))
        return kb

    def add(self, item: Knowledge) -> bool:
        """Add unless the sequence is already known; True if it was new."""
        key = item.key
        if key in self._items:
            return False
        self._items[key] = item
        return True

    def lookup(self, sequence: str | Iterable[Condition]) -> Knowledge | None:
        key = sequence if isinstance(sequence, str) else sequence_key(sequence)
        return self._items.get(key)

    def remove(self, sequence: str | Iterable[Condition]) -> Knowledge | None:
        """Forget the item answering ``sequence``; the item, or None if it was not known."""
        key = sequence if isinstance(sequence, str) else sequence_key(sequence)
        return self._items.pop(key, None)

    def __contains__(self, key: object) -> bool:
        return key in self._items

    def __len__(self) -> int:
        return len(self._items)

    def __iter__(self) -> Iterator[Knowledge]:
        return iter(self._items.values())

    def keys(self) -> list[str]:
        return list(self._items)

    # -- persistence ---------------------------------------------------------------------------

    def to_json(self) -> str:
        entries = [
            {
                "sequence": k.key,
                "subtree": format_tree(k.subtree, "compact"),
                "segment": k.segment,
                "source": k.source,
                "learned_at": k.learned_at,
                **{
                    name: value
                    for name, value in (
                        ("author", k.author),
                        ("signature", k.signature),
                        ("received_at", k.received_at),
                    )
                    if value is not None
                },
            }
            for k in self
        ]
        return json.dumps({"version": FORMAT_VERSION, "knowledge": entries}, indent=1)

    @classmethod
    def from_json(cls, text: str, limits: Limits = DEFAULT_LIMITS) -> KnowledgeBase:
        """Read a saved base; raises ValueError (bad file) or StringBTError (bad tree)."""
        try:
            data = json.loads(text)
            if not isinstance(data, dict) or data.get("version") != FORMAT_VERSION:
                raise ValueError(f"not a version-{FORMAT_VERSION} knowledge file")
            entries = data.get("knowledge", [])
            if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
                raise ValueError("'knowledge' must be a list of objects")
            kb = cls()
            for entry in entries:
                kb.add(_entry(entry, limits))
        except (KeyError, TypeError, RecursionError) as exc:
            raise ValueError(f"malformed knowledge file: {exc!r}") from None
        return kb

    def save(self, path: str | Path) -> None:
        """Write atomically (temporary file, fsync, rename, fsync of the folder): after a crash
        the file holds either the previous or the new base, never a mixture."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(self.to_json())
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
        directory = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(directory)
        finally:
            os.close(directory)

    @classmethod
    def load(cls, path: str | Path, limits: Limits = DEFAULT_LIMITS) -> KnowledgeBase:
        """Read a saved base, at most ``MAX_FILE`` bytes of it (a path such as /dev/zero is
        refused, not read until memory runs out); raises ValueError or StringBTError."""
        with open(path, "rb") as f:
            data = f.read(MAX_FILE + 1)
        if len(data) > MAX_FILE:
            raise ValueError(f"{path} is larger than a knowledge file may be ({MAX_FILE} bytes)")
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            raise ValueError(f"{path} is not UTF-8") from None
        return cls.from_json(text, limits)


MAX_FILE = 64_000_000
"""The largest knowledge file read (a thousand items at the wire's largest size)."""


def _entry(entry: dict[str, object], limits: Limits) -> Knowledge:
    def text(name: str) -> str | None:
        value = entry.get(name)
        return None if value is None else str(value)

    learned_at = entry.get("learned_at")
    return Knowledge(
        parse_sequence(str(entry["sequence"]), limits),
        parse(str(entry["subtree"]), limits=limits).root,
        str(entry.get("segment", "new")),
        text("source"),
        learned_at if isinstance(learned_at, int | float) else None,
        author=text("author"),
        signature=text("signature"),
        received_at=text("received_at"),
    )


def salvage(text: str, limits: Limits = DEFAULT_LIMITS) -> list[Knowledge]:
    """The items a damaged knowledge file still holds whole (a truncated one, say): each entry
    of its ``knowledge`` list is read in turn until one cannot be. Nothing here raises."""
    start = text.find("[", text.find('"knowledge"'))
    if start < 0:
        return []
    decoder = json.JSONDecoder()
    items: list[Knowledge] = []
    pos = start + 1
    while True:
        while pos < len(text) and text[pos] in " \t\r\n,":
            pos += 1
        try:
            entry, pos = decoder.raw_decode(text, pos)
            if not isinstance(entry, dict):
                break
            items.append(_entry(entry, limits))
        except (ValueError, KeyError, TypeError, RecursionError, StringBTError):
            break
    return items


def remove_stale_temporaries(path: str | Path) -> list[Path]:
    """Delete the temporary files a save killed midway left next to ``path``; returns them."""
    path = Path(path)
    removed = []
    for tmp in path.parent.glob(f".{path.name}.*.tmp"):
        try:
            tmp.unlink()
        except OSError:
            continue
        removed.append(tmp)
    return removed
