"""The eclipse-zenoh transport: agents in separate processes and on separate machines.

Key expressions (``spec/protocol.md``):

- ``ktbt/v1/knowledge/<peer>``: each peer's queryable. A query's payload is a ``Query``; a
  reply's payload is a ``Response`` (or an ``ErrorReply``, sent as a reply error).
- ``ktbt/v1/catalog/<peer>``: answers with the sequences the peer knows (``ktbt peer list``).
- ``ktbt/v1/inbox/<peer>``: where a late answer is put when the asker's query has closed.
- ``ktbt/v1/peers/<peer>``: a liveliness token, present while the peer runs.
- ``ktbt/v1/answers/<peer>``: with ``publish_answers``, a copy of every answer the peer sends,
  for the peers that overhear (``overhear``; spec section 4.3).
- ``ktbt/v1/events/<peer>``: with ``publish_events``, every event of the peer's transfer log
  (spec section 10).

Queries are issued from a worker thread, never from a zenoh callback; every query a peer
receives is finished (answered, refused, or dropped once its answer window passes); sessions are
closed by :meth:`ZenohTransport.close` (use the transport as a context manager).

What a hostile peer can do is bounded here (spec section 3): replies are not consolidated, so a
silent peer delays no one and an impostor cannot replace another peer's answer; a reply counts
only on its sender's own key, once per get; queries arrive only through the queryable, and a
query already open under the same sender and id is not replaced; inboxes and the queue of
outgoing queries are bounded, and what does not fit is refused, counted and logged, never
silently dropped.
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

from ..events import EventPublisher
from ..messages import (
    MAX_MESSAGE_BYTES,
    ErrorReply,
    MessageRefused,
    Query,
    Response,
    decode,
    encode,
)
from ..signing import Identity, SignedItem
from ..transferlog import TransferLog
from .base import Message

log = logging.getLogger("ktbt.zenoh")

PREFIX = "ktbt/v1"
Lookup = Callable[[str], str | SignedItem | None]
"""Sequence key -> compact subtree (signed by its author, or not), or None: answers queries
straight from the callback."""


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
    catalog: Callable[[], Sequence[str | dict[str, Any]]] | None = None
    """What this peer knows: sequences, or objects with ``sequence`` and provenance."""
    query_timeout: float = 2.0
    answer_window: float = 1.0
    serving: bool = True
    """False for a peer that only asks (``ktbt peer ask``, ``list``): queries to it are
    finished at once, unanswered."""
    max_pending: int = 256
    inbox_limit: int = 1024
    max_asking: int = 8
    """Queries waiting for the worker threads at most; a broadcast beyond is refused."""
    max_bytes: int = MAX_MESSAGE_BYTES
    identity: Identity | None = None
    """With a key pair, the replies this peer's ``lookup`` gives are hop-signed."""
    log: TransferLog | None = None
    screen: Callable[[Response], str | None] | None = None
    """The asker's check of a reply's signatures (its trust policy), run before the reply takes
    its sender's one place in a get, so that a forgery on a peer's key cannot keep that peer's
    genuine answer out. An agent sets it (``Agent`` gives its policy)."""
    publish_answers: bool = False
    """Publish a copy of every answer this peer sends on ``ktbt/v1/answers/<name>`` (section
    4.3), so that peers that overhear can learn it; off, nothing extra is sent."""
    overhear: bool = False
    """Subscribe to ``ktbt/v1/answers/*`` and hand the answers others publish to the agent,
    whose ``overhear`` setting decides what to do with them (section 4.3)."""
    overheard_limit: int = 64
    """Overheard answers waiting for the agent at most; a newcomer beyond is refused, so a
    flood of published answers never takes a direct answer's place in the inbox."""
    publish_events: bool = False
    """Publish every event of ``log`` (one is made if there is none) on ``ktbt/v1/events/<name>``,
    signed with ``identity`` if there is one (section 10)."""
    refused: int = 0
    """Every message this transport refused (undecodable, on a wrong key, flooding...)."""
    _session: Any = field(init=False, default=None)

    def __post_init__(self) -> None:
        self._inbox: deque[Message] = deque()
        self._overheard: deque[Response] = deque()
        self._asked: deque[str] = deque(maxlen=256)
        """The ids of this peer's latest queries: a published copy of an answer to one of them
        is not overheard (the answer itself comes as a reply)."""
        self._publisher: Any = None
        self._asking = 0
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
            if self.publish_answers:
                self._publisher = self._session.declare_publisher(f"{PREFIX}/answers/{self.name}")
                self._declared.append(self._publisher)
            if self.publish_events:
                self.log = self.log or TransferLog(None)
                events, publisher = EventPublisher.on_session(
                    self._session, self.name, identity=self.identity
                )
                self._declared.append(publisher)
                self.log.add_sink(events)
            if self.overhear:
                self._declared.append(
                    self._session.declare_subscriber(
                        f"{PREFIX}/answers/*",
                        self._on_answer,
                        allowed_origin=zenoh.Locality.REMOTE,  # not our own answers
                    )
                )
        except BaseException:
            self._session.close()
            raise
        self.closed = False

    # -- the Transport interface ----------------------------------------------------------------

    def broadcast(self, message: Message) -> None:
        """Ask every reachable peer (a get from a worker thread); answers arrive in the inbox."""
        if self.closed:
            return
        with self._lock:
            full = self._asking >= self.max_asking
            if not full:
                self._asking += 1
        if full:
            self._refuse(f"query {message.id} not sent: {self.max_asking} queries already waiting")
            return
        self._workers.submit(self._ask_queued, message)

    def _ask_queued(self, message: Message) -> None:
        try:
            self._ask(message)
        finally:
            with self._lock:
                self._asking -= 1

    def _refuse(self, reason: str, **fields: Any) -> None:
        """Count, log and record one refusal (spec section 2: every refusal is counted)."""
        with self._lock:
            self.refused += 1
        log.info("%s refused: %s", self.name, reason)
        if self.log is not None:
            self.log.record("refused", peer=self.name, reason=reason, where="transport", **fields)

    def _deliver(self, message: Message) -> None:
        """Into the inbox, unless it is full: then the newcomer is refused, and what arrived
        first (the first answer, which wins) is kept."""
        with self._lock:
            full = len(self._inbox) >= self.inbox_limit
            if not full:
                self._inbox.append(message)
        if full:
            self._refuse(
                f"inbox full ({self.inbox_limit} messages): a {message.type} from "
                f"{message.sender} is dropped"
            )

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
        else:
            self._session.put(f"{PREFIX}/inbox/{to}", payload)
        if isinstance(message, Response):
            self._publish(payload)

    def _publish(self, payload: bytes) -> None:
        """The same encoded answer, once more, on this peer's answers key (section 4.3)."""
        if self._publisher is not None:
            self._publisher.put(payload)

    def receive(self) -> list[Message]:
        self._expire()
        with self._lock:
            messages = list(self._inbox)
            messages.extend(self._overheard)
            self._inbox.clear()
            self._overheard.clear()
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

    def ask(
        self,
        query: Query,
        timeout: float | None = None,
        on_answer: Callable[[Response], None] | None = None,
    ) -> list[Response]:
        """Broadcast ``query`` and wait for the answers (blocking; for tools and tests).
        ``on_answer`` sees each answer the moment it arrives."""
        return self._ask(query, timeout, keep=False, on_answer=on_answer)

    def _ask(
        self,
        message: Message,
        timeout: float | None = None,
        keep: bool = True,
        on_answer: Callable[[Response], None] | None = None,
    ) -> list[Response]:
        """One get. Replies are not consolidated: each is handled as it arrives. A reply is an
        answer only if it is a response to this query, on its sender's own key, and the first
        from that key."""
        answers: list[Response] = []
        heard: set[str] = set()
        with self._lock:
            self._asked.append(message.id)
        try:
            replies = self._session.get(
                f"{PREFIX}/knowledge/*",
                payload=encode(message),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=self.query_timeout if timeout is None else timeout,
                allowed_destination=zenoh.Locality.REMOTE,  # not our own queryable
            )
            for reply in replies:
                answer = self._reply(reply, message, heard)
                if answer is None:
                    continue
                answers.append(answer)
                if on_answer is not None:
                    on_answer(answer)
                if keep:
                    self._deliver(answer)
        except Exception:  # a closing session; the query is simply lost
            log.debug("%s: query failed", self.name, exc_info=True)
        return answers

    def _reply(self, reply: Any, asked: Message, heard: set[str]) -> Response | None:
        """The answer a reply carries, or None (refused and counted, or a peer's error)."""
        sample = reply.ok if reply.ok is not None else reply.err
        key = str(getattr(sample, "key_expr", "")) if reply.ok is not None else ""
        try:
            answer = decode(sample.payload.to_bytes(), self.max_bytes)
        except MessageRefused as exc:
            self._refuse(f"a reply to {asked.id}: {exc.reason}", key=key)
            return None
        if isinstance(answer, ErrorReply):
            log.info("%s: %s refused query %s: %s", self.name, answer.sender, asked.id, answer)
            if self.log is not None:
                self.log.record(
                    "error-received", peer=self.name, sender=answer.sender, reason=answer.message
                )
            return None
        if not isinstance(answer, Response):
            self._refuse(f"a {answer.type} from {answer.sender} sent as a reply", key=key)
            return None
        if key != f"{PREFIX}/knowledge/{answer.sender}":
            self._refuse(f"a reply naming {answer.sender} came on {key[:80]}", key=key)
            return None
        if answer.id != asked.id or answer.sequence != getattr(asked, "sequence", None):
            self._refuse(f"a reply from {answer.sender} answers another question", key=key)
            return None
        why = self.screen(answer) if self.screen is not None else None
        if why is not None:
            self._refuse(f"from {answer.sender}: {why}", key=key)
            return None
        if key in heard:
            self._refuse(f"another reply from {answer.sender} to the same query", key=key)
            return None
        heard.add(key)
        return answer

    # -- being asked ------------------------------------------------------------------------------

    def _on_query(self, query: Any) -> None:
        try:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            message = decode(payload, self.max_bytes)
            if not isinstance(message, Query):
                raise MessageRefused(f"expected a query, got a {message.type}")
        except MessageRefused as exc:
            self._refuse(f"a query: {exc.reason}")
            error = ErrorReply(id="0", sender=self.name, code="refused", message=exc.reason)
            try:
                query.reply_err(encode(error))
            finally:
                query.drop()
            return
        if message.sender == self.name or not self.serving:
            query.drop()
            return
        if self.lookup is not None:
            if self.log is not None:
                self.log.record(
                    "query-received",
                    peer=self.name,
                    sender=message.sender,
                    id=message.id,
                    sequence=message.sequence,
                )
            try:
                self._answer_at_once(query, message, self.lookup)
            finally:
                query.drop()
            return
        self._expire()
        key = (message.sender, message.id)
        with self._lock:
            if len(self._pending) >= self.max_pending:
                # Full: this one is finished unanswered, as a teacher in cool-down would.
                full, taken = True, False
            else:
                full, taken = False, key in self._pending
                if not taken:
                    self._pending[key] = (query, time.monotonic() + self.answer_window)
        if full or taken:
            query.drop()
            if taken:  # a replay: the query already open keeps its place
                self._refuse(f"query {message.id} from {message.sender} is already open")
            return
        self._deliver(message)

    def _answer_at_once(self, query: Any, message: Query, lookup: Lookup) -> None:
        """A knowledge server's answer, given inside the callback."""
        found = lookup(message.sequence)
        if found is None:
            return
        item = found if isinstance(found, SignedItem) else SignedItem(found)
        response = Response(
            id=message.id,
            sender=self.name,
            sequence=message.sequence,
            subtree=item.subtree,
            author=item.author,
            signature=item.signature,
        )
        if self.identity is not None:
            response = self.identity.sign_reply(response)
        payload = encode(response)
        query.reply(f"{PREFIX}/knowledge/{self.name}", payload)
        self._publish(payload)
        if self.log is not None:
            self.log.record(
                "answer-sent",
                peer=self.name,
                to=message.sender,
                id=message.id,
                sequence=message.sequence,
                author=item.author,
            )

    def _on_catalog(self, query: Any) -> None:
        known = self.catalog() if self.catalog is not None else []
        query.reply(f"{PREFIX}/catalog/{self.name}", json.dumps(known).encode())
        query.drop()

    def _on_inbox(self, sample: Any) -> None:
        """A late answer. Only a response is taken: a query arrives only through the
        queryable, where zenoh knows it came from a get."""
        try:
            message = decode(sample.payload.to_bytes(), self.max_bytes)
        except MessageRefused as exc:
            self._refuse(f"a message in the inbox: {exc.reason}")
            return
        if not isinstance(message, Response):
            self._refuse(f"a {message.type} from {message.sender} put in the inbox")
            return
        self._deliver(message)

    def _on_answer(self, sample: Any) -> None:
        """An answer another peer published (section 4.3), checked as a reply is: within the
        message limits, a response, believed only as coming from the key it arrived on, and
        passing the trust policy; then queued for the agent, a newcomer to a full queue refused.
        A copy of an answer to this peer's own query is left to the reply."""
        key = str(sample.key_expr)
        try:
            answer = decode(sample.payload.to_bytes(), self.max_bytes)
        except MessageRefused as exc:
            self._refuse(f"an overheard answer: {exc.reason}", key=key[:80])
            return
        if not isinstance(answer, Response):
            self._refuse(f"a {answer.type} from {answer.sender} published as an answer", key=key)
            return
        if key != f"{PREFIX}/answers/{answer.sender}" or answer.sender == self.name:
            self._refuse(f"an answer naming {answer.sender} came on {key[:80]}", key=key[:80])
            return
        with self._lock:
            mine = answer.id in self._asked
        if mine:
            return
        why = self.screen(answer) if self.screen is not None else None
        if why is not None:
            self._refuse(f"overheard from {answer.sender}: {why}", key=key)
            return
        with self._lock:
            full = len(self._overheard) >= self.overheard_limit
            if not full:
                self._overheard.append(answer)
        if full:
            self._refuse(
                f"{self.overheard_limit} overheard answers waiting: one from {answer.sender} "
                "is dropped",
                key=key,
            )

    def _expire(self) -> None:
        now = time.monotonic()
        with self._lock:
            expired = [k for k, (_, deadline) in self._pending.items() if deadline < now]
            queries = [self._pending.pop(k)[0] for k in expired]
        for query in queries:
            query.drop()


