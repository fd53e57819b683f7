"""Learning for a BehaviorTree.CPP program: each learned item as a BT.CPP document in a folder.

A running BT.CPP tree cannot be edited, so a KT-BT agent beside the program learns for it and
:class:`LearnedExport` mirrors what the agent has learned into a folder (spec/stringbt.md,
section 12.1): one file per item, ``NNNNNN-<placeholder>-<digest>.xml``, whose one
``<BehaviorTree ID="ktbt-<placeholder>-<digest>">`` is the item ``Sequence(conditions,
subtree)``. ``NNNNNN`` numbers the items in the order they were learned, so the program places
them in that order; the digest names the item's placeholder and condition sequence. A file is
replaced whole (``ktbt_proto.files``), so the program never reads half of one, and it is removed
when the agent forgets its item. An item BT.CPP could not load (a node named like one of its
built-ins) is refused with its reason, logged once and not written. The export only observes
the agent's knowledge base (:meth:`LearnedExport.sync`, after each tick): it changes nothing in
the agent.
"""

from __future__ import annotations

import hashlib
import logging
import os
import re
from collections.abc import Iterable
from pathlib import Path

from ..errors import StringBTError
from ..files import fsync_folder, write_atomic
from ..knowledge import Knowledge
from .btcpp import to_xml

__all__ = ["LearnedExport"]

log = logging.getLogger(__name__)

_FILE = re.compile(
    r"(?P<number>[0-9]{6})-(?P<slot>[A-Za-z_][A-Za-z0-9_.]*)-(?P<digest>[0-9a-f]{16})\.xml"
)


def item_digest(item: Knowledge) -> str:
    """Names an item by its placeholder and condition sequence (what a forget names)."""
    return hashlib.sha256(f"{item.segment}\n{item.key}".encode()).hexdigest()[:16]


def tree_id(item: Knowledge) -> str:
    return f"ktbt-{item.segment.replace('.', '-')}-{item_digest(item)}"


class LearnedExport:
    """Keeps ``folder`` holding exactly one BT.CPP file per learned item.

    Files of this pattern already in the folder (a previous run's) are adopted when their item
    is still known, with their number, and removed at the first :meth:`sync` otherwise. Other
    files are left alone. A file that cannot be written or removed is logged and tried again at
    the next sync, never raised into the agent's loop.
    """

    def __init__(self, folder: str | os.PathLike[str]) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.files: dict[tuple[str, str], Path] = {}  # (placeholder, digest) -> file
        self.errors = 0
        """Writes and removals that failed (the folder's own errors, not a peer's)."""
        self.refused: dict[tuple[str, str], str] = {}
        """Items BT.CPP could not load (a name it reserves, say), with the reason: logged once,
        never written. The agent may still run them; the BT.CPP program does not get them."""
        self._next = 1
        for path in sorted(self.folder.iterdir()):
            match = _FILE.fullmatch(path.name)
            if match is not None:
                self.files[(match["slot"], match["digest"])] = path
                self._next = max(self._next, int(match["number"]) + 1)
        self._known: frozenset[tuple[str, str]] | None = None

    def sync(self, knowledge: Iterable[Knowledge]) -> None:
        """Write the learned items (``source`` set) that have no file yet, in the order given,
        and remove the files of items no longer there. Cheap when nothing changed."""
        learned = [item for item in knowledge if item.source is not None]
        known = frozenset((item.segment, item_digest(item)) for item in learned)
        if known == self._known:
            return
        changed = False
        for key in [key for key in self.files if key not in known]:
            try:
                self.files[key].unlink(missing_ok=True)
            except OSError as exc:
                self._failed(f"cannot remove {self.files[key]}: {exc}")
                continue
            log.info("removed %s (forgotten)", self.files.pop(key).name)
            changed = True
        for item in learned:
            key = (item.segment, item_digest(item))
            if key in self.files or key in self.refused:
                continue
            path = self.folder / f"{self._next:06d}-{key[0]}-{key[1]}.xml"
            try:
                document = to_xml(item.item(), tree_id=tree_id(item))
            except StringBTError as err:
                self.refused[key] = f"{err.code.value} {err.message}"
                log.warning("not exported to BT.CPP: %s: %s", item.key, self.refused[key])
                continue
            try:
                write_atomic(path, document)
            except OSError as exc:
                self._failed(f"cannot write {path}: {exc}")
                continue
            self._next += 1
            self.files[key] = path
            log.info("wrote %s", path.name)
        if changed:
            try:
                fsync_folder(self.folder)
            except OSError as exc:
                self._failed(f"cannot flush {self.folder}: {exc}")
        written = set(self.files)
        if written <= known and known <= written | self.refused.keys():  # all done: skip next time
            self._known = known

    def _failed(self, message: str) -> None:
        self.errors += 1
        log.warning("export of learned knowledge: %s", message)
