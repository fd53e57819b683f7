"""The ROS 2 knowledge transfer as a user compares it: the shipped lifecycle node (``ktbt ros2
run``, its default 100 Hz tick) against a hand-written rclpy pair (a node that asks on a topic,
one that answers), both pairs on the same executor and in the same process layout: one process
answering, one asking, for each pair. Run inside the benchmark's network namespace by
:mod:`benchmarks.bench_ros2`, one process per ``--role``:

* ``teacher-ours``: ``ktbt ros2 run --autostart --executor KIND`` itself (the command's own
  code, its ``main``), knowing ``colours.sbt``, with timing wrappers around the transport's
  query callback, its reading of a message and its serialiser; on its end it writes what they
  timed to ``--marks``.
* ``learner-ours``: the same lifecycle node (:class:`~ktbt_proto.tools.ros2.node.KtbtNode`,
  configured and activated as ``--autostart`` does, spun as the command spins it:
  ``spin_once(timeout_sec=0.1)`` in a loop), told one sequence to meet at a time through its
  ``sequences`` parameter; what it learned is forgotten between rounds as ``~/forget`` does
  (``agent.forget``, ``member.forgot``), untimed.
* ``learner-attach``: a user's node (``/attacher/bt``) ticking its py_trees tree on its own
  100 Hz timer, a robot attached to it with ``attach``'s defaults (its agent's timer every
  0.1 s), told with ``meet``; it asks a ``teacher-ours`` of its own on fleet topics of its own
  (``--topics /ktbt_attach``). Its round ends when the user's tick that inserts the item
  returns.
* ``teacher-hand``: the hand-written answering node: on ``/bench/raw/queries`` it publishes a
  ready ``Answer``; on ``/bench/floor/queries`` it looks the sequence up and builds the
  ``Answer`` for the query (the floor: the transfer's own work and none of the protocol's).
* ``learner-hand``: the hand-written asking node: raw (publish the ``Query``, the answer in its
  subscription's callback is the end) and floor (a fresh ``Query``; in the callback the answer's
  subtree is parsed with the receiving limits, merged and the tree ticked).

Every node of both pairs has a 100 Hz timer ticking a tree (ours its own; the hand-written ones a
``LiveTree`` of the demo robot's control tree), as a robot's node has.

**One transfer, defined alike for all**: from the moment the learner's code is told it needs a
sequence (ours: ``node.set_parameters(sequences=[...])`` is called; hand-written: the line
before ``publish``) to the moment the learner's tree returns from its first tick with the item
merged (ours: the control tree's ``tick`` returns with the item known, read by a wrapper around
it; floor: ``live.tick()`` returns in the callback; raw has no tree: the answer is in the
callback). Each round starts after a pause drawn uniformly from :data:`PAUSE` (one tick period
wide, so a need falls at any phase of the node's tick, as a robot's does; long enough that the
node's open queries, 2 s each, stay under its bound of 32).

**Where the time goes** (ours): wrappers (``time.perf_counter_ns``, about 0.2 µs a call) around
the node's timer callback, the transport's ``broadcast``, serialiser, query and answer callbacks
and message reader, the agent's ``receive`` and ``accept``, its provenance check, its item reader
(parse and validate), the control tree's ``merge`` and ``tick``. Both processes read the same
monotonic clock, so the teacher's callback is placed between the learner's publish and the
answer's arrival. The DDS share (both ways, with each executor's wake and take) is what is left
of that interval once the teacher's callback is taken out.
"""

from __future__ import annotations

import argparse
import gc
import json
import queue
import random
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

PAUSE = (0.050, 0.060)
"""Seconds before each round (uniform): one tick period at 100 Hz wide."""
ATTACH_PAUSE = (0.100, 0.200)
"""The same for an attached robot: one period of its agent's timer (0.1 s, ``attach``'s
default) wide."""
WAIT = 2.0
"""Seconds one round may take; its answer ends it long before."""
CONNECT_TIMEOUT = 60.0
RAW_QUERIES, RAW_ANSWERS = "/bench/raw/queries", "/bench/raw/answers"
FLOOR_QUERIES, FLOOR_ANSWERS = "/bench/floor/queries", "/bench/floor/answers"
EXECUTORS = ("events", "single")
"""``events``: rclpy's events executor, the one ``ktbt ros2 run`` spins by default;
``single``: rclpy's ``SingleThreadedExecutor`` (``--executor single``, and ``rclpy.spin``'s)."""
TICK_RATE = 100.0
"""The node's default tick rate, Hz; the hand-written nodes' timers run at it too."""

