"""The knowledge base: known condition sequences (the paper's L_ks) and their action subtrees
(L_ka), keyed by the canonical form of the sequence, and persisted so a robot keeps what it
learned across a crash.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from ktbt_proto.errors import StringBTError
from ktbt_proto.files import TooLarge, read_bounded, temporaries, write_atomic
from ktbt_proto.formatter import format_tree
from ktbt_proto.items import (
    parse_sequence,
    sequence_key,
    split_item,
)
from ktbt_proto.limits import DEFAULT_LIMITS, Limits
from ktbt_proto.merge import merge
from ktbt_proto.syntax import parse
from ktbt_proto.tree import (
    Condition,
    Node,
    Placeholder,
    Selector,
    SequenceNode,
    Tree,
    as_node,
    walk,
)

__all__ = [
    "MAX_FILE",
    "Knowledge",
    "KnowledgeBase",
    "remove_stale_temporaries",
    "salvage",
]

FORMAT_VERSION = 1


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

    @cached_property
    def key(self) -> str:
        """The item's sequence key (``spec/protocol.md`` section 1), formatted once: a learner
        looks its items up, records and counts them by it."""
        return sequence_key(self.conditions)

    def item(self) -> SequenceNode:
        return SequenceNode((*self.conditions, self.subtree))


class KnowledgeBase:
    """Known sequences and their subtrees, first answer kept (a later one is not an update)."""

    def __init__(self, items: Iterable[Knowledge] = ()) -> None:
        self._items: dict[str, Knowledge] = {}
        self.version = 0
        """Counts the changes (an item added or removed): what is built from the items (a
        catalog, :func:`~ktbt_proto.exchange.answers.catalog`) is built again only when it
        moved."""
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
        self.version += 1
        return True

    def lookup(self, sequence: str | Iterable[Condition]) -> Knowledge | None:
        return self._items.get(sequence_key(sequence))

    def remove(self, sequence: str | Iterable[Condition]) -> Knowledge | None:
        """Forget the item answering ``sequence``; the item, or None if it was not known."""
        item = self._items.pop(sequence_key(sequence), None)
        if item is not None:
            self.version += 1
        return item

    def __contains__(self, key: object) -> bool:
        return key in self._items

    def __len__(self) -> int:
        return len(self._items)

    def __iter__(self) -> Iterator[Knowledge]:
        return iter(self._items.values())

    def keys(self) -> list[str]:
        return list(self._items)

    def tree(self) -> Tree:
        """The items as a tree: each in a placeholder named for its segment, under a selector
        (what a teacher that ticks no tree shows, spec/protocol.md section 10)."""
        segments: dict[str, list[Node]] = {}
        # An item inside another's placeholder is shown there, in its parent, not again.
        inner = {
            node.name
            for item in self
            for node, _ in walk(item.subtree)
            if isinstance(node, Placeholder)
        }
        for item in self:
            if item.segment not in inner:
                segments.setdefault(item.segment, []).append(item.item())
        slots = tuple(Placeholder(tuple(items), name) for name, items in segments.items())
        return Tree(Selector(slots or (Placeholder((), "new"),)))

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
        """Write durably (spec/protocol.md section 5): after a crash the file holds either the
        previous or the new base, never a mixture."""
        write_atomic(path, self.to_json())

    @classmethod
    def load(cls, path: str | Path, limits: Limits = DEFAULT_LIMITS) -> KnowledgeBase:
        """Read a saved base, at most ``MAX_FILE`` bytes of it (a path such as /dev/zero is
        refused, not read until memory runs out); raises ValueError or StringBTError."""
        try:
            data = read_bounded(path, MAX_FILE)
        except TooLarge:
            raise ValueError(
                f"{path} is larger than a knowledge file may be ({MAX_FILE} bytes)"
            ) from None
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
    removed = []
    for tmp in temporaries(path):
        try:
            tmp.unlink()
        except OSError:
            continue
        removed.append(tmp)
    return removed


def learning_slot(tree: Tree) -> str | None:
    """The placeholder a robot learns into: ``<k>(new)`` if its control tree has one, else its
    last placeholder (the lowest priority in a selector); None without any (spec/protocol.md
    section 4.5)."""
    names = [n.name for n, _ in tree.walk() if isinstance(n, Placeholder)]
    if not names:
        return None
    return "new" if "new" in names else names[-1]


def with_knowledge(
    control: str | Tree, knowledge: KnowledgeBase | None, fallback: str = "prior"
) -> str | Tree:
    """The control tree with ``knowledge``'s items in their placeholders (``fallback`` when the
    tree has no placeholder of an item's name, ``prior`` if it has one): what the agent starts
    knowing, and teaches."""
    if knowledge is None or not len(knowledge):
        return control
    tree = parse(control) if isinstance(control, str) else control
    names = {n.name for n, _ in tree.walk() if isinstance(n, Placeholder)}
    for item in knowledge:
        tree = merge(tree, item.subtree, item_slot(names, item.segment, fallback), item.conditions)
    return tree


def item_slot(names: set[str], segment: str, fallback: str) -> str:
    """Where an item a robot starts with goes, its control tree having the placeholders
    ``names``: the one its ``segment`` names, else ``prior``, else ``fallback``."""
    if segment in names:
        return segment
    return "prior" if "prior" in names else fallback
