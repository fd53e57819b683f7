"""Every host of the fleet member keeps one contract (spec/protocol.md section 4.5), driven by
one test as the control tree is driven on both of its backends: ``ktbt peer run`` over zenoh,
the ROS 2 lifecycle node (``ktbt ros2 run``), and a user's own rclpy node with ``attach``.

The contract, in the order a fleet meets it: a robot that meets a sequence it lacks asks for it
and learns it from a teacher that knows it, and says so in one line naming the teacher; it lists
what it knows, with who taught it, through its host's listing command; once the teacher is gone,
it teaches what it learned to a robot that appears later and meets the same sequence. Each
host's processes are real and run in a network namespace of the test's own with only loopback
up (zenoh on loopback endpoints, DDS discovery kept there too)."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import pytest

from ktbt_proto.files import packaged
from tests.interop.ros2.rosns import RosNamespace, wait_for_line

pytestmark = [pytest.mark.network, pytest.mark.slow, pytest.mark.timeout(300)]

KNOWLEDGE = packaged("examples", "knowledge", "colours.sbt")
GREEN = "TargetSeen(colour=2)"


class Host(Protocol):
    """How one kind of host starts a robot and lists what a robot knows."""

    def start(
        self, ns: RosNamespace, name: str, *, teaches: bool, after: str | None
    ) -> subprocess.Popen[str]:
        """Start robot ``name``: a teacher knowing ``colours.sbt`` (``teaches``), else a robot
        that knows nothing and meets the green sequence; ``after`` is the robot it reaches
        first (zenoh dials it; ROS 2 discovers everyone)."""

    def listing(self, ns: RosNamespace, name: str) -> list[str]:
        """What robot ``name`` knows, a line an item, as its host's listing command prints it."""


@dataclass
class ZenohPeers:
    """``ktbt peer run``: each robot listens on a port of its own and dials the one before."""

    ports: dict[str, int]

    def endpoint(self, name: str) -> str:
        return f"tcp/127.0.0.1:{self.ports.setdefault(name, 7447 + len(self.ports))}"

    def start(
        self, ns: RosNamespace, name: str, *, teaches: bool, after: str | None
    ) -> subprocess.Popen[str]:
        args = ["peer", "run", "--id", name, "--listen", self.endpoint(name), "--duration", "300"]
        if after is not None:
            args += ["--connect", self.endpoint(after)]
        args += ["--knowledge", str(KNOWLEDGE)] if teaches else ["--sequence", GREEN]
        return ns.ktbt(*args, name=name)

    def listing(self, ns: RosNamespace, name: str) -> list[str]:
        return section(ns.run("peer", "list", "--connect", self.endpoint(name)), name)


@dataclass
class LifecycleNodes:
    """``ktbt ros2 run``: the node ``ktbt`` in the robot's namespace, configured by a
    parameter file and activated at start."""

    tmp: Path

    def start(
        self, ns: RosNamespace, name: str, *, teaches: bool, after: str | None
    ) -> subprocess.Popen[str]:
        what = f"knowledge: {KNOWLEDGE}" if teaches else f'sequences: ["{GREEN}"]'
        params = self.tmp / f"{name}.yaml"
        params.write_text(f"/{name}/ktbt:\n  ros__parameters:\n    {what}\n", encoding="utf-8")
        return ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", f"__ns:=/{name}",
                "--params-file", str(params), name=name)  # fmt: skip

    def listing(self, ns: RosNamespace, name: str) -> list[str]:
        listed = ns.run("ros2", "list", f"/{name}/ktbt", "--until", GREEN, "--timeout", "60")
        return section(listed, f"/{name}/ktbt")


@dataclass
class EmbeddedRobots:
    """``attach``: a user's node named ``bt`` in the robot's namespace, ticking its own
    py_trees tree (the script of ``test_ros2_embedded_pair``)."""

    script: Path

    def start(
        self, ns: RosNamespace, name: str, *, teaches: bool, after: str | None
    ) -> subprocess.Popen[str]:
        args = [str(KNOWLEDGE)] if teaches else ["-", GREEN]
        ros_args = ["--ros-args", "-r", f"__ns:=/{name}"]
        return ns.start([sys.executable, str(self.script), *args, *ros_args], name)

    def listing(self, ns: RosNamespace, name: str) -> list[str]:
        listed = ns.run("ros2", "list", f"/{name}/bt/ktbt", "--until", GREEN, "--timeout", "60")
        return section(listed, f"/{name}/bt/ktbt")


@pytest.fixture(params=["peer run", "ros2 run", "attach"])
def host(request: pytest.FixtureRequest, tmp_path: Path) -> Host:
    if request.param == "peer run":
        return ZenohPeers({})
    request.getfixturevalue("ros2_built")
    if request.param == "ros2 run":
        return LifecycleNodes(tmp_path)
    from tests.interop.ros2.test_ros2_embedded_pair import USER_NODE

    script = tmp_path / "user_robot.py"
    script.write_text(USER_NODE, encoding="utf-8")
    return EmbeddedRobots(script)


def section(listed: subprocess.CompletedProcess[str], header: str) -> list[str]:
    """The item lines under ``header:`` in a listing command's output (each robot's items are
    indented under a line naming it)."""
    assert listed.returncode == 0, listed.stdout + listed.stderr
    lines = listed.stdout.splitlines()
    starts = [i for i, line in enumerate(lines) if line.startswith(f"{header}: ")]
    assert len(starts) == 1, listed.stdout
    items = []
    for line in lines[starts[0] + 1 :]:
        if not line.startswith("  "):
            break
        items.append(line.strip())
    return items


def test_every_host_learns_lists_and_teaches_onward(host: Host, tmp_path: Path) -> None:
    ns = RosNamespace(tmp_path)
    try:
        teacher = host.start(ns, "teacher", teaches=True, after=None)
        host.start(ns, "learner", teaches=False, after="teacher")
        wait_for_line(ns, "learner", f"learner: learned {GREEN} from teacher")

        [item] = host.listing(ns, "learner")
        assert item.startswith(f"{GREEN}  (") and "teacher teacher" in item, item

        teacher.terminate()  # the teacher leaves; only the learner knows the skill now
        teacher.wait(timeout=30)
        host.start(ns, "newcomer", teaches=False, after="learner")
        wait_for_line(ns, "newcomer", f"newcomer: learned {GREEN} from learner")
        for name in ("teacher", "learner", "newcomer"):
            assert "Traceback" not in ns.log(name), ns.log(name)
    finally:
        ns.close()
