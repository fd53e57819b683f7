"""What ``ktbt monitor`` knows of a fleet, built from fleet events (``spec/protocol.md``
section 10), liveliness and catalogs, and handed to the page as batches of changes.

Everything is bounded: peers, items, each peer's recent events, the transfers, refusals and
changes kept. What does not fit is dropped and counted, so a flooding or hostile fleet costs
the monitor a counter, not its memory. The items table is shared fairly: when it is full, the
items of peers the monitor has least reason to believe go first (a name not in the trust store
and with no liveliness token), and among equals the peers that hold the most of it give way
(:meth:`FleetState._make_room`), so one peer, or a few, listing junk cannot crowd out what the rest
of the fleet knows. What each peer holds is kept up to date as peers learn and forget, so
making room costs a look at the peers, not a sum over the table. A page that falls behind
the kept changes gets a fresh snapshot instead. Data flows one way: zenoh callbacks call
:meth:`FleetState.peer_joined`, :meth:`FleetState.event` and friends; the web side reads
:meth:`FleetState.changes_since` and :meth:`FleetState.snapshot`.
"""

from __future__ import annotations

import itertools
import re
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.events import FleetEvent, clip
from ktbt_proto.exchange.messages import NAME_PATTERN
from ktbt_proto.exchange.refusals import internal_error
from ktbt_proto.exchange.transferlog import Event
from ktbt_proto.exchange.trust import TrustStore
from ktbt_proto.items import parse_sequence, sequence_digest

MAX_PEERS = 512
MAX_ITEMS = 512
RECENT = 50
"""Events kept per peer, for its detail view."""
KEPT = 200
"""Transfers and refusals kept, each."""
CHANGES = 20_000
"""Changes kept for pages catching up; one further behind is sent a snapshot."""
TIMELINE = 5000
"""Points of the spreading timeline kept (one a merge or forget)."""
REASONS = 5
"""The last reasons kept for each kind of thing refused, shown on the page."""
LOST_AFTER = 5.0
"""A query sent and not answered within this many seconds is counted lost."""
EPSILON = 1e-9
"""Loads closer than this are equal (they are sums of fractions)."""
TIERS = 3
"""How much the monitor believes a peer's name, low to high (:meth:`FleetState._tier`)."""


PEER_NAME = re.compile(NAME_PATTERN)


def _iso(seconds: float) -> str:
    return datetime.fromtimestamp(seconds, UTC).isoformat(timespec="milliseconds")


@dataclass
class Peer:
    name: str
    status: str = "heard"
    """``present`` (its liveliness token is up), ``gone`` (it went down) or ``heard`` (events
    only, as from a simulator)."""
    since: float = 0.0
    knows: dict[str, dict[str, Any]] = field(default_factory=dict)
    recent: deque[dict[str, Any]] = field(default_factory=lambda: deque(maxlen=RECENT))
    last_n: int = -1
    lost_events: int = 0
    dropped: int = 0
    key: str | None = None
    queries_lost: int = 0
    open_queries: dict[str, float] = field(default_factory=dict)
    heard: float = 0.0
    """When anything last came from or about it (monotonic): the oldest idle peer goes first."""
    load: float = 0.0
    """Its share of the items table: the sum, over the items it knows, of one over the number
    of peers that know each (:meth:`FleetState._make_room`), kept up to date as peers learn and
    forget."""

    def view(self) -> dict[str, Any]:
        return {
            "k": "peer",
            "peer": self.name,
            "status": self.status,
            "since": self.since,
            "signed": self.key is not None,
            "lost_events": self.lost_events,
            "dropped": self.dropped,
            "queries_lost": self.queries_lost,
        }


