"""The knowledge base: known condition sequences (the paper's L_ks) and their action subtrees
(L_ka), keyed by the canonical form of the sequence, and persisted so a robot keeps what it
learned across a crash.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from .errors import StringBTError
from .format import format as format_tree
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
        from .errors import ErrorCode, ParseError

        raise ParseError(ErrorCode.UNEXPECTED_TOKEN, "a sequence holds conditions only")
    return tuple(c for c in conds if isinstance(c, Condition))


@dataclass(frozen=True)
class Knowledge:
    """One item: ``Sequence(conditions, subtree)``, where it lives, and where it came from."""

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


def _split_item(node: Node) -> tuple[tuple[Condition, ...], Node] | None:
    if isinstance(node, Sequence) and not node.memory and len(node.children) >= 2:
        *conds, subtree = node.children
        if conds and all(isinstance(c, Condition) for c in conds):
            return tuple(c for c in conds if isinstance(c, Condition)), subtree
    return None


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
                    split = _split_item(child)
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
