"""A docking station: a real ROS 2 action server for ``ktbt_example_interfaces/action/Dock`` on
``/dock``, in a process of its own (docs/tutorials/ros2.md, "Embedding in your own node").

    python examples/ros2/dock_server.py   # until Ctrl-C

It knows the docks ``A`` and ``B``: a goal for either is driven to (feedback: the distance left)
and docked (``docked`` true); any other is aborted with ``docked`` false and the reason. It
prints one line per goal, so that whoever started it sees what it was asked.
"""

from __future__ import annotations

import signal
import threading
from typing import Any

import rclpy
from ktbt_example_interfaces.action import Dock
from rclpy.action.server import ActionServer
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import try_shutdown

DOCKS = {"A": 1.5, "B": 4.0}
"""The docks this station knows, with how far each is (metres)."""


def execute(goal: Any) -> Any:
    """Drive to the dock asked, reporting the distance left, and dock."""
    dock = goal.request.dock
    print(f"dock_server: goal dock={dock}", flush=True)
    result = Dock.Result()
    if dock not in DOCKS:
        goal.abort()
        result.docked, result.message = False, f"no dock {dock!r} (known: {', '.join(DOCKS)})"
    else:
        distance = DOCKS[dock]
        while distance > 0:
            distance = max(0.0, distance - 0.5)
            goal.publish_feedback(Dock.Feedback(distance=distance))
        goal.succeed()
        result.docked, result.message = True, f"docked at {dock}"
    print(f"dock_server: {result.message}", flush=True)
    return result


def main() -> None:
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("dock_server")
    server = ActionServer(node, Dock, "/dock", execute)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    print("dock_server: serving /dock (docks A, B)", flush=True)
    try:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.1)
    finally:
        server.destroy()
        executor.shutdown()
        node.destroy_node()
        try_shutdown()


if __name__ == "__main__":
    main()
