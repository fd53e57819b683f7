"""Groot2 monitoring of a live tree: BehaviorTree.CPP's Groot2 protocol, served for a LiveTree.

A :class:`Groot2Publisher` answers Groot2 (or ``btview``) as BehaviorTree.CPP's own
``Groot2Publisher`` does: ZeroMQ REP on ``port`` for requests, PUB on ``port + 1`` for the
breakpoint notices. It serves the running tree as BehaviorTree.CPP XML with node ids, the nodes'
statuses, the blackboard, transition recording, and hooks and breakpoints that replace a node's
result. Whenever a merge or a forget takes effect the tree gets a new UUID, so a client that sees
it change fetches the tree again and shows what was learned. spec/groot2.md says what is served,
byte by byte, and where this publisher differs from BehaviorTree.CPP's.

Statuses come from a :class:`~ktbt_proto.runtime.Probe` the publisher puts around every node at
the tree's next tick boundary; a tree that nobody serves runs exactly as compiled. Needs the
``groot`` extra: ``pip install 'ktbt[groot]'``.
"""

from __future__ import annotations

import json
import logging
import secrets
import struct
import threading
import time
import uuid
import xml.etree.ElementTree as ET
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.knowledge import KnowledgeBase
from ktbt_proto.formatter import format_value
from ktbt_proto.interop.btcpp import to_xml
from ktbt_proto.items import show_sequence
from ktbt_proto.registry import Registry
from ktbt_proto.render import call_text
from ktbt_proto.runtime import Halt, LiveTree, Tick
from ktbt_proto.status import FAILURE, RUNNING, SUCCESS, Status
from ktbt_proto.tree import (
    Action,
    Condition,
    Container,
    Node,
    Placeholder,
    Tree,
    Visitor,
    Wait,
    walk,
)

try:
    import msgpack
    import zmq
except ImportError as exc:  # pragma: no cover - exercised without the extra
    raise ImportError(
        "Groot2 monitoring needs pyzmq and msgpack: pip install 'ktbt[groot]'"
    ) from exc

__all__ = ["PROTOCOL_ID", "Groot2Publisher", "knowledge_tree"]

log = logging.getLogger("ktbt.groot2")

PROTOCOL_ID = 2
"""``BT::Monitor::kProtocolID``."""
HEADER = struct.Struct("<BBI")
"""A request header: protocol id, request type, request id (little-endian)."""
MAX_UID = 0xFFFF
"""Node ids are 16 bits on the wire."""
MAX_TRANSITIONS = 1000
"""Transitions kept while recording, newest last (as BehaviorTree.CPP keeps them)."""
MAX_REQUEST = 1 << 20
"""Bytes a request frame may hold (spec/groot2.md section 6): the largest hook array is far less."""
HEARTBEAT = 5.0
"""Seconds without a request after which every hook is disabled (a client went away)."""

# Status bytes (spec/groot2.md section 3): BT::NodeStatus, and 10 + the status a node was in
# when its parent reset it to IDLE, as BehaviorTree.CPP shows nodes between ticks.
IDLE, RUNNING_BYTE, SKIPPED = 0, 1, 4
IDLE_FROM_RUNNING, IDLE_FROM_SUCCESS, IDLE_FROM_FAILURE = 11, 12, 13
_SAME = {SUCCESS: IDLE_FROM_SUCCESS, FAILURE: IDLE_FROM_FAILURE, RUNNING: RUNNING_BYTE}
_INVERTED = {SUCCESS: IDLE_FROM_FAILURE, FAILURE: IDLE_FROM_SUCCESS, RUNNING: RUNNING_BYTE}
_FAILING = {SUCCESS: IDLE_FROM_FAILURE, FAILURE: IDLE_FROM_FAILURE, RUNNING: IDLE_FROM_FAILURE}
_RAW = {RUNNING_BYTE: 1, IDLE_FROM_SUCCESS: 2, IDLE_FROM_FAILURE: 3, IDLE_FROM_RUNNING: 0}
"""What a recorded transition says for a status byte: the status entered (IDLE after a halt)."""
_FORCED = {"SUCCESS": SUCCESS, "FAILURE": FAILURE}
_STATUS_NAMES = ("IDLE", "RUNNING", "SUCCESS", "FAILURE", "SKIPPED")
PRE, POST = 0, 1
BREAKPOINT, REPLACE = 0, 1


