"""``ktbt ros2 bridge``: a relay between a zenoh fleet and a ROS 2 fleet, both ways
(spec/protocol.md section 11, "Bridge").

The bridge relays; it never judges, signs or rewrites. Every message crosses as the same
protocol message (section 1), so the author's and the sender's signatures (section 7) verify on
the far side, and a learner there under the ``trusted`` policy takes the item from its author's
key as if the teacher were beside it.

How each side sees the other:

- **A ROS robot on zenoh** is a :class:`~ktbt_proto.transport.zenoh.ZenohTransport` of the
  robot's own name (a *mirror*): its liveliness token says the robot is present, its catalog
  queryable serves what the robot's latched ``~/catalog`` says, and its knowledge queryable takes
  zenoh queries, which the bridge publishes on the ROS query topic. The robot's answer, heard
  on the answer topic with its ``to`` (the transport's ``relay``), goes to the query of that
  asker and ``id`` back through the robot's own mirror, so it replies on the robot's own key
  (``ktbt/v1/knowledge/<robot>``), the only key a zenoh asker accepts it on (section 3). A ROS
  robot is found by its ``~/catalog`` topic (type ``ktbt_interfaces/msg/Catalog``, read as
  :class:`~ktbt_proto.interop.ros2.showing.FleetCatalogs` reads it) or by a query it sends.
- **A zenoh peer on ROS** is a node of its own in the bridge's process (a *proxy*, under
  ``<bridge>/zenoh``): subscribed to the query topic, so that ROS robots count it present and
  a learner asks at once (section 11, "Presence"), with the peer's catalog on its latched
  ``~/catalog``. A ROS robot's query is asked on zenoh through the asker's mirror; each answer
  is published on the ROS answer topic, addressed to the asker.

**No loops, no diversion.** A query is relayed once per asker and ``id``, and only away from
the side its asker lives on: a zenoh query from a name the bridge mirrors (a mirror's own get,
heard by the other mirrors) and a ROS query from a zenoh peer's name (one the bridge
published) are not relayed back. An answer is relayed only to a query the bridge relayed, from
the side that query went to, and only to the asker it is addressed to: a peer repeating
another's ``id`` in its own name asks a question of its own, and never takes the other's
answers. An answer the bridge published on ROS, heard back, names a zenoh peer and is dropped.
Names are one side's each: a ROS robot named as a zenoh peer already present is refused, and
the other way round.

**Whose names cross.** A ROS topic does not say who published a message, so a ROS robot's name
is its own word. Under the ``any`` policy the bridge mirrors every name a catalog or a query
gives (the one WARNING of section 7 says so at start), at most :data:`MAX_PER_SOURCE` names of
one source: the DDS participant publishing the catalog topic (:func:`participants`), and for
names known only by their queries the query topic as one source; so a process inventing names
takes at most its share of :data:`MAX_ROBOTS`. Under ``trusted`` a name crosses only once it is
*proven*: a fleet event (section 10) naming it as its ``peer``, or an answer naming it as its
``sender``, is signed (the event's ``sig``, the answer's ``hop``) by a key of the bridge's trust
store, the key the store binds to that name if it binds one, else a key it binds to no name.
The bridge follows the events of its fleet's robots for this, and every :data:`PROVE_PERIOD`
s asks, in its own name, for what the catalogs of unproven robots list, so that an idle teacher
answers and says so in a signed event. A query from a name not proven yet waits up to
:data:`HOLD` s for its proof; a name not proven is refused, and nothing of it is relayed.

**Hostile input.** What the transports refuse (too large, not a message, a replay, a reply on
a wrong key) they count and log at WARNING; the bridge adds its own refusals, counted and
logged the same way: an answer whose signatures are present but do not verify (the ``any``
policy of section 7: the bridge never carries a forgery), an answer to a question it did not
relay or to another sequence, a robot beyond :data:`MAX_ROBOTS` or its source's share, a
name not proven under ``trusted``, an event that is not one, a catalog that is not one
(larger than 1 MiB serialized or not a ``Catalog``: :class:`FleetCatalogs`' bounds, of which
the first 1,024 entries are read; naming no robot; an entry without a sequence; or larger, as
JSON, than the 65,536 bytes a zenoh peer reads of a catalog, section 3). Nothing a peer sends
ends the bridge. Everything is logged through the bridge node's logger, so it reaches
``/rosout`` at the node's level (``--ros-args --log-level``).
"""

