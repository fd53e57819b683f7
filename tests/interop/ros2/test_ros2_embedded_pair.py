"""Two robots embedded the usual way, each a user's node named ``bt`` in a namespace of its own
(``/robot1/bt``, ``/robot2/bt``), learn from each other: they are named by the one rule of every
ROS 2 host (the namespace's last name), run the one fleet member, and offer the lifecycle
node's services under ``~/ktbt`` (spec/protocol.md sections 4.5 and 11, "Embedding"). Real
rclpy processes in a network namespace of the module's own (``rosns``)."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from typing import Any

import pytest

from ktbt_proto.files import packaged
from tests.interop.ros2.rosns import SEQUENCE, Probe, RosNamespace, wait_for_line

pytestmark = [pytest.mark.network, pytest.mark.slow, pytest.mark.timeout(300)]

KNOWLEDGE = packaged("examples", "knowledge", "colours.sbt")
GREEN = "TargetSeen(colour=2)"

USER_NODE = '''
"""A user's robot: their node, their py_trees tree ticked by their timer, and KT-BT attached."""
import sys

import py_trees
import rclpy

from ktbt_proto.interop.ros2.embed import attach
from ktbt_proto.tools.demo import demo_registry

rclpy.init(args=sys.argv)
node = rclpy.create_node("bt")
root = py_trees.composites.Selector(
    "Root", memory=False,
    children=[py_trees.composites.Selector("k:new", memory=False),
              py_trees.behaviours.Running("Wander")],
)
tree = py_trees.trees.BehaviourTree(root)
knowledge = sys.argv[1] if len(sys.argv) > 1 and sys.argv[1] != "-" else None
sequences = sys.argv[2:3] if len(sys.argv) > 2 and not sys.argv[2].startswith("--") else None
try:
    robot = attach(node, tree, demo_registry(), knowledge=knowledge, sequences=sequences, wait=1.0)
except ValueError as exc:  # a name the fleet already has, say: one line
    node.get_logger().error(str(exc))
    sys.exit(1)
node.get_logger().info(f"attached as {robot.name}")
node.create_timer(0.05, tree.tick)
try:
    rclpy.spin(node)
except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
    pass
finally:
    robot.close()
