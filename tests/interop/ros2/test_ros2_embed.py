"""A KT-BT agent in its user's own rclpy node and py_trees tree (spec/protocol.md section 11,
"Embedding"), and the lifecycle node reading the fleet's catalogs (section 4.5): the example
docking robot (``examples/ros2/``), a real ``Dock`` action server in another process,
a ``ktbt ros2 run`` teacher and learner, all real rclpy processes in one network namespace
shared by this module's tests (``rosns``), every wait a topic or output condition with a
deadline."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from ktbt_proto.files import packaged
from tests.interop.ros2.probe import echo
from tests.interop.ros2.rosns import Probe, RosNamespace, wait_for_line

pytestmark = [pytest.mark.network, pytest.mark.slow, pytest.mark.timeout(300)]

VOCABULARY = packaged("examples", "ros2", "dock.toml")
DOCK = packaged("examples", "ros2", "dock.sbt")
SEQUENCE = "<c>(BatteryLow)"
ECHO = os.environ.get("KTBT_ECHO_TO")
"""A folder to write what ``ros2 topic echo`` would show of the learner (the tutorial's)."""


def wait_for_item(probe: Probe, catalog: str, teacher: str, timeout: float = 120) -> None:
    """Until the latched ``catalog`` lists the docking skill taught by ``teacher`` (a latched
    topic, so what was published before the probe matched is not missed, as an event is)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for msg in probe.messages(catalog):
            if [(i["sequence"], i["teacher"]) for i in msg["items"]] == [(SEQUENCE, teacher)]:
                return
        time.sleep(0.05)
    raise AssertionError(f"{catalog} never listed {SEQUENCE} from {teacher}")


@pytest.fixture(scope="module")
def fleet(ros2_built: None, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    """One namespace for the module: a probe, the dock server, a teacher of the docking skill
    and the example robot, which knows nothing and is told no sequence."""
    ns = RosNamespace(tmp_path_factory.mktemp("embed"))
    try:
        probe = Probe(ns)
        for topic in ("/dock_robot/ktbt/events", "/learner/ktbt/events"):
            probe.subscribe(topic, "FleetEvent")
        probe.subscribe("/learner/ktbt/tree", "TreeSnapshot", latched=True)
        probe.subscribe("/dock_robot/ktbt/catalog", "Catalog", latched=True)
        example = packaged("examples", "ros2")
        ns.start([sys.executable, str(example / "dock_server.py")], "server")
        teacher = ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/teacher",
                          "-p", f"vocabulary:={VOCABULARY}", "-p", f"knowledge:={DOCK}",
                          name="teacher")  # fmt: skip
        ns.start([sys.executable, str(example / "dock_robot.py")], "robot")
        yield ns, probe, teacher
    finally:
        ns.close()


def test_the_example_robot_learns_to_dock_and_its_skill_calls_the_action_server(
    fleet: Any,
) -> None:
    ns, probe, _ = fleet
    # Told nothing, it asks for what the teacher's catalog lists, and learns it.
    wait_for_line(ns, "robot", "will meet BatteryLow (listed by teacher)")
    wait_for_item(probe, "/dock_robot/ktbt/catalog", "teacher")
    wait_for_line(ns, "robot", "dock_robot: learned BatteryLow from teacher")
    # Its battery low, the learned item runs the robot's own action client: the server in the
    # other process gets the goal, and the robot the result.
    wait_for_line(ns, "server", "dock_server: goal dock=A")
    wait_for_line(ns, "robot", "Dock result: docked True, docked at A")
    assert "Traceback" not in ns.log("robot") + ns.log("server")


def test_the_embedded_robot_teaches_a_lifecycle_node_told_no_sequences(fleet: Any) -> None:
    """The teacher gone, a ``ktbt ros2 run`` learner given the same vocabulary and no
    ``sequences`` reads the robot's catalog and learns the skill from it."""
    ns, probe, teacher = fleet
    wait_for_item(probe, "/dock_robot/ktbt/catalog", "teacher")
    teacher.terminate()  # ours: ended by its pid
    teacher.wait(timeout=30)
    ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/learner",
            "-p", f"vocabulary:={VOCABULARY}", name="learner")  # fmt: skip
    wait_for_line(ns, "learner", "will meet BatteryLow (listed by dock_robot)")
    snapshot = probe.wait("/learner/ktbt/tree", 120, tree='<a>(Dock,dock="A")', changed=True)
    assert snapshot["peer"] == "learner"  # latched: its learned tree
    wait_for_line(ns, "learner", "learner: learned BatteryLow from dock_robot")
    probe.wait("/dock_robot/ktbt/events", 30, event="answer-sent", to="learner")
    if ECHO:  # what the tutorial shows of `ros2 topic echo`, from this run
        folder = Path(ECHO)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "events.yaml").write_text(echo(probe.messages("/learner/ktbt/events")))
        (folder / "tree.yaml").write_text(echo(probe.messages("/learner/ktbt/tree")))


