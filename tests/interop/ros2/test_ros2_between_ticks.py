"""A ROS robot steps between its ticks (spec/protocol.md section 11, "The node" and
"Embedding"): told what to meet, it asks at once, and an answer to its query is merged at once,
not at its next tick. Real rclpy nodes in one process in a network namespace of their own, on
each of rclpy's executors: a lifecycle node that ticks once in 1,000 s learns with its tick
count still 0, and its tree runs the item at its first tick; an embedded robot (``attach``)
whose agent's timer runs once a minute learns with that timer never run, and its user's next
tick inserts the item."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import pytest

from ktbt_proto.files import packaged
from tests.interop.ros2.rosns import RosNamespace

pytestmark = [pytest.mark.network, pytest.mark.slow, pytest.mark.timeout(300)]

PRELUDE = """
import json, sys, time
import py_trees, rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.experimental.events_executor import EventsExecutor
from rclpy.parameter import Parameter
from ktbt_proto.exchange.member import FleetMember
from ktbt_proto.interop.ros2.embed import attach
from ktbt_proto.items import sequence_key
from ktbt_proto.tools.demo import demo_registry
from ktbt_proto.tools.ros2.node import KtbtNode

kind, colours = sys.argv[1], sys.argv[2]
green = sequence_key(["TargetSeen(colour=2)"])
rclpy.init()
executor = EventsExecutor() if kind == "events" else SingleThreadedExecutor()
teacher = KtbtNode(namespace="/teacher", parameter_overrides=[
    Parameter("knowledge", value=colours), Parameter("sequences", value=["TargetSeen(colour=1)"])])
teacher.trigger_configure()
teacher.trigger_activate()
executor.add_node(teacher)

def spin_until(done, seconds=120):
    deadline = time.monotonic() + seconds
    while not done():
        if time.monotonic() > deadline:
            raise SystemExit("timed out")
        executor.spin_once(timeout_sec=0.05)

def matched(transport):
    # until each hears the other's queries and answers (DDS matched both ways)
    spin_until(lambda: transport._queries.get_subscription_count() >= 2
               and teacher.transport._answers.get_subscription_count() >= 2)
"""
"""The teacher (a lifecycle node knowing the colours) and the helpers both scripts use."""

SCRIPT = (
    PRELUDE
    + """
learner = KtbtNode(namespace="/learner", parameter_overrides=[
    Parameter("tick_rate", value=0.001), Parameter("sequences", value=["TargetSeen(colour=1)"])])
learner.trigger_configure()
learner.trigger_activate()
executor.add_node(learner)
matched(learner.transport)  # before it is told
learner.set_parameters([Parameter("sequences", value=["TargetSeen(colour=2)"])])
spin_until(lambda: learner.agent.knows([green]))
learned_at = learner.agent.now
learner.agent.blackboard["target"] = 2
learner.agent.control.tick()
print(json.dumps({"learned_at_tick": learned_at,
                  "source": learner.agent.metrics.learned[green][1],
                  "carrying": learner.agent.blackboard.get("Carrying") is True,
                  "queries_sent": learner.agent.metrics.queries_sent}), flush=True)
for node in (teacher, learner):
    node.trigger_shutdown()
    node.destroy_node()
rclpy.shutdown()
"""
)

EMBEDDED = (
    PRELUDE
    + """
runs = []
step = FleetMember.step
def counted(self, now, tick=True):  # the embedded robot's steps at a run of its timer
    if self.name == "robot1" and tick:
        runs.append(now)
    return step(self, now, tick=tick)
FleetMember.step = counted

user = rclpy.create_node("bt", namespace="/robot1")
root = py_trees.composites.Selector("Root", memory=False, children=[
    py_trees.composites.Selector("k:new", memory=False), py_trees.behaviours.Running("Wander")])
tree = py_trees.trees.BehaviourTree(root)
robot = attach(user, tree, demo_registry(), sequences=[], period=60.0)
executor.add_node(user)
matched(robot.transport)  # before it is told
robot.meet("TargetSeen(colour=2)")
spin_until(lambda: robot.knows([green]))
timer_runs = len(runs)
robot.blackboard["target"] = 2
tree.tick()
print(json.dumps({"timer_runs": timer_runs,
                  "source": robot.agent.metrics.learned[green][1],
                  "inserted": any(n.name == "k:new" and n.children for n in tree.root.iterate()),
                  "queries_sent": robot.agent.metrics.queries_sent}), flush=True)
robot.close()
teacher.trigger_shutdown()
teacher.destroy_node()
user.destroy_node()
rclpy.shutdown()
"""
)


def run_script(ns: RosNamespace, tmp: Path, text: str, name: str, kind: str) -> dict[str, Any]:
    """``text`` run in the namespace with the executor ``kind``; the JSON line it ends with."""
    script = tmp / f"{name}.py"
    script.write_text(text)
    colours = str(packaged("examples", "knowledge", "colours.sbt"))
    proc = ns.start([sys.executable, str(script), kind, colours], f"{name}-{kind}", stdin=True)
    out, _ = proc.communicate(timeout=240)
    assert proc.returncode == 0, ns.log(f"{name}-{kind}")
    result: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
    return result


@pytest.mark.parametrize("kind", ["events", "single"])
def test_a_robot_told_what_to_meet_learns_it_between_its_ticks(
    rosns: Any, tmp_path: Path, kind: str
) -> None:
    result = run_script(rosns, tmp_path, SCRIPT, "between", kind)
    assert result["learned_at_tick"] == 0  # asked and merged with no tick in between
    assert result["source"] == "teacher" and result["queries_sent"] == 1
    assert result["carrying"]  # its first tick runs what it learned


@pytest.mark.parametrize("kind", ["events", "single"])
def test_an_embedded_robot_told_to_meet_learns_between_runs_of_its_timer(
    rosns: Any, tmp_path: Path, kind: str
) -> None:
    result = run_script(rosns, tmp_path, EMBEDDED, "embedded", kind)
    assert result["timer_runs"] == 0  # asked and merged before the agent's timer ever ran
    assert result["source"] == "teacher" and result["queries_sent"] == 1
    assert result["inserted"]  # the user's next tick put it in the tree
