"""Two robots in one process log each line once, through their own node's logger, at that
node's level (spec/protocol.md section 11, ``ktbt_proto.interop.ros2.logs``): a user's script
attaches KT-BT to two nodes spun by one executor, ``/robot1/bt`` (logging errors only,
``--log-level robot1.bt:=error``) and ``/robot2/bt``; the test's probe sends each an answer to
no question of its, which each refuses. A real rclpy process in a network namespace of its own
(``rosns``)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import pytest

from ktbt_proto.files import packaged
from tests.interop.ros2.rosns import SEQUENCE, SUBTREE, Probe, RosNamespace, wait_for_line

pytestmark = [pytest.mark.network, pytest.mark.slow, pytest.mark.timeout(300)]

KNOWLEDGE = packaged("examples", "knowledge", "colours.sbt")
GREEN = "TargetSeen(colour=2)"

TWO_NODES = '''
"""Two users' robots in one process: a node each, a tree each, KT-BT attached to both."""
import sys

import py_trees
import rclpy
from rclpy.executors import SingleThreadedExecutor

from ktbt_proto.interop.ros2.embed import attach
from ktbt_proto.tools.demo import demo_registry

rclpy.init(args=sys.argv)
robots, executor = [], SingleThreadedExecutor()
for namespace, knowledge, sequences in (
    ("/robot1", sys.argv[1], None),
    ("/robot2", None, [sys.argv[2]]),
):
    node = rclpy.create_node("bt", namespace=namespace)
    root = py_trees.composites.Selector(
        "Root", memory=False,
        children=[py_trees.composites.Selector("k:new", memory=False),
                  py_trees.behaviours.Running("Wander")],
    )
    tree = py_trees.trees.BehaviourTree(root)
    robots.append(attach(node, tree, demo_registry(), knowledge=knowledge, sequences=sequences))
    node.create_timer(0.05, tree.tick)
    executor.add_node(node)
try:
    executor.spin()
except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
    pass
finally:
    for robot in robots:
        robot.close()
'''


def test_two_robots_in_one_process_log_each_line_once_through_their_own_node(
    rosns: Any, tmp_path: Path
) -> None:
    ns: RosNamespace = rosns
    script = tmp_path / "two_robots.py"
    script.write_text(TWO_NODES)
    probe = Probe(ns)
    for robot in ("robot1", "robot2"):
        probe.subscribe(f"/{robot}/bt/ktbt/events", "FleetEvent")
    ns.start([sys.executable, str(script), str(KNOWLEDGE), GREEN,
              "--ros-args", "--log-level", "robot1.bt:=error"], "robots")  # fmt: skip
    learned = wait_for_line(ns, "robots", f"robot2: learned {GREEN} from robot1", 120)
    assert "[robot2.bt]" in learned

    # An answer to no question of theirs: each robot's agent refuses it (the library's record).
    for robot in ("robot1", "robot2"):
        forged = {"v": 1, "id": "none", "sender": "stranger", "to": robot,
                  "sequence": SEQUENCE, "subtree": SUBTREE}  # fmt: skip
        probe.until({"op": "publish", "topic": "/ktbt/answers", "type": "Answer",
                     "subscribers": 2, "fields": forged})  # fmt: skip
        # The refusal is logged before it is recorded: once its event is out, so is its line.
        probe.wait(f"/{robot}/bt/ktbt/events", 60, event="refused", sender="", reason="stranger")
    lines = ns.log("robots").splitlines()
    refusals = [line for line in lines if "refused knowledge: from stranger" in line]
    assert len(refusals) == 1, lines  # robot2's; robot1 logs errors only
    assert "[WARN]" in refusals[0] and "[robot2.bt]" in refusals[0]
    assert "robot2 refused knowledge" in refusals[0]
    assert sum(f"robot2: learned {GREEN}" in line for line in lines) == 1
    assert not any("[robot1.bt]" in line for line in lines), lines