class FleetState:
    """The fleet's state, thread-safe; every change is also appended to a bounded list of
    changes numbered from 1."""

    def __init__(self, trust: TrustStore | None = None) -> None:
        self.trust = trust
        """Keys of peers known by name (``ktbt monitor --trust``): such a peer's events must be
        signed by its key. Any other peer's first key is pinned."""
        self._lock = threading.Lock()
        self.peers: dict[str, Peer] = {}
        self.items: dict[str, str] = {}
        self.transfers: deque[dict[str, Any]] = deque(maxlen=KEPT)
        self.refusals: deque[dict[str, Any]] = deque(maxlen=KEPT)
        self.timeline: deque[dict[str, Any]] = deque(maxlen=TIMELINE)
        self.drops: Counter[str] = Counter()
        """What the monitor refused, by why: malformed, oversized, wrong key, forged, replayed,
        flood, full; and items some peer knew, evicted to make room (evicted)."""
        self.reasons: dict[str, deque[str]] = {}
        """The last :data:`REASONS` reasons of each kind refused."""
        self.events = 0
        self._changes: deque[tuple[int, dict[str, Any]]] = deque(maxlen=CHANGES)
        self._version = 0
        self._dirty: set[str] = set()
        """Peers whose counters changed: one view each per batch, not one per event."""
        self._knowers: dict[str, set[str]] = {}
        """The peers that know each item (the items no peer knows are not in it)."""
        self._tiers: dict[str, list[int]] = {}
        """How many of each item's knowers are of each tier (:meth:`_tier`)."""
        self._unknown: dict[str, None] = {}
        """The items of the table no peer knows, in the order they came to be so: the first
        makes room."""
        self._known_version = 0
        """Counts the changes to what the peers know, and to their tiers."""
        self._no_room: dict[str, int] = {}
        """Peers refused room in a full table, with the known version then: one is refused
        again without a look while nothing the peers know changed (the look would find what it
        found). A peer's entry goes with the peer, so it holds at most :data:`MAX_PEERS`."""

    # -- input -------------------------------------------------------------------------------

    def drop(self, why: str, reason: str | None = None) -> None:
        """Count one thing refused, keeping its reason; the count goes with every batch
        (:meth:`stats`), not as a change, so a flood of junk never pushes real changes out."""
        with self._lock:
            self._drop(why, reason)

    def _drop(self, why: str, reason: str | None) -> None:
        self.drops[why] += 1
        if reason is not None:
            self.reasons.setdefault(why, deque(maxlen=REASONS)).append(clip(reason, 200))

    def _named(self, name: str, where: str) -> Peer | None:
        """The peer of a name from a key expression: a peer name (section 1) or refused."""
        if not PEER_NAME.fullmatch(name):
            self._drop("malformed", f"{where}: {clip(name, 64)!r} is not a peer name")
            return None
        return self._peer(name)

    def peer_joined(self, name: str) -> None:
        with self._lock:
            peer = self._named(name, "liveliness")
            if peer is not None and peer.status != "present":
                if peer.status == "gone":
                    peer.last_n = -1  # it restarted: its numbering starts over
                self._status(peer, "present")
                self._change(peer.view())

    def peer_left(self, name: str) -> None:
        with self._lock:
            peer = self.peers.get(name)
            if peer is not None and peer.status != "gone":
                self._status(peer, "gone")
                self._change(peer.view())

    def _status(self, peer: Peer, status: str) -> None:
        before = self._tier(peer)
        peer.status, peer.since = status, time.time()
        self._retier(peer, before)

    def _retier(self, peer: Peer, before: int) -> None:
        """``peer``'s rank was ``before``: its items are counted at its rank now."""
        after = self._tier(peer)
        if after != before:
            for item in peer.knows:
                tiers = self._tiers[item]
                tiers[before] -= 1
                tiers[after] += 1
            self._known_version += 1

    def catalog(self, name: str, sequences: list[str]) -> None:
        """What a peer's catalog says it knows (served or learned before we listened): each
        entry must be a sequence of conditions (stringBT); what the peer no longer lists, and
        did not learn in the last :data:`LOST_AFTER` seconds, it has forgotten (its forget
        event may have been lost)."""
        now = time.time()
        entries: list[tuple[str, str]] = []  # checked before the lock: nobody waits on it
        errors: list[str] = []
        for sequence in sequences[:MAX_ITEMS]:
            try:
                parse_sequence(sequence)
                entries.append((sequence_digest(sequence), sequence))
            except (StringBTError, UnicodeError, RecursionError) as exc:
                errors.append(str(exc).splitlines()[0])
            except Exception as exc:  # the reader's own failure (spec/protocol.md 2.1)
                errors.append(internal_error(exc))
        with self._lock:
            peer = self._named(name, "catalog")
            if peer is None:
                return
            for error in errors:
                self._drop("malformed", f"catalog of {peer.name}: {error}")
            listed: set[str] = set()
            whole = len(sequences) <= MAX_ITEMS and not errors
            for item, sequence in entries:
                listed.add(item)
                if item not in peer.knows and self._item(item, sequence, peer, learns=True):
                    self._know(peer, item, {"how": "known", "t": None, "at": now})
                    self._change({"k": "know", "peer": peer.name, "item": item, "how": "known"})
                    self._spread(item, _iso(now))  # a knower more, whose merge went unheard
            if not whole:
                return
            for item in [i for i, k in peer.knows.items() if i not in listed]:
                if now - peer.knows[item].get("at", 0.0) > LOST_AFTER:
                    self._unknow(peer, item)
                    self._spread(item, _iso(now))

    def event(self, event: FleetEvent) -> None:
        """One event, already checked (:func:`~ktbt_proto.exchange.events.decode_event`) and known
        to
        have come on its peer's own key. Refused, and counted, when it is not signed by the key
        the trust store gives its peer, or by the first key it came with, or comes unsigned
        after signed ones ("forged"), or numbers at or below one already taken ("replayed")."""
        now = time.time()
        signed = event.sig is not None
        with self._lock:
            peer = self._peer(event.peer)
            if peer is None:
                return
            refused = self._refusal(peer, event)
            if refused is not None:
                self._drop(*refused)
                return
            self.events += 1
            if event.n > peer.last_n + 1:
                peer.lost_events += event.n - peer.last_n - 1
            peer.last_n = event.n
            peer.dropped = max(peer.dropped, event.dropped)
            if signed and peer.key is None:  # its first signed event: it may rank higher now
                before = self._tier(peer)
                peer.key = event.key
                self._retier(peer, before)
            if peer.status == "heard" and not peer.since:
                peer.since = now
            seen = {
                "k": "event",
                "peer": peer.name,
                "event": event.event,
                "t": event.t,
                "n": event.n,
                "signed": signed,
            }
            for name in ("item", "sender", "to", "teacher", "reason", "where", "tick"):
                value = getattr(event, name)
                if value is not None:
                    seen[name] = value
            if event.item is not None and event.sequence is not None:
                whole = sequence_digest(event.sequence) == event.item
                if whole or event.sequence.endswith("..."):  # clipped (section 10)
                    learns = event.event == Event.MERGED
                    self._item(event.item, event.sequence, peer, clipped=not whole, learns=learns)
                else:
                    self._drop(
                        "malformed",
                        f"event {event.n} of {peer.name}: its sequence is not of its item",
                    )
            peer.recent.append(seen)
            self._change(seen)
            self._follow(peer, event, signed, now)
            self._expire_queries(peer, now)
            self._dirty.add(peer.name)

    def _refusal(self, peer: Peer, event: FleetEvent) -> tuple[str, str] | None:
        bound = self.trust.names.get(peer.name) if self.trust is not None else None
        expected = bound or peer.key
        if expected is not None and event.key != expected:
            how = "the trust store's" if bound else "its first"
            what = "unsigned" if event.key is None else f"signed by {event.key}"
            return "forged", f"event {event.n} of {peer.name}: {what}, not by {how} key"
        if event.n <= peer.last_n:
            return "replayed", f"event {event.n} of {peer.name}: {peer.last_n} was taken already"
        return None

    def _follow(self, peer: Peer, event: FleetEvent, signed: bool, now: float) -> None:
        kind = event.event
        if kind == Event.QUERY_SENT and event.id is not None:
            if len(peer.open_queries) < 64:
                peer.open_queries[event.id] = now
        elif kind == Event.ANSWER_RECEIVED and event.id is not None:
            peer.open_queries.pop(event.id, None)
        elif kind == Event.MERGED and event.item is not None and event.item in self.items:
            self._know(
                peer,
                event.item,
                {"how": "learned", "t": event.t, "teacher": event.teacher, "at": now},
            )
            transfer = {
                "k": "transfer",
                "t": event.t,
                "learner": peer.name,
                "teacher": event.teacher,
                "item": event.item,
                "author": event.author,
                "signed": signed,
            }
            self.transfers.append(transfer)
            self._change(transfer)
            self._change(
                {"k": "know", "peer": peer.name, "item": event.item, "how": "learned", "t": event.t}
            )
            self._spread(event.item, event.t)
        elif kind == Event.FORGOTTEN and event.item is not None:
            if self._unknow(peer, event.item):
                self._spread(event.item, event.t)
        elif kind in (Event.REFUSED, Event.ERROR_RECEIVED):
            refusal = {
                "k": "refusal",
                "t": event.t,
                "peer": peer.name,
                "reason": event.reason or "",
                "where": event.where or ("peer" if kind == Event.ERROR_RECEIVED else "agent"),
                "sender": event.sender,
            }
            self.refusals.append(refusal)
            self._change(refusal)

    def _spread(self, item: str, t: str) -> None:
        """One point of the timeline: how many peers know ``item`` now."""
        count = len(self._knowers.get(item, ()))
        point = {"k": "spread", "item": item, "t": t, "count": count}
        self.timeline.append(point)
        self._change(point)

    def _expire_queries(self, peer: Peer, now: float) -> None:
        late = [q for q, sent in peer.open_queries.items() if now - sent > LOST_AFTER]
        for q in late:
            del peer.open_queries[q]
        peer.queries_lost += len(late)

    def tend(self) -> None:
        """Count queries lost on peers that went quiet (called now and then)."""
        now = time.time()
        with self._lock:
            for peer in self.peers.values():
                before = peer.queries_lost
                self._expire_queries(peer, now)
                if peer.queries_lost != before:
                    self._change(peer.view())

    # -- bounded tables ----------------------------------------------------------------------

    def _peer(self, name: str) -> Peer | None:
        """The peer named, made if need be; when the table is full, the peer not present that
        was heard from longest ago makes room, and only if every peer is present is the new
        one refused."""
        peer = self.peers.get(name)
        if peer is None:
            if len(self.peers) >= MAX_PEERS:
                idle = [p for p in self.peers.values() if p.status != "present"]
                if not idle:
                    self.drops["full"] += 1
                    return None
                oldest = min(idle, key=lambda p: p.heard)
                for item in list(oldest.knows):  # the page forgets them with the peer
                    self._unknow(oldest, item, tell=False)
                del self.peers[oldest.name]
                self._no_room.pop(oldest.name, None)
                self._dirty.discard(oldest.name)
                self._change({"k": "unpeer", "peer": oldest.name})
            peer = self.peers[name] = Peer(name)
            self._change(peer.view())
        peer.heard = time.monotonic()
        return peer

    def _item(
        self, item: str, sequence: str, peer: Peer, clipped: bool = False, learns: bool = False
    ) -> bool:
        """Name ``item`` by ``sequence``: its whole text (whose digest it is) or, from an
        event, its text clipped, replaced by the whole once a catalog or event says it.
        ``peer`` named it; ``learns``: it is to know it (its catalog lists it, or it merged it).
        When the table is full, room is made (:meth:`_make_room`) or the item is refused."""
        known = self.items.get(item)
        if known is not None:
            if clipped or known == sequence:
                return True
        elif len(self.items) >= MAX_ITEMS and not self._make_room(peer, learns):
            return False
        if known is None and item not in self._knowers:
            self._unknown[item] = None
        self.items[item] = sequence
        self._change({"k": "item", "item": item, "sequence": sequence})
        return True

    def _make_room(self, peer: Peer, learns: bool) -> bool:
        """Room in the full items table for an item ``peer`` named; False, counted "full", if
        there is none for it (section 10).

        The item no peer has known for longest goes first. An item a peer is only naming (a
        query's) never takes a known item's place. For one it is to know, peers are ranked by
        how much the monitor believes their names (:meth:`_tier`): an item known only by peers
        ranked below ``peer`` goes before any other, the one the heaviest of them holds most
        (below); an item known by a peer ranked above ``peer`` never goes for it. Among peers
        of ``peer``'s rank the table is a fair share: each item is charged to the peers that
        know it, in equal parts, and a peer's load is what it is charged for. The heaviest
        peer of that rank gives way, with the item whose knowers' mean load is the highest (the
        oldest one only it knows, charged it all, if any; else the oldest of equals), if that
        is above what ``peer``'s load would be with the new item alone; else the new item is
        refused. So a
        peer listing junk is charged for all of it and gives way first, to its own junk only
        when it is the heaviest (no churn), and an item known by many is charged to each a
        little. Loads are kept up to date as peers learn and forget (:meth:`_know`), so this
        costs a look at the peers and at one peer's items; a refusal is remembered until what
        the peers know changes, so a flood of new items from one peer costs one look until
        then."""
        unknown = next(iter(self._unknown), None)
        if unknown is not None:
            self._remove(unknown)
            return True
        if not learns:
            self._drop("full", f"an item {peer.name} named: all {MAX_ITEMS} items are known")
            return False
        if self._no_room.get(peer.name) == self._known_version:
            self._drop("full", self._full(peer, "as at its last refusal"))
            return False
        victim = self._victim(peer)
        if victim is None:
            self._no_room[peer.name] = self._known_version
            self._drop("full", self._full(peer, "it was looked at"))
            return False
        sequence, count = self.items[victim], len(self._knowers[victim])
        self._unknow_all(victim)
        self._spread(victim, _iso(time.time()))  # nobody knows it now
        self._remove(victim)
        self._drop(
            "evicted",
            f"{clip(sequence, 60)}, known by {count}, for one {clip(peer.name, 64)} knows",
        )
        return True

    def _victim(self, peer: Peer) -> str | None:
        """The item to go for one ``peer`` is to know (:meth:`_make_room`), or None."""
        rank = self._tier(peer)
        bar = peer.load + 1 + EPSILON
        for tier in range(rank + 1):
            ranked = [p for p in self.peers.values() if p.knows and self._tier(p) == tier]
            ranked.sort(key=lambda p: p.load, reverse=True)
            for heaviest in ranked:
                if tier == rank and heaviest.load <= bar:
                    return None  # no item of its peers is charged more than it
                item, crowding = self._heaviest_item(heaviest, tier)
                if item is not None:
                    return item if tier < rank or crowding > bar else None
        return None

    def _heaviest_item(self, peer: Peer, tier: int) -> tuple[str | None, float]:
        """The item ``peer`` gives way with, and its load: the oldest item only it knows, if it
        has one (charged its whole load: among knowers of one rank, the most any item can be
        when the peer is the heaviest, though knowers of a lower rank may carry more); else,
        of the items only peers of ``tier`` or below know, the one whose knowers' mean load is
        the highest, the oldest of equals (one whose mean is the peer's load ends the
        search)."""
        own = next((i for i in peer.knows if len(self._knowers[i]) == 1), None)
        if own is not None:  # its rank is the peer's: no need to count the others
            return own, peer.load
        best, most = None, -1.0
        for item in peer.knows:
            if max(t for t, n in enumerate(self._tiers[item]) if n) != tier:
                continue
            knowers = self._knowers[item]
            crowding = sum(self.peers[n].load for n in knowers) / len(knowers)
            if crowding > most + EPSILON:
                best, most = item, crowding
            if most >= peer.load - EPSILON:
                break
        return best, most

    def _tier(self, peer: Peer) -> int:
        """How much the monitor believes ``peer``'s name: 2 if the trust store binds it to a key
        and an event signed by that key came (events of its name must be), 1 if its liveliness
        token is up, else 0. Without the router's access control (section 9) names and tokens
        are free, and a catalog is not signed (anyone may reply on a peer's catalog key), so
        only the trust store's rank, for what a trusted peer merged, and the fair share among
        equals, hold against a hostile peer."""
        if self.trust is not None and peer.key is not None and peer.name in self.trust.names:
            return 2
        return 1 if peer.status == "present" else 0

    def _full(self, peer: Peer, when: str) -> str:
        return (
            f"an item {peer.name} knows: all {MAX_ITEMS} items are known, none only by peers "
            f"ranked below it, and no item of the heaviest peer of its rank is charged more than "
            f"its load would be with it ({when})"
        )

    def _remove(self, item: str) -> None:
        """``item`` leaves the table (nobody knows it)."""
        self._unknown.pop(item, None)
        del self.items[item]
        self._change({"k": "unitem", "item": item})

    def _know(self, peer: Peer, item: str, known: dict[str, Any]) -> None:
        if item not in peer.knows:
            knowers = self._knowers.setdefault(item, set())
            self._share(knowers, len(knowers), len(knowers) + 1)
            knowers.add(peer.name)
            peer.load += 1 / len(knowers)
            self._tiers.setdefault(item, [0] * TIERS)[self._tier(peer)] += 1
            self._unknown.pop(item, None)
            self._known_version += 1
        peer.knows[item] = known

    def _unknow(self, peer: Peer, item: str, tell: bool = True) -> bool:
        """``peer`` no longer knows ``item`` (a change for the page, if ``tell``); False if it
        did not."""
        if peer.knows.pop(item, None) is None:
            return False
        knowers = self._knowers[item]
        peer.load = peer.load - 1 / len(knowers) if peer.knows else 0.0
        knowers.discard(peer.name)
        self._tiers[item][self._tier(peer)] -= 1
        if knowers:
            self._share(knowers, len(knowers) + 1, len(knowers))
        else:
            del self._knowers[item], self._tiers[item]
            if item in self.items:
                self._unknown[item] = None
        self._known_version += 1
        if tell:
            self._change({"k": "know", "peer": peer.name, "item": item, "how": None})
        return True

    def _unknow_all(self, item: str) -> None:
        """Nobody knows ``item`` now (its knowers forget it at once: each loses its part,
        nobody's part grows, so this costs one step a knower)."""
        knowers = self._knowers.pop(item)
        part = 1 / len(knowers)
        del self._tiers[item]
        for name in knowers:
            peer = self.peers[name]
            del peer.knows[item]
            peer.load = peer.load - part if peer.knows else 0.0
            self._change({"k": "know", "peer": name, "item": item, "how": None})
        self._unknown[item] = None
        self._known_version += 1

    def _share(self, knowers: set[str], before: int, after: int) -> None:
        """The ``knowers`` of an item, ``before`` of them, are to be ``after``: each one's part
        of it changes."""
        if knowers:
            delta = 1 / after - 1 / before
            for name in knowers:
                self.peers[name].load += delta

    def _change(self, change: dict[str, Any]) -> None:
        self._version += 1
        self._changes.append((self._version, change))

    # -- output ------------------------------------------------------------------------------

    def changes_since(
        self, version: int, most: int = 5000
    ) -> tuple[int, list[dict[str, Any]] | None]:
        """At most ``most`` changes after ``version`` and the version they bring the page to;
        ``None`` if some were no longer kept (send a snapshot)."""
        with self._lock:
            for name in self._dirty:
                self._change(self.peers[name].view())
            self._dirty.clear()
            if version >= self._version:
                return self._version, []
            first = self._changes[0][0] if self._changes else self._version + 1
            if version + 1 < first:
                return self._version, None
            skip = version + 1 - first
            out = [c for _, c in itertools.islice(self._changes, skip, skip + most)]
            return version + len(out), out

    def stats(self) -> dict[str, Any]:
        with self._lock:
            reasons = {why: list(kept) for why, kept in self.reasons.items()}
            return {"drops": dict(self.drops), "reasons": reasons, "events": self.events}

    def snapshot(self) -> tuple[int, dict[str, Any]]:
        with self._lock:
            peers = []
            for peer in self.peers.values():
                view = peer.view()
                view["knows"] = {item: k["how"] for item, k in peer.knows.items()}
                view["recent"] = list(peer.recent)
                peers.append(view)
            return self._version, {
                "peers": peers,
                "items": dict(self.items),
                "transfers": list(self.transfers),
                "refusals": list(self.refusals),
                "timeline": list(self.timeline)[-2000:],
                "drops": dict(self.drops),
                "events": self.events,
            }