Mark = tuple[str, int, int]
MARKS: list[Mark] = []
"""(what, entry ns, exit ns) of every wrapped call, in the order they returned."""
MARKS_KEPT = 200_000


def timed(owner: Any, attr: str, name: str) -> None:
    """Wrap ``owner.attr`` (a function of a class or module, a method of an object) so that
    every call records ``(name, entry, exit)`` in :data:`MARKS`."""
    original = getattr(owner, attr)
    clock, marks = time.perf_counter_ns, MARKS

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start = clock()
        try:
            return original(*args, **kwargs)
        finally:
            if len(marks) < MARKS_KEPT:
                marks.append((name, start, clock()))

    setattr(owner, attr, wrapper)


def make_executor(kind: str) -> Any:
    from rclpy.executors import SingleThreadedExecutor

    if kind == "events":
        from rclpy.experimental.events_executor import EventsExecutor

        return EventsExecutor()
    return SingleThreadedExecutor()


def spin_for(executor: Any, seconds: float) -> None:
    """Spin as ``ktbt ros2 run`` does until ``seconds`` have passed."""
    deadline = time.perf_counter() + seconds
    while (left := deadline - time.perf_counter()) > 0:
        executor.spin_once(timeout_sec=min(left, 0.1))


def spin_until(executor: Any, done: Callable[[], bool], limit: float) -> bool:
    deadline = time.monotonic() + limit
    while not done():
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=0.1)
    return True


def _commands() -> queue.Queue[dict[str, Any]]:
    """The parent's requests, one JSON object a line on stdin, read by a thread so that the
    node keeps spinning between them (an idle learner costs what it costs while others are
    timed)."""
    got: queue.Queue[dict[str, Any]] = queue.Queue()

    def read() -> None:
        for line in sys.stdin:
            got.put(json.loads(line))
        got.put({"op": "quit"})

    threading.Thread(target=read, daemon=True).start()
    return got


