"""The ROS 2 transport: the agent's :class:`Transport` over rclpy topics (spec/protocol.md
section 11, "ROS 2 binding").

Three fleet-wide topics carry the protocol's messages as ``ktbt_interfaces`` types:

- the query topic (``/ktbt/queries``): every robot publishes its queries there and reads
  everyone's;
- the answer topic (``/ktbt/answers``): every answer, addressed to its asker by ``to``; a robot
  reads all of them, takes those addressed to it, and overhears the others (section 4.3) when
  it is asked to, so overhearing needs no topic of its own;
- the error topic (``/ktbt/errors``): the error reply to a malformed query, from one robot of
  the fleet (:meth:`Ros2Transport.first_named`).

Each robot also announces its name on the graph, a publisher never published on, on
``<query topic>/robots/<name>`` (:func:`robot_topic`): a robot starting refuses a name another
has (:meth:`Ros2Transport.claim`), and the robots agree on who replies to a malformed query.

The names are absolute, so robots in namespaces of their own (``/robot1/ktbt``) share them, and
configurable, so two fleets on one ROS domain can be kept apart. The QoS of all three
(:func:`exchange_qos`) is RELIABLE, VOLATILE, KEEP_LAST 64: a query or an answer matters only
while its asker waits, so a robot that joins later must not be handed old ones (VOLATILE), and
each is small and rare, so the network may retransmit it (RELIABLE); 64 bounds what a slow
reader's queue holds. Each publisher and subscription accepts ROS's standard QoS overrides by
parameter (``qos_overrides./ktbt/queries.publisher.reliability: best_effort``).

Messages are read raw (serialized CDR), so that whatever arrives is checked in this order: size
first (more than the message limit plus :data:`CDR_SLACK` is refused before it is read), then
its fields, read by :mod:`cdr`, then section 1's schema through the one decoder
(:func:`ktbt_proto.exchange.messages.decode_fields`), applied to the JSON object the fields
make. What this robot publishes is serialized by :mod:`cdr` too, without a Python message
object. A message refused is counted (``refused``), logged at WARNING through the node's logger
with its reason, and recorded in the transfer log, never raised. Inboxes and the table of
queries seen are bounded as on zenoh (section 2), the newcomer refused when full. ROS has no
error of its own about a query (no get that times out), so ``network_errors`` stays 0.

An inactive transport (``active`` false: a lifecycle node not active) neither asks nor
answers: it publishes nothing, and everything it reads is dropped unread.
"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

from ktbt_interfaces.msg import Answer as AnswerMsg
from ktbt_interfaces.msg import ErrorReply as ErrorMsg
from ktbt_interfaces.msg import Query as QueryMsg
from rclpy.event_handler import (
    PublisherEventCallbacks,
    QoSRequestedIncompatibleQoSInfo,
    SubscriptionEventCallbacks,
)
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_policy_name_from_kind,
)
from rclpy.qos_overriding_options import QoSOverridingOptions

from ktbt_proto.exchange.answers import live_answers
from ktbt_proto.exchange.core import AgentCore
from ktbt_proto.exchange.messages import (
    MAX_MESSAGE_BYTES,
    ErrorReply,
    MessageRefused,
    Query,
    Response,
    decode_fields,
)
from ktbt_proto.exchange.refusals import Throttle, guarded, internal_error
from ktbt_proto.exchange.signing import Identity
from ktbt_proto.exchange.transferlog import Event, TransferLog
from ktbt_proto.exchange.transport import Message, Received
from ktbt_proto.exchange.trust import refusal
from ktbt_proto.transport import cdr
from ktbt_proto.transport.inbox import AnswersGiven, Inbox, Lookup

QUERIES = "/ktbt/queries"
ANSWERS = "/ktbt/answers"
ERRORS = "/ktbt/errors"
CDR_SLACK = 1024
"""Bytes a serialized message may take beyond the JSON limit: CDR's header, string lengths and
padding (a few dozen bytes for our messages)."""
NAME = r"[A-Za-z0-9_.-]{1,64}"
"""A robot's name (section 1)."""

