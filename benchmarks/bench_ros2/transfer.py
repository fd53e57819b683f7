"""The ROS 2 knowledge transfer against a raw rclpy request and reply, as robots run it: the
answering side and the asking side in two processes (run inside the benchmark's network
namespace by :mod:`benchmarks.bench_ros2`).

* ``--role teacher``: the teacher's node (a :class:`Ros2Transport` that answers at once from
  ``colours.sbt`` through ``lookup=``, as a node does) and the anchors' server node, each spun
  as its kind of program spins it: ours by ``--executor`` in the main thread, as ``ktbt ros2
  run`` spins its node, the anchors by ``--anchor-executor`` (the same executor when of the same
  kind, else in a thread of their own). It says ``ready`` on stdout once both are up, and on
  SIGTERM prints one JSON line (answers given, refusals) and ends.
* ``--role learner``: the learner's node and the anchors' client node, each on its executor,
  spun in the timed loop by the contender being timed. It waits for the teacher's process
  (graph counts, then one complete round of each contender, with deadlines), times the
  rounds, and prints one JSON object.

``--executor`` and ``--anchor-executor`` each pick rclpy's ``SingleThreadedExecutor``
(``single``, the one ``rclpy.spin`` runs) or its events executor (``events``,
``rclpy.experimental.events_executor``, the one ``ktbt ros2 run`` spins by default).

* raw (the anchor): the raw client publishes a ``ktbt_interfaces/Query`` on a topic of its own;
  the raw server's subscription callback publishes a ready ``ktbt_interfaces/Answer`` on
  another; the time covers the publish and the client's spinning until its subscription has the
  answer. The messages are the very ones ours carry (same types, same field values, so the same
  serialized sizes), with the same QoS (:func:`exchange_qos`). Topics with the same message
  types are the faithful anchor: ours is topics (spec/protocol.md section 11), and a service
  would measure another mechanism (a request topic and a reply topic with their own headers).
* floor: the least any robot written with rclpy does for a transfer, without the protocol's
  checks: the raw pair's round trip on topics of its own, where the answering side looks the
  asked sequence up and builds its ``Answer`` for the query (``id``, ``to``), and the asking
  side, the answer in, parses its subtree (:func:`kp.parse` with the receiving limits),
  merges it and ticks, as ours does. What ours takes beyond the floor is the protocol's work
  (section 2's checks, the bookkeeping of open queries, the answer window); what the floor
  takes beyond raw is the transfer's own (building the answer, parse, merge, tick).
* ours: the learner's :class:`Ros2Transport` asks the teacher's. The time covers building the
  ``Query``, ``broadcast``, spinning until ``receive`` hands over the answer (the teacher's
  lookup and reply, and each side's checks of what it reads), the checks of ``Agent.accept``,
  ``parse``, ``live.merge`` and the first ``live.tick()``, into a fresh running tree each round.

The three contenders alternate round by round (which goes first rotating), with the cyclic
collector off while timing, as in ``benchmarks/bench_transfer.py`` (zenoh).
"""

from __future__ import annotations

import argparse
import gc
import json
import signal
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from ktbt_interfaces.msg import Answer as AnswerMsg
from ktbt_interfaces.msg import Query as QueryMsg
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.serialization import serialize_message
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import try_shutdown

import ktbt_proto as kp
from ktbt_proto.exchange.answers import answers
from ktbt_proto.exchange.messages import Query, Response
from ktbt_proto.exchange.receiving import RECEIVE_LIMITS
from ktbt_proto.interop.knowledge_file import load_knowledge
from ktbt_proto.items import parse_sequence
from ktbt_proto.tools.demo import DEMO_CONTROL, demo_registry
from ktbt_proto.transport.inbox import Lookup
from ktbt_proto.transport.ros2 import Ros2Transport, exchange_qos, to_msg

from ..bench_transfer import (
    COLOURS,
    KNOWLEDGE_PATH,
    LEARNER,
    PHASES,
    SLOT,
    TEACHER,
    _Learner,
    _us,
    fresh_learner,
    take_answer,
    wire_messages,
)
from ..timing import gc_paused