from __future__ import annotations

import hashlib
import json
import re
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any, TypeVar

import zenoh
from ktbt_interfaces.msg import Catalog, FleetEvent
from ktbt_interfaces.msg import Query as QueryMsg
from rclpy.node import Node
from rclpy.serialization import deserialize_message

from ktbt_proto.exchange.events import MAX_EVENT_BYTES, decode_event
from ktbt_proto.exchange.messages import MAX_MESSAGE_BYTES, MessageRefused, Query, Response
from ktbt_proto.exchange.refusals import Throttle, guarded, internal_error
from ktbt_proto.exchange.trust import Policy, TrustStore, refusal
from ktbt_proto.interop.ros2.showing import (
    FleetCatalogs,
    catalog_entries,
    event_json,
    events_qos,
    latched,
    participants,
)
from ktbt_proto.transport.ros2 import (
    CDR_SLACK,
    NAME,
    Ros2Transport,
    Topics,
    exchange_qos,
    to_msg,
)
from ktbt_proto.transport.zenoh import (
    PREFIX,
    ZenohSettings,
    ZenohTransport,
    catalog_replies,
    open_session,
)

_A = TypeVar("_A")
_B = TypeVar("_B")

MAX_ROBOTS = 64
"""ROS robots mirrored on zenoh, and zenoh peers shown on ROS, at most (each side)."""
MAX_RELAYED = 1024
"""Queries being relayed at once at most; the oldest is forgotten beyond."""
GRAPH_PERIOD = 0.5
"""Seconds between two reads of the ROS graph (catalog topics, robots gone)."""
MIRROR_IDLE = 60.0
"""Seconds a ROS robot known only by its queries stays mirrored after its last query."""
CATALOG_PERIOD = 2.0
"""Seconds between two readings of the zenoh fleet's catalogs."""
MAX_PER_SOURCE = 16
"""Names one source (a DDS participant; the query topic for names known only by their
queries) has mirrored at most, and catalog and event topics of one participant followed."""
PROVE_PERIOD = 5.0
"""Seconds between two of the bridge's own queries asking unproven robots to show their keys."""
HOLD = 2.0
"""Seconds a query from a name not proven yet waits for its proof (under ``trusted``)."""
MAX_SEQUENCE = 4096
"""A sequence longer than a query may name (section 1) is not asked for."""
MAX_HELD = 64
"""Queries waiting for their sender's proof at most; one beyond is refused."""
QUERIED = "the query topic"
"""The source of a name known only by its queries (a message does not say who sent it)."""
_KINDS = {
    "a ROS robot named": "names",
    "zenoh peer": "names",
    "events topic": "events",
    "an event": "events",
    "an answer": "answers",
    "": "other",
}
"""The kinds of the bridge's refusals, by how their reasons begin (see ``Bridge._warns``)."""
EVENT_TYPE = "ktbt_interfaces/msg/FleetEvent"
"""The type by which a robot's events topic is found on the graph."""


def ros_name(name: str, taken: set[str]) -> str:
    """A ROS node name for the zenoh peer ``name`` (letters, digits and ``_``, not starting
    with a digit), distinct from those ``taken``."""
    base = re.sub(r"[^A-Za-z0-9_]", "_", name)
    if not base[:1].isalpha():
        base = "z" + base
    if base in taken:
        base = f"{base}_{hashlib.sha256(name.encode()).hexdigest()[:8]}"
    return base


_LOOPBACK = re.compile(r"^[a-z0-9-]+/(127\.[0-9.]+|localhost|\[::1\]):")


def mirror_settings(settings: ZenohSettings) -> ZenohSettings:
    """A mirror's zenoh settings: it connects where the bridge connects (and to the bridge's
    own listen endpoints), and listens on a port of the system's choosing, on loopback when
    the fleet is reached on loopback, else on every interface. Zenoh's gossip tells the fleet's
    peers where it listens, so a peer that only connects (``ktbt peer run --connect``) reaches
    it too: peers do not route for one another (section 3)."""
    own = [re.sub(r"/0\.0\.0\.0:", "/127.0.0.1:", e) for e in settings.listen]
    reached = [*settings.connect, *own]
    local = bool(reached) and all(_LOOPBACK.match(e) for e in reached)
    here = "tcp/127.0.0.1:0" if local else "tcp/0.0.0.0:0"
    return replace(settings, listen=(here,), connect=tuple(reached), zid=None)


