"""The transfer log: one JSON object a line for every knowledge exchange event
(``spec/protocol.md`` section 8), so an operator can see every query, answer and refusal.

The events are the members of :class:`Event`, the one list of their names: fleet events
(section 10), the monitor, the fleet tool and ``ktbt log`` all use it. Every line has ``t``
(UTC, ISO 8601), ``event`` and ``peer`` (whose log it is); the other fields depend on the event
(a ``refused`` line carries its ``reason``).
The log is append-only and written from several threads (zenoh callbacks, the agent's loop), so
each line is written whole under a lock and flushed.

A log may also have sinks (:meth:`TransferLog.add_sink`): callables that see every event as it
is recorded, after its line is written. Events flow one way, from the log to its sinks; a peer
publishing its fleet events (section 10) is one. A log may have sinks and no file.
"""

from __future__ import annotations

import json
import threading
from collections import Counter
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from enum import StrEnum
from pathlib import Path
from typing import Any, TextIO


class Event(StrEnum):
    """Every kind of transfer-log event (``spec/protocol.md`` section 8). A member is its
    name on the wire and in the log (``Event.MERGED == "merged"``)."""

    QUERY_SENT = "query-sent"
    QUERY_RECEIVED = "query-received"
    ANSWER_SENT = "answer-sent"
    ANSWER_RECEIVED = "answer-received"
    REFUSED = "refused"
    """An answer (or query) refused, with its ``reason``: a peer's fault or a policy's."""
    MERGED = "merged"
    FORGOTTEN = "forgotten"
    ERROR_RECEIVED = "error-received"
    """A peer's error reply (section 2)."""
    NETWORK_ERROR = "network-error"
    """The network's own failure, never a peer's refusal."""
    LATE_ANSWER = "late-answer"
    """An answer to a query already closed: counted, not merged (section 4)."""
    SESSION_UP = "session-up"
    """The peer's session is open (section 3): the first mark of a transfer's timeline."""
    PEER_SEEN = "peer-seen"
    """Another peer's liveliness appeared (``sender``: its name; section 3)."""
    ANNOUNCED = "announced"
    """An announcement of what the peer just learned, put once for all its neighbours
    (``sequence``, ``more``; sections 3 and 4.5)."""


MAX_LINE = 1_000_000
"""A line longer than this is not read (a log is ours, but a file may be anything)."""

Sink = Callable[[dict[str, Any]], None]
"""Sees each event recorded, as the dict written (``t``, ``event``, ``peer`` and its fields)."""


class TransferLog:
    """Append events to a JSON-lines file (or any text stream; ``None``: no file, sinks only)."""

    def __init__(self, target: str | Path | TextIO | None) -> None:
        self._lock = threading.Lock()
        self._file: TextIO | None
        if isinstance(target, str | Path):
            self._file = open(target, "a", encoding="utf-8")  # noqa: SIM115
            self._owned = True
        else:
            self._file, self._owned = target, False
        self._sinks: tuple[Sink, ...] = ()
        self.counts: Counter[str] = Counter()
        """Events recorded, by kind."""

    def add_sink(self, sink: Sink) -> None:
        """Hand every later event to ``sink`` too (called outside the log's lock, from the
        recording thread; a sink must not raise, and must not record into this log)."""
        with self._lock:
            self._sinks = (*self._sinks, sink)

    @property
    def sinks(self) -> tuple[Sink, ...]:
        """The sinks events are handed to now."""
        return self._sinks

    def remove_sink(self, sink: Sink) -> None:
        """Stop handing events to ``sink`` (a transport closing removes its publisher, so a
        log reused by another transport publishes once)."""
        with self._lock:
            self._sinks = tuple(s for s in self._sinks if s is not sink)

    def record(self, event: Event, **fields: Any) -> None:
        entry = {"t": datetime.now(UTC).isoformat(timespec="milliseconds"), "event": event}
        entry.update({k: v for k, v in fields.items() if v is not None})
        line = json.dumps(entry, ensure_ascii=False, default=str)
        with self._lock:
            self.counts[event] += 1
            if self._file is not None and not self._file.closed:
                self._file.write(line + "\n")
                self._file.flush()
            sinks = self._sinks
        for sink in sinks:
            sink(entry)

    def close(self) -> None:
        with self._lock:
            if self._owned and self._file is not None and not self._file.closed:
                self._file.close()

    def __enter__(self) -> TransferLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read(path: str | Path) -> Iterator[dict[str, Any] | str]:
    """The events of a log file, in order; a line that is not an event comes back as the
    reason it is not (a torn last line after a crash, say), so nothing stops the reading."""
    with open(path, "rb") as f:
        for number, raw in enumerate(f, 1):
            if len(raw) > MAX_LINE:
                yield f"line {number}: longer than {MAX_LINE} bytes"
                continue
            try:
                entry = json.loads(raw)
            except (ValueError, RecursionError):
                yield f"line {number}: not a JSON object"
                continue
            if not isinstance(entry, dict) or not isinstance(entry.get("event"), str):
                yield f"line {number}: not an event"
                continue
            yield entry


def describe(entry: dict[str, Any]) -> str:
    """One event as one readable line."""
    head = f"{entry.get('t', '?')} {entry.get('peer', '?')} {entry['event']}"
    rest = {k: v for k, v in entry.items() if k not in ("t", "peer", "event", "reason")}
    words = [f"{k}={v}" for k, v in rest.items()]
    if "reason" in entry:
        words.append(f"reason: {entry['reason']}")
    return " ".join([head, *words])
