"""Three robots' ROS 2 transports in one process, on Fast DDS (run by
``test_ros2_transport.py`` inside a test's network namespace): a teacher that answers at once,
a learner that asks, and a listener that overhears; then a flood. Prints what each saw as one
JSON object. Every wait is on what arrived, with a deadline."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from typing import Any

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.utilities import try_shutdown

from ktbt_proto.exchange.messages import Query, Response
from ktbt_proto.exchange.signing import SignedItem
from ktbt_proto.exchange.transport import Received
from ktbt_proto.transport.ros2 import Ros2Transport
from tests.interop.ros2.rosns import SEQUENCE, SUBTREE

OTHER = "<c>(TargetSeen,colour=3)"
OTHER_SUBTREE = "<sq><a>(PickTreasure)<a>(AssignCollectionPoint,colour=3)<e>"


def main() -> None:
    rclpy.init()
    executor = SingleThreadedExecutor()
    nodes = {name: rclpy.create_node("ktbt", namespace=f"/{name}") for name in ("t", "l", "o")}
    for node in nodes.values():
        executor.add_node(node)
    items = {SEQUENCE: SignedItem(SUBTREE), OTHER: SignedItem(OTHER_SUBTREE)}
    teacher = Ros2Transport(nodes["t"], "teacher", lookup=items.get)
    learner = Ros2Transport(nodes["l"], "learner", inbox_limit=3)
    listener = Ros2Transport(nodes["o"], "listener", overhear=True)
    got: dict[str, list[Received]] = {"learner": [], "listener": []}

    def spin_until(done: Callable[[], bool], seconds: float = 30, drain: bool = True) -> bool:
        deadline = time.monotonic() + seconds
        while not done():
            if time.monotonic() > deadline:
                return False
            executor.spin_once(timeout_sec=0.05)
            if drain:
                got["learner"] += learner.receive()
                got["listener"] += listener.receive()
        return True

    def answers(name: str) -> list[dict[str, Any]]:
        return [m.model_dump() for m in got[name] if isinstance(m, Response)]

    def queries(name: str) -> list[str]:
        return [m.id for m in got[name] if isinstance(m, Query)]

    out: dict[str, Any] = {}
    # Presence: each sees the other two reading the query topic.
    out["present"] = spin_until(lambda: len(learner.peers()) == 2 and len(teacher.peers()) == 2)
    out["peers"] = sorted(learner.peers())
    # The fleet's subscriptions are matched both ways once the learner's publisher reaches both.
    spin_until(lambda: learner._queries.get_subscription_count() >= 2)
    spin_until(lambda: teacher._answers.get_subscription_count() >= 2)
    query = Query(id="q1", sender="learner", sequence=SEQUENCE)
    learner.broadcast(query)
    out["answered"] = spin_until(lambda: bool(answers("learner")) and bool(answers("listener")))
    out["learner_got"] = answers("learner")
    out["listener_got"] = answers("listener")
    # The same query again within the answer window: the teacher does not answer it twice,
    # and a second copy of an answer to it takes no second place at the learner.
    learner.broadcast(query)
    teacher.send("learner", Response.of("q1", "teacher", SEQUENCE, SUBTREE))
    out["repeat_refused"] = spin_until(lambda: learner.refused >= 1)
    out["learner_answers_after_repeat"] = len(answers("learner"))
    # One query naming two sequences (section 1): an answer for each, in the order asked;
    # the teacher read it after the repeat (one publisher's messages arrive in order), so
    # its count shows the repeat went unanswered.
    both = Query(id="q3", sender="learner", sequence=OTHER, more=(SEQUENCE,))
    learner.broadcast(both)
    out["both_answered"] = spin_until(lambda: len(answers("learner")) >= 3)
    out["both"] = [a["sequence"] for a in answers("learner") if a["id"] == "q3"]
    out["teacher_answered"] = teacher.answered
    # A flood into the learner's inbox (3 places), not read meanwhile: the newcomers are
    # refused, the first three kept.
    got["learner"].clear()
    refused = learner.refused
    for i in range(6):
        listener.send("learner", Response.of(f"x{i}", "listener", SEQUENCE, SUBTREE))
    spin_until(lambda: learner.refused >= refused + 3, 10, drain=False)
    out["flood_refused"] = learner.refused - refused
    out["flood_kept"] = [m.id for m in learner.receive()]
    # Inactive, a robot reads nothing and answers nothing: the listener's copy of the query
    # shows it reached the fleet.
    teacher.active = False
    learner.broadcast(Query(id="q2", sender="learner", sequence=SEQUENCE))
    out["q2_heard"] = spin_until(lambda: "q2" in queries("listener"))
    executor.spin_once(timeout_sec=0.05)
    out["inactive_answered"] = teacher.answered
    out["q2_answers"] = [a for a in answers("learner") if a["id"] == "q2"]
    # A robot that comes later is a new neighbour as soon as its subscription to the query
    # topic matches the learner's query publisher (its own, the teacher's and the listener's
    # matched before).
    out["joined_before"] = learner.joined
    nodes["late"] = rclpy.create_node("ktbt", namespace="/late")
    executor.add_node(nodes["late"])
    late = Ros2Transport(nodes["late"], "late")
    out["joined_late"] = spin_until(lambda: learner.joined > out["joined_before"])
    out["joined_after"] = learner.joined
    for transport in (teacher, learner, listener, late):
        transport.close()
    for node in nodes.values():
        node.destroy_node()
    try_shutdown()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
