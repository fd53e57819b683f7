"""The idle benchmark's anchor: a bare rclpy node with a timer (100 Hz, the lifecycle node's
default tick rate) that does nothing, on the executor given: ``single`` spun the idiomatic way
(``rclpy.spin`` with a ``SingleThreadedExecutor``), ``events`` (rclpy's events executor) spun as
``ktbt ros2 run`` spins it (``spin_once(timeout_sec=0.1)`` until SIGTERM: ``rclpy.spin`` with
that executor never ran the timer here). Run inside the benchmark's network namespace by
:mod:`benchmarks.bench_ros2`; it says ``ready`` on stdout once its timer ran, and ends on
SIGTERM."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Sequence

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.utilities import try_shutdown


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_ros2.bare_node")
    parser.add_argument("--rate", type=float, default=100.0, help="timer rate, Hz")
    parser.add_argument("--executor", choices=("events", "single"), default="single")
    args = parser.parse_args(argv)
    rclpy.init()
    stop = threading.Event()

    def end(*_: object) -> None:
        stop.set()
        try_shutdown()

    signal.signal(signal.SIGTERM, end)
    node = rclpy.create_node("bare", namespace=f"/bare_{args.executor}")
    ticks = [0]

    def tick() -> None:
        ticks[0] += 1
        if ticks[0] == 1:
            print("ready", flush=True)

    node.create_timer(1.0 / args.rate, tick)
    try:
        if args.executor == "events":
            from rclpy.experimental.events_executor import EventsExecutor

            executor = EventsExecutor()
            executor.add_node(node)
            while not stop.is_set():
                executor.spin_once(timeout_sec=0.1)
        else:
            rclpy.spin(node, executor=SingleThreadedExecutor())
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        try_shutdown()
    print(f"ticks {ticks[0]}", file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
