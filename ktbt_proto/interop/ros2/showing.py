"""What a KT-BT robot shows on ROS 2, and what it reads of the others' (spec/protocol.md section
11, "ROS 2 binding"), whoever runs it: the lifecycle node (``ktbt ros2 run``) and a robot
embedded in its user's own node (:mod:`ktbt_proto.interop.ros2.embed`) alike.

- :class:`ShownTopics`: its fleet events (section 10) on ``events``, its control tree on
  ``tree`` and its catalog on ``catalog``, under one prefix (``~`` for the lifecycle node,
  ``~/ktbt`` for an embedded robot, so that the user's own topics keep their names);
- :class:`FleetCatalogs`: the other robots' latched catalogs, found on the ROS graph by their
  type, which a learner told no sequences reads to know what to ask for (section 4.5, as
  ``ktbt peer run`` reads zenoh's catalog queryables), and the bridge reads to mirror the
  robots on zenoh (section 11, "Bridge").

A catalog is a peer's word: it is read raw, bounded (:data:`MAX_CATALOG_BYTES`, at most
:data:`MAX_CATALOGS` topics followed, :data:`MAX_ENTRIES` entries each), and what it lists is
only ever asked for; the answers are checked as any other (section 2).
"""

from __future__ import annotations

import json
import math
import re
import threading
from collections.abc import Callable, Mapping, Sequence
from datetime import UTC, datetime
from functools import partial
from typing import Any

from builtin_interfaces.msg import Time
from ktbt_interfaces.msg import Catalog, CatalogEntry, FleetEvent, TreeSnapshot
from ktbt_interfaces.srv import Forget, ListKnowledge
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.serialization import deserialize_message

from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.events import EventPublisher
from ktbt_proto.exchange.member import CATALOG_PERIOD, FleetMember
from ktbt_proto.exchange.refusals import Throttle, guarded, internal_error
from ktbt_proto.exchange.signing import Identity
from ktbt_proto.exchange.transferlog import TransferLog
from ktbt_proto.formatter import format_tree
from ktbt_proto.items import read_sequence, sequence_key, show_key
from ktbt_proto.transport.cdr import BOUNDS
from ktbt_proto.transport.ros2 import NAME, quiet, watched
from ktbt_proto.tree import Tree

__all__ = [
    "CATALOG_TYPE",
    "EVENT_TEXT",
    "FleetCatalogs",
    "Services",
    "ShownTopics",
    "catalog_entries",
    "entry_fields",
    "event_json",
    "event_msg",
    "events_qos",
    "latched",
    "participants",
    "received_text",
    "received_time",
]

EVENT_TEXT = {
    "peer": "peer", "t": "t", "event": "event", "item": "item", "sequence": "sequence",
    "id": "id", "sender": "sender", "to": "to", "teacher": "teacher", "author": "author",
    "reason": "reason", "where": "where", "on": "refused_on", "key": "key", "sig": "sig",
}  # fmt: skip
"""An event's text fields (section 10's JSON names) and their ``msg/FleetEvent`` names: the
same but ``on``, ``refused_on`` there (``on`` is a boolean in YAML 1.1, as ``ros2 topic pub``
reads a message)."""
CATALOG_TYPE = "ktbt_interfaces/msg/Catalog"
"""The type by which a robot's catalog topic is found on the graph, whatever its name."""
ENTRY_BOUNDS = {"sequence": BOUNDS["sequence"], "author": BOUNDS["author"], "teacher": BOUNDS["to"]}
"""A catalog entry's text fields (section 3's, ``msg/CatalogEntry``; its ``received_at`` is a
``builtin_interfaces/Time``) and their bounds, in characters."""
MAX_CATALOGS = 64
"""Catalog topics a robot follows at most (the first found)."""
MAX_ENTRIES = 1024
"""Entries read of one catalog (the first)."""
MAX_CATALOG_BYTES = 1 << 20
"""A serialized catalog longer than this is refused unread."""

