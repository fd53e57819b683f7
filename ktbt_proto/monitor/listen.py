"""The monitor's ear: a zenoh session that hears fleet events (``spec/protocol.md`` section
10), liveliness tokens (section 3) and, now and then, catalogs, and feeds a :class:`Fleet`.

The monitor is a listener only: it declares no liveliness token, queryable or publisher, so it
never shows up as a peer. A hostile stream costs counters: an event is refused unless it is
within the size limit, decodes, verifies when signed, and names the peer whose key it came on;
each key may send at most :data:`RATE` events a second (more are a flood, dropped and counted).
"""

from __future__ import annotations

import json
import threading
from typing import Any

import zenoh

from ..events import MAX_EVENT_BYTES, PREFIX, RateLimit, decode_event
from ..messages import MAX_MESSAGE_BYTES, MessageRefused
from ..transport.zenoh import ZenohSettings, open_session
from .fleet import MAX_PEERS, Fleet

RATE = 1000.0
"""Events a second the monitor takes from one key at most (5 times what a publisher sends)."""
CATALOG_EVERY = 3.0
"""Seconds between two readings of the fleet's catalogs."""


class Listener:
    """Feeds ``fleet`` from the zenoh network described by ``settings`` until closed."""

    def __init__(self, fleet: Fleet, settings: ZenohSettings) -> None:
        self.fleet = fleet
        self._limits: dict[str, RateLimit] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._session = open_session(settings)
        try:
            self._declared: list[Any] = [
                self._session.declare_subscriber(f"{PREFIX}/*", self._on_event),
                self._session.liveliness().declare_subscriber(
                    "ktbt/v1/peers/*", self._on_liveliness, history=True
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
        key = str(sample.key_expr)
        with self._lock:
            limit = self._limits.get(key)
            if limit is None:
                if len(self._limits) >= 4 * MAX_PEERS:
                    self._limits.clear()  # a flood of keys: start the buckets afresh
                limit = self._limits[key] = RateLimit(RATE, int(RATE))
            flooding = not limit.take()
        if flooding:
            self.fleet.drop("flood")
            return
        payload = sample.payload
        if len(payload) > MAX_EVENT_BYTES:
            self.fleet.drop("oversized")
            return
        try:
            event = decode_event(payload.to_bytes())
        except MessageRefused:
            self.fleet.drop("malformed")
            return
        if key != f"{PREFIX}/{event.peer}":
            self.fleet.drop("wrong key")
            return
        self.fleet.event(event, signed=event.sig is not None)

    def _read_catalogs(self) -> None:
        """What each peer says it knows, every few seconds, from a thread of our own (a get is
        never issued from a zenoh callback)."""
        while True:
            try:
                for reply in self._session.get("ktbt/v1/catalog/*", timeout=1.0):
                    self._catalog(reply)
            except Exception:  # a closing session
                return
            self.fleet.tend()
            if self._stop.wait(CATALOG_EVERY):
                return

    def _catalog(self, reply: Any) -> None:
        if reply.ok is None:
            return
        name = str(reply.ok.key_expr).split("/", 3)[-1]
        payload = reply.ok.payload.to_bytes()
        if len(payload) > MAX_MESSAGE_BYTES:
            self.fleet.drop("oversized")
            return
        try:
            value = json.loads(payload)
        except (ValueError, RecursionError):
            self.fleet.drop("malformed")
            return
        if not isinstance(value, list):
            self.fleet.drop("malformed")
            return
        sequences = [
            v["sequence"] if isinstance(v, dict) else v
            for v in value
            if isinstance(v, str) or (isinstance(v, dict) and isinstance(v.get("sequence"), str))
        ]
        self.fleet.catalog(name, [s for s in sequences if len(s) <= 4096])

    def close(self) -> None:
        self._stop.set()
        self._reader.join(timeout=5)
        for entity in self._declared:
            entity.undeclare()
        self._session.close()  # type: ignore[no-untyped-call]