def _say(obj: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def serve(
    executor: Any, rounds: Callable[[int], dict[str, Any]], ready: Callable[[], bool]
) -> None:
    """Spin, answering the parent's requests: ``ready`` (discovery and one complete round),
    ``rounds`` (that many timed rounds, one JSON object back), ``quit``."""
    commands = _commands()
    while True:
        try:
            command = commands.get_nowait()
        except queue.Empty:
            executor.spin_once(timeout_sec=0.1)
            continue
        if command["op"] == "quit":
            return
        if command["op"] == "ready":
            _say({"ok": ready()})
        elif command["op"] == "rounds":
            with _gc_paused():
                _say(rounds(int(command["n"])))


@contextmanager
def _gc_paused() -> Iterator[None]:
    gc.collect()
    gc.disable()
    try:
        yield
    finally:
        gc.enable()


def _pause(executor: Any) -> None:
    spin_for(executor, random.uniform(*PAUSE))


# -- ours -------------------------------------------------------------------------------------


ATTACH_TOPICS = "/ktbt_attach"
"""The attached robot's pair has fleet topics of its own (``/ktbt_attach/queries``, ...): two
learners on one fleet would answer each other's queries."""


def teacher_ours(kind: str, marks: Path, topics: str | None = None) -> int:
    """``ktbt ros2 run`` as a user starts it, its transport's callbacks timed; with ``topics``,
    on the fleet topics under that prefix."""
    from rclpy.publisher import Publisher

    from ktbt_proto.tools.cli import main
    from ktbt_proto.transport import ros2 as transport

    from ..bench_transfer import KNOWLEDGE_PATH

    timed(transport.Ros2Transport, "_on_query", "on_query")
    timed(transport.Ros2Transport, "_read", "read")
    timed(transport, "serialized", "serialize")
    timed(Publisher, "publish", "publish")
    where = ["-r", "__ns:=/teacher"]
    if topics is not None:
        where = ["-r", "__ns:=/teacher_attach"] + [
            arg for name in ("queries", "answers", "errors")
            for arg in ("-p", f"{name}_topic:={topics}/{name}")
        ]  # fmt: skip
    sys.argv = [
        "ktbt", "ros2", "run", "--autostart", "--executor", kind,
        "--ros-args", *where, "-p", f"knowledge:={KNOWLEDGE_PATH}",
    ]  # fmt: skip
    try:
        main()
    except SystemExit:
        pass
    finally:
        marks.write_text(json.dumps(MARKS))
    return 0


class _Wanted:
    """The round's sequence key, and when the control tree's tick first returned knowing it."""

    key: str | None = None
    end: int | None = None


def learner_ours(kind: str) -> int:
    import rclpy
    from rclpy.parameter import Parameter
    from rclpy.publisher import Publisher
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import try_shutdown

    from ktbt_proto.exchange import core
    from ktbt_proto.exchange.application import ApplicationTimedAgent
    from ktbt_proto.exchange.knowledge import KnowledgeBase
    from ktbt_proto.exchange.transferlog import TransferLog
    from ktbt_proto.items import read_sequence, sequence_key
    from ktbt_proto.tools.ros2.node import KtbtNode
    from ktbt_proto.transport import ros2 as transport

    from ..bench_transfer import COLOURS, sequence_of

    for owner, attr, name in (
        (KtbtNode, "_tick", "node_tick"),
        (KtbtNode, "_step", "node_step"),
        (transport.Ros2Transport, "broadcast", "broadcast"),
        (transport, "serialized", "serialize"),
        (transport.Ros2Transport, "_on_query", "on_query"),
        (transport.Ros2Transport, "_on_answer", "on_answer"),
        (transport.Ros2Transport, "_read", "read"),
        (ApplicationTimedAgent, "receive", "receive"),
        (core.AgentCore, "accept", "accept"),
        (core, "check_provenance", "provenance"),
        (core, "read_item", "read_item"),
        (Publisher, "publish", "publish"),
        (TransferLog, "record", "record"),
        (KnowledgeBase, "add", "kb_add"),
        (transport.Ros2Transport, "appeared", "appeared"),
    ):
        timed(owner, attr, name)
    first = sequence_of(COLOURS[0])
    rclpy.init(
        args=["ktbt", "--ros-args", "-r", "__ns:=/learner", "-p", f"sequences:=['{first}']"],
        signal_handler_options=SignalHandlerOptions.NO,
    )
    node: Any = KtbtNode("ktbt")  # as ktbt ros2 run --autostart makes it ready
    node.trigger_configure()
    node.trigger_activate()
    agent, member = node.agent, node.member
    if agent is None or member is None:
        raise RuntimeError("the learner's node did not configure")
    executor = make_executor(kind)
    executor.add_node(node)
    wanted = _Wanted()
    control = agent.control
    timed(control, "merge", "merge")
    timed(member, "say", "say")
    tick_control = control.tick
    clock, marks = time.perf_counter_ns, MARKS

    def tick() -> Any:
        start = clock()
        status = tick_control()
        end = clock()
        marks.append(("control_tick", start, end))
        if wanted.end is None and wanted.key is not None and wanted.key in agent.knowledge:
            wanted.end = end
        return status

    control.tick = tick
    known = [sequence_key(read_sequence(first))]
    """What the last round learned (the first sequence before the first round)."""

    def ready() -> bool:
        return spin_until(executor, lambda: known[0] in agent.knowledge, CONNECT_TIMEOUT)

    def rounds(n: int) -> dict[str, Any]:
        samples: list[int] = []
        phases: list[dict[str, int]] = []
        idle: list[int] = []
        for _ in range(n):
            text = sequence_of(COLOURS[(COLOURS.index(_colour(known[0])) + 1) % len(COLOURS)])
            key = sequence_key(read_sequence(text))
            # Untimed: what the last round learned is forgotten, as ~/forget does.
            if agent.forget(known[0]):
                member.forgot(known[0])
            marks.clear()
            _pause(executor)
            # The pause's ticks but the first (which applies the forget): ticks with nothing
            # to learn, what an idle node pays 100 times a second.
            idle += [m[2] - m[1] for m in marks if m[0] == "node_tick"][1:]
            marks.clear()
            wanted.key, wanted.end = key, None
            start = clock()
            node.set_parameters([Parameter("sequences", Parameter.Type.STRING_ARRAY, [text])])
            told = clock()
            if not spin_until(executor, lambda: wanted.end is not None, WAIT) or wanted.end is None:
                raise RuntimeError(f"ours: {text} not learned within {WAIT} s")
            samples.append(wanted.end - start)
            phases.append(ours_phases(list(marks), start, told, wanted.end))
            known[0] = key
        return {
            "ours": samples,
            "phases": phases,
            "idle_ticks": idle,
            "refused": node.transport.refused,
        }

    try:
        serve(executor, rounds, ready)
    finally:
        node.destroy_node()
        try_shutdown()
    return 0


def learner_attach(kind: str) -> int:
    """A user's node with their py_trees tree ticked by their own 100 Hz timer, a KT-BT agent
    attached to it with ``attach``'s defaults (its timer every 0.1 s), told what to meet with
    ``meet``. A round ends when the user's tick that applies the merged item returns (an item
    accepted by the agent's timer is inserted at the next tick's start, section 4.4)."""
    import py_trees
    import rclpy
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import try_shutdown

    from ktbt_proto.interop.ros2.embed import Embedded, attach
    from ktbt_proto.items import read_sequence, sequence_key
    from ktbt_proto.tools.demo import demo_registry
    from ktbt_proto.transport import ros2 as transport

    from ..bench_transfer import COLOURS, sequence_of

    for owner, attr, name in (
        (Embedded, "_step", "agent_step"),
        (transport.Ros2Transport, "broadcast", "broadcast"),
        (transport.Ros2Transport, "_on_answer", "on_answer"),
    ):
        timed(owner, attr, name)
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("bt", namespace="/attacher")
    root = py_trees.composites.Selector(
        "Root", memory=False,
        children=[py_trees.composites.Selector("k:new", memory=False),
                  py_trees.behaviours.Running("Wander")],
    )  # fmt: skip
    tree = py_trees.trees.BehaviourTree(root)
    first = sequence_of(COLOURS[0])
    topics = transport.Topics(*(f"{ATTACH_TOPICS}/{n}" for n in ("queries", "answers", "errors")))
    robot = attach(node, tree, demo_registry(), sequences=[first], topics=topics)
    wanted = _Wanted()
    clock, marks = time.perf_counter_ns, MARKS

    def user_tick() -> None:
        applies = wanted.end is None and wanted.key is not None and robot.knows(wanted.key)
        start = clock()
        tree.tick()
        end = clock()
        marks.append(("user_tick", start, end))
        if applies:
            wanted.end = end

    node.create_timer(1.0 / TICK_RATE, user_tick)
    executor = make_executor(kind)
    executor.add_node(node)
    known = [sequence_key(read_sequence(first))]

    def ready() -> bool:
        return spin_until(executor, lambda: robot.knows(known[0]), CONNECT_TIMEOUT)

    def rounds(n: int) -> dict[str, Any]:
        samples: list[int] = []
        phases: list[dict[str, int]] = []
        for _ in range(n):
            text = sequence_of(COLOURS[(COLOURS.index(_colour(known[0])) + 1) % len(COLOURS)])
            key = sequence_key(read_sequence(text))
            if robot.agent.forget(known[0]):  # untimed, as ~/ktbt/forget does
                robot.member.forgot(known[0])
            spin_for(executor, random.uniform(*ATTACH_PAUSE))
            marks.clear()
            wanted.key, wanted.end = key, None
            start = clock()
            robot.meet(text)
            told = clock()
            if not spin_until(executor, lambda: wanted.end is not None, WAIT) or wanted.end is None:
                raise RuntimeError(f"attach: {text} not learned within {WAIT} s")
            samples.append(wanted.end - start)
            phases.append(attach_phases(list(marks), start, told, wanted.end))
            known[0] = key
        return {"attach": samples, "phases": phases}

    try:
        serve(executor, rounds, ready)
    finally:
        robot.close()
        node.destroy_node()
        try_shutdown()
    return 0


def attach_phases(marks: list[Mark], start: int, told: int, end: int) -> dict[str, int]:
    """One round of the attached robot cut into consecutive phases (ns): its agent's steps are
    its timer's runs and those between them (told to meet, an answer arrived)."""
    broadcast = next(m for m in marks if m[0] == "broadcast" and m[1] >= told)
    ask_step = next(m for m in marks if m[0] == "agent_step" and m[1] <= broadcast[1] <= m[2])
    answer = next(m for m in marks if m[0] == "on_answer" and m[1] >= broadcast[2])
    take_step = next(m for m in marks if m[0] == "agent_step" and m[1] >= answer[2])
    user = next(m for m in marks if m[0] == "user_tick" and m[2] == end)
    return {
        "tell": told - start,
        "wait_ask": ask_step[1] - told,
        "step_to_ask": broadcast[2] - ask_step[1],
        "network": answer[1] - broadcast[2],
        "answer_read": answer[2] - answer[1],
        "wait_take": take_step[1] - answer[2],
        "take_step": take_step[2] - take_step[1],
        "tick_wait": user[1] - take_step[2],
        "user_tick": user[2] - user[1],
    }


def _colour(key: str) -> int:
    return int(key.rsplit("colour=", 1)[1].rstrip(")"))


def _within(marks: list[Mark], name: str, start: int, end: int) -> list[Mark]:
    return [m for m in marks if m[0] == name and m[1] >= start and m[2] <= end]


def ours_phases(marks: list[Mark], start: int, told: int, end: int) -> dict[str, int]:
    """One round of ours cut into consecutive phases (ns), from the wrappers' marks; they add
    up to the round's time. A step is a tick's or one between ticks (told its sequences, an
    answer arrived); the item may be merged in the tick's step that runs it, or in a step
    before. ``teacher`` is filled in by the parent (from the teacher's marks) and taken out of
    ``network``."""
    broadcast = next(m for m in marks if m[0] == "broadcast" and m[1] >= told)
    ask_step = next(m for m in marks if m[0] == "node_step" and m[1] <= broadcast[1] <= m[2])
    serialize = _within(marks, "serialize", broadcast[1], broadcast[2])
    answer = next(m for m in marks if m[0] == "on_answer" and m[1] >= broadcast[2])
    read = _within(marks, "read", answer[1], answer[2])
    control_tick = next(m for m in marks if m[0] == "control_tick" and m[2] == end)
    accept = next(m for m in marks if m[0] == "accept" and m[1] >= answer[2])
    merge_step = next(m for m in marks if m[0] == "node_step" and m[1] <= accept[1] <= m[2])
    tick_step = next(m for m in marks if m[0] == "node_step" and m[1] <= control_tick[1] <= m[2])
    provenance = _within(marks, "provenance", accept[1], accept[2])
    item = _within(marks, "read_item", accept[1], accept[2])
    merge = _within(marks, "merge", accept[1], accept[2])
    own = _within(marks, "on_query", broadcast[2], answer[1])
    ser = sum(m[2] - m[1] for m in serialize)
    sent = _within(marks, "publish", broadcast[1], broadcast[2])

    def spent(name: str, start: int, end: int) -> int:
        return sum(m[2] - m[1] for m in _within(marks, name, start, end))

    checks = [sum(m[2] - m[1] for m in part) for part in (provenance, item, merge)]
    if tick_step == merge_step:  # merged in the tick's step that runs it
        rest, waited, to_tick = 0, 0, control_tick[1] - accept[2]
    else:
        rest = merge_step[2] - accept[2]
        waited, to_tick = tick_step[1] - merge_step[2], control_tick[1] - tick_step[1]
    return {
        "at_published": broadcast[2],
        "at_answer": answer[1],
        "tell": told - start,
        "wait_ask": ask_step[1] - told,
        "step_to_ask": broadcast[1] - ask_step[1],
        "serialize": ser,
        "publish": sum(m[2] - m[1] for m in sent),
        "bookkeeping": broadcast[2] - broadcast[1] - ser - sum(m[2] - m[1] for m in sent),
        "network": answer[1] - broadcast[2],
        "own_query_read_back": sum(m[2] - m[1] for m in own),
        "ask_step_after_publish": ask_step[2] - broadcast[2],
        "answer_decode": sum(m[2] - m[1] for m in read),
        "answer_check": answer[2] - answer[1] - sum(m[2] - m[1] for m in read),
        "wait_merge": merge_step[1] - answer[2],
        "step_to_accept": accept[1] - merge_step[1],
        "provenance": checks[0],
        "parse_validate": checks[1],
        "merge": checks[2],
        "accept_rest": accept[2] - accept[1] - sum(checks),
        "accept_records": spent("record", accept[1], accept[2]),
        "accept_publishes": spent("publish", accept[1], accept[2]),
        "accept_kb_add": spent("kb_add", accept[1], accept[2]),
        "merge_step_rest": rest,
        "step_say": spent("say", accept[2], control_tick[1]),
        "step_appeared": spent("appeared", accept[2], control_tick[1]),
        "tick_wait_run": waited,
        "step_to_tick": to_tick,
        "control_tick": control_tick[2] - control_tick[1],
    }


# -- the hand-written pair --------------------------------------------------------------------


def _user_tree() -> Any:
    """A robot's tree for the hand-written nodes' 100 Hz timers to tick."""
    import ktbt_proto as kp
    from ktbt_proto.tools.demo import DEMO_CONTROL, demo_registry

    return kp.LiveTree(kp.parse(DEMO_CONTROL), demo_registry(), kp.Blackboard(target=1))


def teacher_hand(kind: str) -> int:
    """The hand-written answering node; on SIGTERM one JSON line: its callbacks' times."""
    import rclpy
    from ktbt_interfaces.msg import Answer, Query
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import try_shutdown

    from ktbt_proto.exchange.answers import answers
    from ktbt_proto.interop.knowledge_file import load_knowledge
    from ktbt_proto.transport.ros2 import exchange_qos, to_msg

    from ..bench_transfer import KNOWLEDGE_PATH, LEARNER, TEACHER, wire_messages

    lookup = answers(load_knowledge(KNOWLEDGE_PATH))
    ready_answer = to_msg(wire_messages(lookup)[1], LEARNER)
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    node = rclpy.create_node("hand", namespace="/teacher")
    tree = _user_tree()
    node.create_timer(1.0 / TICK_RATE, tree.tick)
    raw_out = node.create_publisher(Answer, RAW_ANSWERS, exchange_qos())
    floor_out = node.create_publisher(Answer, FLOOR_ANSWERS, exchange_qos())
    clock = time.perf_counter_ns
    calls: dict[str, list[list[int]]] = {"raw": [], "floor": []}
    """Each callback's [entry, publish entered, publish returned, exit] (ns)."""

    def raw(_query: Any) -> None:
        start = clock()
        publish = clock()
        raw_out.publish(ready_answer)
        published = clock()
        calls["raw"].append([start, publish, published, clock()])

    def floor(query: Any) -> None:
        start = clock()
        found = lookup(query.sequence)
        if found is not None:
            subtree = found if isinstance(found, str) else found.subtree
            answer = Answer(v=1, id=query.id, sender=TEACHER, to=query.sender,
                            sequence=query.sequence, subtree=subtree)  # fmt: skip
            publish = clock()
            floor_out.publish(answer)
            published = clock()
            calls["floor"].append([start, publish, published, clock()])

    node.create_subscription(Query, RAW_QUERIES, raw, exchange_qos())
    node.create_subscription(Query, FLOOR_QUERIES, floor, exchange_qos())
    executor = make_executor(kind)
    executor.add_node(node)
    print("ready", flush=True)
    try:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.1)
    finally:
        node.destroy_node()
        try_shutdown()
    print(json.dumps(calls), flush=True)
    return 0