def _catalog_replies(owner: ZenohTransport, timeout: float) -> dict[str, list[dict[str, str]]]:
    """Each peer's catalog entries as ``{"sequence": ..., "author": ..., ...}``; a reply on a
    key that is not a catalog, too large, or not a JSON array is ignored."""
    out: dict[str, list[dict[str, str]]] = {}
    for reply in owner._session.get(f"{PREFIX}/catalog/*", timeout=timeout):
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
        if not isinstance(value, list):
            continue
        entries = []
        for v in value:
            if isinstance(v, dict) and isinstance(v.get("sequence"), str):
                entries.append({str(k): str(x)[:200] for k, x in v.items()})
            elif not isinstance(v, dict | list):
                entries.append({"sequence": str(v)})
        out[name] = entries
    out.pop(owner.name, None)
    return out


def catalogs(owner: ZenohTransport, timeout: float = 1.0) -> dict[str, list[dict[str, str]]]:
    """What each peer knows, with the provenance it reports (author, teacher, time)."""
    return _catalog_replies(owner, timeout)


def peers(session_owner: ZenohTransport, timeout: float = 1.0) -> dict[str, list[str]]:
    """Who is present (liveliness) and what each knows (its catalog)."""
    session = session_owner._session
    present = sorted(
        str(r.ok.key_expr).rsplit("/", 1)[-1]
        for r in session.liveliness().get(f"{PREFIX}/peers/*", timeout=timeout)
        if r.ok is not None
    )
    known: dict[str, list[str]] = {name: [] for name in present}
    for name, entries in _catalog_replies(session_owner, timeout).items():
        known[name] = [e["sequence"] for e in entries]
    known.pop(session_owner.name, None)
    return known
