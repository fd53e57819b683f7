"""Fleets of ROS 2 robots (spec/protocol.md section 11, "ROS 2 binding"): namespaced robots
configured by one YAML parameters file, as a ROS user launches them (docs/tutorials/ros2.md),
and a teacher that dies during a transfer. One network namespace, one probe and one YAML file
serve the module; each test starts its own robots, on fleet topics of its own, so that no test
depends on another's side effects."""

from __future__ import annotations

import signal
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from ktbt_proto.files import packaged
from ktbt_proto.syntax import parse
from tests.interop.ros2.rosns import Probe, RosNamespace
from tests.zenoh_helpers import wait_until

pytestmark = [pytest.mark.network, pytest.mark.slow, pytest.mark.timeout(300)]

COLOURS = packaged("examples", "knowledge", "colours.sbt")


def skill(colour: int) -> str:
    """The compact subtree of the colours knowledge's item for ``colour``."""
    return f"<sq><a>(PickTreasure)<a>(AssignCollectionPoint,colour={colour})<e>"


def key(colour: int) -> str:
    return f"<c>(TargetSeen,colour={colour})"


def fleet_yaml(tmp: Path) -> Path:
    """One parameters file for every robot of the module, a section per node."""
    doomed = tmp / "doomed.sbt"
    doomed.write_text(
        "<k>(prior)<sq><c>(TargetSeen, colour=3)<a>(PickTreasure)"
        "<a>(AssignCollectionPoint, colour=3)<e><e>\n"
    )
    fleet_b = "\n".join(f"    {t}_topic: /fleet_b/{t}" for t in ("queries", "answers", "errors"))
    path = tmp / "fleet.yaml"
    path.write_text(
        f"""\
/**:
  ros__parameters:
    tick_rate: 20.0
    wait_ticks: 60
/teacher/ktbt:
  ros__parameters:
    knowledge: {COLOURS}
/robot1/ktbt:
  ros__parameters:
    sequences: ["TargetSeen(colour=1)"]
/robot2/ktbt:
  ros__parameters:
    sequences: ["TargetSeen(colour=2)", "TargetSeen(colour=4)"]
/robot3/ktbt:
  ros__parameters:
    agent_name: scout3
    sequences: ["TargetSeen(colour=3)"]
/pupil/ktbt:
  ros__parameters:
{fleet_b}
    sequences: ["TargetSeen(colour=3)", "TargetSeen(colour=4)"]
/doomed/ktbt:
  ros__parameters:
{fleet_b}
    knowledge: {doomed}
/second/ktbt:
  ros__parameters:
{fleet_b}
    knowledge: {COLOURS}
"""
    )
    return path


@dataclass
class Fleet:
    ns: RosNamespace
    probe: Probe
    params: Path

    def run(self, robot: str, autostart: bool = True) -> Any:
        """``ktbt ros2 run`` for ``/robot/ktbt``, configured by the file, started active
        unless not ``autostart``."""
        start = ["--autostart"] if autostart else []
        return self.ns.ktbt("ros2", "run", *start, "--ros-args", "-r", f"__ns:=/{robot}",
                            "--params-file", str(self.params), name=robot)  # fmt: skip


@pytest.fixture(scope="module")
def fleet(module_rosns: Any) -> Iterator[Fleet]:
    ns: RosNamespace = module_rosns
    yield Fleet(ns, Probe(ns), fleet_yaml(ns.tmp))


def test_three_namespaced_robots_and_a_teacher_configured_by_one_yaml_file_all_learn(
    fleet: Fleet,
) -> None:
    ns, probe = fleet.ns, fleet.probe
    wanted = {"robot1": [1], "robot2": [2, 4], "robot3": [3]}
    for robot in wanted:
        probe.subscribe(f"/{robot}/ktbt/tree", "TreeSnapshot", latched=True)
    started = {robot: fleet.run(robot) for robot in ("teacher", *wanted)}
    for robot, colours in wanted.items():
        for colour in colours:
            snapshot = probe.wait(f"/{robot}/ktbt/tree", 120, tree=skill(colour))
        assert snapshot["peer"] == {"robot3": "scout3"}.get(robot, robot)
        listed = probe.until({"op": "call", "service": f"/{robot}/ktbt/list_knowledge",
                              "type": "ListKnowledge"})["response"]["items"]  # fmt: skip
        assert sorted((i["sequence"], i["teacher"]) for i in listed) == [
            (key(c), "teacher") for c in colours
        ]
    # Each robot read its own section, and the section for every node.
    values = probe.until({"op": "params", "node": "/robot2/ktbt",
                          "names": ["sequences", "tick_rate", "agent_name"]})["values"]  # fmt: skip
    assert values == {
        "sequences": ["TargetSeen(colour=2)", "TargetSeen(colour=4)"],
        "tick_rate": 20.0,
        "agent_name": "",
    }
    assert "scout3: learned TargetSeen(colour=3) from teacher" in ns.log("robot3")
    stop(ns, started)