def learner_hand(kind: str) -> int:
    import rclpy
    from ktbt_interfaces.msg import Answer, Query
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import try_shutdown

    import ktbt_proto as kp
    from ktbt_proto.exchange.answers import answers
    from ktbt_proto.exchange.messages import Query as ProtocolQuery
    from ktbt_proto.exchange.receiving import RECEIVE_LIMITS
    from ktbt_proto.interop.knowledge_file import load_knowledge
    from ktbt_proto.items import parse_sequence
    from ktbt_proto.tools.demo import DEMO_CONTROL, demo_registry
    from ktbt_proto.transport.ros2 import exchange_qos, to_msg

    from ..bench_transfer import COLOURS, KNOWLEDGE_PATH, LEARNER, SLOT, fresh_learner
    from ..bench_transfer import wire_messages as messages

    query, ready_answer = messages(answers(load_knowledge(KNOWLEDGE_PATH)))
    raw_query, raw_subtree = to_msg(query), ready_answer.subtree
    control, registry = kp.parse(DEMO_CONTROL), demo_registry()
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("hand", namespace="/learner")
    tree = _user_tree()
    node.create_timer(1.0 / TICK_RATE, tree.tick)
    raw_out = node.create_publisher(Query, RAW_QUERIES, exchange_qos())
    floor_out = node.create_publisher(Query, FLOOR_QUERIES, exchange_qos())
    clock = time.perf_counter_ns
    got: dict[str, Any] = {}

    def raw_answer(msg: Any) -> None:
        entry = clock()
        if msg.subtree == raw_subtree:
            got.update(entry=entry, end=clock())

    def floor_answer(msg: Any) -> None:
        entry = clock()
        p = got.get("learner")
        if p is None or msg.id != got.get("id"):
            return
        subtree = kp.parse(msg.subtree, limits=RECEIVE_LIMITS).root
        parsed = clock()
        changed = p.live.merge(subtree, SLOT, when=parse_sequence(p.key, RECEIVE_LIMITS))
        merged = clock()
        status = p.live.tick()
        end = clock()
        if changed and status is kp.SUCCESS and p.live.blackboard.get("zone") == p.colour:
            got.update(entry=entry, parsed=parsed, merged=merged, end=end)

    node.create_subscription(Answer, RAW_ANSWERS, raw_answer, exchange_qos())
    node.create_subscription(Answer, FLOOR_ANSWERS, floor_answer, exchange_qos())
    executor = make_executor(kind)
    executor.add_node(node)

    def one(contender: str, colour: int) -> dict[str, int]:
        """One round: ``total`` and its phases (ns), with the absolute times the parent
        places the teacher's callback between."""
        got.clear()
        if contender == "floor":
            p = fresh_learner(control, registry, colour)
            msg = Query(v=1, id=ProtocolQuery.new_id(), sender=LEARNER, sequence=p.key)
            got.update(learner=p, id=msg.id)
            out = floor_out
        else:
            msg, out = raw_query, raw_out
        _pause(executor)
        start = clock()
        out.publish(msg)
        published = clock()
        if not spin_until(executor, lambda: "end" in got, WAIT):
            raise RuntimeError(f"{contender}: no answer within {WAIT} s")
        phases = {
            "at_published": published,
            "at_answer": got["entry"],
            "publish": published - start,
            "network": got["entry"] - published,
        }
        if contender == "floor":
            phases |= {
                "parse": got["parsed"] - got["entry"],
                "merge": got["merged"] - got["parsed"],
                "tick": got["end"] - got["merged"],
            }
        return {"total": got["end"] - start, **phases}

    def ready() -> bool:
        deadline = time.monotonic() + CONNECT_TIMEOUT
        while time.monotonic() < deadline:
            if (
                raw_out.get_subscription_count() >= 1
                and floor_out.get_subscription_count() >= 1
                and node.count_publishers(RAW_ANSWERS) >= 1
                and node.count_publishers(FLOOR_ANSWERS) >= 1
            ):
                try:
                    one("raw", 1), one("floor", 1)
                    return True
                except RuntimeError:
                    continue  # matched one way before the other: again
            executor.spin_once(timeout_sec=0.1)
        return False

    state = {"round": 0}

    def rounds(n: int) -> dict[str, Any]:
        timed: dict[str, list[dict[str, int]]] = {"raw": [], "floor": []}
        for _ in range(n):
            state["round"] += 1
            colour = COLOURS[state["round"] % len(COLOURS)]
            order = ("raw", "floor") if state["round"] % 2 else ("floor", "raw")
            for contender in order:
                timed[contender].append(one(contender, colour))
        return timed

    try:
        serve(executor, rounds, ready)
    finally:
        node.destroy_node()
        try_shutdown()
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_ros2.transfer")
    roles = ("teacher-ours", "learner-ours", "learner-attach", "teacher-hand", "learner-hand")
    parser.add_argument("--role", choices=roles, required=True)
    parser.add_argument("--executor", choices=EXECUTORS, default="events")
    parser.add_argument("--marks", type=Path, help="teacher-ours: where its timings go")
    parser.add_argument("--topics", help="teacher-ours: the fleet topics' prefix (/ktbt)")
    args = parser.parse_args(argv)
    if args.role == "teacher-ours":
        if args.marks is None:
            parser.error("--marks: give a file for teacher-ours")
        return teacher_ours(args.executor, args.marks, args.topics)
    if args.role == "learner-ours":
        return learner_ours(args.executor)
    if args.role == "learner-attach":
        return learner_attach(args.executor)
    if args.role == "teacher-hand":
        return teacher_hand(args.executor)
    return learner_hand(args.executor)


if __name__ == "__main__":
    raise SystemExit(main())
