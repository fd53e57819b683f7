"""The ROS package ``ktbt_ros`` (``ros2/ktbt_ros``, ament_python) as a ROS team adopts it
(spec/protocol.md section 11, "ROS 2 binding"): built with ``ktbt_interfaces`` (and the example
robot's ``ktbt_example_interfaces``) in a colcon workspace by the colcon of the package registry
(the ``ros2`` extra), over the ROS 2 wheels as the underlay; then, with ``install/setup.bash``
sourced, its installed executable (``lib/ktbt_ros/ktbt_node``, what ``ros2 run ktbt_ros
ktbt_node`` starts) runs a teacher and two learners configured by the package's installed
parameter files, and the learners learn.

The workspace is a copy of the three packages in the test's tmp folder, so that colcon builds
nothing else of the repository and writes nothing into it (its ``build/``, ``install/`` and
``log/`` stay in the tmp folder). The robots run in the test's network namespace (``rosns``),
each one bash process that sources the workspace and then becomes the node (``exec``), so that
it is ended by its pid like any other.
"""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from ktbt_proto.tools.ros2 import interfaces
from tests.interop.ros2.rosns import RosNamespace
from tests.zenoh_helpers import wait_until

pytestmark = [pytest.mark.network, pytest.mark.slow, pytest.mark.timeout(300)]

REPO = Path(__file__).resolve().parents[3]
PACKAGES = ("ktbt_interfaces", "ktbt_example_interfaces", "ktbt_ros")
VENV = Path(sys.prefix)
BUILD_SECONDS = 180
"""The colcon build's deadline: about 20-45 s on a busy two-core machine, mostly
ktbt_interfaces' generated C and C++."""


WHERE = """\
import sys
from ament_index_python.packages import get_package_prefix
import ktbt_interfaces
from ktbt_example_interfaces.action import Dock
print(get_package_prefix("ktbt_ros"))
print(get_package_prefix("ktbt_interfaces"))
print(ktbt_interfaces.__file__)
print(sys.modules["ktbt_example_interfaces"].__file__)
"""
"""Where a sourced workspace's Python finds the packages: as ``ros2 run`` does (the ament
index), and as an import does (the example robot's ``Dock`` action too)."""


def underlay() -> dict[str, str]:
    """What a workspace over the wheels needs before colcon runs and before it is sourced: the
    environment's prefix as the ament and CMake prefix, its ``bin/`` on PATH (ros2.md, "A colcon
    workspace over the wheels"). With a sourced ROS 2 instead, its own environment is the
    underlay."""
    if interfaces.system_ros() is not None:
        return {}
    return {
        "AMENT_PREFIX_PATH": str(VENV),
        "CMAKE_PREFIX_PATH": str(VENV),
        "PATH": f"{VENV / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}",
    }


def colcon() -> str:
    """The colcon to build with: this environment's (the ``ros2`` extra's), else a sourced ROS
    installation's."""
    found = VENV / "bin" / "colcon"
    if found.is_file():
        return str(found)
    other = shutil.which("colcon") if interfaces.system_ros() is not None else None
    if other is None:
        pytest.fail(f"colcon is not installed in {VENV}: pip install 'ktbt[ros2]'")
    return other


def build_workspace(ws: Path) -> float:
    """Copy the packages into ``ws/src`` and ``colcon build`` them; the build's seconds.
    The build's output goes to ``ws/colcon-build.log``, whose end a failure shows."""
    for package in PACKAGES:
        shutil.copytree(
            REPO / "ros2" / package,
            ws / "src" / package,
            ignore=shutil.ignore_patterns("__pycache__"),
        )
    if interfaces.system_ros() is None:  # as `ktbt ros2 build` does before configuring
        interfaces.repair_exports(interfaces.prefix() / "share")
    env = {**os.environ, **underlay(), "COLCON_HOME": str(ws / ".colcon")}
    output = ws / "colcon-build.log"
    start = time.monotonic()
    with output.open("w") as out:
        done = subprocess.run(
            [colcon(), "build", "--base-paths", "src", "--event-handlers", "console_direct-"],
            cwd=ws,
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
            timeout=BUILD_SECONDS,
            check=False,
        )
    seconds = time.monotonic() - start
    log = output.read_text(errors="replace")
    assert done.returncode == 0, f"colcon build failed ({done.returncode}):\n{log[-4000:]}"
    assert all(f"Finished <<< {package}" in log for package in PACKAGES), log[-2000:]
    return seconds


def sourced(ws: Path, *command: str) -> list[str]:
    """``command`` run by a bash that first sources the workspace over its underlay, then
    becomes the command (``exec``: the pid started is the command's)."""
    exports = " ".join(f"{name}={shlex.quote(value)}" for name, value in underlay().items())
    script = (f"export {exports}; " if exports else "") + 'source install/setup.bash && exec "$@"'
    return ["bash", "-c", script, "bash", *command]