LOOK_FOR = 1.0
"""Seconds :meth:`Ros2Transport.appeared` looks in the graph for a newcomer after a new match
(the graph and the match are both DDS discovery, not always seen at the same instant)."""

SETTLE = 2.0
"""Seconds the ROS graph must stay unchanged, once it shows another node, before a robot
starting takes its name as free (:meth:`Ros2Transport.claim`): discovery is under way when a
node starts."""
SETTLE_MOST = 4.0
"""Seconds a robot starting waits at most for the graph: a robot alone waits this long (DDS
discovery may take up to a participant's announcement period, 3 s with Fast DDS's defaults,
measured here up to 2.6 s on a loaded machine)."""

Clock = Callable[[], float]
"""A host's clock: seconds, read at every use."""

_M = TypeVar("_M", Query, Response, ErrorReply)


def robot_name(node: Node, given: str | None = None, what: str = "name") -> str:
    """A robot's name in messages, one rule for every host (section 11): the name ``given``;
    else the last segment of its node's namespace (``/robot1/bt`` is ``robot1``: robots are
    told apart by namespace, their nodes often share a name); else the node's name. Raises
    ``ValueError`` for a name that is not one (section 1), naming the setting (``what``)."""
    name = given or node.get_namespace().strip("/").rsplit("/", 1)[-1] or node.get_name()
    if re.fullmatch(NAME, name) is None:
        raise ValueError(f"{what} {name!r}: use 1 to 64 letters, digits, '_', '.', '-'")
    return name


def robot_topic(queries: str, name: str) -> str:
    """The topic on which a robot announces its name to its fleet (section 11):
    ``<queries topic>/robots/<name>``, every character of the name but a letter (or, after the
    first, a digit) written ``_`` and its two hex digits (``r-1`` is ``r_2d1``), so that every
    name of section 1 is a ROS name, and two names two topics."""
    token = "".join(
        c if c.isascii() and (c.isalpha() or (i and c.isdigit())) else f"_{ord(c):02x}"
        for i, c in enumerate(name)
    )
    return f"{queries}/robots/{token}"


def announced_name(token: str) -> str:
    """The robot name a :func:`robot_topic`'s last token announces."""
    return re.sub(r"_([0-9a-f]{2})", lambda m: chr(int(m.group(1), 16)), token)


def announced(node: Node, queries: str) -> set[str]:
    """The names the robots of the fleet on ``queries`` announce (:func:`robot_topic`), read
    from the ROS graph."""
    prefix = f"{queries}/robots/"
    return {
        announced_name(topic[len(prefix) :])
        for topic, _ in node.get_topic_names_and_types()
        if topic.startswith(prefix)
    }


def node_clock(node: Node) -> Clock:
    """The seconds of ``node``'s clock (section 11): ROS time, which is the simulation's
    (``/clock``) when the node's ``use_sim_time`` is true, so that every period and timeout of
    a ROS robot follows its host. Under ``use_sim_time`` with no ``/clock`` published yet, ROS
    time stands at 0: the node's timers do not fire, so it neither ticks nor asks, and what
    waits on time (an open query, the answer window) waits until the clock moves."""
    clock = node.get_clock()
    return lambda: clock.now().nanoseconds / 1e9


def open_to_strangers(node: Node, name: str, policy: str) -> str | None:
    """The one WARNING a robot on the ``any`` policy logs when it starts listening (section 7):
    every participant of its ROS domain can teach it; None under ``signed`` or ``trusted``."""
    if policy != "any":
        return None
    domain = node.context.get_domain_id()
    return (
        f"{name}: policy any: every participant of ROS domain {domain} can teach this robot; "
        "give the fleet keys (ktbt peer keys) and the policy trusted"
    )


@dataclass(frozen=True)
class Topics:
    """The fleet's three topics; absolute names, shared by every robot of the fleet."""

    queries: str = QUERIES
    answers: str = ANSWERS
    errors: str = ERRORS

    def __post_init__(self) -> None:
        for field_name in ("queries", "answers", "errors"):
            value = getattr(self, field_name)
            if not value.startswith("/"):
                raise ValueError(
                    f"topic {field_name} {value!r}: use an absolute name (/ktbt/{field_name}), "
                    "shared by the fleet whatever each robot's namespace"
                )