'''


@pytest.fixture(scope="module")
def pair(ros2_built: None, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    tmp = tmp_path_factory.mktemp("pair")
    script = tmp / "user_robot.py"
    script.write_text(USER_NODE)
    ns = RosNamespace(tmp)
    ns.script = script  # type: ignore[attr-defined]
    try:
        for name, args in (
            ("robot1", [str(KNOWLEDGE)]),  # knows the colour skills, told to meet nothing
            ("robot2", ["-", GREEN]),  # knows nothing, meets the green one
        ):
            ns.start(
                [sys.executable, str(script), *args, "--ros-args", "-r", f"__ns:=/{name}"],
                name,
            )
        yield ns
    finally:
        ns.close()


def test_two_robots_both_named_bt_by_their_nodes_learn_from_each_other(pair: Any) -> None:
    ns = pair
    wait_for_line(ns, "robot1", "attached as robot1")
    wait_for_line(ns, "robot2", "attached as robot2")
    # On the default policy, each says once who can teach it.
    wait_for_line(ns, "robot1", f"robot1: policy any: every participant of ROS domain {ns.domain}")
    wait_for_line(ns, "robot2", f"robot2: learned {GREEN} from robot1")
    assert "refused" not in ns.log("robot2"), ns.log("robot2")


def test_an_embedded_robot_answers_list_and_forget(pair: Any) -> None:
    ns = pair
    wait_for_line(ns, "robot2", f"robot2: learned {GREEN} from robot1")
    listed = ns.run("ros2", "list", "/robot2/bt/ktbt", "--until", GREEN, "--timeout", "60")
    assert listed.returncode == 0, listed.stdout + listed.stderr
    assert GREEN in listed.stdout and "robot1" in listed.stdout
    innate = ns.run("ros2", "forget", "/robot1/bt/ktbt", GREEN, "--timeout", "60")
    assert innate.returncode != 0 and "innate" in innate.stdout + innate.stderr
    forgot = ns.run("ros2", "forget", "/robot2/bt/ktbt", GREEN, "--timeout", "60")
    assert forgot.returncode == 0, forgot.stdout + forgot.stderr
    wait_for_line(ns, "robot2", f"robot2: forgot {GREEN} (asked)")
    after = ns.run("ros2", "list", "/robot2/bt/ktbt", "--timeout", "60")
    assert after.returncode == 0 and GREEN not in after.stdout, after.stdout


def test_a_robot_started_under_a_name_already_taken_is_refused_with_one_line(pair: Any) -> None:
    """A name is the robot's, announced to its fleet (section 11): a lifecycle node and an
    embedded robot started under a name the fleet already has are refused, each with one line
    naming both nodes (one whose explicit name is free starts: the next test's)."""
    ns: RosNamespace = pair
    wait_for_line(ns, "robot1", "attached as robot1")
    wait_for_line(ns, "robot2", "attached as robot2")

    # A lifecycle node told the name robot1: configure fails, the process ends.
    node = ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/robot3",
                   "-p", "agent_name:=robot1", name="robot3")  # fmt: skip
    assert node.wait(timeout=120) == 1, ns.log("robot3")
    lines = [line for line in ns.log("robot3").splitlines() if "is taken" in line]
    assert len(lines) == 1 and "[ERROR]" in lines[0], ns.log("robot3")
    assert lines[0].endswith(
        "configure failed: agent_name 'robot1' is taken: /robot1/bt announces it "
        "(this node: /robot3/ktbt)"
    ), lines

    # An embedded robot named robot2 by its namespace, on another node there.
    user = ns.start([sys.executable, str(ns.script), "-", "--ros-args",  # type: ignore[attr-defined]
                     "-r", "__ns:=/robot2", "-r", "__node:=bt2"], "bt2")  # fmt: skip
    assert user.wait(timeout=120) == 1, ns.log("bt2")
    lines = [line for line in ns.log("bt2").splitlines() if "is taken" in line]
    assert len(lines) == 1 and "[ERROR]" in lines[0], ns.log("bt2")
    assert lines[0].endswith("name 'robot2' is taken: /robot2/bt announces it (this node: "
                             "/robot2/bt2)"), lines  # fmt: skip
    assert "Traceback" not in ns.log("bt2")


def test_a_malformed_query_gets_one_error_reply_from_a_fleet_of_three(pair: Any) -> None:
    """One error reply per malformed query, from the robot whose name comes first of those
    the fleet announces (section 11), not one per robot: three robots read it, each refuses
    it, one replies. The barrier: a valid query afterwards, answered by two of them. The third
    robot is in the namespace /robot1, whose name is taken, but named alpha: it starts."""
    ns: RosNamespace = pair
    wait_for_line(ns, "robot1", "attached as robot1")
    wait_for_line(ns, "robot2", "attached as robot2")
    ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/robot1",
            "-p", "agent_name:=alpha", "-p", f"knowledge:={KNOWLEDGE}", name="alpha")  # fmt: skip
    wait_for_line(ns, "alpha", "alpha: active", 120)
    assert "is taken" not in ns.log("alpha")
    probe = Probe(ns)
    probe.subscribe("/ktbt/errors", "ErrorReply")
    probe.subscribe("/ktbt/answers", "Answer")
    probe.until({"op": "subscribers", "topic": "/ktbt/queries", "count": 3})
    v2 = {"v": 2, "id": "h1", "sender": "hostile", "sequence": SEQUENCE}
    probe.until({"op": "publish", "topic": "/ktbt/queries", "type": "Query", "subscribers": 3,
                 "fields": v2})  # fmt: skip
    for name in ("robot1", "robot2", "alpha"):
        wait_for_line(ns, name, f"{name} refused: on /ktbt/queries", 60)
    error = probe.wait("/ktbt/errors", 60, to="hostile", code="refused")
    assert error["sender"] == "alpha"  # alpha < robot1 < robot2
    valid = {"v": 1, "id": "b1", "sender": "hostile", "sequence": SEQUENCE}
    probe.until({"op": "publish", "topic": "/ktbt/queries", "type": "Query", "subscribers": 3,
                 "fields": valid})  # fmt: skip
    for teacher in ("robot1", "alpha"):
        probe.wait("/ktbt/answers", 60, id="b1", to="hostile", sender=teacher)
    assert len(probe.messages("/ktbt/errors")) == 1, probe.messages("/ktbt/errors")
