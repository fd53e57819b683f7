"""The ROS 2 knowledge transfer against a raw rclpy request and reply (run inside the benchmark's
network namespace by :mod:`benchmarks.bench_ros2`; prints one JSON object).

The shape of ``benchmarks/bench_transfer.py`` (zenoh): one process, the teacher and the learner
each a participant of their own, the raw anchor a separate pair beside them, the two contenders
alternating round by round with the cyclic collector off while timing. Here each side is a
node, and each side spins its own executor, as each zenoh session has its own threads: the
answering side (the teacher's node and the raw server's) in a thread of its own, the asking
side (the learner's node and the raw client's) in the timed loop.

* raw (the anchor): the raw client publishes a ``ktbt_interfaces/Query`` on a topic of its own;
  the raw server's subscription callback publishes a ready ``ktbt_interfaces/Answer`` on
  another; the time covers the publish and the client's spinning until its subscription has the
  answer. The messages are the very ones ours carry (same types, same field values, so the same
  serialized sizes), with the same QoS (:func:`exchange_qos`). Topics with the same message
  types are the faithful anchor: ours is topics (spec/protocol.md section 11), and a service
  would measure another mechanism (a request topic and a reply topic with their own headers).
* ours: a learner :class:`Ros2Transport` asks a teacher :class:`Ros2Transport` that answers at
  once from ``colours.sbt`` through ``lookup=`` (as a node does). The time covers building the
  ``Query``, ``broadcast``, spinning until ``receive`` hands over the answer (the teacher's
  lookup and reply, and each side's checks of what it reads), the checks of ``Agent.accept``,
  ``parse``, ``live.merge`` and the first ``live.tick()``, into a fresh running tree each round.
"""

from __future__ import annotations

import argparse
import gc
import json
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from ktbt_interfaces.msg import Answer as AnswerMsg
from ktbt_interfaces.msg import Query as QueryMsg
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.serialization import serialize_message
from rclpy.utilities import try_shutdown

import ktbt_proto as kp
from ktbt_proto.exchange.answers import answers
from ktbt_proto.exchange.knowledge import parse_sequence
from ktbt_proto.exchange.messages import Query, Response
from ktbt_proto.exchange.receiving import RECEIVE_LIMITS
from ktbt_proto.interop.robot import DEMO_CONTROL, demo_registry, load_knowledge
from ktbt_proto.interop.ros2.transport import Ros2Transport, exchange_qos, to_msg

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
    wire_messages,
)
from ..timing import gc_paused

WAIT = 2.0
"""Seconds one round may wait for its answer; the answer ends it long before."""
CONNECT_TIMEOUT = 30.0
"""Seconds for discovery (usually under half a second, once seen at 3.4 s)."""
RAW_QUERIES, RAW_ANSWERS = "/bench/raw/queries", "/bench/raw/answers"

Timed = tuple[int, bool]


def _spin_until(executor: SingleThreadedExecutor, done: Callable[[], bool], limit: float) -> bool:
    deadline = time.monotonic() + limit
    while not done():
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=0.05)
    return True


class RawPair:
    """The anchor: a client that publishes a query and a server that answers it, with our
    message types and QoS, on topics of their own."""

    def __init__(self, server: Node, client: Node, query: Any, answer: Any) -> None:
        self.query, self.answer = query, answer
        self.got: list[Any] = []
        answer_pub = server.create_publisher(AnswerMsg, RAW_ANSWERS, exchange_qos())
        server.create_subscription(
            QueryMsg, RAW_QUERIES, lambda _msg: answer_pub.publish(answer), exchange_qos()
        )
        self.publisher = client.create_publisher(QueryMsg, RAW_QUERIES, exchange_qos())
        client.create_subscription(AnswerMsg, RAW_ANSWERS, self.got.append, exchange_qos())
        self.answer_pub = answer_pub

    def connected(self) -> bool:
        return (
            self.publisher.get_subscription_count() >= 1
            and self.answer_pub.get_subscription_count() >= 1
        )

    def round_trip(self, executor: SingleThreadedExecutor) -> Timed:
        got, clock = self.got, time.perf_counter_ns
        got.clear()
        start = clock()
        self.publisher.publish(self.query)
        deadline = time.monotonic() + WAIT
        while not got and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=WAIT)
        elapsed = clock() - start
        return elapsed, len(got) == 1 and got[0].subtree == self.answer.subtree