def test_the_workspace_builds_and_its_installed_node_runs_robots_that_learn(
    rosns: Any, tmp_path: Path
) -> None:
    ns: RosNamespace = rosns
    ws = tmp_path / "ws"
    seconds = build_workspace(ws)
    print(f"colcon build: {seconds:.1f} s", file=sys.stderr)
    assert not any((REPO / "ros2" / p / d).exists() for p in PACKAGES for d in ("build", "log"))

    # What `ros2 run ktbt_ros ktbt_node` finds: the package in the ament index, its executable
    # in lib/ktbt_ros; the example files in share/ktbt_ros/config; the workspace's interfaces.
    lib = ws / "install" / "ktbt_ros" / "lib" / "ktbt_ros"
    share = ws / "install" / "ktbt_ros" / "share" / "ktbt_ros"
    node, bridge = lib / "ktbt_node", lib / "ktbt_bridge"
    assert os.access(node, os.X_OK) and os.access(bridge, os.X_OK)
    assert {p.name for p in (share / "config").iterdir()} >= {
        "robot.yaml",
        "fleet.yaml",
        "colours.sbt",
    }
    where = subprocess.run(
        [*ns.enter, "--", *sourced(ws, "python", "-c", WHERE)],
        cwd=ws, env=ns.env(), capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert where.returncode == 0, where.stderr
    install = ws / "install"
    prefixes = [Path(line) for line in where.stdout.splitlines()]
    assert prefixes[:2] == [install / "ktbt_ros", install / "ktbt_interfaces"], where.stdout
    assert prefixes[2].is_relative_to(install / "ktbt_interfaces"), where.stdout
    assert prefixes[3].is_relative_to(install / "ktbt_example_interfaces"), where.stdout
    # The bridge's executable runs `ktbt ros2 bridge`: without a fleet to bridge, one line.
    refused = subprocess.run(
        [*ns.enter, "--", *sourced(ws, str(bridge))],
        cwd=ws, env=ns.env(), capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert (refused.returncode, refused.stderr.strip()) == (
        2,
        "error: --connect: required: the zenoh fleet to bridge (--connect ENDPOINT)",
    ), refused

    # A teacher and robot1 configured by the installed fleet.yaml (robot1 told the green
    # skill), a learner by robot.yaml (told nothing: it meets what the teacher's catalog lists).
    fleet, robot = str(share / "config" / "fleet.yaml"), str(share / "config" / "robot.yaml")
    knowledge = f"knowledge:={share / 'config' / 'colours.sbt'}"
    started = {
        "teacher": ns.start(sourced(ws, str(node), "--autostart", "--ros-args", "-r",
                                    "__ns:=/teacher", "--params-file", fleet, "-p", knowledge),
                            "teacher", cwd=ws),
        "robot1": ns.start(sourced(ws, str(node), "--autostart", "--ros-args", "-r",
                                   "__ns:=/robot1", "--params-file", fleet), "robot1", cwd=ws),
        "learner": ns.start(sourced(ws, str(node), "--autostart", "--ros-args", "-r",
                                    "__ns:=/learner", "--params-file", robot), "learner", cwd=ws),
    }  # fmt: skip
    # From the teacher, or from the learner that learned it first (a member teaches on).
    learned = "robot1: learned TargetSeen(colour=2) from "
    assert wait_until(
        lambda: learned in ns.log("robot1") or any(p.poll() is not None for p in started.values()),
        90,
    ), ns.log("robot1")
    assert learned in ns.log("robot1"), {name: ns.log(name) for name in started}
    # Yellow only the teacher knows: the learner, told no sequence, learns it from its catalog.
    listed = subprocess.run(
        [*ns.enter, "--", *sourced(ws, "ktbt", "ros2", "list", "/learner/ktbt",
                                   "--until", "TargetSeen(colour=3)", "--timeout", "90")],
        cwd=ws, env=ns.env(), capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert listed.returncode == 0, (listed.stderr, ns.log("learner"))
    assert "  TargetSeen(colour=3)  (teacher teacher)\n" in listed.stdout, listed.stdout
    assert "learner: learned TargetSeen(colour=3) from teacher" in ns.log("learner")

    # Each ends cleanly on SIGTERM (by its pid), its summary logged.
    for proc in started.values():
        proc.send_signal(signal.SIGTERM)
    for name, proc in started.items():
        assert proc.wait(timeout=30) == 0, ns.log(name)
        log = ns.log(name)
        assert "Traceback" not in log and "queries sent" in log, log
