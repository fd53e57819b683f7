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
from tests.interop.ros2.rosns import RosNamespace, wait_for_line

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
robot = attach(node, tree, demo_registry(), knowledge=knowledge, sequences=sequences, wait=1.0)
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