WAIT = 2.0
"""Seconds one round may wait for its answer; the answer ends it long before."""
CONNECT_TIMEOUT = 60.0
"""Seconds for discovery and the first complete rounds (usually under a second; the two
processes start on shared cores)."""
RAW_QUERIES, RAW_ANSWERS = "/bench/raw/queries", "/bench/raw/answers"
FLOOR_QUERIES, FLOOR_ANSWERS = "/bench/floor/queries", "/bench/floor/answers"
CONTENDERS = ("raw", "floor", "ours")
EXECUTORS = ("events", "single")
"""``events``: rclpy's events executor, the one ``ktbt ros2 run`` spins; ``single``: rclpy's
``SingleThreadedExecutor``."""

Timed = tuple[int, bool]


def make_executor(kind: str) -> Executor:
    if kind == "events":
        from rclpy.experimental.events_executor import EventsExecutor

        return EventsExecutor()
    return SingleThreadedExecutor()


def _spin_until(executor: Executor, done: Callable[[], bool], limit: float) -> bool:
    deadline = time.monotonic() + limit
    while not done():
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=0.05)
    return True


def _messages() -> tuple[Any, Any, Any]:
    """The teacher's lookup, and the raw pair's query and answer: the very messages ours
    carries (same types, same field values)."""
    lookup = answers(load_knowledge(KNOWLEDGE_PATH))
    query, response = wire_messages(lookup)
    return lookup, to_msg(query), to_msg(response, LEARNER)


class RawServer:
    """The anchor's answering half: answers every query on its topic with a ready answer."""

    def __init__(self, node: Node, answer: Any) -> None:
        self.publisher = node.create_publisher(AnswerMsg, RAW_ANSWERS, exchange_qos())
        node.create_subscription(
            QueryMsg, RAW_QUERIES, lambda _msg: self.publisher.publish(answer), exchange_qos()
        )


class _Asker:
    """An anchor's asking half: publishes on its query topic and spins until its answer is in."""

    def __init__(self, node: Node, queries: str, answers: str) -> None:
        self.node, self.answers = node, answers
        self.got: list[Any] = []
        self.publisher = node.create_publisher(QueryMsg, queries, exchange_qos())
        node.create_subscription(AnswerMsg, answers, self.got.append, exchange_qos())

    def discovered(self) -> bool:
        return (
            self.publisher.get_subscription_count() >= 1
            and self.node.count_publishers(self.answers) >= 1
        )

    def ask(self, query: Any, executor: Executor) -> Any | None:
        """Publish ``query`` and spin until the one answer is in (None after ``WAIT``)."""
        got = self.got
        got.clear()
        self.publisher.publish(query)
        deadline = time.monotonic() + WAIT
        while not got and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=WAIT)
        return got[0] if len(got) == 1 else None


class RawClient(_Asker):
    """The anchor's asking half: the ready query, and its answer."""

    def __init__(self, node: Node, query: Any, answer: Any) -> None:
        super().__init__(node, RAW_QUERIES, RAW_ANSWERS)
        self.query, self.answer = query, answer

    def round_trip(self, executor: Executor) -> Timed:
        clock = time.perf_counter_ns
        start = clock()
        got = self.ask(self.query, executor)
        elapsed = clock() - start
        return elapsed, got is not None and got.subtree == self.answer.subtree


class FloorServer:
    """The floor's answering half (see the module's docstring): the answer to each query,
    looked up and built for it, published from the subscription's callback."""

    def __init__(self, node: Node, lookup: Lookup) -> None:
        self.publisher = node.create_publisher(AnswerMsg, FLOOR_ANSWERS, exchange_qos())

        def answer(query: Any) -> None:
            found = lookup(query.sequence)
            if found is not None:
                subtree = found if isinstance(found, str) else found.subtree
                self.publisher.publish(
                    AnswerMsg(v=1, id=query.id, sender=TEACHER, to=query.sender,
                              sequence=query.sequence, subtree=subtree)
                )  # fmt: skip

        node.create_subscription(QueryMsg, FLOOR_QUERIES, answer, exchange_qos())


