"""A KT-BT robot as the ROS graph sees it (spec/protocol.md section 11, "ROS 2 binding"): a
third node finds its topics, services and their types through the graph API; a robot learns a
skill from another and runs it; a managed node is driven through its whole lifecycle. One
network namespace, one probe and one teacher and learner serve the module (``robots``); the
lifecycle test starts its own node on a fleet of its own (``/managed_fleet``), so that no test
depends on another's side effects."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from ktbt_proto.files import packaged
from tests.interop.ros2.rosns import SEQUENCE, SUBTREE, Probe, RosNamespace
from tests.zenoh_helpers import wait_until

pytestmark = [pytest.mark.network, pytest.mark.slow, pytest.mark.timeout(300)]

COLOURS = packaged("examples", "knowledge", "colours.sbt")

SEEING = '''\
"""A robot that sees a green target, and says in its log when its actions run."""

import logging

from ktbt_proto.blackboard import Blackboard
from ktbt_proto.tools.demo import Colour
from ktbt_proto.registry import Registry
from ktbt_proto.status import SUCCESS, Status

said = logging.getLogger("ktbt.seeing")


def registry() -> Registry:
    reg = Registry()
    reg.flags("Carrying")

    @reg.condition("TargetSeen")
    def seen(bb: Blackboard, colour: Colour) -> bool:
        return colour == 2

    @reg.action("PickTreasure")
    def pick(bb: Blackboard) -> Status:
        bb["Carrying"] = True
        return SUCCESS

    @reg.action("AssignCollectionPoint")
    def assign(bb: Blackboard, colour: Colour) -> Status:
        ran = bb["ran"] = bb.get("ran", 0) + 1
        if ran <= 3:
            said.info(f"AssignCollectionPoint colour={colour} ran, time {ran}")
        return SUCCESS

    return reg
'''
"""The learner's vocabulary (``seeing:registry``, imported from the namespace's folder): its
action says when it runs, so that the test sees the learned skill tick."""


@dataclass
class Robots:
    ns: RosNamespace
    probe: Probe
    teacher: Any
    learner: Any


@pytest.fixture(scope="module")
def robots(module_rosns: Any) -> Iterator[Robots]:
    """A teacher (the demo robot, the colours knowledge) and a learner with its own vocabulary,
    both started active, and a probe."""
    ns: RosNamespace = module_rosns
    (ns.tmp / "seeing.py").write_text(SEEING)
    probe = Probe(ns)
    probe.subscribe("/learner/ktbt/tree", "TreeSnapshot", latched=True)
    teacher = ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/teacher",
                      "-p", f"knowledge:={COLOURS}", name="teacher")  # fmt: skip
    learner = ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/learner",
                      "-p", "vocabulary:=seeing:registry", "-p", "tick_rate:=20.0",
                      "-p", "sequences:=[TargetSeen(colour=2)]", name="learner")  # fmt: skip
    yield Robots(ns, probe, teacher, learner)


LEARNER_TOPICS = {
    "/learner/ktbt/events": "ktbt_interfaces/msg/FleetEvent",
    "/learner/ktbt/tree": "ktbt_interfaces/msg/TreeSnapshot",
    "/learner/ktbt/catalog": "ktbt_interfaces/msg/Catalog",
    "/learner/ktbt/transition_event": "lifecycle_msgs/msg/TransitionEvent",
    "/ktbt/queries": "ktbt_interfaces/msg/Query",
    "/ktbt/answers": "ktbt_interfaces/msg/Answer",
    "/ktbt/errors": "ktbt_interfaces/msg/ErrorReply",
}
LEARNER_SERVICES = {
    "/learner/ktbt/list_knowledge": "ktbt_interfaces/srv/ListKnowledge",
    "/learner/ktbt/forget": "ktbt_interfaces/srv/Forget",
    "/learner/ktbt/change_state": "lifecycle_msgs/srv/ChangeState",
    "/learner/ktbt/get_state": "lifecycle_msgs/srv/GetState",
    "/learner/ktbt/get_available_states": "lifecycle_msgs/srv/GetAvailableStates",
    "/learner/ktbt/get_available_transitions": "lifecycle_msgs/srv/GetAvailableTransitions",
    "/learner/ktbt/get_transition_graph": "lifecycle_msgs/srv/GetAvailableTransitions",
    "/learner/ktbt/get_parameters": "rcl_interfaces/srv/GetParameters",
    "/learner/ktbt/set_parameters": "rcl_interfaces/srv/SetParameters",
}


def test_a_third_node_sees_the_robots_topics_services_and_types_through_the_graph(
    robots: Robots,
) -> None:
    probe = robots.probe
    seen = probe.until(
        {"op": "graph", "topics": list(LEARNER_TOPICS), "services": list(LEARNER_SERVICES)}, 90
    )
    for name, type_name in LEARNER_TOPICS.items():
        assert seen["topics"][name] == [type_name], name
    for name, type_name in LEARNER_SERVICES.items():
        assert seen["services"][name] == [type_name], name
    # Who publishes what, with which QoS: the snapshot latched, the fleet's answers reliable
    # and shared by both robots.
    tree = probe.until(
        {"op": "publishers", "topic": "/learner/ktbt/tree", "count": 1, "named": True}, 60
    )
    assert (tree["nodes"], tree["types"]) == (
        ["/learner/ktbt"],
        ["ktbt_interfaces/msg/TreeSnapshot"],
    )
    assert tree["durability"] == ["TRANSIENT_LOCAL"] and tree["reliability"] == ["RELIABLE"]
    events = probe.until(
        {"op": "publishers", "topic": "/learner/ktbt/events", "count": 1, "named": True}, 60
    )
    assert events["nodes"] == ["/learner/ktbt"] and events["durability"] == ["VOLATILE"]
    answers = probe.until(
        {"op": "publishers", "topic": "/ktbt/answers", "count": 2, "named": True}, 60
    )
    assert sorted(answers["nodes"]) == ["/learner/ktbt", "/teacher/ktbt"]
    assert set(answers["types"]) == {"ktbt_interfaces/msg/Answer"}
    assert set(answers["reliability"]) == {"RELIABLE"}


def test_a_robot_learns_a_skill_from_another_over_ros_and_runs_it(robots: Robots) -> None:
    ns, probe = robots.ns, robots.probe
    snapshot = probe.wait("/learner/ktbt/tree", 90, tree=SUBTREE)
    assert snapshot["peer"] == "learner" and snapshot["changed"]
    assert wait_until(lambda: "learned TargetSeen(colour=2) from teacher" in ns.log("learner"), 30)
    # Its learned actions tick, again and again: the vocabulary's action says so in its log.
    assert wait_until(
        lambda: "AssignCollectionPoint colour=2 ran, time 3" in ns.log("learner"), 60
    ), ns.log("learner")
    log = ns.log("learner")
    assert log.index("learned TargetSeen(colour=2)") < log.index("colour=2 ran, time 1")
    warned = [line for line in log.splitlines() if "[WARN]" in line]
    assert "Traceback" not in log and len(warned) == 1 and "policy any:" in warned[0]
    listed = probe.until({"op": "call", "service": "/learner/ktbt/list_knowledge",
                          "type": "ListKnowledge"})["response"]["items"]  # fmt: skip
    assert [(i["sequence"], i["teacher"]) for i in listed] == [(SEQUENCE, "teacher")]


def lifecycle(ns: RosNamespace, transition: str) -> str:
    done = ns.run("ros2", "lifecycle", "/managed/ktbt", transition, "--timeout", "60", timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def state(probe: Probe) -> str:
    """The managed node's state, as a third node reads it (lifecycle_msgs' ``get_state``)."""
    got = probe.until({"op": "call", "service": "/managed/ktbt/get_state", "type": "GetState"})
    return str(got["response"]["current_state"]["label"])


def answered(probe: Probe, name: str, attempts: int = 20) -> bool:
    """Whether ``managed`` answers a query ``name-N`` (asked again until it does, or
    ``attempts`` times, 3 s each: a query sent before its subscription matched is lost)."""
    for n in range(attempts):
        query = {"v": 1, "id": f"{name}-{n}", "sender": "probe", "sequence": SEQUENCE}
        probe.until({"op": "publish", "topic": "/managed_fleet/queries", "type": "Query",
                     "fields": query})  # fmt: skip
        got = probe.ask({"op": "wait", "topic": "/managed_fleet/answers",
                         "match": {"id": f"{name}-{n}", "sender": "managed"}}, 3)  # fmt: skip
        if got["ok"]:
            assert got["msg"]["subtree"] == SUBTREE and got["msg"]["to"] == "probe"
            return True
    return False


def test_a_managed_robot_goes_through_its_lifecycle_and_answers_only_while_active(
    robots: Robots,
) -> None:
    """configure, activate, deactivate, cleanup, configure again, activate, shutdown, with
    ``ktbt ros2 lifecycle``, each state read by the probe. The robot answers the probe's
    queries on a fleet of its own (``/managed_fleet``). A query sent while it is inactive,
    then one after it is active again: the second is answered, the first never (the queries
    travel in order from one publisher, and each lifecycle command takes far longer than a
    delivery on the loopback)."""
    ns, probe = robots.ns, robots.probe
    fleet = [f"{t}_topic:=/managed_fleet/{t}" for t in ("queries", "answers", "errors")]
    probe.subscribe("/managed_fleet/answers", "Answer")
    probe.subscribe("/managed/ktbt/events", "FleetEvent")
    ros_args = ["-r", "__ns:=/managed", "-p", f"knowledge:={COLOURS}"]
    for value in fleet:
        ros_args += ["-p", value]
    managed = ns.ktbt("ros2", "run", "--ros-args", *ros_args, name="managed")
    services = ["/managed/ktbt/list_knowledge", "/managed/ktbt/forget"]
    probe.until({"op": "graph", "services": ["/managed/ktbt/change_state"]}, 90)
    assert state(probe) == "unconfigured"
    probe.until({"op": "graph", "services": services, "absent": True}, 5)  # nothing made yet

    assert "configure done" in lifecycle(ns, "configure")
    assert state(probe) == "inactive"
    probe.until({"op": "graph", "services": services}, 30)
    probe.until({"op": "subscribers", "topic": "/managed_fleet/queries", "count": 1})
    silent = {"v": 1, "id": "inactive-1", "sender": "probe", "sequence": SEQUENCE}
    probe.until({"op": "publish", "topic": "/managed_fleet/queries", "type": "Query",
                 "fields": silent})  # fmt: skip

    assert "activate done" in lifecycle(ns, "activate")
    assert answered(probe, "active-1")

    assert "deactivate done" in lifecycle(ns, "deactivate")
    assert state(probe) == "inactive"
    silent["id"] = "inactive-2"
    probe.until({"op": "publish", "topic": "/managed_fleet/queries", "type": "Query",
                 "fields": silent})  # fmt: skip
    assert "cleanup done" in lifecycle(ns, "cleanup")
    assert state(probe) == "unconfigured"
    probe.until({"op": "graph", "services": services, "absent": True}, 30)

    assert "configure done" in lifecycle(ns, "configure")
    assert "activate done" in lifecycle(ns, "activate")
    assert state(probe) == "active"
    assert answered(probe, "active-2")
    ids = {m["id"] for m in probe.messages("/managed_fleet/answers") if m["sender"] == "managed"}
    assert not ids & {"inactive-1", "inactive-2"}, ids

    assert "shutdown done" in lifecycle(ns, "shutdown")
    probe.until({"op": "graph", "services": services, "absent": True}, 30)
    log = ns.log("managed")
    assert log.count("managed: configured, knows 4") == 2
    assert log.count("managed: active") == 2 and "managed: inactive" in log
    assert "Traceback" not in log
    assert managed.wait(timeout=30) == 0  # finalized, it ends by itself
