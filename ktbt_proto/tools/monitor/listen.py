"""The monitor's ear: a zenoh session that hears fleet events (``spec/protocol.md`` section
10), liveliness tokens (section 3) and, now and then, catalogs, and feeds a :class:`Fleet`;
on the page's asking, one peer's control tree (:meth:`Listener.tree`).

The monitor is a listener only: it declares no liveliness token, queryable or publisher, so it
never shows up as a peer. A hostile stream costs counters: an event is refused unless it is
within the size limit, decodes, verifies when signed, and names the peer whose key it came on;
the fleet may send at most :data:`RATE_ALL` events a second, and each key and signer at most
:data:`RATE` (more are a flood, dropped and counted).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Any

import zenoh

from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.events import MAX_EVENT_BYTES, PREFIX, RateLimit, decode_event
from ktbt_proto.exchange.messages import MAX_MESSAGE_BYTES, MessageRefused
from ktbt_proto.exchange.refusals import internal_error
from ktbt_proto.limits import Limits
from ktbt_proto.render import render
from ktbt_proto.syntax import parse
from ktbt_proto.tools.monitor.state import MAX_PEERS, PEER_NAME, FleetState
from ktbt_proto.transport import zenoh as zenoh_transport
from ktbt_proto.transport.zenoh import ZenohSettings, catalog_replies, open_session

RATE = 1000.0
"""Events a second the monitor takes from one key at most (5 times what a publisher sends)."""
RATE_ALL = 20_000.0
"""Events a second the monitor takes from the whole fleet at most, before decoding any."""
BUCKETS = 4 * MAX_PEERS
"""Buckets kept, one per key and signer."""
CATALOG_EVERY = 3.0
"""Seconds between two readings of the fleet's catalogs."""
TREE_LIMITS = Limits(max_size=MAX_MESSAGE_BYTES, max_depth=64, max_nodes=5_000, max_literal=256)
"""What a peer's control tree may be to be shown: a message's size, and tight bounds on the
rest."""
TREE_TIMEOUT = 1.0
"""Seconds a tree is waited for."""


def shown_tree(fleet: FleetState, name: str, payload: bytes | str) -> str | None:
    """A peer's control tree as ``ktbt show``'s outline, or None (counted malformed) if it is
    not stringBT within :data:`TREE_LIMITS`."""
    try:
        return render(parse(payload, limits=TREE_LIMITS))
    except (StringBTError, RecursionError) as exc:
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        fleet.drop("malformed", f"tree of {name}: {why}")
        return None
    except Exception as exc:  # the reader's own failure (spec/protocol.md 2.1)
        fleet.drop("malformed", f"tree of {name}: {internal_error(exc)}")
        return None