class FloorClient(_Asker):
    """The floor's asking half: a fresh query published, spun until its answer is in, then the
    answer parsed, merged and ticked into the learner's tree."""

    def __init__(self, node: Node) -> None:
        super().__init__(node, FLOOR_QUERIES, FLOOR_ANSWERS)

    def transfer(self, executor: Executor, p: _Learner) -> Timed:
        clock, live = time.perf_counter_ns, p.live
        start = clock()
        query = QueryMsg(v=1, id=Query.new_id(), sender=LEARNER, sequence=p.key)
        got = self.ask(query, executor)
        if got is None or got.id != query.id:
            return clock() - start, False
        subtree = kp.parse(got.subtree, limits=RECEIVE_LIMITS).root
        changed = live.merge(subtree, SLOT, when=parse_sequence(p.key, RECEIVE_LIMITS))
        status = live.tick()
        elapsed = clock() - start
        return elapsed, changed and status is kp.SUCCESS and live.blackboard.get("zone") == p.colour


def transfer(
    learner: Ros2Transport,
    executor: Executor,
    p: _Learner,
    phases: list[list[int]],
) -> Timed:
    """One transfer of ours, as ``Agent`` does it (``_QueryAndWait`` then ``accept``)."""
    clock = time.perf_counter_ns
    start = clock()
    query = Query(id=Query.new_id(), sender=learner.name, sequence=p.key)
    learner.broadcast(query)
    response: Response | None = None
    deadline = time.monotonic() + WAIT
    while response is None and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=WAIT)
        response = next(
            (m for m in learner.receive() if isinstance(m, Response) and m.id == query.id), None
        )
    timed = take_answer(p, query, response, (start, clock()), phases)
    _close(learner, query)
    return timed


def _close(learner: Ros2Transport, query: Query) -> None:
    """Untimed: the query is closed, as a robot's is before it asks again. A robot has one
    query open at a time, for 2 s; this loop asks a new one every millisecond or so, and would
    otherwise hit the open-query bound (max_asking) and carry a long table."""
    with learner._lock:
        learner._open.pop(query.id, None)


def _executors(ours: str, anchor: str) -> tuple[Executor, Executor]:
    """Ours' executor and the anchors' (raw and floor): one and the same when of one kind."""
    executor = make_executor(ours)
    return executor, executor if anchor == ours else make_executor(anchor)


def _nodes(robot: str, anchor: str, ours: Executor, anchors: Executor) -> list[Node]:
    """Our robot's node (``/ROBOT/ktbt``) on ``ours`` and the anchors' (``/bench/ANCHOR``) on
    ``anchors``."""
    nodes = [
        rclpy.create_node("ktbt", namespace=f"/{robot}"),
        rclpy.create_node(anchor, namespace="/bench"),
    ]
    ours.add_node(nodes[0])
    anchors.add_node(nodes[1])
    return nodes


def _spin(executor: Executor, stop: threading.Event) -> None:
    while not stop.is_set():
        executor.spin_once(timeout_sec=0.1)


def teach(kind: str, anchor_kind: str) -> dict[str, Any]:
    """The answering process: spins until SIGTERM; what it answered and refused. With the
    anchors on another executor than ours, theirs spins in a thread of its own, as a node
    spun by ``rclpy.spin`` in a thread would be."""
    lookup, _query_msg, answer_msg = _messages()
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    ours, anchors = _executors(kind, anchor_kind)
    nodes = _nodes(TEACHER, "raw_server", ours, anchors)
    teacher = Ros2Transport(nodes[0], TEACHER, lookup=lookup)
    RawServer(nodes[1], answer_msg)
    FloorServer(nodes[1], lookup)
    apart = threading.Thread(target=_spin, args=(anchors, stop)) if anchors is not ours else None
    if apart is not None:
        apart.start()
    print("ready", flush=True)
    try:
        _spin(ours, stop)
        return {"teacher_answered": teacher.answered, "teacher_refused": teacher.refused}
    finally:
        stop.set()
        if apart is not None:
            apart.join()
        teacher.close()
        for node in nodes:
            node.destroy_node()
        try_shutdown()