def exchange_qos() -> QoSProfile:
    """The QoS of the query, answer and error topics (see the module's docstring)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=64,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


def quiet() -> PublisherEventCallbacks:
    """A publisher's QoS events: none handled. rclpy's defaults give every publisher and
    subscription two event handlers (incompatible QoS, incompatible type), each one more
    entity its Python executors add to their wait set at every wake: an idle node's CPU went
    mostly to that (``benchmarks/bench_ros2``). A mismatch is reported at the subscription
    (:func:`watched`)."""
    return PublisherEventCallbacks(use_default_callbacks=False)


def watched(node: Node, topic: str) -> SubscriptionEventCallbacks:
    """A subscription's QoS events: one handled, a publisher of ``topic`` that offers QoS this
    subscription cannot take (none of its messages will arrive), logged at WARNING with the
    policy at fault (section 11)."""

    def incompatible(event: QoSRequestedIncompatibleQoSInfo) -> None:
        policy = qos_policy_name_from_kind(event.last_policy_kind)
        node.get_logger().warning(
            f"{topic}: a publisher offers QoS incompatible with this subscription ({policy}); "
            "none of its messages will arrive"
        )

    return SubscriptionEventCallbacks(incompatible_qos=incompatible, use_default_callbacks=False)


_OPTIONAL = ("author", "signature", "key", "hop")


def wire_fields(fields: Mapping[str, Any], kind: str) -> dict[str, Any]:
    """The JSON object (section 1) a received ROS message of ``kind`` (query, response, error)
    is, from its ``fields`` (:func:`cdr.read`): by name, ``to`` (this binding's addressing) and
    an empty optional field left out."""
    wire: dict[str, Any] = {
        "v": fields["v"], "type": kind, "id": fields["id"], "sender": fields["sender"]
    }  # fmt: skip
    if kind == "query":
        wire["sequence"] = fields["sequence"]
        if fields["more"]:  # an empty list: a single-sequence query (section 1)
            wire["more"] = list(fields["more"])
    elif kind == "response":
        wire["sequence"] = fields["sequence"]
        wire["subtree"] = fields["subtree"]
        for name in _OPTIONAL:
            if fields[name]:
                wire[name] = fields[name]
    else:
        wire["code"] = fields["code"]
        wire["message"] = fields["message"]
    return wire


def ros_fields(message: Message, to: str = "") -> dict[str, Any]:
    """The fields of the ROS message for a protocol message, by name (an absent optional field
    the empty string); ``to``: the asker an answer or error is for."""
    fields: dict[str, Any] = {"v": message.v, "id": message.id, "sender": message.sender}
    if isinstance(message, Query):
        fields.update(sequence=message.sequence, more=list(message.more or ()))
    elif isinstance(message, Response):
        fields.update(to=to, sequence=message.sequence, subtree=message.subtree)
        fields.update({name: getattr(message, name) or "" for name in _OPTIONAL})
    else:
        fields.update(to=to, code=message.code, message=message.message)
    return fields


def to_msg(message: Message, to: str = "") -> Any:
    """The ROS message object for a protocol message (what a tool or a test publishes; the
    transport publishes :func:`serialized` bytes)."""
    kind = {Query: QueryMsg, Response: AnswerMsg, ErrorReply: ErrorMsg}[type(message)]
    return kind(**ros_fields(message, to))


def serialized(message: Message, to: str = "") -> bytes:
    """The ROS message for a protocol message, serialized (:mod:`cdr`), as published."""
    return cdr.write(ros_fields(message, to), _KINDS[type(message)][1])


_KINDS: dict[type, tuple[str, tuple[str, ...], str]] = {
    Query: ("query", cdr.QUERY, "Query"),
    Response: ("response", cdr.ANSWER, "Answer"),
    ErrorReply: ("error", cdr.ERROR, "ErrorReply"),
}
"""Each protocol message's ``type`` (section 1), ROS layout and ROS type name."""


class Ros2Transport:
    """A robot on a ROS 2 graph, implementing the agent's :class:`Transport` through ``node``.

    With ``lookup``, a query is answered inside the subscription's callback from what the
    robot knows now (as a zenoh fleet member is, section 4.5); without, it is handed to the
    agent, whose teach tree answers through :meth:`send`. ``query_timeout``: how long one of
    this robot's queries stays open (its answers counted once per sender), in seconds of
    ``clock`` (default: the node's, :func:`node_clock`), as are the answer window and the look
    for newcomers; a clock that goes back (a simulation reset) ends what was open.
    """

    def __init__(
        self,
        node: Node,
        name: str,
        topics: Topics | None = None,
        *,
        lookup: Lookup | None = None,
        query_timeout: float = 2.0,
        answer_window: float = 1.0,
        max_pending: int = 256,
        inbox_limit: int = 1024,
        max_asking: int = 32,
        max_bytes: int = MAX_MESSAGE_BYTES,
        identity: Identity | None = None,
        log: TransferLog | None = None,
        overhear: bool = False,
        overheard_limit: int = 64,
        active: bool = True,
        answer_at_once: bool = True,
        relay: Callable[[str, Response], None] | None = None,
        clock: Clock | None = None,
        arrived: Callable[[], object] | None = None,
    ) -> None:
        self.node, self.name = node, name
        self.arrived = arrived
        """Called (in the network's callback) when an answer to one of this robot's queries
        is delivered to the agent: a host that steps its member at once then (section 11)."""
        self.clock = clock or node_clock(node)
        """The host's seconds (:func:`node_clock`): every period and timeout here is on it."""
        self.topics = topics or Topics()
        self.lookup = lookup
        self.query_timeout, self.answer_window = query_timeout, answer_window
        self.max_pending, self.inbox_limit, self.max_asking = max_pending, inbox_limit, max_asking
        self.max_bytes = max_bytes
        self.identity = identity
        """With a key pair, the answers ``lookup`` gives are hop-signed (section 7)."""
        self.log = log
        self.overhear, self.overheard_limit = overhear, overheard_limit
        self.relay = relay
        """Given, every answer addressed to another robot, once decoded, goes to it with its ``to``,
        instead of the overheard inbox: a relay (the bridge, section 11) routes each answer to
        its asker, which the protocol message itself does not name."""
        self.active = active
        """False: neither ask nor answer (a lifecycle node that is not active)."""
        self.answer_at_once = answer_at_once
        """With an agent attached and no ``lookup``, answer from its knowledge at once."""
        self.screen: Callable[[Response], str | None] | None = None
        """The asker's trust policy, run before an answer takes its sender's one place in a
        query (:meth:`attach` sets it)."""
        self.refused = 0
        """Every message this transport refused (undecodable, oversized, a replay, ...)."""
        self.network_errors = 0
        """Always 0: ROS reports no error about a query (kept for the agent's summary)."""
        self.answered = 0
        """Queries ``lookup`` answered inside the callback."""
        self.joined = 0
        """Subscriptions to the query topic that matched this robot's query publisher since it
        started, as :meth:`receive` found them: robots that can now hear its queries, this
        robot's own among them."""
        self._matched = 0
        self._present: set[str] = set()
        self._look_from: float | None = None
        """Since when :meth:`appeared` reads the graph (a new match not seen there yet), for
        :data:`LOOK_FOR` seconds."""
        self._announced: set[str] = set()
        """Query ids published again since the last :meth:`receive` (:meth:`send`). This,
        ``_present`` and ``_look_from`` belong to the agent's tick, the one caller of
        :meth:`receive`, :meth:`appeared` and :meth:`send`; the network's callbacks never
        touch them."""
        self.closed = False
        self._lock = threading.Lock()
        self._warn = Throttle(node.get_logger().warning)
        self._inbox = Inbox(self._refuse, inbox_limit, overheard_limit)
        self._given = AnswersGiven(
            name, answer_window, max_pending, node.get_logger().warning, self.clock
        )
        self._open: dict[str, tuple[tuple[str, ...], float, set[tuple[str, str]]]] = {}
        """This robot's open queries: id -> (sequences, opened at, (sender, sequence) heard)."""
        self._seen: dict[tuple[str, str], float] = {}
        """Queries from others still in their answer window: (sender, id) -> seen at."""

        # A profile and options of its own for each entity: rclpy writes the overridden
        # values into the profile it is given.
        def qos() -> dict[str, Any]:
            return {
                "qos_profile": exchange_qos(),
                "qos_overriding_options": QoSOverridingOptions.with_default_policies(),
            }

        topics = self.topics
        self._queries = node.create_publisher(
            QueryMsg, topics.queries, event_callbacks=quiet(), **qos()
        )
        self._answers = node.create_publisher(
            AnswerMsg, topics.answers, event_callbacks=quiet(), **qos()
        )
        self._errors = node.create_publisher(
            ErrorMsg, topics.errors, event_callbacks=quiet(), **qos()
        )
        self._name_topic = robot_topic(topics.queries, name)
        self._announce = node.create_publisher(
            QueryMsg, self._name_topic, exchange_qos(), event_callbacks=quiet()
        )  # never published on: its topic is the announcement
        self._namesakes: set[str] = set()
        """Other nodes found announcing this robot's name (each warned of once)."""
        self._subscriptions = [
            node.create_subscription(
                kind, topic, callback, raw=True, event_callbacks=watched(node, topic), **qos()
            )
            for kind, topic, callback in (
                (QueryMsg, topics.queries, self._on_query),
                (AnswerMsg, topics.answers, self._on_answer),
                (ErrorMsg, topics.errors, self._on_error),
            )
        ]

    # -- the Transport interface ----------------------------------------------------------------

    def broadcast(self, message: Message) -> None:
        """Publish a query on the fleet's query topic; answers arrive in the inbox."""
        if self.closed or not self.active or not isinstance(message, Query):
            return
        now = self.clock()
        with self._lock:
            self._expire(now)
            again = self._open.get(message.id)  # the same query, repeated while it waits
            full = again is None and len(self._open) >= self.max_asking
            if not full:  # asked again (for part of it, say): what it first asked stays open
                sequences, heard = (
                    (again[0], again[2]) if again is not None else (message.sequences, set())
                )
                self._open[message.id] = (sequences, now, heard)
        if not full and again is None:
            self._inbox.asked(message.id)
        if full:
            self._refuse(f"query {message.id} not sent: {self.max_asking} queries already open")
            return
        self._queries.publish(serialized(message))

    def send(self, to: str, message: Message) -> None:
        """Answer ``to``'s query (or tell it of an error) on the answer (error) topic, where
        every robot that overhears also reads it. A query announced to a robot that appeared
        (section 4.5) is published on the query topic again, for every robot: ROS has no
        unicast; once a tick, however many robots it is announced to (those that answered it
        already do not answer again within the answer window)."""
        if self.closed or not self.active:
            return
        if isinstance(message, Query):
            if message.id not in self._announced:  # open (again) for a whole query timeout
                self._announced.add(message.id)
                self.broadcast(message)
        elif isinstance(message, Response):
            self._answers.publish(serialized(message, to))
        elif isinstance(message, ErrorReply):
            self._errors.publish(serialized(message, to))

    def receive(self) -> list[Received]:
        if self.closed:
            return []
        # A new match of the query publisher: a robot that can hear this one's queries now.
        # Read at every call (one call into DDS): rclpy's events executor never runs a
        # publisher's matched-event handler.
        matched, now = self._queries.get_subscription_count(), self.clock()
        with self._lock:
            if matched > self._matched:
                self.joined += matched - self._matched
            if matched != self._matched:  # one came, or one went (and may come back)
                self._look_from = now
            self._matched = matched
            self._expire(now)
        self._announced.clear()
        return self._inbox.drain()

    def appeared(self) -> list[str]:
        """The robots present now that were not at the last call, by full name (section 4.5):
        read from the graph when :meth:`receive` found a new match of the query publisher, and
        again at every call for up to :data:`LOOK_FOR` seconds while the graph does not show
        the newcomer yet."""
        since = self._look_from
        if self.closed or since is None or not 0 <= self.clock() - since <= LOOK_FOR:
            return []
        present = self.peers()
        new = sorted(present - self._present)
        self._present = present
        for other in set(self.namesakes()) - self._namesakes:
            if "_NODE_NAME_UNKNOWN_" not in other:
                self._namesakes.add(other)
                self._warn(
                    f"{self.name}: {other} announces this robot's name too (this node: "
                    f"{self.node.get_fully_qualified_name()}): answers to one reach both"
                )
        if len(present) + 1 >= self._matched:  # every match named (its own among them)
            self._look_from = None
        return new

    def close(self) -> None:
        """Destroy the publishers and subscriptions (the node stays)."""
        if self.closed:
            return
        self.closed = True
        for sub in self._subscriptions:
            self.node.destroy_subscription(sub)
        for pub in (self._queries, self._answers, self._errors, self._announce):
            self.node.destroy_publisher(pub)

    def attach(self, agent: AgentCore) -> None:
        """What an agent built on this transport calls (``AgentCore``): from then on answers
        are checked against the agent's trust policy before they take their sender's place,
        and, with ``answer_at_once``, queries are answered from the agent's live knowledge,
        signed with its key pair, as ``ktbt peer run`` does (section 4.5). What the transport
        was given already (a ``lookup``, an ``identity``, a ``log``) is kept."""
        security = agent.security
        self.screen = lambda r: refusal(r, security.policy, security.trust)
        if self.identity is None:
            self.identity = security.identity
        if self.log is None:
            self.log = security.log
        if self.lookup is None and self.answer_at_once:
            self.lookup = live_answers(lambda: agent.knowledge, self.identity)

    # -- presence -------------------------------------------------------------------------------

    def namesakes(self) -> list[str]:
        """The other nodes that announce this robot's name (:func:`robot_topic`), by full name
        (``_NODE_NAME_UNKNOWN_`` while discovery has not named one yet)."""
        me = self.node.get_fully_qualified_name()
        found = {
            f"{info.node_namespace.rstrip('/')}/{info.node_name}"
            for info in self.node.get_publishers_info_by_topic(self._name_topic)
        }
        return sorted(found - {me})

    def claim(self, what: str = "name") -> None:
        """Refuse to start under a name another node of the fleet announces (section 11):
        ``ValueError``, one line naming both nodes and the setting (``what``). The graph is
        read until it shows another node and has then stayed unchanged :data:`SETTLE`
        seconds, at most :data:`SETTLE_MOST` (wall-clock seconds, as discovery runs in real
        time): a node that has just started is still discovering the others. Two robots that
        start together under one name may both miss the other; each warns when it finds the
        other later (:meth:`appeared`)."""
        me = self.node.get_fully_qualified_name()
        began = settled = time.monotonic()
        graph: object = None
        while True:
            others = self.namesakes()
            if others and "_NODE_NAME_UNKNOWN_" not in others[0]:
                break
            now = time.monotonic()
            named = self.node.get_node_names_and_namespaces()
            nodes = frozenset(f"{ns.rstrip('/')}/{n}" for n, ns in named)
            seen = (nodes, frozenset(t for t, _ in self.node.get_topic_names_and_types()))
            if seen != graph or not self._endpoints_known(named, me):
                graph, settled = seen, now
            elif (nodes - {me} and now - settled >= SETTLE) or now - began >= SETTLE_MOST:
                break
            time.sleep(0.02)
        if others:
            self._namesakes.update(others)
            raise ValueError(
                f"{what} {self.name!r} is taken: {others[0]} announces it "
                f"(this node: {self.node.get_fully_qualified_name()})"
            )

    def _endpoints_known(self, named: list[tuple[str, str]], me: str) -> bool:
        """Whether every other node of the graph has shown an endpoint (every rclpy node
        publishes ``/parameter_events``): a node is named before its endpoints are discovered
        (two steps of DDS discovery), and a namesake's announcement is one of them, so a graph
        with a node still unresolved has not settled (section 11). A node with no endpoint at
        all keeps it unsettled until :data:`SETTLE_MOST`."""
        graph = self.node
        for name, namespace in named:
            if f"{namespace.rstrip('/')}/{name}" == me:
                continue
            try:
                if not (
                    graph.get_publisher_names_and_types_by_node(name, namespace)
                    or graph.get_subscriber_names_and_types_by_node(name, namespace)
                ):
                    return False
            except RuntimeError:  # gone since it was named, or a name rcl cannot look up
                continue
        return True

    def first_named(self) -> bool:
        """Whether this robot's name comes first among the names its fleet announces: the one
        robot that replies to a malformed query (section 11)."""
        return self.name <= min(announced(self.node, self.topics.queries), default=self.name)

    def peers(self) -> set[str]:
        """The other nodes reading the query topic, by full name (``/robot1/ktbt``): who is
        present, from the ROS graph."""
        me = self.node.get_fully_qualified_name()
        found = set()
        for info in self.node.get_subscriptions_info_by_topic(self.topics.queries):
            namespace = info.node_namespace.rstrip("/")
            full = f"{namespace}/{info.node_name}"
            if full != me:
                found.add(full)
        return found

    # -- what arrives -----------------------------------------------------------------------------

    def _refuse(self, reason: str, **fields: Any) -> None:
        """Count, log (WARNING) and record one refusal (section 2: every refusal is counted)."""
        with self._lock:
            self.refused += 1
        self._warn(f"{self.name} refused: {reason}")
        if self.log is not None:
            self.log.record(
                Event.REFUSED, peer=self.name, reason=reason, where="transport", **fields
            )

    def _read(
        self,
        data: bytes,
        kind: type[_M],
        topic: str,
        wanted: Callable[[dict[str, Any]], bool],
    ) -> tuple[dict[str, Any], _M] | Literal["refused", "skipped"]:
        """A raw message from ``topic`` as the protocol message ``kind``, with the ROS fields it
        came as; anything else is refused, with its reason. ``wanted``: whether this robot
        reads a message whose fields could be read: one addressed to another, or its own heard
        back, is skipped unchecked (checking is most of a read's cost)."""
        what = f"on {topic}"
        if len(data) > self.max_bytes + CDR_SLACK:
            self._refuse(f"{what}: {len(data)} bytes, more than the limit", key=topic)
            return "refused"
        label, layout, ros_type = _KINDS[kind]
        try:
            fields = cdr.read(data, layout)
        except cdr.CdrError as exc:
            self._refuse(f"{what}: not a {ros_type} ({exc})", key=topic)
            return "refused"
        except Exception as exc:  # the reader's own failure (section 2.1)
            self._refuse(f"{what}: {internal_error(exc)}", key=topic)
            return "refused"
        if not wanted(fields):
            return "skipped"
        try:
            message = decode_fields(wire_fields(fields, label), self.max_bytes)
        except MessageRefused as exc:
            self._refuse(f"{what}: {exc.reason}", key=topic)
            return "refused"
        except (UnicodeError, ValueError) as exc:
            self._refuse(f"{what}: {type(exc).__name__}", key=topic)
            return "refused"
        except Exception as exc:  # the reader's own failure (section 2.1)
            self._refuse(f"{what}: {internal_error(exc)}", key=topic)
            return "refused"
        if not isinstance(message, kind):
            self._refuse(f"{what}: a {message.type} where a {kind.__name__} belongs", key=topic)
            return "refused"
        return fields, message

    @guarded("a query")
    def _on_query(self, data: bytes) -> None:
        if self.closed or not self.active:
            return
        read = self._read(data, Query, self.topics.queries, lambda f: f["sender"] != self.name)
        if read == "refused":
            self._error_reply(data)
        if not isinstance(read, tuple):
            return  # refused, or our own query heard back
        query = read[1]
        if self.lookup is not None:
            self._answer_at_once(query, self.lookup)
            return
        now = self.clock()
        key = (query.sender, query.id)
        with self._lock:
            self._expire(now)
            replay = key in self._seen
            full = not replay and len(self._seen) >= self.max_pending
            if not replay and not full:
                self._seen[key] = now
        if replay:  # heard again: an open query announced to a newcomer reaches every robot
            self.node.get_logger().debug(f"query {query.id} from {query.sender} heard again")
        elif full:  # left unanswered, as a teacher in cool-down would, but counted
            self._refuse(f"query {query.id} from {query.sender}: {self.max_pending} queries open")
        else:
            self._inbox.deliver(query)

    def _error_reply(self, data: bytes) -> None:
        """The error reply to a query that could not be read, addressed to its sender when
        that much of it could be read and is a name; else none is sent (a reply addressed to
        no one helps no one), and an oversized query is never deserialized to find out. Of the
        fleet, only the robot whose name comes first replies (:meth:`first_named`): one reply
        per query, not one per robot."""
        if len(data) > self.max_bytes + CDR_SLACK:
            return
        try:  # its first two fields alone: a later one beyond its bound leaves these readable
            sender = cdr.read(data, cdr.QUERY[:2])["sender"]
        except Exception:  # nothing of it could be read (cdr.CdrError), or the reader failed
            return
        if re.fullmatch(NAME, sender) is None or not self.first_named():
            return
        unread, refused = ErrorMsg.UNREAD_ID, ErrorMsg.REFUSED
        error = ErrorReply(id=unread, sender=self.name, code=refused, message="malformed query")
        self._errors.publish(serialized(error, sender))

    def _answer_at_once(self, query: Query, lookup: Lookup) -> None:
        """An answer to each sequence of ``query`` this robot knows, published at once
        (section 4.5, :class:`AnswersGiven`)."""
        for response in self._given.answers(query, lookup, self.identity, self.log):
            self._answers.publish(serialized(response, query.sender))
            self.answered += 1

    @guarded("an answer")
    def _on_answer(self, data: bytes) -> None:
        if self.closed or not self.active:
            return
        read = self._read(
            data,
            Response,
            self.topics.answers,
            lambda f: (
                f["sender"] != self.name
                and (f["to"] == self.name or self.overhear or self.relay is not None)
            ),
        )
        if not isinstance(read, tuple):
            return  # refused, addressed to another, or our own answer heard back
        fields, answer = read
        if fields["to"] == self.name:
            self._answer_to_me(answer)
        elif self.relay is not None:
            self.relay(fields["to"], answer)
        elif self.overhear:  # an answer to another robot (section 4.3)
            self._inbox.overhear(answer, self.screen)

    def _answer_to_me(self, answer: Response) -> None:
        """An answer addressed to this robot: to an open query, it must answer the sequence
        asked, pass the trust policy, and be its sender's first; any other (late, or to no
        query of ours) is the agent's to judge (section 2)."""
        with self._lock:
            opened = self._open.get(answer.id)
        if opened is not None:
            sequences, _, heard = opened
            if answer.sequence not in sequences:
                self._refuse(f"an answer from {answer.sender} answers another question")
                return
            why = self.screen(answer) if self.screen is not None else None
            if why is not None:
                self._refuse(f"from {answer.sender}: {why}")
                return
            place = (answer.sender, answer.sequence)  # one per sender and sequence asked
            with self._lock:
                again = place in heard
                heard.add(place)
            if again:
                self._refuse(f"another answer from {answer.sender} to the same query")
                return
        self._inbox.deliver(answer)
        if opened is not None and self.arrived is not None:
            self.arrived()

    @guarded("an error reply")
    def _on_error(self, data: bytes) -> None:
        if self.closed or not self.active:
            return
        read = self._read(data, ErrorReply, self.topics.errors, lambda f: f["to"] == self.name)
        if not isinstance(read, tuple):
            return
        error = read[1]
        self.node.get_logger().info(f"{error.sender} refused a query of ours: {error.message}")
        if self.log is not None:
            self.log.record(
                Event.ERROR_RECEIVED, peer=self.name, sender=error.sender, reason=error.message
            )

    def _expire(self, now: float) -> None:
        """Forget open queries and seen queries whose time is over, or that the clock went back
        past (under the lock)."""
        timeout, window = self.query_timeout, self.answer_window
        for qid in [q for q, (_, t, _) in self._open.items() if not 0 <= now - t <= timeout]:
            del self._open[qid]
        for key in [k for k, t in self._seen.items() if not 0 <= now - t <= window]:
            del self._seen[key]