Entries = Callable[[], list[str | dict[str, Any]]]
"""What a robot's catalog lists now (``ktbt_proto.exchange.answers.catalog``)."""


def participants(node: Node, topic: str) -> frozenset[str]:
    """Who publishes ``topic``: the DDS participants (one a process's ROS context) of its
    publishers, each the first 12 bytes of a publisher's GID, its DDS GUID prefix, in hex.
    A received message does not say who published it (Jazzy's ``MessageInfo`` holds its
    timestamps and sequence numbers only), so a source is read from the graph, by topic
    (section 11, "Bridge": a bound per source)."""
    return frozenset(
        bytes(info.endpoint_gid[:12]).hex() for info in node.get_publishers_info_by_topic(topic)
    )


def latched() -> QoSProfile:
    """``~/tree`` and ``~/catalog``: RELIABLE, TRANSIENT_LOCAL, depth 1, so a reader that
    comes later gets the latest at once (as py_trees_ros's snapshots)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )


def events_qos() -> QoSProfile:
    """``~/events``: RELIABLE, VOLATILE, depth 100: a watcher sees what happens from when it
    starts (a gap in ``n`` is events lost), as on zenoh (section 10)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=100,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


def event_msg(data: bytes) -> FleetEvent:
    """The ROS message of an encoded fleet event (section 10's JSON): absent text is "", an
    absent tick -1, so the JSON, and its signature, come back from the fields alone."""
    fields = json.loads(data)
    msg = FleetEvent(v=fields["v"], n=fields["n"], dropped=fields.get("dropped", 0))
    for name, field in EVENT_TEXT.items():
        setattr(msg, field, fields.get(name) or "")
    msg.tick = fields.get("tick", -1)
    return msg


def event_json(msg: FleetEvent) -> bytes:
    """Section 10's JSON of a received event, from its fields alone (what ``sig`` signs, with
    ``sig`` added): :func:`ktbt_proto.exchange.events.decode_event` checks it."""
    fields: dict[str, Any] = {"v": msg.v, "type": "event", "n": msg.n, "dropped": msg.dropped}
    fields.update({name: getattr(msg, f) for name, f in EVENT_TEXT.items() if getattr(msg, f)})
    if msg.tick >= 0:
        fields["tick"] = msg.tick
    return json.dumps(fields, ensure_ascii=False).encode("utf-8")


def received_time(text: object) -> Time:
    """``received_at`` as ``builtin_interfaces/Time``, from section 3's ISO 8601 text (UTC;
    a time without an offset is taken as UTC); zero (unknown) for anything else, and for a
    time ``Time`` cannot hold (its seconds are an ``int32``: 1901 to 2038)."""
    if not isinstance(text, str) or not text:
        return Time()
    try:
        when = datetime.fromisoformat(text)
        if when.tzinfo is None:
            when = when.replace(tzinfo=UTC)
        seconds = math.floor(when.timestamp())
    except (ValueError, OverflowError):  # a peer's text: no time, or none a computer holds
        return Time()
    if not -(2**31) <= seconds < 2**31:
        return Time()
    return Time(sec=seconds, nanosec=when.microsecond * 1000)


def received_text(time: Time) -> str:
    """Section 3's ``received_at`` text of a ``Time`` (UTC, to the second); "" for zero."""
    if time.sec == 0 and time.nanosec == 0:
        return ""
    return datetime.fromtimestamp(time.sec, UTC).isoformat(timespec="seconds")