ERRORS = """
import py_trees, rclpy
from ktbt_proto.errors import StringBTError
from ktbt_proto.interop.ros2.embed import attach
from ktbt_proto.registry import Registry
from ktbt_proto.tools.vocabulary import load_vocabulary

rclpy.init()
node = rclpy.create_node("user")
vocabulary = load_vocabulary(r"{vocabulary}")
bare = py_trees.trees.BehaviourTree(py_trees.behaviours.Running("Patrol"))
learner = py_trees.trees.BehaviourTree(py_trees.composites.Selector(
    "Root", memory=False, children=[py_trees.composites.Selector("k:new", memory=False)]))
for what, call in [
    ("no placeholder", lambda: attach(node, bare, vocabulary)),
    ("not a tree", lambda: attach(node, bare.root, vocabulary)),
    ("not a registry", lambda: attach(node, learner, {{}})),
    ("bad name", lambda: attach(node, learner, vocabulary, name="a b")),
    ("bad sequence", lambda: attach(node, learner, vocabulary, sequences=["TargetSeen(colour=2)"])),
    ("bad knowledge", lambda: attach(node, learner, Registry(), knowledge=r"{dock}")),
]:
    try:
        call()
    except (TypeError, ValueError, StringBTError) as exc:
        print(what, "|", type(exc).__name__, "|", exc)
print("entities", len(node.get_publisher_names_and_types_by_node("user", "/")),
      len(learner.pre_tick_handlers))
with attach(node, learner, vocabulary, sequences=["BatteryLow"]) as robot:
    print("attached", robot.name, robot.todo)
print("closed", len(learner.pre_tick_handlers))
"""


def test_what_a_user_gets_wrong_is_one_line_and_leaves_the_node_as_it_was(fleet: Any) -> None:
    ns, _, _ = fleet
    script = ERRORS.format(vocabulary=VOCABULARY, dock=DOCK)
    done = subprocess.run([*ns.enter, "--", sys.executable, "-c", script], capture_output=True,
                          text=True, env=ns.env(), timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    lines = dict(line.split(" | ", 1) for line in done.stdout.splitlines() if " | " in line)
    assert lines["no placeholder"].startswith("ValueError | the py_trees tree has no knowledge")
    assert lines["not a tree"].startswith("TypeError | a py_trees control tree is a py_trees")
    assert lines["not a registry"].startswith("TypeError | registry: a ktbt_proto Registry")
    assert (
        lines["bad name"] == "ValueError | name 'a b': use 1 to 64 letters, digits, '_', '.', '-'"
    )
    assert lines["bad sequence"].startswith("StringBTError | ")
    assert (
        "SBT305 sequence 'TargetSeen(colour=2)': unknown condition 'TargetSeen'"
        in (lines["bad sequence"])
    )
    assert lines["bad knowledge"].startswith("ValidationError | ")  # a StringBTError
    assert "SBT305" in lines["bad knowledge"] and "BatteryLow" in lines["bad knowledge"]
    out = done.stdout.splitlines()
    # Nothing was added to the node or the tree by a refused attach; a closed one takes all off.
    assert "entities 2 0" in out, out  # rclpy's own /rosout and /parameter_events
    assert "attached user ['<c>(BatteryLow)']" in out and "closed 0" in out
