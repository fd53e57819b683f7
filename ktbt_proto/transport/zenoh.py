"""The eclipse-zenoh transport: agents in separate processes and on separate machines.

Key expressions (``spec/protocol.md``):

- ``ktbt/v1/knowledge/<peer>``: each peer's queryable. A query's payload is a ``Query``; a
  reply's payload is a ``Response`` (or an ``ErrorReply``, sent as a reply error).
- ``ktbt/v1/catalog/<peer>``: answers with the sequences the peer knows (``ktbt peer list``).
- ``ktbt/v1/inbox/<peer>``: where a late answer is put when the asker's query has closed.
- ``ktbt/v1/peers/<peer>``: a liveliness token, present while the peer runs.

Queries are issued from a worker thread, never from a zenoh callback; every query a peer
receives is finished (answered, refused, or dropped once its answer window passes); sessions are
closed by :meth:`ZenohTransport.close` (use the transport as a context manager).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from ..messages import (
    MAX_MESSAGE_BYTES,
    ErrorReply,
    MessageRefused,
    Query,
    Response,
    decode,
    encode,
)
from .base import Message

log = logging.getLogger("ktbt.zenoh")

PREFIX = "ktbt/v1"
Lookup = Callable[[str], str | None]
"""Sequence key -> compact subtree, or None: answers queries straight from the callback."""


@dataclass(frozen=True)
class ZenohSettings:
    """How to reach the fleet. ``config`` is a zenoh JSON5 file (TLS, mTLS, user/password...);
    ``listen``/``connect`` endpoints and ``mode`` are applied on top of it."""

    listen: Sequence[str] = ()
    connect: Sequence[str] = ()
    config: str | Path | None = None
    mode: str = "peer"
    multicast_scouting: bool = False

    def zenoh_config(self) -> zenoh.Config:
        conf = zenoh.Config.from_file(str(self.config)) if self.config else zenoh.Config()
        conf.insert_json5("mode", json.dumps(self.mode))
        if self.listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        if self.connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(self.multicast_scouting))
        return conf


def open_session(settings: ZenohSettings) -> zenoh.Session:
    return zenoh.open(settings.zenoh_config())


@dataclass(eq=False)
class ZenohTransport:
    """A peer on a zenoh network, implementing the agent's :class:`Transport`.

    With ``lookup``, queries are answered inside the queryable callback (a knowledge server);
    without, they are handed to the agent, whose teach tree answers through :meth:`send`.
    ``query_timeout``: how long a broadcast query collects answers, in seconds.
    """

    name: str
    settings: ZenohSettings = field(default_factory=ZenohSettings)
    lookup: Lookup | None = None
    catalog: Callable[[], list[str]] | None = None
    query_timeout: float = 2.0
    answer_window: float = 1.0
    serving: bool = True
    """False for a peer that only asks (``ktbt peer ask``, ``list``): queries to it are
    finished at once, unanswered."""
    max_pending: int = 256
    inbox_limit: int = 1024
    max_bytes: int = MAX_MESSAGE_BYTES
    refused: int = 0
    _session: Any = field(init=False, default=None)

    def __post_init__(self) -> None:
        self._inbox: deque[Message] = deque(maxlen=self.inbox_limit)
        self._lock = threading.Lock()
        self._pending: dict[tuple[str, str], tuple[Any, float]] = {}
        self._workers = ThreadPoolExecutor(max_workers=2, thread_name_prefix=f"ktbt-{self.name}")
        self._session = open_session(self.settings)
        try:
            self._declared: list[Any] = [
                self._session.declare_queryable(f"{PREFIX}/knowledge/{self.name}", self._on_query),
                self._session.declare_queryable(f"{PREFIX}/catalog/{self.name}", self._on_catalog),
                self._session.declare_subscriber(f"{PREFIX}/inbox/{self.name}", self._on_inbox),
                self._session.liveliness().declare_token(f"{PREFIX}/peers/{self.name}"),
            ]
        except BaseException:
            self._session.close()
            raise
        self.closed = False

    # -- the Transport interface ----------------------------------------------------------------

    def broadcast(self, message: Message) -> None:
        """Ask every reachable peer (a get from a worker thread); answers arrive in the inbox."""
        if self.closed:
            return
        self._workers.submit(self._ask, message)

    def send(self, to: str, message: Message) -> None:
        """Answer a query this peer received, or put the message in ``to``'s inbox."""
        if self.closed:
            return
        payload = encode(message)
        with self._lock:
            pending = self._pending.pop((to, message.id), None)
        if pending is not None:
            query = pending[0]
            try:
                if isinstance(message, ErrorReply):
                    query.reply_err(payload)
                else:
                    query.reply(f"{PREFIX}/knowledge/{self.name}", payload)
            finally:
                query.drop()
            return
        self._session.put(f"{PREFIX}/inbox/{to}", payload)

    def receive(self) -> list[Message]:
        self._expire()
        with self._lock:
            messages = list(self._inbox)
            self._inbox.clear()
        return messages

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self._workers.shutdown(wait=True, cancel_futures=True)
        with self._lock:
            pending, self._pending = self._pending, {}
        for query, _ in pending.values():
            query.drop()
        for entity in self._declared:
            entity.undeclare()
        self._session.close()

    def __enter__(self) -> ZenohTransport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- asking -----------------------------------------------------------------------------------

    def ask(self, query: Query, timeout: float | None = None) -> list[Message]:
        """Broadcast ``query`` and wait for the answers (blocking; for tools and tests)."""
        return self._ask(query, timeout, keep=False)

    def _ask(
        self, message: Message, timeout: float | None = None, keep: bool = True
    ) -> list[Message]:
        answers: list[Message] = []
        try:
            replies = self._session.get(
                f"{PREFIX}/knowledge/*",
                payload=encode(message),
                timeout=self.query_timeout if timeout is None else timeout,
                allowed_destination=zenoh.Locality.REMOTE,  # not our own queryable
            )
            for reply in replies:
                sample = reply.ok if reply.ok is not None else reply.err
                try:
                    answer = decode(sample.payload.to_bytes(), self.max_bytes)
                except MessageRefused as exc:
                    self.refused += 1
                    log.info("%s refused a reply: %s", self.name, exc.reason)
                    continue
                answers.append(answer)
                if keep:
                    with self._lock:
                        self._inbox.append(answer)
        except Exception:  # a closing session; the query is simply lost
            log.debug("%s: query failed", self.name, exc_info=True)
        return answers

    # -- being asked ------------------------------------------------------------------------------

    def _on_query(self, query: Any) -> None:
        try:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            message = decode(payload, self.max_bytes)
            if not isinstance(message, Query):
                raise MessageRefused(f"expected a query, got a {message.type}")
        except MessageRefused as exc:
            self.refused += 1
            error = ErrorReply(id="0", sender=self.name, code="refused", message=exc.reason)
            query.reply_err(encode(error))
            query.drop()
            return
        if message.sender == self.name or not self.serving:
            query.drop()
            return
        if self.lookup is not None:
            subtree = self.lookup(message.sequence)
            if subtree is not None:
                response = Response(
                    id=message.id, sender=self.name, sequence=message.sequence, subtree=subtree
                )
                query.reply(f"{PREFIX}/knowledge/{self.name}", encode(response))
            query.drop()
            return
        self._expire()
        with self._lock:
            if len(self._pending) >= self.max_pending:
                # Full: this one is finished unanswered, as a teacher in cool-down would.
                query.drop()
                return
            key = (message.sender, message.id)
            stale = self._pending.pop(key, None)
            self._pending[key] = (query, time.monotonic() + self.answer_window)
            self._inbox.append(message)
        if stale is not None:
            stale[0].drop()

    def _on_catalog(self, query: Any) -> None:
        known = self.catalog() if self.catalog is not None else []
        query.reply(f"{PREFIX}/catalog/{self.name}", json.dumps(known).encode())
        query.drop()

    def _on_inbox(self, sample: Any) -> None:
        try:
            message = decode(sample.payload.to_bytes(), self.max_bytes)
        except MessageRefused as exc:
            self.refused += 1
            log.info("%s refused a message: %s", self.name, exc.reason)
            return
        with self._lock:
            self._inbox.append(message)

    def _expire(self) -> None:
        now = time.monotonic()
        with self._lock:
            expired = [k for k, (_, deadline) in self._pending.items() if deadline < now]
            queries = [self._pending.pop(k)[0] for k in expired]
        for query in queries:
            query.drop()


def peers(session_owner: ZenohTransport, timeout: float = 1.0) -> dict[str, list[str]]:
    """Who is present (liveliness) and what each knows (its catalog)."""
    session = session_owner._session
    present = sorted(
        str(r.ok.key_expr).rsplit("/", 1)[-1]
        for r in session.liveliness().get(f"{PREFIX}/peers/*", timeout=timeout)
        if r.ok is not None
    )
    known: dict[str, list[str]] = {name: [] for name in present}
    for reply in session.get(f"{PREFIX}/catalog/*", timeout=timeout):
        if reply.ok is None:
            continue
        name = str(reply.ok.key_expr).rsplit("/", 1)[-1]
        payload = reply.ok.payload.to_bytes()
        if len(payload) > MAX_MESSAGE_BYTES:
            continue
        try:
            value = json.loads(payload)
        except (ValueError, RecursionError):  # a peer's garbage is its own problem
            continue
        if isinstance(value, list):
            known[name] = [str(v) for v in value]
    known.pop(session_owner.name, None)
    return known
