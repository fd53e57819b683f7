"""A docking robot written as a ROS 2 user writes one: its own rclpy node, its own py_trees
tree ticked by its own timer, and one call, ``kp.attach``
(:func:`ktbt_proto.interop.ros2.embed.attach`), that lets the tree learn and teach over ROS 2
(docs/tutorials/ros2.md, "Embedding in your own node").

    python examples/ros2/dock_robot.py [--name NAME] [--sequence SEQ ...]

The robot patrols, and its battery drains. It does not know how to dock: its tree has a
placeholder (``k:new``) where learned knowledge runs, before patrolling. Told no sequence, it
asks the fleet for what the fleet's catalogs list that its vocabulary (``dock.toml``) can
execute; a teacher that knows ``dock.sbt`` answers, and from the next tick, with the battery
low, the learned item runs ``Dock(dock="A")``: the robot's own :class:`DockClient`, which sends
a goal to the ``/dock`` action server (``dock_server.py``, another process) and succeeds when
it is docked. Then it charges, and teaches what it learned to whoever asks.
"""

from __future__ import annotations

import argparse
import signal
import threading
from pathlib import Path
from typing import Any

import py_trees
import rclpy
from ktbt_example_interfaces.action import Dock
from rclpy.action.client import ActionClient
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import try_shutdown

import ktbt_proto as kp

VOCABULARY = Path(__file__).with_name("dock.toml")
Status = py_trees.common.Status


class DockClient(py_trees.behaviour.Behaviour):
    """``Dock(dock=...)``: one goal to the ``/dock`` action server, RUNNING until its result.
    Made from a learned leaf's arguments, and set up with the node, as py_trees_ros sets up
    its behaviours (``setup(node=...)``)."""

    def __init__(self, dock: str) -> None:
        super().__init__(f"Dock {dock}")
        self.dock = dock
        self.node: Any = None
        self.client: Any = None
        self.docked = False

    def setup(self, **kwargs: Any) -> None:
        self.node = kwargs["node"]
        self.client = ActionClient(self.node, Dock, "/dock")

    def initialise(self) -> None:
        self.goal: Any = None
        self.result: Any = None

    def update(self) -> Status:
        if self.goal is None:  # never blocks: the node's executor completes the futures
            if not self.client.server_is_ready():
                return Status.RUNNING
            self.goal = self.client.send_goal_async(Dock.Goal(dock=self.dock))
            return Status.RUNNING
        if self.result is None:
            if not self.goal.done():
                return Status.RUNNING
            handle = self.goal.result()
            if not handle.accepted:
                return Status.FAILURE
            self.result = handle.get_result_async()
        if not self.result.done():
            return Status.RUNNING
        outcome = self.result.result().result
        self.node.get_logger().info(f"Dock result: docked {outcome.docked}, {outcome.message}")
        self.docked = bool(outcome.docked)
        return Status.SUCCESS if outcome.docked else Status.FAILURE

    def terminate(self, new_status: Status) -> None:
        if new_status == Status.INVALID and self.goal is not None and self.goal.done():
            self.goal.result().cancel_goal_async()  # halted while docking


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="A docking robot that learns over ROS 2.")
    parser.add_argument("--name", default="dock_robot", help="its node's name")
    parser.add_argument("--sequence", action="append", help="what to learn (default: the fleet's)")
    args = parser.parse_args(argv)
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(args.name)

    # The user's own tree: learned knowledge first, then patrolling.
    root = py_trees.composites.Selector("DockingRobot", memory=False, children=[
        py_trees.composites.Selector("k:new", memory=False),  # the placeholder <k>(new)
        py_trees.behaviours.Running("Patrol"),
    ])  # fmt: skip
    tree = py_trees.trees.BehaviourTree(root)

    # The one call: the tree learns and teaches over ROS 2 from now on.
    robot = kp.attach(
        node, tree, kp.load_vocabulary(VOCABULARY), behaviours={"Dock": DockClient},
        sequences=args.sequence,
    )  # fmt: skip

    battery = [1.0]

    def tick() -> None:  # the user's own timer ticks the tree, 10 Hz
        battery[0] = max(0.0, battery[0] - 0.02)
        robot.blackboard["BatteryLow"] = battery[0] < 0.5
        tree.tick()
        if any(isinstance(b, DockClient) and b.docked for b in root.iterate()):
            battery[0] = 1.0  # docked: charged
            for b in root.iterate():
                if isinstance(b, DockClient):
                    b.docked = False

    node.create_timer(0.1, tick)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.1)
    finally:
        robot.close()
        executor.shutdown()
        node.destroy_node()
        try_shutdown()


if __name__ == "__main__":
    main()
