"""The fleet in the editor (``ktbt lsp --fleet ENDPOINT``): which robots know each item's
sequence, and where a file's item differs from what the fleet teaches for that sequence.

Off by default: without ``--fleet`` this module is never imported and no session is opened.
With it, one background thread owns a zenoh session and does all the network's work, so that
the editor never waits on the network; request handlers read :meth:`Fleet.snapshot`, a copy
taken under a lock. The thread is read-only and bounded:

- every :data:`PERIOD` seconds it reads every peer's catalog (spec/protocol.md section 3: the
  ``ktbt/v1/catalog/<peer>`` queryable), through
  :func:`~ktbt_proto.transport.zenoh.catalog_replies`, which skips a reply too large or not a
  JSON array, and keeps the latest of at most
  :data:`MAX_PEERS` peers and :data:`MAX_ENTRIES` entries each, counting what it drops;
- a catalog names sequences only (with their provenance), not subtrees, so to compare it asks
  the fleet (a query, section 1) for the sequences the open documents hold and some catalog
  names, at most :data:`MAX_ASKS` per round, each again only after :data:`REASK` seconds, and
  caches the answers (:data:`MAX_ANSWERS` sequences at most).

A change of what the fleet says calls ``changed`` (from the thread), so the server re-publishes
its diagnostics.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ktbt_proto.errors import StringBTError
from ktbt_proto.formatter import format_tree
from ktbt_proto.items import sequence_key, split_item
from ktbt_proto.syntax import parse

if TYPE_CHECKING:
    from ktbt_proto.transport.zenoh import ZenohTransport

log = logging.getLogger("ktbt.lsp.fleet")

SOURCE = "ktbt fleet"
"""The source of the fleet's diagnostics: they are the fleet's word, not the language's, so
they carry no SBT code."""
PERIOD = 3.0
"""Seconds between two reads of the fleet's catalogs."""
MAX_PEERS = 64
MAX_ENTRIES = 1024
"""Entries kept of one peer's catalog; the rest are dropped and counted."""
MAX_ASKS = 8
"""Sequences asked of the fleet in one round at most."""
REASK = 30.0
"""Seconds before a sequence already asked is asked again."""
MAX_ANSWERS = 512
ASK_TIMEOUT = 1.0
NAME = "ktbt-lsp"
"""The name the editor's session asks under (it serves nothing)."""


@dataclass(frozen=True)
class Snapshot:
    """What the fleet said, as of the last round: each peer's catalog entries, and for each
    sequence asked, each answering peer's subtree in canonical compact form."""

    catalogs: dict[str, list[dict[str, str]]] = field(default_factory=dict)
    answers: dict[str, dict[str, str]] = field(default_factory=dict)
    dropped: int = 0

    def knowers(self, key: str) -> list[tuple[str, str | None]]:
        """The peers whose catalog names ``key``, each with the author it gives."""
        out = []
        for peer, entries in sorted(self.catalogs.items()):
            for entry in entries:
                if entry.get("sequence") == key:
                    out.append((peer, entry.get("author")))
                    break
        return out


def compact(subtree: str) -> str | None:
    """``subtree`` in canonical compact form, or None if it is not stringBT."""
    try:
        return format_tree(parse(subtree), "compact")
    except (StringBTError, RecursionError, ValueError):
        return None


def item_of(text: str) -> tuple[str, str] | None:
    """The sequence key and the subtree (canonical compact) of one item written as ``text``
    (``<sq><c>(A)...<e>``), or None if it is not an item."""
    try:
        split = split_item(parse(text).root)
    except (StringBTError, RecursionError, ValueError):
        return None
    if split is None:
        return None
    return sequence_key(split[0]), format_tree(split[1], "compact")


class Fleet:
    """The background reader of the fleet (see the module's docstring)."""

    def __init__(self, endpoint: str, changed: Callable[[], None] | None = None) -> None:
        from ktbt_proto.transport.zenoh import ZenohSettings  # zenoh loads only with --fleet

        self.settings = ZenohSettings(connect=[endpoint])
        self.changed = changed
        self._lock = threading.Lock()
        self._snapshot = Snapshot()
        self._wanted: set[str] = set()
        self._asked: dict[str, tuple[float, frozenset[str]]] = {}
        """When each sequence was last asked, and of which knowers (a new knower: ask again)."""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ktbt-fleet", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)  # at most one ask of ASK_TIMEOUT, then the close

    def snapshot(self) -> Snapshot:
        with self._lock:
            return self._snapshot

    def want(self, keys: Iterable[str]) -> None:
        """The sequences the open documents hold (only those are ever asked)."""
        with self._lock:
            self._wanted = set(list(keys)[:MAX_ANSWERS])

    def _run(self) -> None:
        from ktbt_proto.transport.zenoh import ZenohTransport

        try:
            transport = ZenohTransport(NAME, self.settings, serving=False)
        except Exception:
            log.exception("ktbt lsp: cannot open the fleet's session; no fleet")
            return
        with transport:
            while not self._stop.is_set():
                try:
                    self._round(transport)
                except Exception:  # the network's error, or a peer's junk: never the end
                    log.warning("ktbt lsp: reading the fleet failed", exc_info=True)
                self._stop.wait(PERIOD)

    def _due(self, key: str, knowers: frozenset[str], now: float) -> bool:
        asked = self._asked.get(key)
        return asked is None or asked[1] != knowers or now - asked[0] >= REASK

    def _round(self, transport: ZenohTransport) -> None:
        from ktbt_proto.exchange.messages import Query
        from ktbt_proto.transport.zenoh import catalogs

        dropped = 0
        read: dict[str, list[dict[str, str]]] = {}
        for peer, entries in sorted(catalogs(transport, ASK_TIMEOUT).items()):
            if len(read) >= MAX_PEERS:
                dropped += 1
                continue
            dropped += max(0, len(entries) - MAX_ENTRIES)
            read[peer] = entries[:MAX_ENTRIES]
        named = {e["sequence"] for entries in read.values() for e in entries}
        with self._lock:
            answers = {k: dict(v) for k, v in self._snapshot.answers.items()}
            wanted = sorted(self._wanted & named)
        now = time.monotonic()
        knowers = {
            k: frozenset(p for p, es in read.items() for e in es if e["sequence"] == k)
            for k in wanted
        }
        due = [k for k in wanted if self._due(k, knowers[k], now)][:MAX_ASKS]
        for key in due:
            self._asked[key] = (now, knowers[key])
            query = Query(id=Query.new_id(), sender=NAME, sequence=key)
            said: dict[str, str] = {}
            for answer in transport.ask(query, ASK_TIMEOUT):
                if answer.id == query.id and answer.sequence == key:
                    form = compact(answer.subtree)
                    if form is not None:
                        said[answer.sender] = form
            answers[key] = said
        answers = {k: v for k, v in answers.items() if k in named}
        self._asked = {k: v for k, v in self._asked.items() if k in named}
        while len(answers) > MAX_ANSWERS:
            del answers[next(iter(answers))]
        if dropped:
            log.info("ktbt lsp: the fleet's catalogs: %d peers or entries past the bounds", dropped)
        snapshot = Snapshot(read, answers, dropped)
        with self._lock:
            before, self._snapshot = self._snapshot, snapshot
        if (before.catalogs, before.answers) != (read, answers) and self.changed is not None:
            self.changed()