class Listener:
    """Feeds ``fleet`` from the zenoh network described by ``settings`` until closed."""

    def __init__(self, fleet: FleetState, settings: ZenohSettings) -> None:
        self.fleet = fleet
        self._limits: OrderedDict[tuple[str, str | None], RateLimit] = OrderedDict()
        self._all = RateLimit(RATE_ALL, int(RATE_ALL))
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._session = open_session(settings)
        try:
            self._declared: list[Any] = [
                self._session.declare_subscriber(f"{PREFIX}/*", self._on_event),
                self._session.liveliness().declare_subscriber(
                    f"{zenoh_transport.PREFIX}/peers/*", self._on_liveliness, history=True
                ),
            ]
        except BaseException:
            self._session.close()  # type: ignore[no-untyped-call]
            raise
        self._reader = threading.Thread(target=self._read_catalogs, daemon=True)
        self._reader.start()

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        name = str(sample.key_expr).split("/", 3)[-1]
        if sample.kind == zenoh.SampleKind.PUT:
            self.fleet.peer_joined(name)
        else:
            self.fleet.peer_left(name)

    def _on_event(self, sample: zenoh.Sample) -> None:
        payload = sample.payload
        if len(payload) > MAX_EVENT_BYTES:  # before copying it out of zenoh
            self.fleet.drop("oversized", f"{len(payload)} bytes on {str(sample.key_expr)[:100]}")
            return
        self.hear(str(sample.key_expr), payload.to_bytes())

    def hear(self, key: str, data: bytes) -> None:
        """One event as it came on ``key`` (``ktbt/v1/events/<peer>``, or the key a ROS robot's
        ``~/events`` stands for: :mod:`ktbt_proto.tools.monitor.ros2`), checked the one way
        whichever network carried it: the fleet's rate, size, decoding and signature, the key
        naming its peer, the key and signer's rate. Whatever reading it raises is counted
        malformed, never the end of the listener (spec/protocol.md section 2.1)."""
        try:
            self._hear(key, data)
        except Exception as exc:
            self.fleet.drop("malformed", f"event on {key[:100]}: {internal_error(exc)}")

    def _hear(self, key: str, data: bytes) -> None:
        with self._lock:
            flooding = not self._all.take()
        if flooding:
            self.fleet.drop("flood", "the whole fleet's events beyond the monitor's rate")
            return
        if len(data) > MAX_EVENT_BYTES:
            self.fleet.drop("oversized", f"{len(data)} bytes on {key[:100]}")
            return
        try:
            event = decode_event(data)
        except MessageRefused as exc:
            forged = exc.reason.endswith("does not verify")
            self.fleet.drop("forged" if forged else "malformed", exc.reason)
            return
        if key != f"{PREFIX}/{event.peer}":
            self.fleet.drop("wrong key", f"event {event.n} of {event.peer} on {key[:100]}")
            return
        if not self._bucket(key, event.key).take():
            self.fleet.drop("flood", f"{event.peer} ({event.key or 'unsigned'}) beyond the rate")
            return
        self.fleet.event(event)

    def _bucket(self, key: str, signer: str | None) -> RateLimit:
        """The bucket of one key and signer, so a forger flooding a peer's key spends its own
        tokens, not the peer's; the least recently used bucket goes first when too many."""
        with self._lock:
            limit = self._limits.pop((key, signer), None)
            if limit is None:
                limit = RateLimit(RATE, int(RATE))
                while len(self._limits) >= BUCKETS:
                    del self._limits[next(iter(self._limits))]
            self._limits[(key, signer)] = limit
            return limit

    def _read_catalogs(self) -> None:
        """What each peer says it knows, every few seconds, from a thread of our own (a get is
        never issued from a zenoh callback). A reply that cannot be read is counted, never the
        end of the loop; only closing ends it."""
        while not self._stop.is_set():
            try:
                for name, entries in catalog_replies(self._session, 1.0, self._refused):
                    try:
                        self.fleet.catalog(name, [e["sequence"] for e in entries])
                    except Exception as exc:  # a peer's junk that got past the checks
                        self.fleet.drop("malformed", f"catalog of {name[:64]!r}: {exc}")
            except zenoh.ZError:  # the network's own error (a closing session): not a peer's
                self.fleet.drop("network", "a catalog query failed")
            self.fleet.tend()
            self._stop.wait(CATALOG_EVERY)

    def tree(self, name: str) -> str | None:
        """The control tree ``name`` serves on ``ktbt/v1/tree/<name>`` (section 10), as
        ``ktbt show``'s outline; ``None`` if it gave none within :data:`TREE_TIMEOUT`. Blocks
        for as long: call it from a thread, never the event loop. A reply on another key, too
        large, or not stringBT within :data:`TREE_LIMITS` is counted malformed, not shown;
        the peer's own refusal (its reply error) is said; a network error is counted apart."""
        if not PEER_NAME.fullmatch(name):
            return None
        key = f"{zenoh_transport.PREFIX}/tree/{name}"
        try:
            replies = self._session.get(key, timeout=TREE_TIMEOUT)
            for reply in replies:
                if reply.ok is None:
                    err = reply.err.payload.to_bytes() if reply.err is not None else b""
                    said = err[:200].decode(errors="replace")
                    return f"({name} gives no tree: {said})"
                on = str(reply.ok.key_expr)
                if on != key:
                    self.fleet.drop("malformed", f"a tree for {name} on {on[:100]}")
                    continue
                shown = shown_tree(self.fleet, name, reply.ok.payload.to_bytes())
                if shown is not None:
                    return shown
        except zenoh.ZError:
            self.fleet.drop("network", f"a tree query to {name} failed")
        return None

    def _refused(self, reason: str) -> None:
        self.fleet.drop("malformed", reason)

    def close(self) -> None:
        self._stop.set()
        self._reader.join(timeout=5)
        for entity in self._declared:
            entity.undeclare()
        self._session.close()  # type: ignore[no-untyped-call]