def transfer(
    learner: Ros2Transport,
    executor: SingleThreadedExecutor,
    p: _Learner,
    phases: list[list[int]],
) -> Timed:
    """One transfer of ours, as ``Agent`` does it (``_QueryAndWait`` then ``accept``)."""
    live, key, clock = p.live, p.key, time.perf_counter_ns
    start = clock()
    query = Query(id=Query.new_id(), sender=learner.name, sequence=key)
    learner.broadcast(query)
    response: Response | None = None
    deadline = time.monotonic() + WAIT
    while response is None and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=WAIT)
        response = next(
            (m for m in learner.receive() if isinstance(m, Response) and m.id == query.id), None
        )
    asked = clock()
    if response is None or response.sequence != query.sequence:
        return clock() - start, False
    conds = parse_sequence(query.sequence, RECEIVE_LIMITS)
    subtree = kp.parse(response.subtree, limits=RECEIVE_LIMITS).root
    parsed = clock()
    changed = live.merge(subtree, SLOT, when=conds)
    status = live.tick()
    end = clock()
    for samples, ns in zip(phases, (asked - start, parsed - asked, end - parsed), strict=True):
        samples.append(ns)
    learned = changed and status is kp.SUCCESS and live.blackboard.get("zone") == p.colour
    # Untimed: the query is closed, as a robot's is before it asks again. A robot has one
    # query open at a time, for 2 s; this loop asks a new one every millisecond or so, and
    # would otherwise hit the open-query bound (max_asking) and carry a long table.
    with learner._lock:
        learner._open.pop(query.id, None)
    return end - start, learned


def run(rounds: int, warmup: int) -> dict[str, Any]:
    kb = load_knowledge(KNOWLEDGE_PATH)
    lookup = answers(kb)
    query, response = wire_messages(lookup)
    query_msg, answer_msg = to_msg(query), to_msg(response, LEARNER)
    control = kp.parse(DEMO_CONTROL)
    registry = demo_registry()
    rclpy.init()
    answering, asking = SingleThreadedExecutor(), SingleThreadedExecutor()
    nodes = {
        "teacher": rclpy.create_node("ktbt", namespace=f"/{TEACHER}"),
        "server": rclpy.create_node("raw_server", namespace="/bench"),
        "learner": rclpy.create_node("ktbt", namespace=f"/{LEARNER}"),
        "client": rclpy.create_node("raw_client", namespace="/bench"),
    }
    for name in ("teacher", "server"):
        answering.add_node(nodes[name])
    for name in ("learner", "client"):
        asking.add_node(nodes[name])
    teacher = Ros2Transport(nodes["teacher"], TEACHER, lookup=lookup)
    learner = Ros2Transport(nodes["learner"], LEARNER)
    raw = RawPair(nodes["server"], nodes["client"], query_msg, answer_msg)
    spinner = threading.Thread(target=answering.spin, name="answering", daemon=True)
    spinner.start()
    try:
        began = time.monotonic()
        if not _spin_until(
            asking,
            lambda: (
                learner._queries.get_subscription_count() >= 2
                and teacher._answers.get_subscription_count() >= 2
                and raw.connected()
            ),
            CONNECT_TIMEOUT,
        ):
            raise TimeoutError(f"the nodes did not discover each other in {CONNECT_TIMEOUT:g} s")
        connect_s = time.monotonic() - began
        raw_ns: list[int] = []
        ours_ns: list[int] = []
        phases: list[list[int]] = [[] for _ in PHASES]
        with gc_paused():
            for r in range(warmup + rounds):
                if r and r % 100 == 0:
                    gc.collect()
                fresh = fresh_learner(control, registry, COLOURS[r % len(COLOURS)])
                timed = phases if r >= warmup else [[] for _ in PHASES]
                for contender in ("raw", "ours") if r % 2 else ("ours", "raw"):
                    if contender == "raw":
                        elapsed, ok = raw.round_trip(asking)
                    else:
                        elapsed, ok = transfer(learner, asking, fresh, timed)
                    if not ok:
                        raise AssertionError(f"{contender}: round {r} did not complete")
                    if r >= warmup:
                        (raw_ns if contender == "raw" else ours_ns).append(elapsed)
        result: dict[str, Any] = {
            "rounds": rounds,
            "warmup_rounds": warmup,
            "connect_s": round(connect_s, 2),
            "payload_bytes": {
                "query": len(serialize_message(query_msg)),
                "response": len(serialize_message(answer_msg)),
            },
            "raw": _us(raw_ns),
            "ours": _us(ours_ns),
            "ours_phases": {name: _us(s) for name, s in zip(PHASES, phases, strict=True)},
            "teacher_answered": teacher.answered,
            "refused": {"teacher": teacher.refused, "learner": learner.refused},
        }
        result["ratio"] = {
            q: round(result["ours"][q] / result["raw"][q], 2) for q in ("median", "p90", "p99")
        }
        return result
    finally:
        answering.shutdown(timeout_sec=5)
        spinner.join(timeout=5)
        for transport in (teacher, learner):
            transport.close()
        for node in nodes.values():
            node.destroy_node()
        try_shutdown()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_ros2.transfer")
    parser.add_argument("--rounds", type=int, default=1000)
    parser.add_argument("--warmup", type=int, default=50)
    args = parser.parse_args(argv)
    print(json.dumps(run(args.rounds, args.warmup)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