def learn(kind: str, anchor_kind: str, rounds: int, warmup: int) -> dict[str, Any]:
    """The asking process: the interleaved rounds, timed; each contender spins its own
    executor (ours ``kind``, the anchors ``anchor_kind``: one executor when of one kind)."""
    _lookup, query_msg, answer_msg = _messages()
    control = kp.parse(DEMO_CONTROL)
    registry = demo_registry()
    rclpy.init()
    executor, anchors = _executors(kind, anchor_kind)
    nodes = _nodes(LEARNER, "raw_client", executor, anchors)

    def both(done: Callable[[], bool]) -> Callable[[], bool]:
        def spun() -> bool:
            if anchors is not executor:
                anchors.spin_once(timeout_sec=0.01)
            return done()

        return spun

    learner = Ros2Transport(nodes[0], LEARNER)
    raw = RawClient(nodes[1], query_msg, answer_msg)
    floor = FloorClient(nodes[1])
    try:
        began = time.monotonic()
        # The teacher's subscriptions to both fleet topics and the raw pair's, seen from here;
        # then one complete round of each (a publisher may be seen before it matches us).
        if not _spin_until(
            executor,
            both(
                lambda: (
                    learner._queries.get_subscription_count() >= 2
                    and learner._answers.get_subscription_count() >= 2
                    and raw.discovered()
                    and floor.discovered()
                )
            ),
            CONNECT_TIMEOUT,
        ) or not _spin_until(
            executor,
            lambda: (
                raw.round_trip(anchors)[1]
                and floor.transfer(anchors, fresh_learner(control, registry, 1))[1]
                and transfer(learner, executor, fresh_learner(control, registry, 1), [[], [], []])[
                    1
                ]
            ),
            CONNECT_TIMEOUT,
        ):
            raise TimeoutError(f"the teacher's process was not reached in {CONNECT_TIMEOUT:g} s")
        connect_s = time.monotonic() - began
        samples: dict[str, list[int]] = {c: [] for c in CONTENDERS}
        phases: list[list[int]] = [[] for _ in PHASES]
        with gc_paused():
            for r in range(warmup + rounds):
                if r and r % 100 == 0:
                    gc.collect()
                colour = COLOURS[r % len(COLOURS)]
                timed = phases if r >= warmup else [[] for _ in PHASES]
                first = r % len(CONTENDERS)
                for contender in CONTENDERS[first:] + CONTENDERS[:first]:
                    if contender == "raw":
                        elapsed, ok = raw.round_trip(anchors)
                    elif contender == "floor":
                        elapsed, ok = floor.transfer(
                            anchors, fresh_learner(control, registry, colour)
                        )
                    else:
                        fresh = fresh_learner(control, registry, colour)
                        elapsed, ok = transfer(learner, executor, fresh, timed)
                    if not ok:
                        raise AssertionError(f"{contender}: round {r} did not complete")
                    if r >= warmup:
                        samples[contender].append(elapsed)
        result: dict[str, Any] = {
            "executor": kind,
            "anchor_executor": anchor_kind,
            "rounds": rounds,
            "warmup_rounds": warmup,
            "connect_s": round(connect_s, 2),
            "payload_bytes": {
                "query": len(serialize_message(query_msg)),
                "response": len(serialize_message(answer_msg)),
            },
            **{contender: _us(ns) for contender, ns in samples.items()},
            "ours_phases": {name: _us(s) for name, s in zip(PHASES, phases, strict=True)},
            "learner_refused": learner.refused,
        }
        result["ratio"] = {
            q: round(result["ours"][q] / result["raw"][q], 2) for q in ("median", "p90", "p99")
        }
        result["floor_ratio"] = {
            q: round(result["floor"][q] / result["raw"][q], 2) for q in ("median", "p90", "p99")
        }
        return result
    finally:
        learner.close()
        for node in nodes:
            node.destroy_node()
        try_shutdown()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_ros2.transfer")
    parser.add_argument("--role", choices=("teacher", "learner"), required=True)
    parser.add_argument("--executor", choices=EXECUTORS, default="events", help="ours'")
    parser.add_argument(
        "--anchor-executor", choices=EXECUTORS, help="the raw pair's and the floor's (ours')"
    )
    parser.add_argument("--rounds", type=int, default=1000)
    parser.add_argument("--warmup", type=int, default=50)
    args = parser.parse_args(argv)
    anchor = args.anchor_executor or args.executor
    if args.role == "teacher":
        print(json.dumps(teach(args.executor, anchor)), flush=True)
    else:
        print(json.dumps(learn(args.executor, anchor, args.rounds, args.warmup)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
