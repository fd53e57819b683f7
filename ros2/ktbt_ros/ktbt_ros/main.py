"""The entry points of ``ktbt_node`` and ``ktbt_bridge`` (spec/protocol.md section 11).

Each is the ``ktbt`` command it stands for, with the same options, ``--ros-args`` handling,
errors and exit statuses: ``ros2 run ktbt_ros ktbt_node ARGS`` is ``ktbt ros2 run ARGS``, and
``ros2 run ktbt_ros ktbt_bridge ARGS`` is ``ktbt ros2 bridge ARGS``. They go through the
``ktbt`` app rather than re-implementing a command, so that a ROS-launched robot and one started
with ``ktbt`` cannot drift apart: what section 11 says of ``ktbt ros2 run`` (lifecycle,
``--autostart``, parameters, exit status 0 once finalized) holds for ``ktbt_node`` too. A
launch file's arguments (``--ros-args -r __node:=NAME -r __ns:=/robot1 --params-file ...``)
come after the user's own, as ``ktbt ros2 run`` expects.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

MISSING = (
    "error: the ktbt Python package is not importable by {python}: install it into the "
    "environment that runs colcon and this package's executables (pip install . in a clone)"
)
"""What an executable says, exit 1, when the Python package it runs is missing."""


def ktbt(command: str, argv: Sequence[str] | None = None) -> None:
    """Run ``ktbt ros2 COMMAND`` with ``argv`` (this process's arguments by default); it ends
    the process with the command's exit status."""
    try:
        from ktbt_proto.tools.cli import app
        from ktbt_proto.tools.ros2.command import register
    except ImportError:
        print(MISSING.format(python=sys.executable), file=sys.stderr)
        raise SystemExit(1) from None
    register(app)  # only the ros2 commands: the other plugins are not needed here
    args = list(sys.argv[1:] if argv is None else argv)
    app(args=["ros2", command, *args], prog_name="ktbt")


def node() -> None:
    """``ktbt_node``: one robot's agent as a lifecycle node (``ktbt ros2 run``)."""
    ktbt("run")


def bridge() -> None:
    """``ktbt_bridge``: a zenoh fleet and a ROS 2 fleet learning from each other
    (``ktbt ros2 bridge``)."""
    ktbt("bridge")