def catalog_entries(
    known: Sequence[str | Mapping[str, Any]], limit: int | None = Catalog.MAX_ITEMS
) -> list[CatalogEntry]:
    """A catalog's entries (section 3) as ``CatalogEntry`` messages, within the message's
    bounds: the first ``limit`` (a catalog's ``Catalog.MAX_ITEMS``; None: all, as
    ``~/list_knowledge`` answers); an entry whose sequence is no string or beyond
    its bound left out (it names nothing a robot could ask for), an author or teacher beyond
    its bound left empty (a zenoh peer's catalog, relayed by the bridge, is the peer's word)."""
    out: list[CatalogEntry] = []
    for entry in known:
        fields = entry if isinstance(entry, Mapping) else {"sequence": entry}
        text = {
            k: v if isinstance(v, str) and len(v) <= bound else ""
            for k, bound in ENTRY_BOUNDS.items()
            for v in (fields.get(k),)
        }
        if not text["sequence"]:
            continue
        out.append(CatalogEntry(**text, received_at=received_time(fields.get("received_at"))))
        if len(out) == limit:
            break
    return out


def entry_fields(entry: CatalogEntry) -> dict[str, str] | None:
    """A received ``CatalogEntry`` as section 3's catalog entry (``sequence``, and ``author``,
    ``teacher``, ``received_at`` when known); None for one with a field beyond its bound."""
    fields = {k: getattr(entry, k) for k in ENTRY_BOUNDS}
    if not fields["sequence"] or any(len(v) > ENTRY_BOUNDS[k] for k, v in fields.items()):
        return None
    fields["received_at"] = received_text(entry.received_at)
    return {k: v for k, v in fields.items() if v}


class ShownTopics:
    """A robot's events, tree snapshot and catalog on ``node``, as ``PREFIX/events``,
    ``PREFIX/tree`` and ``PREFIX/catalog`` (section 11): the events of ``log`` as they are
    recorded (signed with ``identity`` if given), the tree and the catalog when :meth:`show`
    finds them changed. Each publisher takes ROS's QoS overrides by parameter."""

    def __init__(
        self,
        node: Node,
        name: str,
        entries: Entries,
        log: TransferLog,
        identity: Identity | None = None,
        prefix: str = "~",
    ) -> None:
        self.node, self.name, self.log = node, name, log
        self._entries = entries
        overrides = QoSOverridingOptions.with_default_policies

        def options() -> dict[str, Any]:
            return {"qos_overriding_options": overrides(), "event_callbacks": quiet()}

        events = node.create_publisher(FleetEvent, f"{prefix}/events", events_qos(), **options())
        self._tree = node.create_publisher(TreeSnapshot, f"{prefix}/tree", latched(), **options())
        self._catalog = node.create_publisher(Catalog, f"{prefix}/catalog", latched(), **options())
        self.catalog_topic = self._catalog.topic_name
        """This robot's own catalog topic, full name (what :class:`FleetCatalogs` skips)."""
        self._publishers = [events, self._tree, self._catalog]
        self._events = EventPublisher(name, lambda data: events.publish(event_msg(data)), identity)
        log.add_sink(self._events)
        self.snapshots = 0
        """Snapshots published so far (the last one's ``number``)."""
        self._shown_tree: str | None = None
        self._shown_object: Tree | None = None
        self._shown_catalog: list[str | dict[str, Any]] | None = None

    def show(self, tree: Tree, periodic: bool = False) -> None:
        """Publish the tree snapshot and the catalog if they changed since last shown; with
        ``periodic``, the snapshot even if it did not (``changed`` false). A tree is immutable
        and a running tree holds a new one after each change (section 4.2), so the very
        object shown last is not formatted again: a robot shows at every tick."""
        if tree is self._shown_object and not periodic:
            text = self._shown_tree
        else:
            text = format_tree(tree, "compact")
            self._shown_object = tree
        changed = text != self._shown_tree
        if text is not None and (changed or periodic):
            self.snapshots += 1
            self._tree.publish(
                TreeSnapshot(
                    stamp=self.node.get_clock().now().to_msg(),
                    peer=self.name,
                    changed=changed,
                    number=self.snapshots,
                    tree=text,
                )
            )
            self._shown_tree = text
        known = self._entries()
        if known != self._shown_catalog:
            self._catalog.publish(Catalog(peer=self.name, items=catalog_entries(known)))
            self._shown_catalog = known

    def entries(self) -> list[CatalogEntry]:
        """What the robot knows, as catalog entries (``~/list_knowledge`` answers with them)."""
        return catalog_entries(self._entries(), None)

    def close(self) -> None:
        """Stop publishing (the node stays)."""
        self.log.remove_sink(self._events)
        for publisher in self._publishers:
            self.node.destroy_publisher(publisher)
        self._publishers = []


