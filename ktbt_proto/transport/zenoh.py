"""The eclipse-zenoh transport: agents in separate processes and on separate machines.

Key expressions (``spec/protocol.md``):

- ``ktbt/v1/knowledge/<peer>``: each peer's queryable. A query's payload is a ``Query``; a
  reply's payload is a ``Response`` (or an ``ErrorReply``, sent as a reply error).
- ``ktbt/v1/catalog/<peer>``: answers with the sequences the peer knows (``ktbt peer list``).
- ``ktbt/v1/inbox/<peer>``: where a late answer is put when the asker's query has closed.
- ``ktbt/v1/peers/<peer>``: a liveliness token, present while the peer runs.
- ``ktbt/v1/learned/<peer>``: a fleet member's announcement of what it just learned, heard by
  its neighbours (:meth:`ZenohTransport.learned`, :meth:`ZenohTransport.news`; spec section 3).
- ``ktbt/v1/answers/<peer>``: with ``publish_answers``, a copy of every answer the peer sends,
  for the peers that overhear (``overhear``; spec section 4.3).
- ``ktbt/v1/events/<peer>``: with ``publish_events``, every event of the peer's transfer log
  (spec section 10).
- ``ktbt/v1/tree/<peer>``: with ``publish_events`` and ``tree``, the peer's control tree in
  compact stringBT, for ``ktbt monitor`` (spec section 10).

A get never holds a thread: its replies are handled by a callback run where zenoh receives
them, and the get's end by the callback's drop, so no number of silent peers or dead links slows
an asker (spec section 3). Every query a peer receives is finished (answered, refused, or
dropped once its answer window passes); sessions are closed by :meth:`ZenohTransport.close`
(use the transport as a context manager). Zenoh's own errors (a get's timeout) are the
network's, counted apart from what peers send (:class:`NetworkError`).

An agent built on a transport attaches to it (:meth:`ZenohTransport.attach`): the transport then
serves the agent's catalog and answers queries from what the agent knows at that moment, as a
fleet member does (spec section 4.5), so a robot built by hand is a fleet member like
``ktbt peer run``. Mistakes in the settings are one line each: an endpoint without its protocol
is refused when the settings are made (:class:`EndpointError`), and a session zenoh cannot open
(an address in use) raises :class:`SessionError`, without zenoh's Rust source locations.

What a hostile peer can do is bounded here (spec section 3): replies are not consolidated, so a
silent peer delays no one and an impostor cannot replace another peer's answer; a reply counts
only on its sender's own key, once per get; queries arrive only through the queryable, and a
query already open under the same sender and id is not replaced; inboxes and the queue of
outgoing queries are bounded, and what does not fit is refused, counted and logged, never
silently dropped.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import re
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Self, TypeVar

import zenoh

from ktbt_proto.exchange.answers import answer_to, catalog, encoded_answer, live_answers
from ktbt_proto.exchange.events import EventPublisher
from ktbt_proto.exchange.member import CATALOG_PERIOD
from ktbt_proto.exchange.messages import (
    MAX_MESSAGE_BYTES,
    MAX_MORE,
    NAME_PATTERN,
    ErrorReply,
    MessageRefused,
    Query,
    Response,
    decode,
    decode_learned,
    encode,
    encode_learned,
)
from ktbt_proto.exchange.refusals import Throttle, guarded, internal_error
from ktbt_proto.exchange.signing import Identity, SignedItem
from ktbt_proto.exchange.transferlog import Event, TransferLog
from ktbt_proto.exchange.transport import Message, NetworkError, Received
from ktbt_proto.exchange.trust import refusal
from ktbt_proto.formatter import format_tree
from ktbt_proto.transport.inbox import AnswersGiven, Inbox, Lookup

if TYPE_CHECKING:
    from ktbt_proto.exchange.core import AgentCore

log = logging.getLogger("ktbt.zenoh")

PREFIX = "ktbt/v1"
_M = TypeVar("_M", Query, Response, ErrorReply)


RX_WORKERS = 32
"""Zenoh's receive workers in a process (its default is 2). Closing a link that died silently
holds a worker for the socket's linger time (10 s); with two workers, a few such links stalled
every healthy link of the session meanwhile. With more workers the dead links are closed side by
side and the healthy ones carry on (spec section 3)."""
CLIENT_WAIT_MS = 10_000
"""How long a client waits for its router at start."""
RETRY_MS = 250
"""An endpoint that does not answer is retried for ever, this many ms apart (``--retry``):
a neighbour that comes back is found within this, at the cost of about 1000/RETRY_MS
connection attempts a second to each endpoint that stays dead (measured: docs/results/fleet.md;
spec section 3)."""
LEASE_MS = 4_000
"""A link that carries nothing, not even keep-alives, for this long is closed (zenoh's
``transport/link/tx/lease``, its default 10 s; ``--lease``), and dialled again. Chosen from the
fleet study's lease table (docs/results/fleet.md, spec section 3), which ran leases of 1, 4
and 10 s: the heal of a 30 s silent partition (0.09 to 0.15 s) and the delay its dead links
cause (none) do not depend on it, and at 1 s no healthy link of 20 peers was dropped (load
averages 2.5 and 5.8). What it sets is how long a link that went silent (a robot out of
range) is kept, 3.8 s here (0.8 s at 1 s, 8.8 s at 10 s), against its cost, 2.0 writes a
second on an idle link, both ends together (7.8 at 1 s, 0.8 at 10 s): a gone robot is given
up within seconds for less than one keep-alive a second each way."""
KEEP_ALIVE = 4
"""Keep-alives a lease (zenoh's default, not varied by the study): one every LEASE_MS / 4 ms
from each end of an idle link, so that a lease expires only after four are missed."""


def stable_zid(name: str) -> str:
    """The zenoh id a peer named ``name`` always has (16 bytes of a hash of the name, in hex,
    never with a leading zero, which zenoh refuses): a restarted peer is the same peer to the
    others, and their tables do not grow with every restart (spec section 3)."""
    digest = bytearray(hashlib.sha256(b"ktbt/v1/zid\0" + name.encode()).digest()[:16])
    digest[0] |= 0x10
    return digest.hex()


MemberMode = Literal["peer", "client"]
"""How a fleet member's session joins: a peer among peers, or a client through a router
(spec/protocol.md section 3)."""
Mode = Literal[MemberMode, "router"]
"""How a session joins; ``router`` serves fleets that span subnets (``ktbt peer router``)."""


class EndpointError(ValueError):
    """A ``listen`` or ``connect`` endpoint zenoh could not read, refused when the settings are
    made (spec section 3). Its text is one line, ``SETTING: ENDPOINT ...: write ...``, so a
    command line prints it as ``--SETTING: ...``; ``setting`` and ``endpoint`` are kept apart
    too."""

    def __init__(self, setting: str, endpoint: str, reason: str) -> None:
        super().__init__(f"{setting}: {reason}")
        self.setting = setting
        self.endpoint = endpoint
        self.reason = reason


class SessionError(OSError):
    """Zenoh could not open a session (an address in use, a protocol it does not know, a config
    file it refuses): one line naming what failed, without zenoh's Rust source locations."""


_PROTOCOL = re.compile(r"[a-z][a-z0-9-]*/\S")
"""An endpoint's start: ``<protocol>/<address>`` (``tcp/127.0.0.1:7447``)."""


def _endpoints(setting: str, value: Sequence[str] | str) -> tuple[str, ...]:
    """``value``'s endpoints (one string is one endpoint), each of the form
    ``<protocol>/<address>[?<metadata>][#<config>]``; anything else is an :class:`EndpointError`
    that says what to write."""
    endpoints = (value,) if isinstance(value, str) else tuple(value)
    for endpoint in endpoints:
        if not isinstance(endpoint, str):
            raise EndpointError(setting, repr(endpoint), f"{endpoint!r} is not an endpoint")
        if _PROTOCOL.match(endpoint):
            continue
        shown = repr(endpoint[:80]) if endpoint != endpoint.strip() else endpoint[:80]
        bare = endpoint.strip()
        if _PROTOCOL.match(bare):
            what, fix = "has spaces around it", bare
        elif "://" in bare:
            what, fix = "is not a zenoh endpoint", bare.replace("://", "/", 1)
        elif "/" not in bare and bare:
            what, fix = "names no protocol", f"tcp/{bare}"
        else:
            what, fix = "is not a zenoh endpoint", "<protocol>/<address>, as tcp/127.0.0.1:7447"
        raise EndpointError(setting, endpoint, f"{shown or repr('')} {what}: write {fix[:80]}")
    return endpoints


@dataclass(frozen=True)
class ZenohSettings:
    """How to reach the fleet. ``config`` is a zenoh JSON5 file (TLS, mTLS, user/password...);
    ``listen``/``connect`` endpoints, ``mode``, the zenoh id ``zid`` and the connection retry
    are applied on top of it (spec section 3). An endpoint is ``<protocol>/<address>``
    (``tcp/127.0.0.1:7447``); one without its protocol is an :class:`EndpointError` here,
    not an error of zenoh's when the session opens.
    """

    listen: Sequence[str] = ()
    connect: Sequence[str] = ()
    config: str | Path | None = None
    mode: Mode = "peer"
    multicast_scouting: bool = False
    zid: str | None = None
    """The session's zenoh id (``stable_zid(name)`` for a fleet member); None: a random one."""
    retry_ms: int = RETRY_MS
    """The period at which an endpoint that does not answer is dialled again (section 3)."""
    lease_ms: int = LEASE_MS
    """How long a silent link lives (section 3)."""

    def __post_init__(self) -> None:
        if not 10 <= self.retry_ms <= 600_000:
            raise ValueError("retry: a period from 10 ms to 600 s")
        if not 500 <= self.lease_ms <= 600_000:
            raise ValueError("lease: from 500 ms to 600 s")
        object.__setattr__(self, "listen", _endpoints("listen", self.listen))
        object.__setattr__(self, "connect", _endpoints("connect", self.connect))

    def zenoh_config(self) -> zenoh.Config:
        conf = zenoh.Config.from_file(str(self.config)) if self.config else zenoh.Config()
        conf.insert_json5("mode", json.dumps(self.mode))
        if self.zid is not None:
            conf.insert_json5("id", json.dumps(self.zid))
        if self.listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        if self.connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        # A peer or router tries every endpoint for ever, with a bounded period, so that one
        # started before its neighbours, or cut off from them, finds them when they are back. A
        # client cannot work without its router: it waits for it CLIENT_WAIT_MS at start, then
        # fails with a message (zenoh's default is one attempt).
        conf.insert_json5(
            "connect/timeout_ms", json.dumps({"router": -1, "peer": -1, "client": CLIENT_WAIT_MS})
        )
        conf.insert_json5(
            "connect/exit_on_failure", json.dumps({"router": False, "peer": False, "client": True})
        )
        conf.insert_json5(
            "connect/retry",
            json.dumps(
                {
                    "period_init_ms": self.retry_ms,
                    "period_max_ms": self.retry_ms,
                    "period_increase_factor": 1,
                }
            ),
        )
        conf.insert_json5("transport/link/tx/lease", json.dumps(self.lease_ms))
        conf.insert_json5("transport/link/tx/keep_alive", json.dumps(KEEP_ALIVE))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(self.multicast_scouting))
        return conf