class RequestRefused(Exception):
    """A request answered with the protocol's error reply; the message is its second frame."""


@dataclass(eq=False)
class _Hook:
    """``BT::Monitor::Hook``: stop (breakpoint) or not (replace), then return desired_status."""

    uid: int
    position: int
    mode: int = BREAKPOINT
    enabled: bool = True
    once: bool = False
    desired_status: str = "SKIPPED"
    ready: bool = False

    def json(self) -> dict[str, object]:
        return {
            "desired_status": self.desired_status,
            "enabled": self.enabled,
            "mode": self.mode,
            "once": self.once,
            "position": self.position,
            "uid": self.uid,
        }


@dataclass(frozen=True, slots=True)
class _Spot:
    """Where a node's status shows: a status byte's offset in the buffer and how to read it
    (a negated condition shows twice, as ``Inverter`` and inverted as its condition; an empty
    placeholder's ``AlwaysFailure`` fails whenever the placeholder ticks)."""

    uid: int
    offset: int
    table: dict[Status, int]


class _View:
    """One version of the tree as served: its UUID, XML, status buffer and node ids."""

    def __init__(self, tree: Tree) -> None:
        self.tree = tree
        self.uuid = uuid.uuid4().bytes  # version 4 and variant bits where BT.CPP sets them
        self.error = ""
        self.xml = b""
        self.spots: list[list[_Spot]] = []  # by node index (pre-order)
        self.owner: dict[int, tuple[int, bool]] = {}  # uid -> (node index, hookable)
        self.halts: dict[int, Halt] = {}  # node index -> its compiled halt
        self.status = bytearray()
        try:  # built in the ticking thread: nothing may raise into LiveTree.tick()
            self._build(tree)
        except StringBTError as err:
            self.error = f"the tree cannot be written as BehaviorTree.CPP XML: {err}"
        except RequestRefused as err:
            self.error = str(err)
        except Exception as err:  # a bug in the XML walk: the tree runs on, unserved
            log.exception("groot2: the tree cannot be served")
            self.error = f"internal error: {type(err).__name__}"
        if self.error:
            self.spots = [[] for _ in self.spots]
            self.owner, self.status = {}, bytearray()

    def _build(self, tree: Tree) -> None:
        doc = ET.fromstring(to_xml(tree))
        body = doc.find("BehaviorTree")
        if body is None or len(body) != 1:
            raise RuntimeError("the tree's XML has no single <BehaviorTree> body")
        body.set("_fullpath", "")
        elements: list[tuple[ET.Element, int, dict[Status, int], bool]] = []
        nodes = [node for node, _ in tree.walk()]
        self.spots = [[] for _ in nodes]
        index = 0
        todo: list[tuple[ET.Element, Node]] = [(body[0], tree.root)]
        while todo:  # the XML in document order is the tree in pre-order, plus two extras
            el, node = todo.pop()
            elements.append((el, index, _SAME, True))
            if isinstance(node, Condition) and node.negated and len(el) == 1:
                elements.append((el[0], index, _INVERTED, False))
                if "name" not in el[0].attrib:
                    el[0].set("name", _leaf_name(node).removeprefix("!"))
            elif isinstance(node, Placeholder) and not node.children and len(el) == 1:
                elements.append((el[0], index, _FAILING, False))
            elif isinstance(node, Container):
                if len(el) != len(node.children):
                    raise RuntimeError(f"<{el.tag}> does not hold its node's children")
                todo.extend(reversed(list(zip(el, node.children, strict=True))))
            if not isinstance(node, Container) and "name" not in el.attrib:
                el.set("name", _leaf_name(node))
            index += 1
        if len(elements) > MAX_UID:
            raise RequestRefused(
                f"the tree has {len(elements)} nodes; Groot2 numbers {MAX_UID} at most"
            )
        self.status = bytearray(3 * len(elements))
        for uid, (el, at, table, hookable) in enumerate(elements, start=1):
            el.set("_uid", str(uid))
            struct.pack_into("<H", self.status, 3 * uid - 3, uid)
            self.spots[at].append(_Spot(uid, 3 * uid - 1, table))
            self.owner[uid] = (at, hookable)
        ET.indent(doc, space="    ")
        self.xml = ET.tostring(doc, encoding="unicode").encode()