class Services:
    """What a fleet member offers on ROS 2, whoever hosts it (section 11): ``PREFIX/
    list_knowledge`` (what it knows, as catalog entries) and ``PREFIX/forget`` (a learned item
    forgotten; innate knowledge never), under the prefix its :class:`ShownTopics` uses, so ``ktbt
    ros2 list`` and ``forget`` reach the lifecycle node and an embedded robot alike. After a
    forget, ``changed`` is called (the host shows its tree and catalog again). A request whose
    reading raises is answered with the reason and logged (section 2.1)."""

    def __init__(
        self,
        node: Node,
        member: FleetMember,
        shown: ShownTopics,
        changed: Callable[[], None],
        prefix: str = "~",
    ) -> None:
        self.node, self.member, self.shown, self.changed = node, member, shown, changed
        self._made = [
            node.create_service(ListKnowledge, f"{prefix}/list_knowledge", self._on_list),
            node.create_service(Forget, f"{prefix}/forget", self._on_forget),
        ]

    def _on_list(self, request: Any, response: Any) -> Any:
        response.items = self.shown.entries()
        return response

    def _on_forget(self, request: Any, response: Any) -> Any:
        """``success`` and ``code`` (``Forget.Response``'s constants), and ``message`` saying
        why not, within its bound."""
        agent, logger = self.member.agent, self.node.get_logger()

        def refuse(code: int, message: str) -> Any:
            response.success, response.code = False, code
            bound = BOUNDS["message"]  # Forget.srv's message: string<=1024, as an error's
            response.message = message if len(message) <= bound else message[: bound - 3] + "..."
            return response

        bound = BOUNDS["sequence"]  # Forget.srv: string<=4096 sequence
        if len(request.sequence) > bound:
            return refuse(
                Forget.Response.INVALID,
                f"sequence: {len(request.sequence)} characters, more than its bound ({bound})",
            )
        try:
            key = sequence_key(read_sequence(request.sequence))
        except StringBTError as err:
            line = str(err).splitlines()[0]  # its column, code and reason (no excerpt)
            return refuse(Forget.Response.INVALID, f"sequence: {line}")
        except Exception as exc:  # a caller's bytes the reader failed on (section 2.1)
            refuse(Forget.Response.INVALID, f"sequence: {internal_error(exc)}")
            logger.warning(f"{agent.name} refused a forget request: {response.message}")
            return response
        item = agent.knowledge.lookup(key)
        if not agent.forget(key):
            if item is None:
                return refuse(Forget.Response.NOT_KNOWN, f"{show_key(key)} is not known")
            return refuse(
                Forget.Response.INNATE,
                f"{show_key(key)} is innate: only learned items are forgotten",
            )
        response.success, response.code = True, Forget.Response.FORGOTTEN
        logger.info(f"{agent.name}: forgot {show_key(key)} (asked)")
        self.member.forgot(key)
        self.changed()
        return response

    def close(self) -> None:
        for service in self._made:
            self.node.destroy_service(service)
        self._made = []