def open_session(settings: ZenohSettings) -> zenoh.Session:
    """A session; the first one a process opens also sizes zenoh's receive workers
    (``RX_WORKERS``), unless ``ZENOH_RUNTIME`` says otherwise. Zenoh's own error is a
    :class:`SessionError` of one line (spec section 3)."""
    os.environ.setdefault("ZENOH_RUNTIME", f"(rx: (worker_threads: {RX_WORKERS}))")
    try:
        return zenoh.open(settings.zenoh_config())
    except zenoh.ZError as exc:
        raise SessionError(session_error(str(exc), settings)) from None


_RUST_PLACE = re.compile(r" at /\S+?\.rs:\d+\.?")
_JSON5_MESSAGE = re.compile(r'Json5Err\(Message \{ msg: "(.*?)", location: .*?\}\)', re.S)


def session_error(text: str, settings: ZenohSettings) -> str:
    """Zenoh's error text as one line for a person: an address in use names its endpoint and
    says so; otherwise zenoh's own words, without the Rust source locations it appends."""
    if "Address already in use" in text or "AddrInUse" in text:
        taken = [e for e in settings.listen if e in text] or list(settings.listen)
        where = ", ".join(taken) or "a listen endpoint"
        return f"cannot listen on {where}: address in use (another peer or program listens there)"
    text = _RUST_PLACE.sub("", text)
    text = _JSON5_MESSAGE.sub(r"\1", text)
    line = " ".join(text.split()).strip(" .[]") or "unknown error"
    config = f" (config {settings.config})" if settings.config else ""
    return f"zenoh could not open a session{config}: {line[:300]}"


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
    max_asking: int = 32
    """Gets of this peer's own open at once at most (each ends with its timeout at the
    latest); a broadcast beyond is refused."""
    max_bytes: int = MAX_MESSAGE_BYTES
    identity: Identity | None = None
    """With a key pair, the replies this peer's ``lookup`` gives are hop-signed."""
    log: TransferLog | None = None
    screen: Callable[[Response], str | None] | None = None
    """The asker's check of a reply's signatures (its trust policy), run before the reply takes
    its sender's one place in a get, so that a forgery on a peer's key cannot keep that peer's
    genuine answer out. An agent sets it (its ``security`` gives the policy and store)."""
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
    tree: Callable[[], str] | None = None
    """The peer's control tree in compact stringBT, served on ``ktbt/v1/tree/<name>`` only with
    ``publish_events`` (section 10); above ``max_bytes`` it is refused with a reply error."""
    answer_at_once: bool = True
    """With an agent attached (:meth:`attach`), answer every query it can from what it knows
    now, inside the callback, as a fleet member does (section 4.5); False: hand queries to the
    agent, whose teach tree answers one asker per cool-down (section 4)."""
    refused: int = 0
    """Every message this transport refused (undecodable, on a wrong key, flooding...)."""
    network_errors: int = 0
    """Zenoh's own errors about this peer's gets (a timeout): never a refusal."""
    answered: int = 0
    """Queries this peer's ``lookup`` answered inside the callback."""
    joined: int = 0
    """Peers that appeared (their liveliness token) since this one started: a new neighbour,
    worth asking again at once."""
    announced: int = 0
    """Announcements of what this peer learned it put (:meth:`learned`, section 3)."""
    announcements: int = 0
    """Announcements of its neighbours it heard and took (:meth:`news`)."""
    _session: Any = field(init=False, default=None)

    def __post_init__(self) -> None:
        self._warn = Throttle(log.warning)
        self.stirred = threading.Event()
        """Set when something arrives for the agent (a message in the inbox, a peer appeared,
        an announcement) or a query's get ends: a host at rest wakes at once (section 4.5)."""
        self._inbox = Inbox(self._refuse, self.inbox_limit, self.overheard_limit, self.stirred.set)
        self._given = AnswersGiven(self.name, self.answer_window, self.max_pending, log.warning)
        self._templates: dict[tuple[str, SignedItem], tuple[bytes, bytes]] = {}
        self._knowledge_key = f"{PREFIX}/knowledge/{self.name}"
        self._publisher: Any = None
        self._sink: EventPublisher | None = None
        self._asking = 0
        self._gets: Counter[tuple[str, str]] = Counter()
        """The gets not ended yet, by query id and the peer sent to ("": all): an answer to
        one may still come (:meth:`awaiting`)."""
        self._lock = threading.Lock()
        self._appeared: deque[str] = deque()
        self._heard: dict[str, tuple[str, ...]] = {}
        """Announcements heard since :meth:`news` was last called: announcer -> sequences."""
        self._announcer: Any = None
        self._hearing: Any = None
        self._pending: dict[tuple[str, str], tuple[Any, float, int]] = {}
        """Queries handed to the agent: (sender, id) -> (query, deadline, answers still
        possible), so a query naming several sequences stays open for an answer to each."""
        self.closed = False
        self._session = open_session(self.settings)
        # Each entity's callbacks run in one Python thread of its own, for the entity's life
        # (zenoh's default): faster than taking the GIL from zenoh's own threads.
        try:
            self._declared: list[Any] = []
            if self.publish_events:  # first, so that the events' count starts with session-up
                self.log = self.log or TransferLog(None)
                events, publisher = EventPublisher.on_session(
                    self._session, self.name, identity=self.identity
                )
                self._declared.append(publisher)
                self.log.add_sink(events)
                self._sink = events
            if self.log is not None:  # the first mark of a transfer's timeline (section 8)
                self.log.record(Event.SESSION_UP, peer=self.name)
            self._declared += [
                self._session.declare_queryable(f"{PREFIX}/knowledge/{self.name}", self._on_query),
                self._session.declare_queryable(f"{PREFIX}/catalog/{self.name}", self._on_catalog),
                self._session.declare_subscriber(f"{PREFIX}/inbox/{self.name}", self._on_inbox),
                self._session.liveliness().declare_token(f"{PREFIX}/peers/{self.name}"),
                self._session.liveliness().declare_subscriber(
                    f"{PREFIX}/peers/*", self._on_presence
                ),
            ]
            if self.publish_answers:
                self._publisher = self._session.declare_publisher(f"{PREFIX}/answers/{self.name}")
                self._declared.append(self._publisher)
            if self.publish_events:
                self._declared.append(
                    self._session.declare_queryable(f"{PREFIX}/tree/{self.name}", self._on_tree)
                )
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

    def attach(self, agent: AgentCore) -> None:
        """What an agent built on this transport calls (``AgentCore``): from then on the
        transport checks replies against the agent's trust policy before they take their
        sender's place (section 3), serves the agent's catalog and, with ``answer_at_once``,
        answers queries from the agent's live knowledge, signed with its key pair, as ``ktbt
        peer run`` does (section 4.5); its control tree is served with ``publish_events``
        (section 10). What the transport was given already (a ``lookup``, a ``catalog``, an
        ``identity``, a ``log``, a ``tree``) is kept. So ``ktbt peer list`` shows what a robot
        built by hand knows."""
        security = agent.security
        self.screen = lambda r: refusal(r, agent.security.policy, agent.security.trust)
        if self.identity is None:
            self.identity = security.identity
        if self.log is None:
            self.log = security.log
        if self.catalog is None:
            self.catalog = lambda: catalog(agent.knowledge, security.identity)()
        if self.lookup is None and self.answer_at_once:
            self.lookup = live_answers(lambda: agent.knowledge, security.identity)
            self._answer_held(self.lookup)
        if self.tree is None:
            # The tree as of the last merge: a Tree is never changed in place, only replaced.
            self.tree = lambda: format_tree(agent.control.tree, "compact")

    def _answer_held(self, lookup: Lookup) -> None:
        """Answer, from what the agent that just attached knows, the queries that arrived
        before it did (its liveliness is up once the session is open, and a peer that sees it
        appear asks at once, section 4.5), as every later one is answered: a newcomer's first
        askers are not left to their next timed ask."""
        with self._lock:
            held, self._pending = self._pending, {}
        self._inbox.withdraw(set(held))  # answered here: the agent must not answer them again
        for query, _, _ in held.values():
            try:
                message = decode(query.payload.to_bytes(), self.max_bytes)
                if isinstance(message, Query):
                    self._answer_at_once(query, message, lookup)
            except Exception as exc:  # never a traceback out of attach (section 2.1)
                self._refuse(f"a query held until the agent attached: {internal_error(exc)}")
            finally:
                query.drop()

    # -- the Transport interface ----------------------------------------------------------------

    def broadcast(self, message: Message) -> None:
        """Ask every reachable peer; returns at once, and answers arrive in the inbox."""
        self._get(message, self.query_timeout)

    def _refuse(self, reason: str, **fields: Any) -> None:
        """Count, log at WARNING and record one refusal (spec section 2: every refusal is
        counted and logged with its reason)."""
        with self._lock:
            self.refused += 1
        self._warn(f"{self.name} refused: {reason}")
        if self.log is not None:
            self.log.record(
                Event.REFUSED, peer=self.name, reason=reason, where="transport", **fields
            )

    def send(self, to: str, message: Message) -> None:
        """Answer a query this peer received, or put the message in ``to``'s inbox."""
        if self.closed:
            return
        if isinstance(message, Query):  # the open query, to one more peer (section 4.1)
            self._get(message, self.query_timeout, to)
            return
        payload = encode(message)
        with self._lock:
            pending = self._pending.pop((to, message.id), None)
            if pending is not None and pending[2] > 1 and isinstance(message, Response):
                self._pending[(to, message.id)] = (pending[0], pending[1], pending[2] - 1)
                done = False
            else:
                done = True
        if pending is not None:
            query = pending[0]
            try:
                if isinstance(message, ErrorReply):
                    query.reply_err(payload)
                else:
                    query.reply(f"{PREFIX}/knowledge/{self.name}", payload)
            finally:
                if done:
                    query.drop()
        else:
            self._session.put(f"{PREFIX}/inbox/{to}", payload)
        if isinstance(message, Response):
            self._publish(payload)

    def _publish(self, payload: bytes) -> None:
        """The same encoded answer, once more, on this peer's answers key (section 4.3)."""
        if self._publisher is not None:
            self._publisher.put(payload)

    def receive(self) -> list[Received]:
        self._expire()
        return self._inbox.drain()

    @property
    def session(self) -> zenoh.Session:
        """The zenoh session this peer runs on (section 3's keys are declared on it), for an
        application that puts, gets or declares keys of its own on the same session; it is
        closed with the transport."""
        session: zenoh.Session = self._session
        return session

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        with self._lock:
            pending, self._pending = self._pending, {}
        for query, *_ in pending.values():
            query.drop()
        if self._sink is not None and self.log is not None:
            self.log.remove_sink(self._sink)
        for entity in (self._announcer, self._hearing):
            if entity is not None:
                entity.undeclare()
        for entity in self._declared:
            entity.undeclare()
        self._session.close()

    def __enter__(self) -> Self:
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
        """Broadcast ``query`` and wait until the get ends, in the caller's thread (for tools,
        tests and benchmarks; an agent uses :meth:`broadcast`). ``on_answer`` sees each answer
        the moment it arrives."""
        answers: list[Response] = []
        heard: set[str] = set()
        self._inbox.asked(query.id)
        try:  # the caller's own thread waits, reading the replies as they arrive
            replies = self._session.get(
                f"{PREFIX}/knowledge/*",
                payload=encode(query),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=self.query_timeout if timeout is None else timeout,
                allowed_destination=zenoh.Locality.REMOTE,  # not our own queryable
            )
            for reply in replies:
                answer = self._reply(reply, query, heard)
                if answer is not None:
                    answers.append(answer)
                    if on_answer is not None:
                        on_answer(answer)
        except Exception:  # a closing session; the query is simply lost
            log.debug("%s: query failed", self.name, exc_info=True)
        return answers

    def _get(self, message: Message, timeout: float, to: str | None = None) -> None:
        """One get, to every peer or to peer ``to`` alone, which holds no thread: each reply
        is handled as it arrives by a callback run in zenoh's own thread (replies are not
        consolidated), and the get's end by the callback's drop. A reply is an answer only if
        it is a response to this query, on its sender's own key, and the first from that key
        for its sequence; answers go to the inbox."""
        if self.closed:
            return
        sent = (message.id, to or "")
        with self._lock:
            full = self._asking >= self.max_asking
            if not full:
                self._asking += 1
                self._gets[sent] += 1
        if not full:
            self._inbox.asked(message.id)
        if full:
            self._refuse(f"query {message.id} not sent: {self.max_asking} queries already open")
            return
        heard: set[str] = set()
        ended = threading.Event()

        def on_reply(reply: Any) -> None:
            if self.closed:
                return
            try:
                answer = self._reply(reply, message, heard)
            except Exception as exc:  # never into zenoh's thread (section 2.1)
                self._refuse(f"a reply to {message.id}: {internal_error(exc)}")
                return
            if answer is not None:
                self._inbox.deliver(answer)

        def on_end() -> None:
            with self._lock:
                self._asking -= 1
                self._gets[sent] -= 1
                if not self._gets[sent]:
                    del self._gets[sent]
            ended.set()
            self.stirred.set()  # an announcement waiting for its answers may be taken now

        try:
            self._session.get(
                f"{PREFIX}/knowledge/{to or '*'}",
                zenoh.handlers.Callback(on_reply, on_end, indirect=False),
                payload=encode(message),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=timeout,
                allowed_destination=zenoh.Locality.REMOTE,  # not our own queryable
            )
        except Exception:  # a closing session: the query is simply lost
            log.debug("%s: query failed", self.name, exc_info=True)
            if not ended.is_set():
                on_end()

    def awaiting(self, id: str, to: str = "") -> bool:
        """Whether the get of query ``id`` sent to peer ``to`` ("": to all) has not ended, so an
        answer to it may still come (section 4.5). A peer finishes a query once it has answered
        what it knows (section 3), and a get ends when every peer it reached has finished it or
        its timeout passed: after that no answer to it is on its way."""
        with self._lock:
            return self._gets[(id, to)] > 0

    def _reply(self, reply: Any, asked: Message, heard: set[str]) -> Response | None:
        """The answer a reply carries, or None: refused and counted, a peer's error, or the
        network's (section 3)."""
        if reply.ok is None:
            self._reply_error(reply.err.payload.to_bytes(), asked)
            return None
        key = str(reply.ok.key_expr)
        answer = self._decoded(reply.ok.payload.to_bytes(), Response, f"a reply to {asked.id}", key)
        if answer is None:
            return None
        if key != f"{PREFIX}/knowledge/{answer.sender}":
            self._refuse(f"a reply naming {answer.sender} came on {key[:80]}", key=key)
            return None
        asked_for = asked.sequences if isinstance(asked, Query) else ()
        if answer.id != asked.id or answer.sequence not in asked_for:
            self._refuse(f"a reply from {answer.sender} answers another question", key=key)
            return None
        why = self.screen(answer) if self.screen is not None else None
        if why is not None:
            self._refuse(f"from {answer.sender}: {why}", key=key)
            return None
        place = f"{key}\0{answer.sequence}"  # one place per sender and sequence asked
        with self._lock:
            again = place in heard
            heard.add(place)
        if again:
            self._refuse(f"another reply from {answer.sender} to the same query", key=key)
            return None
        return answer

    def _reply_error(self, payload: bytes, asked: Message) -> None:
        """A reply error. A peer's is an error message (a JSON object, section 1), logged at
        WARNING (a peer refused this one's query: the user should see why); what
        zenoh itself sends (``Timeout``, as text) is the network's: counted apart, handed to the
        agent as a :class:`NetworkError`, never decoded as a peer's message nor refused."""
        if not payload.lstrip().startswith(b"{"):
            reason = payload[:80].decode("utf-8", "replace").strip() or "no reason given"
            reason = "".join(c if c.isprintable() else "?" for c in reason)
            with self._lock:
                self.network_errors += 1
            log.debug("%s: query %s: network error: %s", self.name, asked.id, reason)
            self._inbox.deliver(NetworkError(asked.id, reason))
            return
        error = self._decoded(payload, ErrorReply, f"an error reply to {asked.id}")
        if error is None:
            return
        log.warning(
            "%s: %s refused query %s: %s", self.name, error.sender, asked.id, error.message[:200]
        )
        if self.log is not None:
            self.log.record(
                Event.ERROR_RECEIVED, peer=self.name, sender=error.sender, reason=error.message
            )

    def _decoded(self, payload: bytes, kind: type[_M], what: str, key: str = "") -> _M | None:
        """``payload`` as a message of the ``kind`` expected where it came (``what``); anything
        else is refused and counted, with the key it came on."""
        fields = {"key": key[:80]} if key else {}
        try:
            message = decode(payload, self.max_bytes)
        except MessageRefused as exc:
            self._refuse(f"{what}: {exc.reason}", **fields)
            return None
        if not isinstance(message, kind):
            self._refuse(f"{what}: a {message.type} from {message.sender}", **fields)
            return None
        return message

    @guarded("a peer's liveliness")
    def _on_presence(self, sample: Any) -> None:
        """A peer's liveliness token appeared (or went): a new neighbour is counted, logged
        (``peer-seen``, section 8) and kept for :meth:`appeared`, so that a learner asks it at
        once (section 4.5)."""
        name = str(sample.key_expr).rsplit("/", 1)[-1]
        if sample.kind == zenoh.SampleKind.PUT and name != self.name:
            with self._lock:
                self.joined += 1
                if len(self._appeared) < self.max_pending:
                    self._appeared.append(name)
            self.stirred.set()
            if self.log is not None:
                self.log.record(Event.PEER_SEEN, peer=self.name, sender=name)

    def appeared(self) -> list[str]:
        """The peers whose liveliness appeared since the last call (section 4.5), at most
        ``max_pending`` of them; the oldest first."""
        with self._lock:
            names = list(self._appeared)
            self._appeared.clear()
        return names

    # -- relaying (section 3) ---------------------------------------------------------------------

    def learned(self, keys: list[str]) -> None:
        """Announce on ``ktbt/v1/learned/<name>`` the sequences this peer just learned (a fleet
        member after a merge, section 4.5): one put, heard by its neighbours only (peers do
        not forward between peers), 64 sequences to an announcement. The publisher is declared
        at the first announcement, so a peer that never learns costs nothing. Each put is an
        ``announced`` event of its log (section 8)."""
        if self.closed or not keys:
            return
        if self._announcer is None:
            self._announcer = self._session.declare_publisher(f"{PREFIX}/learned/{self.name}")
        for first in range(0, len(keys), 1 + MAX_MORE):
            told = keys[first : first + 1 + MAX_MORE]
            self._announcer.put(encode_learned(told))
            self.announced += 1
            if self.log is not None:  # a message like a query (the fleet study counts it)
                more = {"more": told[1:]} if len(told) > 1 else {}
                self.log.record(Event.ANNOUNCED, peer=self.name, sequence=told[0], **more)

    def news(self, now: float = 0.0) -> list[tuple[str, tuple[str, ...]]]:
        """The announcements heard since the last call (section 4.5): (announcer, sequences),
        one entry per announcer, oldest first (``now`` is not needed: they arrive as
        events). The subscription to ``ktbt/v1/learned/*`` is declared at the first call, so
        only a peer that reads announcements hears them."""
        if self.closed:
            return []
        if self._hearing is None:
            self._hearing = self._session.declare_subscriber(
                f"{PREFIX}/learned/*",
                self._on_learned,
                allowed_origin=zenoh.Locality.REMOTE,  # not our own announcements
            )
        with self._lock:
            heard, self._heard = list(self._heard.items()), {}
        return heard

    @guarded("an announcement")
    def _on_learned(self, sample: Any) -> None:
        """An announcement (section 3): believed only as its key's peer's, a JSON array of 1
        to 64 sequences within the message limit; anything else is refused. Announcements of
        one peer between two calls of :meth:`news` are taken as one (the latest 64
        sequences); those of a newcomer beyond ``max_pending`` announcers are refused."""
        key = str(sample.key_expr)
        name = key.rsplit("/", 1)[-1]
        if re.fullmatch(NAME_PATTERN, name) is None or name == self.name:
            self._refuse(f"an announcement came on {key[:80]}", key=key[:80])
            return
        try:
            sequences = decode_learned(sample.payload.to_bytes(), self.max_bytes)
        except MessageRefused as exc:
            self._refuse(f"an announcement from {name}: {exc.reason}", key=key)
            return
        with self._lock:
            known = self._heard.get(name)
            full = known is None and len(self._heard) >= self.max_pending
            if not full:
                merged = dict.fromkeys((*(known or ()), *sequences))
                self._heard[name] = tuple(merged)[-(1 + MAX_MORE) :]
                self.announcements += 1
        self.stirred.set()
        if full:
            self._refuse(f"an announcement from {name}: {self.max_pending} announcers waiting")

    # -- being asked ------------------------------------------------------------------------------

    @guarded("a query")
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
                    deadline = time.monotonic() + self.answer_window
                    self._pending[key] = (query, deadline, len(message.sequences))
        if full or taken:
            query.drop()
            if taken:  # a replay: the query already open keeps its place
                self._refuse(f"query {message.id} from {message.sender} is already open")
            return
        self._inbox.deliver(message)

    def _answer_at_once(self, query: Any, message: Query, lookup: Lookup) -> None:
        """A knowledge server's answers, given inside the callback: one reply for each
        sequence of the query it knows, not given already (section 4.5, :class:`AnswersGiven`).
        Without a key pair, each answer's bytes are made once per item and given the query's id
        (:func:`encoded_answer`): a teacher's work per query is then its lookup."""
        identity = self.identity

        def make(sequence: str, item: SignedItem) -> bytes:
            if identity is None:
                return self._encoded(message.id, sequence, item)
            return encode(answer_to(message, self.name, item, identity, sequence))

        for payload in self._given.made(message, lookup, self.log, make):
            query.reply(self._knowledge_key, payload)
            self.answered += 1
            self._publish(payload)

    def _encoded(self, id: str, sequence: str, item: SignedItem) -> bytes:
        """The unsigned answer with ``item`` for ``sequence`` to the query ``id``, its bytes
        made once and kept for the next queries (at most ``max_pending`` items; the queryable's
        one callback thread is the only one to use them)."""
        made = self._templates.get((sequence, item))
        if made is None:
            made = encoded_answer(self.name, sequence, item)
            if len(self._templates) >= self.max_pending:
                self._templates.clear()
            self._templates[(sequence, item)] = made
        return made[0] + id.encode() + made[1]

    def _on_catalog(self, query: Any) -> None:
        known = self.catalog() if self.catalog is not None else []
        reply_catalog(query, self.name, json.dumps(known).encode())

    def _on_tree(self, query: Any) -> None:
        reply_tree(query, self.name, self.tree() if self.tree is not None else None, self.max_bytes)

    @guarded("a message in the inbox")
    def _on_inbox(self, sample: Any) -> None:
        """A late answer. Only a response is taken: a query arrives only through the
        queryable, where zenoh knows it came from a get."""
        message = self._decoded(sample.payload.to_bytes(), Response, "a message in the inbox")
        if message is not None:
            self._inbox.deliver(message)

    @guarded("an overheard answer")
    def _on_answer(self, sample: Any) -> None:
        """An answer another peer published (section 4.3), checked as a reply is: within the
        message limits, a response, believed only as coming from the key it arrived on, and
        passing the trust policy; then queued for the agent, a newcomer to a full queue refused.
        A copy of an answer to this peer's own query is left to the reply."""
        key = str(sample.key_expr)
        answer = self._decoded(sample.payload.to_bytes(), Response, "an overheard answer", key)
        if answer is None:
            return
        if key != f"{PREFIX}/answers/{answer.sender}" or answer.sender == self.name:
            self._refuse(f"an answer naming {answer.sender} came on {key[:80]}", key=key[:80])
            return
        self._inbox.overhear(answer, self.screen, key=key)

    def _expire(self) -> None:
        now = time.monotonic()
        with self._lock:
            expired = [k for k, (_, deadline, _) in self._pending.items() if deadline < now]
            queries = [self._pending.pop(k)[0] for k in expired]
        for query in queries:
            query.drop()