class _LeafNames(Visitor[str]):
    """A leaf as stringBT writes it, for Groot2 to show: ``TargetSeen(colour=1)``, ``!_inZoneF``
    (the command line's own forms: ``items.show_sequence``, ``render``'s calls)."""

    def condition(self, node: Condition) -> str:
        return show_sequence([node])

    def action(self, node: Action) -> str:
        return call_text(node.name, node.args)

    def wait(self, node: Wait) -> str:
        return f"wait {format_value(node.duration)} {node.unit}"

    def other(self, node: Node) -> str:
        raise RequestRefused(f"a {type(node).__name__} is not a leaf")


_leaf_name = _LeafNames().visit


def _json_value(value: Any) -> Any:
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, list | tuple):
        return [_json_value(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _json_value(v) for k, v in sorted(value.items(), key=lambda kv: str(kv[0]))}
    return str(value)


class Groot2Publisher:
    """Serve ``tree`` (a :class:`LiveTree`, or an agent: its control tree) to Groot2.

    Binds ``tcp://{host}:{port}`` (REP) and ``port + 1`` (PUB); loopback by default, ``host="*"``
    for every interface (anyone who reaches the port can force the robot's nodes' results).
    Raises ``OSError`` if a port is taken. Close it (or use it as a context manager) to stop
    serving: the probe leaves the tree at its next tick boundary, and a tick waiting at a
    breakpoint goes on. ``stop``, an event the ticking program sets to end (on SIGTERM, say),
    releases a breakpoint too: a robot waiting for a client that never unlocks still stops.
    """

    def __init__(
        self,
        tree: Any,
        port: int = 1667,
        host: str = "127.0.0.1",
        stop: threading.Event | None = None,
    ) -> None:
        live = getattr(tree, "control", tree)
        if not isinstance(live, LiveTree):
            raise TypeError(f"Groot2 serves a LiveTree or an agent ticking one, not {tree!r}")
        self.live = live
        self.port = port
        self._stop = stop if stop is not None else threading.Event()
        """Set by whoever ticks the tree (a signal, say): a breakpoint waits no longer."""
        self.errors: Counter[str] = Counter()
        """Error replies sent, by reason (a hostile or confused client is counted, not fatal)."""
        self.requests = 0
        self.heartbeat = HEARTBEAT
        """Seconds without a request after which every hook is disabled (the client went away)."""
        self._lock = threading.Condition()
        self._view: _View | None = None
        self._hooks: dict[tuple[int, int], _Hook] = {}
        self._hooks_enabled = True
        self._recording = False
        self._record_start = 0.0
        self._transitions: deque[bytes] = deque(maxlen=MAX_TRANSITIONS)
        self._closed = False
        self._last_request = time.monotonic()
        self._context = zmq.Context()
        self._rep = self._context.socket(zmq.REP)
        self._pub = self._context.socket(zmq.PUB)
        self._pub_lock = threading.Lock()
        for sock in (self._rep, self._pub):
            sock.setsockopt(zmq.LINGER, 0)
            sock.setsockopt(zmq.SNDTIMEO, 1000)
        self._rep.setsockopt(zmq.MAXMSGSIZE, MAX_REQUEST)  # a larger one drops its sender
        try:
            self._rep.bind(f"tcp://{host}:{port}")
            self._pub.bind(f"tcp://{host}:{port + 1}")
        except zmq.ZMQError as err:
            self._context.destroy(linger=0)
            raise OSError(f"cannot serve Groot2 on {host}:{port} and {port + 1}: {err}") from None
        self._thread = threading.Thread(target=self._serve, name=f"groot2:{port}", daemon=True)
        try:
            live.probe(self)
        except RuntimeError:
            self._context.destroy(linger=0)
            raise
        self._thread.start()

    # -- the probe (called by the live tree, in its ticking thread) ------------------------------

    def rewired(self, tree: Tree) -> None:
        with self._lock:
            if self._view is not None and self._view.tree == tree:
                return  # the same tree: new wrappers (recording toggled), nothing else changed
            changed = self._view is not None
            self._view = _View(tree)
            if changed:  # node ids now name other nodes: hooks on the old ones must go
                self._drop_hooks()
                log.info("groot2: the tree changed; new uuid %s", self._view.uuid.hex())

    def _spots(self, index: int) -> list[_Spot]:
        view = self._view
        return view.spots[index] if view is not None and index < len(view.spots) else []

    def tick(self, index: int, tick: Tick) -> Tick:
        spots = self._spots(index)
        view = self._view
        if not spots or view is None:
            return tick
        show = self._shower(spots, view.status)

        def probed() -> Status:
            status = tick()
            show(status)
            return status

        # Hooks are looked up at tick time: inserting or removing one needs no new wrappers.
        hooks, hooked = self._hooks, self._hooked(index, probed, show, spots[0], view)

        def entry() -> Status:
            return hooked() if hooks else probed()

        return entry

    def holds(self, index: int, holds: Callable[[], object]) -> Callable[[], object]:
        spots = self._spots(index)
        view = self._view
        if not spots or view is None:
            return holds
        show = self._shower(spots, view.status)

        def probed() -> object:
            result = holds()
            show(SUCCESS if result else FAILURE)
            return result

        def as_tick() -> Status:
            return SUCCESS if probed() else FAILURE

        hooks, hooked = self._hooks, self._hooked(index, as_tick, show, spots[0], view)

        def predicate() -> object:
            return hooked() is SUCCESS if hooks else probed()

        return predicate

    def halt(self, index: int, halt: Halt) -> Halt:
        spots = self._spots(index)
        view = self._view
        if not spots or view is None:
            return halt
        view.halts[index] = halt
        status = view.status
        offsets = [s.offset for s in spots]
        uids = [s.uid for s in spots]

        def probed() -> None:
            halt()
            for offset in offsets:
                status[offset] = IDLE_FROM_RUNNING
            if self._recording:
                for uid in uids:
                    self._record(uid, IDLE_FROM_RUNNING)

        return probed

    def _shower(self, spots: list[_Spot], status: bytearray) -> Callable[[Status], None]:
        """Write a node's status into the buffer (and, while recording, its transitions)."""
        if len(spots) == 1 and not self._recording:
            offset, table = spots[0].offset, spots[0].table

            def show_one(result: Status) -> None:
                status[offset] = table[result]

            return show_one
        record = self._record if self._recording else None

        def show(result: Status) -> None:
            for spot in spots:
                byte = spot.table[result]
                if record is not None and status[spot.offset] != byte:
                    record(spot.uid, byte)
                status[spot.offset] = byte

        return show

    def _record(self, uid: int, byte: int) -> None:
        micros = int((time.monotonic() - self._record_start) * 1e6)
        raw = struct.pack("<Q", max(micros, 0))[:6] + struct.pack("<HB", uid, _RAW.get(byte, 0))
        self._transitions.append(raw)

    def _hooked(
        self, index: int, tick: Tick, show: Callable[[Status], None], spot: _Spot, view: _View
    ) -> Tick:
        """A node with a hook: BehaviorTree.CPP's pre- and post-tick callbacks. A forced result
        ends the node's activation: if it was running, it is halted first."""
        uid, offset, status = spot.uid, spot.offset, view.status

        def halt() -> None:
            compiled = view.halts.get(index)
            if status[offset] == RUNNING_BYTE and compiled is not None:
                compiled()

        def hooked() -> Status:
            pre = self._hooks.get((PRE, uid))
            if pre is not None:
                forced = self._run(pre)
                if forced is not None:
                    halt()
                    show(forced)
                    return forced
            result = tick()
            post = self._hooks.get((POST, uid))
            if post is not None:
                forced = self._run(post)
                if forced is not None:
                    if result is RUNNING:
                        halt()
                    show(forced)
                    return forced
            return result

        return hooked

    def _run(self, hook: _Hook) -> Status | None:
        """``runHook``: announce the breakpoint, wait while it is one, then say what to return."""
        with self._lock:
            if not hook.enabled or not self._hooks_enabled or self._closed or self._stop.is_set():
                return None
        header = HEADER.pack(PROTOCOL_ID, ord("N"), secrets.randbits(32))
        with self._pub_lock:
            try:
                self._pub.send_multipart([header, str(hook.uid).encode()], zmq.NOBLOCK)
            except zmq.ZMQError:
                return None
        with self._lock:
            if hook.mode == BREAKPOINT:
                # In slices: the stop event is set from outside the lock (a signal handler).
                while not self._lock.wait_for(
                    lambda: (
                        hook.ready
                        or not hook.enabled
                        or not self._hooks_enabled
                        or self._closed
                        or self._stop.is_set()
                    ),
                    timeout=0.1,
                ):
                    pass
                hook.ready = False
            if not hook.enabled or not self._hooks_enabled or self._closed or self._stop.is_set():
                return None
            forced = _FORCED.get(hook.desired_status)
            if hook.once:
                hook.enabled = False
                if self._hooks.get((hook.position, hook.uid)) is hook:
                    del self._hooks[(hook.position, hook.uid)]
            return forced

    # -- the server ---------------------------------------------------------------------------

    def _serve(self) -> None:
        rep = self._rep
        rep.setsockopt(zmq.RCVTIMEO, 100)  # to notice close() and a client gone quiet
        while not self._closed:
            try:
                frames = rep.recv_multipart()
            except zmq.Again:
                self._heartbeat()
                continue
            except zmq.ZMQError:
                break
            self.requests += 1
            with self._lock:
                self._last_request = time.monotonic()
                if not self._hooks_enabled:
                    self._hooks_enabled = True
            try:
                reply = self._answer(frames)
            except RequestRefused as err:
                reason = str(err)
                self.errors[reason.split(":")[0]] += 1
                log.info("groot2: error reply: %s", reason)
                reply = [b"error", reason.encode()]
            except Exception as err:  # a bug here must not take the robot's monitor down
                log.exception("groot2: request failed")
                self.errors["internal error"] += 1
                reply = [b"error", f"internal error: {type(err).__name__}".encode()]
            try:
                rep.send_multipart(reply)  # REP drops a reply its peer does not read: no block
            except zmq.ZMQError:
                if self._closed:
                    break

    def _heartbeat(self) -> None:
        with self._lock:
            if self._hooks_enabled and time.monotonic() - self._last_request > self.heartbeat:
                self._hooks_enabled = False  # wakes every breakpoint: the client went away
                self._lock.notify_all()

    def _answer(self, frames: list[bytes]) -> list[bytes]:
        head = frames[0]
        if len(head) != HEADER.size:
            raise RequestRefused("wrong request header")
        protocol, kind, request_id = HEADER.unpack(head)
        if protocol != PROTOCOL_ID:
            raise RequestRefused(
                f"wrong protocol id: {protocol}, this publisher speaks {PROTOCOL_ID}"
            )
        with self._lock:
            view = self._view
        if view is None:
            raise RequestRefused("the tree has not ticked since the publisher started")
        reply = [HEADER.pack(PROTOCOL_ID, kind, request_id) + view.uuid]
        letter = chr(kind)
        if letter in "TSB" and view.error:
            raise RequestRefused(view.error)
        if letter == "T":
            return [*reply, view.xml]
        if letter == "S":
            return [*reply, bytes(view.status)]
        if letter in "BIRUr" and len(frames) != 2:
            raise RequestRefused("must be 2 parts message")
        if letter == "B":
            return [*reply, self._blackboard(frames[1])]
        if letter == "I":
            self._insert(_json(frames[1]), view)
        elif letter == "U":
            self._unlock(_json(frames[1]))
        elif letter == "R":
            self._remove(_json(frames[1]))
        elif letter == "A":
            with self._lock:
                self._drop_hooks()
        elif letter == "X":
            with self._lock:
                for hook in self._hooks.values():
                    hook.enabled = False
                self._lock.notify_all()
        elif letter == "D":
            with self._lock:
                dump = [hook.json() for hook in self._hooks.values()]
            return [*reply, json.dumps(dump, separators=(",", ":"), sort_keys=True).encode()]
        elif letter == "r":
            return reply + self._toggle(frames[1])
        elif letter == "t":
            with self._lock:
                taken, self._transitions = self._transitions, deque(maxlen=MAX_TRANSITIONS)
            return [*reply, b"".join(taken)]
        else:
            raise RequestRefused("Request not recognized")
        return reply

    def _blackboard(self, names: bytes) -> bytes:
        dump: dict[str, object] = {}
        for name in dict.fromkeys(names.decode("utf-8", "replace").split(";")):  # each once
            if name == "MainTree":
                entries = dict(self.live.blackboard)
                dump[name] = _json_value(entries) if entries else None
        packed: bytes = msgpack.packb(dump or None, use_bin_type=True)
        return packed

    def _toggle(self, command: bytes) -> list[bytes]:
        with self._lock:
            if command == b"start":
                self._record_start = time.monotonic()  # deltas; wall time only in the reply
                self._transitions.clear()
                self._recording = True
                started = [str(int(time.time() * 1e6)).encode()]
            elif command == b"stop":
                self._recording, started = False, []
            else:
                return []
        self.live.probe(self)  # wrappers that record (or no longer do)
        return started

    def _insert(self, received: object, view: _View) -> None:
        entries = received if isinstance(received, list) else [received]
        hooks = [_hook_from(entry) for entry in entries]
        for hook in hooks:  # every one checked before any is stored: all or nothing
            owner = view.owner.get(hook.uid)
            if owner is not None and not owner[1]:
                raise RequestRefused(
                    f"node {hook.uid} is part of its parent's node: hook its parent"
                )
        self._store(hooks, view)  # the wrappers look hooks up as they tick

    def _store(self, hooks: list[_Hook], view: _View) -> None:
        with self._lock:
            for hook in hooks:
                if hook.uid not in view.owner:
                    continue  # as BehaviorTree.CPP: an unknown node id is ignored
                old = self._hooks.get((hook.position, hook.uid))
                if old is None:
                    self._hooks[(hook.position, hook.uid)] = hook
                    continue
                was_breakpoint = old.mode == BREAKPOINT
                old.mode, old.enabled = hook.mode, hook.enabled
                old.once, old.desired_status = hook.once, hook.desired_status
                if was_breakpoint and old.mode == REPLACE:
                    old.ready = True
                self._lock.notify_all()

    def _unlock(self, received: object) -> None:
        fields = _fields(received, uid=int, desired_status=str, position=int, remove_when_done=bool)
        with self._lock:
            hook = self._hooks.get((_int(fields["position"]), _int(fields["uid"])))
            if hook is None:
                raise RequestRefused("Node ID not found")
            status = str(fields["desired_status"])
            hook.desired_status = status if status in _FORCED else "SKIPPED"
            hook.once = hook.once or bool(fields["remove_when_done"])
            if hook.mode == BREAKPOINT:
                hook.ready = True
                self._lock.notify_all()

    def _remove(self, received: object) -> None:
        fields = _fields(received, uid=int, position=int)
        with self._lock:
            hook = self._hooks.pop((_int(fields["position"]), _int(fields["uid"])), None)
            if hook is None:
                raise RequestRefused("Node ID not found")
            hook.enabled = False
            self._lock.notify_all()

    def _drop_hooks(self) -> None:
        for hook in self._hooks.values():
            hook.enabled = False
        self._hooks.clear()
        self._lock.notify_all()

    # -- life ---------------------------------------------------------------------------------

    @property
    def uuid(self) -> bytes:
        """The UUID of the tree as served now (a new one after every merge or forget)."""
        with self._lock:
            return self._view.uuid if self._view is not None else b""

    def close(self) -> None:
        """Stop serving; the probe leaves the tree at its next tick boundary."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._drop_hooks()
        self._thread.join()
        self.live.unprobe(self)
        with self._pub_lock:
            self._context.destroy(linger=0)

    def __enter__(self) -> Groot2Publisher:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()


def _json(frame: bytes) -> object:
    try:
        return json.loads(frame)
    except (ValueError, RecursionError) as err:
        raise RequestRefused(f"[json.exception.parse_error] {err}") from None


def _fields(received: object, **types: type) -> dict[str, object]:
    if not isinstance(received, dict):
        raise RequestRefused("[json.exception.type_error] a JSON object was expected")
    out: dict[str, object] = {}
    for key, kind in types.items():
        value = received.get(key)
        if value is None:
            raise RequestRefused(f"[json.exception.out_of_range] key '{key}' not found")
        if type(value) is not kind:
            raise RequestRefused(f"[json.exception.type_error] '{key}' must be {kind.__name__}")
        out[key] = value
    return out


def _int(value: object) -> int:
    """A field ``_fields`` has checked is an int (a peer's JSON otherwise refused)."""
    if type(value) is not int:
        raise RequestRefused("[json.exception.type_error] an integer was expected")
    return value


def _hook_from(entry: object) -> _Hook:
    fields = _fields(
        entry, enabled=bool, uid=int, once=bool, mode=int, position=int, desired_status=str
    )
    uid, mode, position = (_int(fields[k]) for k in ("uid", "mode", "position"))
    status = str(fields["desired_status"])
    if not 0 <= uid <= MAX_UID or mode not in (BREAKPOINT, REPLACE) or position not in (PRE, POST):
        raise RequestRefused("[json.exception.out_of_range] uid, mode or position out of range")
    if status not in _STATUS_NAMES:
        raise RequestRefused(f"Cannot convert this to NodeStatus: {status}")
    return _Hook(uid, position, mode, bool(fields["enabled"]), bool(fields["once"]), status)


def knowledge_tree(knowledge: KnowledgeBase) -> LiveTree:
    """What a teacher that ticks no tree (``ktbt peer serve``) shows Groot2: its items, each in a
    placeholder named for its segment, under a reactive selector, with stand-in behaviours that
    are never ticked (spec/groot2.md section 2)."""
    tree = knowledge.tree()
    reg = Registry()
    for node, _ in walk(tree.root):
        if isinstance(node, Condition) and not reg.has_condition(node.name):
            reg.add_condition(node.name, _never)
        elif isinstance(node, Action) and not reg.has_action(node.name):
            reg.add_action(node.name, _never)
    return LiveTree(tree, reg)


def _never(bb: object, **args: object) -> Status:
    return FAILURE