class FleetCatalogs:
    """The other robots' catalogs, as a learner told no sequences reads them (section 4.5), and
    as the bridge reads the ROS robots it mirrors (section 11, "Bridge"): every topic of type
    ``ktbt_interfaces/msg/Catalog`` on the graph with a publisher, but ``own`` and those
    ``skip`` names, is followed, latched, as :meth:`refresh` finds it (at most ``limit``; one
    beyond is refused once); :meth:`read` gives what each lists, by peer, in the form
    :class:`ktbt_proto.exchange.member.ListedSequences` reads, and ``heard``, if given, is told
    of each catalog read (its topic, the peer it names as given, its entries). ``version``
    counts the catalogs received, so a learner reads again when one changed. A catalog that is
    too large or does not deserialize is refused with a WARNING, and read no further."""

    def __init__(
        self,
        node: Node,
        own: str = "",
        *,
        skip: Callable[[str], bool] | None = None,
        limit: int = MAX_CATALOGS,
        heard: Callable[[str, str, list[dict[str, str]]], None] | None = None,
        fleet: Callable[[], set[str]] | None = None,
        per_source: int | None = None,
    ) -> None:
        self.node, self.own, self.limit, self.heard = node, own, limit, heard
        self.fleet = fleet
        self.per_source = per_source
        """Given, at most this many topics are followed of one publishing participant
        (:func:`participants`), so one process inventing topics cannot take every place."""
        self._sources: dict[str, frozenset[str]] = {}
        """Topic followed -> the participants publishing it when it was found."""
        """The nodes of this robot's fleet (``Ros2Transport.peers``: those reading its query
        topic); given, a catalog is followed only if one of them publishes it, so that a fleet
        on other topics of the same graph is not read (section 11)."""
        self.skip = skip or (lambda topic: False)
        self.version = 0
        self.refused = 0
        self._lock = threading.Lock()
        self._subscriptions: dict[str, Any] = {}
        self._warn = Throttle(self.node.get_logger().warning)
        self._ignored: set[str] = set()
        """Topics beyond ``limit``, refused once each (at most ``4 * limit`` remembered)."""
        self._refreshed, self._taken = -math.inf, -1
        self._found: dict[str, tuple[str, list[dict[str, str]]]] = {}
        """Topic -> (the peer it names, its entries)."""
        self._fresh: dict[str, tuple[str, tuple[str, ...]]] = {}
        """Topic -> (the peer it names, its sequences), for catalogs received since
        :meth:`news` was last called."""

    def refresh(self) -> int:
        """Follow the catalog topics that appeared on the graph with a publisher (a topic only
        read has no catalog to give); how many are followed."""
        for topic, types in self.node.get_topic_names_and_types():
            if CATALOG_TYPE not in types or topic in self._subscriptions or topic == self.own:
                continue
            if topic in self._ignored or self.skip(topic) or not self._ours(topic):
                continue
            full = self._full(topic)
            if full is not None:
                if len(self._ignored) < 4 * self.limit:
                    self._ignored.add(topic)
                    self._refuse(f"catalog topic {topic[:80]}: {full}")
                continue
            self._subscriptions[topic] = self.node.create_subscription(
                Catalog, topic, partial(self._on_catalog, topic), latched(), raw=True,
                event_callbacks=watched(self.node, topic),
            )  # fmt: skip
        return len(self._subscriptions)

    def _full(self, topic: str) -> str | None:
        """Why ``topic`` cannot be followed now (the places are taken), or None; a topic
        followed is charged to the participants publishing it."""
        if len(self._subscriptions) >= self.limit:
            return f"{self.limit} already followed"
        if self.per_source is None:
            return None
        sources = participants(self.node, topic)
        for source in sorted(sources):
            taken = sum(source in s for s in self._sources.values())
            if taken >= self.per_source:
                return f"participant {source} publishes {taken} followed already"
        self._sources[topic] = sources
        return None

    def sources(self, topic: str) -> frozenset[str]:
        """The participants publishing ``topic`` (as found when it was followed)."""
        found = self._sources.get(topic)
        return found if found is not None else participants(self.node, topic)

    def _ours(self, topic: str) -> bool:
        """Whether ``topic`` has a publisher (of this fleet, when ``fleet`` is given)."""
        if self.fleet is None:
            return bool(self.node.count_publishers(topic))
        fleet = self.fleet()
        return any(
            f"{info.node_namespace.rstrip('/')}/{info.node_name}" in fleet
            for info in self.node.get_publishers_info_by_topic(topic)
        )

    def gone(self) -> list[str]:
        """The topics followed that have no publisher left: no longer followed, their
        catalogs forgotten (the bridge ends the mirror of a robot gone)."""
        ended = [t for t in self._subscriptions if not self.node.count_publishers(t)]
        for topic in ended:
            self.node.destroy_subscription(self._subscriptions.pop(topic))
            self._sources.pop(topic, None)
            with self._lock:
                if self._found.pop(topic, None) is not None:
                    self.version += 1
        return ended

    @guarded("a catalog")
    def _on_catalog(self, topic: str, data: bytes) -> None:
        if len(data) > MAX_CATALOG_BYTES:
            self._refuse(f"catalog on {topic}: {len(data)} bytes, more than {MAX_CATALOG_BYTES}")
            return
        try:
            msg = deserialize_message(data, Catalog)
        except Exception as exc:  # a hostile publisher's bytes: rclpy raises its own types
            self._refuse(f"catalog on {topic}: not a Catalog ({type(exc).__name__})")
            return
        read = (entry_fields(e) for e in msg.items[:MAX_ENTRIES])
        entries = [e for e in read if e is not None]
        peer = msg.peer if re.fullmatch(NAME, msg.peer) else topic
        with self._lock:
            self._found[topic] = (peer, entries)
            self._fresh[topic] = (peer, tuple(e["sequence"] for e in entries))
            self.version += 1
        if self.heard is not None:
            self.heard(topic, msg.peer[:200], entries)

    def _refuse(self, reason: str) -> None:
        self.refused += 1
        self._warn(f"refused: {reason}")

    def changed(self, now: float, appeared: bool) -> dict[str, list[dict[str, str]]] | None:
        """For a fleet member (:class:`~ktbt_proto.exchange.member.Catalogs`): the catalog
        topics that appeared followed (when a robot appeared, and every ``CATALOG_PERIOD``
        seconds of the host's clock, or when that clock went back), and what the catalogs list
        when one changed since the last call; else None."""
        if appeared or not 0 <= now - self._refreshed < CATALOG_PERIOD:
            self._refreshed = now
            self.refresh()
        if self.version == self._taken:
            return None
        self._taken = self.version
        return self.read()

    def learned(self, keys: list[str]) -> None:
        """For a fleet member (:class:`~ktbt_proto.exchange.member.Relay`): nothing to send
        (section 11), as its host republishes its latched catalog after the merge, and that
        republished catalog is the announcement its neighbours hear."""

    def news(self, now: float) -> list[tuple[str, tuple[str, ...]]]:
        """For a fleet member (:class:`~ktbt_proto.exchange.member.Relay`): every catalog
        received since the last call, as its peer's announcement of what it knows (section
        11); the catalog topics that appeared are followed every ``CATALOG_PERIOD``."""
        if now - self._refreshed >= CATALOG_PERIOD:
            self._refreshed = now
            self.refresh()
        with self._lock:
            fresh, self._fresh = list(self._fresh.values()), {}
        return fresh

    def read(self) -> dict[str, list[dict[str, str]]]:
        """What each peer's catalog lists now, by peer (two topics naming one peer are told
        apart by the later one's topic)."""
        out: dict[str, list[dict[str, str]]] = {}
        with self._lock:
            for topic, (peer, entries) in sorted(self._found.items()):
                out[topic if peer in out else peer] = entries
        return out

    def close(self) -> None:
        for subscription in self._subscriptions.values():
            self.node.destroy_subscription(subscription)
        self._subscriptions = {}