def reply_catalog(query: Any, name: str, payload: bytes) -> None:
    """Answer a query on ``ktbt/v1/catalog/<name>`` (section 3) with ``payload``, the catalog
    as JSON, and end it."""
    query.reply(f"{PREFIX}/catalog/{name}", payload)
    query.drop()


def reply_tree(query: Any, name: str, text: str | None, max_bytes: int) -> None:
    """Answer a query on ``ktbt/v1/tree/<name>`` (section 10) with the control tree ``text``,
    whole or not at all: one above ``max_bytes`` is refused with a reply error saying its
    size, never clipped into text that does not parse; ``None``: there is none."""
    if text is None:
        query.reply_err(b"no control tree")
    else:
        payload = text.encode()
        if len(payload) > max_bytes:
            why = f"the control tree is {len(payload)} bytes, the limit is {max_bytes}"
            query.reply_err(why.encode())
        else:
            query.reply(f"{PREFIX}/tree/{name}", payload)
    query.drop()


def catalog_replies(
    session: zenoh.Session, timeout: float, refused: Callable[[str], None] | None = None
) -> Iterator[tuple[str, list[dict[str, str]]]]:
    """Each peer's catalog, as its name and its entries ``{"sequence": ..., "author": ...,
    ...}`` (a sequence whole, other values clipped to 200 characters); a reply too large or not
    a JSON array is skipped, and ``refused`` told why."""
    for reply in session.get(f"{PREFIX}/catalog/*", timeout=timeout):
        if reply.ok is None:
            continue
        name = str(reply.ok.key_expr).rsplit("/", 1)[-1]
        payload = reply.ok.payload.to_bytes()
        why = None
        if len(payload) > MAX_MESSAGE_BYTES:
            why = f"catalog of {name[:64]!r}: {len(payload)} bytes"
        else:
            try:
                value = json.loads(payload)
            except (ValueError, RecursionError):  # a peer's garbage is its own problem
                value = None
            if not isinstance(value, list):
                why = f"catalog of {name[:64]!r}: not a JSON array"
        if why is not None:
            if refused is not None:
                refused(why)
            continue
        entries = []
        for v in value:
            if isinstance(v, dict) and isinstance(v.get("sequence"), str):
                entry = {str(k): str(x)[:200] for k, x in v.items()}
                entries.append({**entry, "sequence": v["sequence"]})
            elif not isinstance(v, dict | list):
                entries.append({"sequence": str(v)})
        yield name, entries