@dataclass
class Relayed:
    """A query being relayed: who asked, what (every sequence it names, section 1), and until
    when its answers are taken."""

    sender: str
    sequences: tuple[str, ...]
    deadline: float


@dataclass
class Counts:
    """What the bridge relayed and refused (its own refusals; the transports count theirs)."""

    queries_to_ros: int = 0
    queries_to_zenoh: int = 0
    answers_to_ros: int = 0
    answers_to_zenoh: int = 0
    refused: int = 0
    reasons: list[str] = field(default_factory=list)


class Bridge:
    """Relays knowledge between the zenoh fleet ``settings`` reach and the ROS 2 fleet on
    ``topics``, through ``node`` (see the module's docstring). Call :meth:`step` often from
    the thread that spins ``node`` (it also makes and ends the proxies' nodes); ``close``
    at the end."""

    def __init__(
        self,
        node: Node,
        settings: ZenohSettings,
        topics: Topics | None = None,
        *,
        query_timeout: float = 2.0,
        max_robots: int = MAX_ROBOTS,
        policy: Policy = Policy.ANY,
        trust: TrustStore | None = None,
        max_per_source: int = MAX_PER_SOURCE,
    ) -> None:
        if policy is Policy.SIGNED or (policy is Policy.TRUSTED and trust is None):
            raise ValueError("a bridge's policy is any, or trusted with a trust store")
        self.node, self.settings = node, settings
        self.logger = node.get_logger()
        self._mirror_settings = mirror_settings(settings)
        self.topics = topics or Topics()
        self.query_timeout, self.max_robots = query_timeout, max_robots
        self.policy, self.trust, self.max_per_source = policy, trust, max_per_source
        self.counts = Counts()
        self._lock = threading.Lock()
        self._warns = {kind: Throttle(self.logger.warning) for kind in _KINDS.values()}
        """Refusals are thinned by kind (names, events, answers, the rest), each at its own rate
        limit: a flood of invented names or malformed events never hides another kind's line,
        an answer in a proven robot's name that its key did not sign above all."""
        self.name = f"bridge.{node.get_name()}"[:64]
        self.ros = Ros2Transport(
            node,
            self.name,
            self.topics,
            answer_at_once=False,
            query_timeout=query_timeout,
            relay=self._answer_from_ros,  # answers addressed to zenoh askers, with their `to`
        )
        # Zenoh's queries, published in their askers' names (the transport's own publisher
        # sends only queries of the bridge's own, whose answers it would not pass on).
        self._queries = node.create_publisher(QueryMsg, self.topics.queries, exchange_qos())
        self.proxy_space = node.get_fully_qualified_name().rstrip("/") + "/zenoh"
        self.mirrors: dict[str, ZenohTransport] = {}
        """ROS robots on zenoh, by name."""
        self._catalogs: dict[str, list[dict[str, str]]] = {}
        """What each ROS robot's ``~/catalog`` says."""
        self._catalog_reader = FleetCatalogs(
            node,
            skip=lambda topic: topic.startswith(self.proxy_space + "/"),  # the proxies'
            limit=2 * max_robots,
            heard=self._on_catalog,
            fleet=self.ros.peers,  # the nodes reading the fleet's query topic: not another's
            per_source=max_per_source,
        )
        self._sources: dict[str, frozenset[str]] = {}
        """A mirrored ROS robot -> the sources that named it (charged for it)."""
        self.proven: dict[str, str] = {}
        """Under ``trusted``: a ROS robot's name -> the trusted key that proved it."""
        self._events: dict[str, Any] = {}
        """Events topic followed -> its subscription (under ``trusted``)."""
        self._event_sources: dict[str, frozenset[str]] = {}
        self._events_ignored: set[str] = set()
        self._held: list[tuple[Query, float]] = []
        """Queries from names not proven yet, each until when it waits."""
        self._next_proof = 0.0
        self._topic_robot: dict[str, str] = {}
        """Catalog topic -> the robot it named."""
        self.proxies: dict[str, tuple[Node, Any, Any]] = {}
        """Zenoh peers on ROS: name -> (node, subscription, catalog publisher)."""
        self._proxy_shown: dict[str, list[dict[str, str]]] = {}
        self._zenoh_present: set[str] = set()
        self._zenoh_catalogs: dict[str, list[dict[str, str]]] = {}
        self._from_zenoh: OrderedDict[tuple[str, str], Relayed] = OrderedDict()
        """Zenoh queries relayed to ROS: (asker, id) -> the query."""
        self._from_ros: OrderedDict[tuple[str, str], Relayed] = OrderedDict()
        """ROS queries relayed to zenoh: (asker, id) -> the query."""
        self._next_graph = 0.0
        self._ended_refused = 0
        """What the mirrors of robots gone had refused."""
        self._asking: dict[str, float] = {}
        """A ROS robot that asked -> when it last did (a robot without a catalog topic is
        mirrored until it has been silent :data:`MIRROR_IDLE` s)."""
        self._stop = threading.Event()
        self._session = open_session(settings)
        try:
            self._presence = self._session.liveliness().declare_subscriber(
                f"{PREFIX}/peers/*", self._on_presence, history=True
            )
        except BaseException:
            self._session.close()  # type: ignore[no-untyped-call]
            raise
        self._reader = threading.Thread(target=self._read_catalogs, daemon=True)
        self._reader.start()
        if policy is Policy.ANY:  # section 7: the risk, said once
            self.logger.warning(
                f"{self.name}: policy any: every participant of ROS domain "
                f"{node.context.get_domain_id()} can put a robot's name on zenoh through this "
                "bridge; give the fleet keys (ktbt peer keys) and --policy trusted --trust FILE"
            )

    # -- counting -------------------------------------------------------------------------------

    def _refuse(self, reason: str) -> None:
        """Count and log (WARNING) one of the bridge's own refusals, under its kind's rate
        limit."""
        with self._lock:
            self.counts.refused += 1
            self.counts.reasons = [*self.counts.reasons[-7:], reason]
        kind = next((k for prefix, k in _KINDS.items() if reason.startswith(prefix)), "other")
        self._warns[kind](f"{self.name} refused: {reason}")

    def refused(self) -> int:
        """Everything refused: the bridge's own refusals and its transports'."""
        mirrors = sum(m.refused for m in list(self.mirrors.values()))
        catalogs = self._catalog_reader.refused
        return self.counts.refused + self.ros.refused + catalogs + mirrors + self._ended_refused

    def summary(self) -> str:
        c = self.counts
        return (
            f"{self.name}: relayed queries {c.queries_to_ros} to ROS, {c.queries_to_zenoh} to "
            f"zenoh; answers {c.answers_to_ros} to ROS, {c.answers_to_zenoh} to zenoh; "
            f"refused {self.refused()}; ROS robots {len(self.mirrors)}, zenoh peers "
            f"{len(self.proxies)}"
        )

    # -- zenoh's side: who is there, what they know ---------------------------------------------

    def _on_presence(self, sample: Any) -> None:
        name = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._zenoh_present.add(name)
            else:
                self._zenoh_present.discard(name)

    def _read_catalogs(self) -> None:
        """The zenoh fleet's catalogs, every :data:`CATALOG_PERIOD` s, in a thread of ours (a
        get is never issued from a zenoh callback); a reply that cannot be read is refused."""
        while not self._stop.is_set():
            found: dict[str, list[dict[str, str]]] = {}
            try:
                for name, entries in catalog_replies(self._session, 1.0, self._refuse):
                    if name not in self.mirrors:
                        found[name] = entries
            except zenoh.ZError:  # the network's own error (a closing session)
                pass
            with self._lock:
                self._zenoh_catalogs = found
            self._stop.wait(CATALOG_PERIOD)

    def zenoh_peers(self) -> set[str]:
        """The zenoh peers present, the bridge's own mirrors left out."""
        with self._lock:
            present = set(self._zenoh_present)
        return present - self.mirrors.keys()

    # -- ROS's side: who is there, what they know -----------------------------------------------

    def _read_graph(self) -> None:
        """Follow every robot's ``~/catalog`` (not the proxies'), and end the mirror of a
        robot whose catalog topic has no publisher any more."""
        self._catalog_reader.refresh()
        now = time.monotonic()
        for name in [n for n, t in self._asking.items() if t < now - MIRROR_IDLE]:
            del self._asking[name]
            if name not in self._topic_robot.values():
                self._end_mirror(name)  # a robot known only by its queries, silent a while
        for topic in self._catalog_reader.gone():
            robot = self._topic_robot.pop(topic, None)
            if robot is not None and robot not in self._topic_robot.values():
                self._catalogs.pop(robot, None)
                self._end_mirror(robot)

    def _on_catalog(self, topic: str, name: str, entries: list[dict[str, str]]) -> None:
        """A ROS robot's catalog, read within :class:`FleetCatalogs`' bounds: mirrored as is,
        unless it names no robot, lists an entry without a sequence, or is larger as JSON
        than section 3's limit of a catalog reply (which a zenoh peer would not read)."""
        if not re.fullmatch(NAME, name):
            self._refuse(f"a catalog on {topic[:80]} names no robot ({name[:64]!r})")
            return
        if not all(e["sequence"] for e in entries):
            self._refuse(f"the catalog of {name} on {topic[:80]}: an entry without a sequence")
            return
        size = len(json.dumps(entries).encode())  # what the mirror's catalog queryable serves
        if size > MAX_MESSAGE_BYTES:
            self._refuse(f"the catalog of {name} on {topic[:80]}: {size} bytes as JSON")
            return
        self._topic_robot[topic] = name
        self._catalogs[name] = entries
        self._mirror(name, self._catalog_reader.sources(topic))

    def _mirror(self, name: str, sources: frozenset[str]) -> ZenohTransport | None:
        """The mirror of the ROS robot ``name``, named by ``sources``, made if need be; None
        (refused) if the name is a zenoh peer's, is not proven under ``trusted``, if one of
        its sources named its share of robots already, or too many robots are mirrored."""
        mirror = self.mirrors.get(name)
        if mirror is not None:
            return mirror
        if name in self.zenoh_peers() or name in self.proxies:
            self._refuse(f"a ROS robot named {name}: that name is a zenoh peer's")
            return None
        if self.policy is Policy.TRUSTED and name not in self.proven:
            self._refuse(
                f"a ROS robot named {name}: its name is not proven (no event or answer of "
                "it signed by a key of the trust store)"
            )
            return None
        if name not in self.proven:  # a name nobody proved: a share per source
            for source in sorted(sources):
                taken = sum(source in s for s in self._sources.values())
                if taken >= self.max_per_source:
                    who = source if source == QUERIED else f"participant {source}"
                    self._refuse(f"a ROS robot named {name}: {who} named {taken} robots already")
                    return None
        if len(self.mirrors) >= self.max_robots:
            self._refuse(f"a ROS robot named {name}: {self.max_robots} robots already bridged")
            return None
        mirror = ZenohTransport(
            name,
            self._mirror_settings,
            catalog=lambda: self._catalogs.get(name, []),
            query_timeout=self.query_timeout,
            answer_window=self.query_timeout,
        )
        self.mirrors[name] = mirror
        self._sources[name] = sources
        self.logger.info(f"{self.name}: ROS robot {name} is on zenoh")
        return mirror

    def _end_mirror(self, name: str) -> None:
        mirror = self.mirrors.pop(name, None)
        self._sources.pop(name, None)
        if mirror is not None:
            self._ended_refused += mirror.refused
            mirror.close()
            self.logger.info(f"{self.name}: ROS robot {name} left")

    # -- proof of a ROS robot's name (under ``trusted``) ----------------------------------------

    def _prove(self, name: str, key: str, how: str) -> None:
        """``key`` signed something of ``name``'s (verified by the caller): the name is proven
        if the trust store binds it to ``key``, or binds it to no key and ``key`` to no name;
        then the robot is mirrored if a catalog names it."""
        if self.trust is None or name in self.proven or re.fullmatch(NAME, name) is None:
            return
        bound = self.trust.names.get(name)
        if bound is None:
            trusted = key in self.trust.keys and key not in self.trust.names.values()
        else:
            trusted = key == bound
        if not trusted or len(self.proven) >= 4 * self.max_robots:
            return
        self.proven[name] = key
        self.logger.info(f"{self.name}: ROS robot {name} proved its name ({how})")
        topics = [t for t, robot in self._topic_robot.items() if robot == name]
        if topics:
            self._mirror(name, self._catalog_reader.sources(topics[0]))

    def _prove_by_answer(self, answer: Response) -> None:
        """An answer signed by its sender (both signatures valid, the store's binding kept)
        proves the sender's name if the key is trusted for it."""
        if (
            self.policy is Policy.TRUSTED
            and answer.sender not in self.proven
            and answer.key is not None
            and refusal(answer, Policy.SIGNED, self.trust) is None
        ):
            self._prove(answer.sender, answer.key, "a signed answer")

    def _follow_events(self) -> None:
        """Follow the events topic of every robot of the fleet (a node reading its query
        topic), as catalogs are followed: at most twice :data:`MAX_ROBOTS` topics, and
        :data:`MAX_PER_SOURCE` of one participant; the topics of robots gone are let go."""
        for topic in [t for t in self._events if not self.node.count_publishers(t)]:
            self.node.destroy_subscription(self._events.pop(topic))
            self._event_sources.pop(topic, None)
        fleet = self.ros.peers()
        for topic, types in self.node.get_topic_names_and_types():
            if EVENT_TYPE not in types or topic in self._events or topic in self._events_ignored:
                continue
            infos = self.node.get_publishers_info_by_topic(topic)
            if topic.startswith(self.proxy_space + "/") or not any(
                f"{i.node_namespace.rstrip('/')}/{i.node_name}" in fleet for i in infos
            ):
                continue
            sources = participants(self.node, topic)
            taken = max((sum(s in t for t in self._event_sources.values()) for s in sources),
                        default=0)  # fmt: skip
            if len(self._events) >= 2 * self.max_robots or taken >= self.max_per_source:
                if len(self._events_ignored) < 8 * self.max_robots:
                    self._events_ignored.add(topic)
                    self._refuse(f"events topic {topic[:80]}: no place left to follow it")
                continue
            self._event_sources[topic] = sources
            self._events[topic] = self.node.create_subscription(
                FleetEvent, topic, partial(self._on_event, topic), events_qos(), raw=True
            )

    @guarded("an event")
    def _on_event(self, topic: str, data: bytes) -> None:
        """A robot's event: one signed by a trusted key proves the name it gives (``peer``);
        one that is not an event (too large, not a ``FleetEvent``, a forged signature) is
        refused; an unsigned one proves nothing."""
        if len(data) > MAX_EVENT_BYTES + CDR_SLACK:
            self._refuse(f"an event on {topic[:80]}: {len(data)} bytes")
            return
        try:
            msg = deserialize_message(data, FleetEvent)
        except Exception as exc:  # a hostile publisher's bytes: rclpy raises its own types
            self._refuse(f"an event on {topic[:80]}: not a FleetEvent ({type(exc).__name__})")
            return
        if msg.peer in self.proven or not msg.sig:
            return  # nothing left to prove, or no proof: not checked further
        try:
            event = decode_event(event_json(msg))
        except MessageRefused as exc:
            self._refuse(f"an event on {topic[:80]}: {exc}")
            return
        if event.key is not None:
            self._prove(event.peer, event.key, f"a signed event on {topic[:80]}")

    def _ask_for_proof(self, now: float) -> None:
        """Every :data:`PROVE_PERIOD` s while a catalog names a robot not proven, one query
        of the bridge's own for the first sequence of each such catalog (at most 64): every
        robot records it in a signed event, and those that know one answer, signed."""
        if now < self._next_proof:
            return
        self._next_proof = now + PROVE_PERIOD
        named = set(self._topic_robot.values())
        wanted = [
            entries[0]["sequence"]
            for name, entries in self._catalogs.items()
            if name not in self.proven and name in named and entries
        ]
        wanted = [w for w in dict.fromkeys(wanted) if len(w) <= MAX_SEQUENCE][:64]
        if wanted:
            self.ros.broadcast(Query.asking(self.name, wanted))

    # -- proxies: zenoh peers on ROS ------------------------------------------------------------

    def _tend_proxies(self) -> None:
        """A proxy node for each zenoh peer present (at most :data:`MAX_ROBOTS`), its catalog
        published when it changed; the proxy of a peer gone is ended."""
        present = self.zenoh_peers()
        with self._lock:
            catalogs = dict(self._zenoh_catalogs)
        for name in list(self.proxies):
            if name not in present:
                proxy, sub, pub = self.proxies.pop(name)
                proxy.destroy_subscription(sub)
                proxy.destroy_publisher(pub)
                proxy.destroy_node()
                self._proxy_shown.pop(name, None)
        for name in sorted(present - self.proxies.keys()):
            if name in self.mirrors or not re.fullmatch(NAME, name):
                continue
            if len(self.proxies) >= self.max_robots:
                self._refuse(f"zenoh peer {name}: {self.max_robots} peers already bridged")
                break
            taken = {p[0].get_name() for p in self.proxies.values()}
            try:
                proxy = Node(  # never spun: it offers no parameter services to time out on
                    ros_name(name, taken),
                    namespace=self.proxy_space,
                    context=self.node.context,
                    start_parameter_services=False,
                )
            except Exception as exc:  # rclpy refused the name: one line, the peer unbridged
                self._refuse(f"zenoh peer {name}: no ROS node ({type(exc).__name__})")
                continue
            # Present on ROS: a reader of the query topic (its queries are the bridge's to
            # read: this subscription is never spun, DDS keeps at most its depth).
            sub = proxy.create_subscription(
                QueryMsg, self.topics.queries, lambda _: None, exchange_qos(), raw=True
            )
            pub = proxy.create_publisher(Catalog, "~/catalog", latched())
            self.proxies[name] = (proxy, sub, pub)
            self.logger.info(f"{self.name}: zenoh peer {name} is on ROS")
        for name, (_, _, pub) in self.proxies.items():
            entries = catalogs.get(name, [])
            if entries != self._proxy_shown.get(name):
                pub.publish(Catalog(peer=name, items=catalog_entries(entries)))
                self._proxy_shown[name] = entries

    # -- relaying -------------------------------------------------------------------------------

    def step(self) -> None:
        """Relay what came from either side since the last step; now and then read the ROS
        graph and tend the proxies."""
        now = time.monotonic()
        self._expire(now)
        if now >= self._next_graph:
            self._next_graph = now + GRAPH_PERIOD
            self._read_graph()
            self._tend_proxies()
            if self.policy is Policy.TRUSTED:
                self._follow_events()
        if self.policy is Policy.TRUSTED:
            self._ask_for_proof(now)
            held, self._held = self._held, []
            for query, until in held:  # waiting for their sender's proof
                if query.sender in self.proven or until < now:
                    self._relay(self._query_from_ros, query, now)
                else:
                    self._held.append((query, until))
        for message in self.ros.receive():  # answers to others come through `relay`
            if isinstance(message, Query):
                if self._waits(message, now):
                    continue
                self._relay(self._query_from_ros, message, now)
            elif isinstance(message, Response):  # to the bridge's own query: a proof
                self._prove_by_answer(message)
        for mirror in list(self.mirrors.values()):
            for message in mirror.receive():
                if isinstance(message, Query):
                    self._relay(self._query_from_zenoh, message, now)
                elif isinstance(message, Response):
                    self._relay(self._answer_from_zenoh, mirror.name, message)
                # a NetworkError is zenoh's own (a get timed out): counted by the mirror

    def _relay(self, relay: Callable[[_A, _B], None], first: _A, second: _B) -> None:
        """One message relayed; whatever relaying it raises is a refusal (section 2.1), and
        the bridge goes on with the next."""
        try:
            relay(first, second)
        except Exception as exc:
            self._refuse(f"relaying a message: {internal_error(exc)}")

    def _waits(self, query: Query, now: float) -> bool:
        """Whether ``query``, from a name not proven yet under ``trusted``, is held a while
        for its proof (a learner's first query comes with the event that proves it)."""
        if self.policy is not Policy.TRUSTED or query.sender in self.proven:
            return False
        if query.sender in self.proxies or (query.sender, query.id) in self._from_zenoh:
            return False  # the bridge's own, heard back
        if len(self._held) >= MAX_HELD:
            return False  # refused as not proven, at once
        self._held.append((query, now + HOLD))
        return True

    def _remember(self, table: OrderedDict[tuple[str, str], Relayed], query: Query) -> bool:
        """Note ``query`` as relayed; False if it already was (relay once per asker and id)."""
        key = (query.sender, query.id)
        if key in table:
            return False
        while len(table) >= MAX_RELAYED:
            table.popitem(last=False)
        until = time.monotonic() + 2 * self.query_timeout
        table[key] = Relayed(query.sender, query.sequences, until)
        return True

    def _query_from_zenoh(self, query: Query, now: float) -> None:
        """A zenoh peer's query, heard by a mirror: to ROS, once."""
        if query.sender in self.mirrors:
            return  # a ROS robot's query, asked on zenoh by its mirror: heard back
        if not self._remember(self._from_zenoh, query):
            return  # heard by every mirror: relayed once
        self._queries.publish(to_msg(query))
        self.counts.queries_to_ros += 1

    def _query_from_ros(self, query: Query, now: float) -> None:
        """A ROS robot's query: to zenoh through its mirror, once."""
        if (query.sender, query.id) in self._from_zenoh or query.sender in self.proxies:
            return  # published by the bridge itself: heard back
        mirror = self._mirror(query.sender, frozenset({QUERIED}))
        if mirror is not None:
            self._asking[query.sender] = now
        if mirror is None or not self._remember(self._from_ros, query):
            return
        mirror.broadcast(query)
        self.counts.queries_to_zenoh += 1

    def _screened(self, answer: Response, relayed: Relayed | None, where: str) -> bool:
        """Whether ``answer`` may be relayed to the query it answers: one the bridge relayed,
        one of its sequences, and signatures that verify where present (never a forgery),
        a name the trust store binds signed by its key. Under ``trusted``, an answer from ROS
        must be signed, by the key that proved its sender's name: a topic does not say who
        published it, and a proven name is not lent to whoever answers in it."""
        if relayed is None:
            self._refuse(f"an answer {where} from {answer.sender} to no query relayed")
            return False
        if answer.sequence not in relayed.sequences:
            self._refuse(f"an answer {where} from {answer.sender} answers another question")
            return False
        why = refusal(answer, Policy.ANY, self.trust)
        proof = self.proven.get(answer.sender)
        if why is None and self.policy is Policy.TRUSTED and where == "on ROS":
            if proof is None:
                why = "its name is not proven"
            elif answer.key != proof or refusal(answer, Policy.SIGNED, self.trust) is not None:
                why = "the reply is not signed by the key that proved its name"
        if why is not None:
            self._refuse(f"an answer {where} from {answer.sender}: {why}")
            return False
        return True

    def _answer_from_ros(self, to: str, answer: Response) -> None:
        """A ROS robot's answer to a zenoh peer's query, addressed (``to``) to its asker: back
        through the robot's mirror, which replies on the robot's own key. A query is known by
        its asker and id together, so a peer that repeats another's id in its own name asks a
        question of its own, and never takes the other's answers."""
        if answer.sender in self.proxies or answer.sender in self.zenoh_peers():
            return  # the bridge's own answer to a ROS robot, heard back
        self._prove_by_answer(answer)
        relayed = self._from_zenoh.get((to, answer.id))
        if relayed is None:
            return  # an answer between ROS robots: not the bridge's
        if not self._screened(answer, relayed, "on ROS"):
            return
        mirror = self._mirror(answer.sender, frozenset({QUERIED}))
        if mirror is None:
            return
        mirror.send(to, answer)
        self.counts.answers_to_zenoh += 1

    def _answer_from_zenoh(self, asker: str, answer: Response) -> None:
        """A zenoh peer's answer to a ROS robot's query (checked by the mirror: on its
        sender's key, once per sender): published on ROS, addressed to the asker."""
        if answer.sender in self.mirrors:
            self._refuse(f"an answer on zenoh naming ROS robot {answer.sender}")
            return
        if not self._screened(answer, self._from_ros.get((asker, answer.id)), "on zenoh"):
            return
        self.ros.send(asker, answer)
        self.counts.answers_to_ros += 1

    def _expire(self, now: float) -> None:
        for table in (self._from_zenoh, self._from_ros):
            while table and next(iter(table.values())).deadline < now:
                table.popitem(last=False)

    # -- the end --------------------------------------------------------------------------------

    def close(self) -> None:
        """End everything the bridge made: the mirrors' sessions, the proxies' nodes, its
        own session and topics (the node stays its owner's)."""
        self._stop.set()
        self._reader.join(timeout=5)
        for name in list(self.mirrors):
            self._end_mirror(name)
        for proxy, sub, pub in self.proxies.values():
            proxy.destroy_subscription(sub)
            proxy.destroy_publisher(pub)
            proxy.destroy_node()
        self.proxies.clear()
        self._catalog_reader.close()
        for subscription in self._events.values():
            self.node.destroy_subscription(subscription)
        self._events.clear()
        self.node.destroy_publisher(self._queries)
        self.ros.close()
        self._presence.undeclare()  # type: ignore[no-untyped-call]
        self._session.close()  # type: ignore[no-untyped-call]
