"""The monitor's ROS 2 ear (``ktbt monitor --ros2``): KT-BT robots found through the ROS graph,
shown beside zenoh peers (spec/protocol.md sections 10 and 11).

A ``ktbt ros2 run`` node publishes its fleet events on ``~/events`` (type
``ktbt_interfaces/msg/FleetEvent``), its catalog on a latched ``~/catalog`` and its tree on a
latched ``~/tree``. Every few tenths of a second this listener reads the graph, subscribes to
each such topic it has not yet, and feeds what comes into the same :class:`FleetState` the
zenoh listener feeds, through the same checks (:meth:`Listener.hear`): an event is read back
into section 10's JSON by its fields alone (``node.event_json``), so its signature verifies.

A ROS topic does not say who published: a node's topics (its namespace, ``/robot1/ktbt``)
are bound to the first robot name heard on any of them, and what names another robot there is
dropped as ``wrong key``, as an event on another's zenoh key is. A robot is present while its
catalog has a publisher on the graph, gone when none is left. What the monitor holds of ROS
robots is bounded as the rest: at most :data:`MAX_NODES` nodes followed.

rclpy runs in a context of the listener's own, spun in a thread of its own, so the monitor's
web side never waits on ROS.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

import rclpy
from ktbt_interfaces.msg import Catalog, FleetEvent, TreeSnapshot
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.utilities import try_shutdown

from ktbt_proto.exchange.events import PREFIX
from ktbt_proto.exchange.messages import MAX_MESSAGE_BYTES
from ktbt_proto.exchange.refusals import internal_error
from ktbt_proto.interop.ros2.showing import event_json, events_qos, latched
from ktbt_proto.tools.monitor.listen import shown_tree
from ktbt_proto.tools.monitor.state import MAX_PEERS, PEER_NAME, FleetState

_M = TypeVar("_M")

TYPES = {
    "ktbt_interfaces/msg/FleetEvent": "events",
    "ktbt_interfaces/msg/Catalog": "catalog",
    "ktbt_interfaces/msg/TreeSnapshot": "tree",
}
GRAPH_PERIOD = 0.5
"""Seconds between two reads of the ROS graph."""
MAX_NODES = MAX_PEERS
"""ROS nodes followed at most; one beyond is dropped and counted."""


class RosListener:
    """Feeds ``fleet`` from the ROS 2 graph until closed; ``hear`` is the zenoh listener's
    check of an event (:meth:`Listener.hear`). ``args``: ROS arguments (``--ros-args ...``)."""

    def __init__(
        self,
        fleet: FleetState,
        hear: Callable[[str, bytes], None],
        args: list[str] | None = None,
    ) -> None:
        self.fleet, self.hear = fleet, hear
        self._context = Context()
        rclpy.init(args=["ktbt-monitor", *(args or [])], context=self._context)
        self.node = rclpy.create_node("ktbt_monitor", context=self._context)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self.node)
        self._subs: dict[str, Any] = {}
        """Topic -> its subscription."""
        self._owner: dict[str, str] = {}
        """A node's path (``/robot1/ktbt``) -> the robot named first on its topics."""
        self._paths: set[str] = set()
        """The nodes followed, by path."""
        self._refused: set[str] = set()
        self._trees: dict[str, str] = {}
        """A robot's name -> its latest tree, compact stringBT."""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        next_read = 0.0
        while not self._stop.is_set():
            try:
                now = time.monotonic()
                if now >= next_read:
                    next_read = now + GRAPH_PERIOD
                    self._read_graph()
                self._executor.spin_once(timeout_sec=0.1)
            except Exception as exc:  # a closing context, or a peer's junk: never the end
                if self._stop.is_set():
                    return
                self.fleet.drop("malformed", f"ROS: {type(exc).__name__}: {exc}"[:200])

    def _read_graph(self) -> None:
        """Subscribe to every KT-BT topic not yet followed; a robot whose catalog has no
        publisher left is gone."""
        for topic, types in self.node.get_topic_names_and_types():
            kinds = [TYPES[t] for t in types if t in TYPES]
            if not kinds or topic in self._subs:
                continue
            path, _, leaf = topic.rpartition("/")
            if leaf != kinds[0]:
                continue  # the robots' own names: ~/events, ~/catalog, ~/tree
            if path not in self._paths:
                if len(self._paths) >= MAX_NODES:
                    if path not in self._refused and len(self._refused) < MAX_NODES:
                        self._refused.add(path)  # said once
                        self.fleet.drop("full", f"ROS node {path[:100]}: {MAX_NODES} followed")
                    continue
                self._paths.add(path)
            self._subscribe(topic, path, kinds[0])
        for topic in [t for t in self._subs if t.endswith("/catalog")]:
            if self.node.count_publishers(topic) == 0:
                self.node.destroy_subscription(self._subs.pop(topic))
                path = topic.rpartition("/")[0]
                owner = self._owner.get(path)
                if owner is not None:
                    self.fleet.peer_left(owner)

    def _subscribe(self, topic: str, path: str, kind: str) -> None:
        if kind == "events":
            self._subs[topic] = self.node.create_subscription(
                FleetEvent, topic, lambda m: self._read(self._on_event, path, m), events_qos()
            )
        elif kind == "catalog":
            self._subs[topic] = self.node.create_subscription(
                Catalog, topic, lambda m: self._read(self._on_catalog, path, m), latched()
            )
        else:
            self._subs[topic] = self.node.create_subscription(
                TreeSnapshot, topic, lambda m: self._read(self._on_tree, path, m), latched()
            )

    def _read(self, on: Callable[[str, _M], None], path: str, msg: _M) -> None:
        """One message of a robot's topic; whatever reading it raises is counted malformed,
        never the end of the spin (spec/protocol.md section 2.1)."""
        try:
            on(path, msg)
        except Exception as exc:
            self.fleet.drop("malformed", f"a message on {path[:100]}: {internal_error(exc)}")

    def _owned(self, path: str, name: str, what: str) -> bool:
        """Whether ``name`` may speak on the node ``path``'s topics: the first name heard
        there binds them."""
        if not PEER_NAME.fullmatch(name):
            self.fleet.drop("malformed", f"{what} on {path[:100]} names no robot")
            return False
        owner = self._owner.setdefault(path, name)
        if owner != name:
            self.fleet.drop("wrong key", f"{what} of {name} on {path[:100]}, {owner}'s topics")
            return False
        return True

    def _on_event(self, path: str, msg: FleetEvent) -> None:
        if self._owned(path, msg.peer, "an event"):
            try:
                data = event_json(msg)
            except (UnicodeError, ValueError) as exc:
                self.fleet.drop("malformed", f"an event on {path[:100]}: {exc}"[:200])
                return
            self.hear(f"{PREFIX}/{msg.peer}", data)

    def _on_catalog(self, path: str, msg: Catalog) -> None:
        if self._owned(path, msg.peer, "a catalog"):
            self.fleet.peer_joined(msg.peer)
            try:
                self.fleet.catalog(msg.peer, [e.sequence for e in msg.items])
            except Exception as exc:  # a robot's junk that got past the checks
                self.fleet.drop("malformed", f"catalog of {msg.peer}: {exc}"[:200])

    def _on_tree(self, path: str, msg: TreeSnapshot) -> None:
        """Keep a robot's latest tree, if within the message limit (section 1): what the
        monitor holds per robot stays bounded."""
        if not self._owned(path, msg.peer, "a tree"):
            return
        if len(msg.tree.encode("utf-8", "replace")) > MAX_MESSAGE_BYTES:
            self.fleet.drop("malformed", f"tree of {msg.peer}: over {MAX_MESSAGE_BYTES} bytes")
            return
        with self._lock:
            self._trees[msg.peer] = msg.tree

    def tree(self, name: str) -> str | None:
        """The latest tree the robot ``name`` published, as ``ktbt show``'s outline; None if
        it is not a ROS robot (or published none)."""
        with self._lock:
            text = self._trees.get(name)
        return None if text is None else shown_tree(self.fleet, name, text)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self._executor.shutdown(timeout_sec=1)
        self.node.destroy_node()
        try_shutdown(context=self._context)