def _catalog_replies(owner: ZenohTransport, timeout: float) -> dict[str, list[dict[str, str]]]:
    out = dict(catalog_replies(owner.session, timeout))
    out.pop(owner.name, None)
    return out


def catalogs(owner: ZenohTransport, timeout: float = 1.0) -> dict[str, list[dict[str, str]]]:
    """What each peer knows, with the provenance it reports (author, teacher, time)."""
    return _catalog_replies(owner, timeout)


class ZenohCatalogs:
    """The fleet's catalogs for a fleet member told no sequences (section 4.5,
    :class:`~ktbt_proto.exchange.member.Catalogs`): one get of every catalog queryable when a
    peer appeared, and every :data:`~ktbt_proto.exchange.member.CATALOG_PERIOD` seconds."""

    def __init__(self, owner: ZenohTransport, timeout: float = 0.5) -> None:
        self.owner, self.timeout = owner, timeout
        self._read_at = -math.inf

    def changed(self, now: float, appeared: bool) -> dict[str, list[dict[str, str]]] | None:
        if not appeared and now - self._read_at < CATALOG_PERIOD:
            return None
        self._read_at = now
        return catalogs(self.owner, self.timeout)


def peers(session_owner: ZenohTransport, timeout: float = 1.0) -> dict[str, list[str]]:
    """Who is present (liveliness) and what each knows (its catalog)."""
    session = session_owner.session
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