def stop(ns: RosNamespace, started: dict[str, Any]) -> None:
    """End the robots a test started, by their pids: each stops cleanly, its summary logged."""
    for proc in started.values():
        proc.send_signal(signal.SIGTERM)
    for robot, proc in started.items():
        assert proc.wait(timeout=30) == 0, ns.log(robot)
        assert "Traceback" not in ns.log(robot) and "queries sent" in ns.log(robot)


def test_a_teacher_killed_during_a_transfer_leaves_the_learner_unharmed(fleet: Fleet) -> None:
    """One YAML file still configures them all. The doomed teacher (the only one up, knowing
    colour 3) is killed (SIGKILL, by its pid) as soon as the pupil's query for colour 3 is seen
    on the fleet's query topic: "during the transfer" approximated. It answers at once from its
    knowledge, so its answer has usually left and the kill lands while the pupil has still to
    check and merge it at its next tick; if it had not left, the query is lost. Either way the
    pupil is unharmed: it refuses nothing, every tree it shows holds whole items only, and it
    goes on to learn from a second teacher started after the kill (colour 4 from it for
    certain, colour 3 from whichever answered)."""
    ns, probe = fleet.ns, fleet.probe
    probe.subscribe("/fleet_b/queries", "Query")
    probe.subscribe("/pupil/ktbt/events", "FleetEvent")
    probe.subscribe("/pupil/ktbt/tree", "TreeSnapshot", latched=True)
    doomed = fleet.run("doomed")
    probe.until({"op": "publishers", "topic": "/doomed/ktbt/tree", "count": 1}, 90)  # active
    # The pupil asks as soon as it is active: configured first, so that the probe (and the
    # doomed teacher) hear its first query.
    pupil = fleet.run("pupil", autostart=False)
    configured = fleet.ns.run("ros2", "lifecycle", "/pupil/ktbt", "configure", "--timeout", "60")
    assert configured.returncode == 0, configured.stderr
    queries = probe.until(
        {"op": "publishers", "topic": "/fleet_b/queries", "count": 2, "named": True}, 60
    )
    assert sorted(queries["nodes"]) == ["/doomed/ktbt", "/pupil/ktbt"]
    probe.until({"op": "subscribers", "topic": "/fleet_b/queries", "count": 3}, 60)
    activated = fleet.ns.run("ros2", "lifecycle", "/pupil/ktbt", "activate", "--timeout", "60")
    assert activated.returncode == 0, activated.stderr
    probe.wait("/fleet_b/queries", 90, sender="pupil", sequence=key(3))
    doomed.send_signal(signal.SIGKILL)
    assert doomed.wait(timeout=30) == -signal.SIGKILL

    second = fleet.run("second")
    probe.wait("/pupil/ktbt/tree", 120, tree=skill(4))
    probe.wait("/pupil/ktbt/tree", 30, tree=skill(3))
    merged = {
        e["sequence"]: e["teacher"]
        for e in probe.messages("/pupil/ktbt/events")
        if e["event"] == "merged"
    }
    assert merged[key(4)] == "second" and merged[key(3)] in ("doomed", "second"), merged
    events = probe.messages("/pupil/ktbt/events")
    assert [e for e in events if e["event"] == "refused"] == []
    for snapshot in probe.messages("/pupil/ktbt/tree"):
        parse(snapshot["tree"])  # every snapshot a whole tree, and its items whole
        rest = snapshot["tree"]
        for colour in (3, 4):
            rest = rest.replace(f"<sq>{key(colour)}{skill(colour)}<e>", "")
        assert "colour=" not in rest, snapshot["tree"]
    assert pupil.poll() is None
    assert wait_until(lambda: "learned TargetSeen(colour=4) from second" in ns.log("pupil"), 30)
    stop(ns, {"pupil": pupil, "second": second})
    log = ns.log("pupil")
    warned = [line for line in log.splitlines() if "[WARN]" in line or "[ERROR]" in line]
    assert warned == [line for line in warned if "policy any: every participant" in line]
    assert len(warned) == 1  # the one warning of the any policy, at activation
    assert "refused 0," in [line for line in log.splitlines() if "queries sent" in line][-1]
