"""Any robot is a peer (spec/protocol.md section 4.5): the door-opening robot of
``tests/door_robot.py``, a vocabulary that is not the search-and-rescue one, learns and teaches
through ``ktbt peer`` over zenoh on loopback, real processes; a BehaviorTree.CPP robot's skills
(``peer serve --knowledge skills.xml``) teach it; what it learns for a BT.CPP program
(``--export-learned``) runs in BehaviorTree.CPP (the ``behaviortreepy`` wheel)."""

from __future__ import annotations

from pathlib import Path

import pytest

import ktbt_proto as kp
from ktbt_proto.files import packaged
from ktbt_proto.interop import from_xml
from ktbt_proto.items import item_digest, sequence_key, split_item
from ktbt_proto.tree import Node
from tests.door_robot import FLAT, VOCABULARY
from tests.zenoh_helpers import endpoint, free_port, ktbt_process, ktbt_run

pytestmark = pytest.mark.network

# A door skill without arguments: what the port-less wheel can load (BT.CPP's own ports need
# the nodes' providedPorts(), which the wheel's Python leaves do not declare).
PORTLESS = "<sq><c>(DoorClosed)<msq><a>(GraspHandle)<a>(Push)<e><e>"
CONTROL = "<sl>\n    <k>(new)<e>\n    <a>(Push)\n<e>\n"

SKILLS_XML = """<?xml version="1.0" encoding="UTF-8"?>
<root BTCPP_format="4">
  <BehaviorTree ID="OpenLeftDoor">
    <ReactiveSequence>
      <DoorClosed/>
      <HandleSeen side="left"/>
      <GraspHandle/>
      <TurnHandle degrees="60"/>
      <Push/>
    </ReactiveSequence>
  </BehaviorTree>
  <BehaviorTree ID="ktbt-new-0123456789abcdef">
    <ReactiveSequence>
      <DoorClosed/>
      <Sequence>
        <GraspHandle/>
        <Push/>
      </Sequence>
    </ReactiveSequence>
  </BehaviorTree>
  <TreeNodesModel>
    <Condition ID="DoorClosed"/>
    <Condition ID="HandleSeen"><input_port name="side" type="std::string"/></Condition>
    <Action ID="GraspHandle"/>
    <Action ID="TurnHandle"><input_port name="degrees" type="int"/></Action>
    <Action ID="Push"/>
  </TreeNodesModel>
</root>
"""


def _item(node: Node) -> str:
    """An item's identity: its condition sequence and subtree (flat or nested, the same)."""
    split = split_item(node)
    assert split is not None
    return item_digest(sequence_key(split[0]), split[1])


def _door(tmp_path: Path) -> tuple[Path, Path, Path]:
    vocabulary, control, knowledge = (
        tmp_path / "door.toml",
        tmp_path / "door_control.sbt",
        tmp_path / "door.sbt",
    )
    vocabulary.write_text(VOCABULARY)
    control.write_text(CONTROL)
    knowledge.write_text(f"<k>(prior)\n    {FLAT}\n    {PORTLESS}\n<e>\n")
    return vocabulary, control, knowledge


def test_a_door_robot_learns_what_its_fleet_lists_and_exports_it_for_btcpp(
    tmp_path: Path,
) -> None:
    """Without --sequence it meets every sequence a catalog lists that its vocabulary can
    execute, and skips the demo teacher's colours with one INFO line each (never asked, so
    never refused); the exported items read back as learned, and the port-less one runs in
    BehaviorTree.CPP with the robot's own node names."""
    vocabulary, control, knowledge = _door(tmp_path)
    colours = packaged("examples", "knowledge", "colours.sbt")
    port, other = free_port(), free_port()
    learned = tmp_path / "learned"
    with (
        ktbt_process("peer", "serve", "--id", "doors", "--vocabulary", str(vocabulary),
                     "--knowledge", str(knowledge), "--listen", endpoint(port), ready="serving"),
        ktbt_process("peer", "serve", "--id", "sar", "--knowledge", str(colours),
                     "--listen", endpoint(other), "--connect", endpoint(port), ready="serving"),
    ):  # fmt: skip
        done = ktbt_run(
            "peer", "run", "--id", "cppbot", "--vocabulary", str(vocabulary),
            "--control", str(control), "--connect", endpoint(port), "--connect", endpoint(other),
            "--export-learned", str(learned), "--exit-when-done", "--duration", "60",
        )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'learned DoorClosed, HandleSeen(side="left") from doors' in done.stdout
    assert "learned DoorClosed from doors" in done.stdout
    skipped = [line for line in done.stderr.splitlines() if "not asking for" in line]
    assert len(skipped) == 4, done.stderr
    assert all("listed by sar" in line and "SBT305" in line for line in skipped)
    assert "refused 0" in done.stdout and "Traceback" not in done.stderr
    files = sorted(learned.iterdir())
    assert len(files) == 2
    assert {_item(from_xml(f.read_text()).root) for f in files} == {
        _item(kp.parse(s).root) for s in (FLAT, PORTLESS)
    }
    bt = pytest.importorskip("behaviortreepy", reason="pip install 'ktbt[btcpp]'")
    [portless] = [f for f in files if "HandleSeen" not in f.read_text()]
    calls: list[str] = []
    factory = bt.BehaviorTreeFactory()
    door = {"DoorClosed": True}

    def condition(node: object) -> object:
        calls.append("DoorClosed")
        return bt.NodeStatus.SUCCESS if door["DoorClosed"] else bt.NodeStatus.FAILURE

    def action(name: str) -> object:
        def run(node: object) -> object:
            calls.append(name)
            if name == "Push":
                door["DoorClosed"] = False
            return bt.NodeStatus.SUCCESS

        return run

    factory.register_simple_condition("DoorClosed", condition)
    for name in ("GraspHandle", "Push"):
        factory.register_simple_stateful_action(name, action(name), action(name))
    tree = factory.create_tree_from_text(portless.read_text())
    assert bt.to_string(tree.tick_exactly_once()) == "SUCCESS"
    assert bt.to_string(tree.tick_exactly_once()) == "FAILURE"  # the door is open now
    assert calls == ["DoorClosed", "GraspHandle", "Push", "DoorClosed"]


def test_a_btcpp_robots_skills_teach_a_python_registry_robot(tmp_path: Path) -> None:
    """``peer serve --knowledge skills.xml``: one <BehaviorTree> per skill, in the shape the
    sidecar writes; the learner is the door robot's Python registry (module:callable), its
    control tree running a learned skill only while the door is closed (it is not, here)."""
    vocabulary, _, _ = _door(tmp_path)
    control = tmp_path / "python_control.sbt"
    control.write_text("<sl><k>(new)<e><c>(DoorClosed)<e>\n")
    skills = tmp_path / "skills.xml"
    skills.write_text(SKILLS_XML)
    port = free_port()
    with ktbt_process(
        "peer", "serve", "--id", "cpp", "--vocabulary", str(vocabulary),
        "--knowledge", str(skills), "--listen", endpoint(port), ready="serving",
    ) as server:  # fmt: skip
        done = ktbt_run(
            "peer", "run", "--id", "pybot", "--vocabulary", "tests.door_robot:door_registry",
            "--control", str(control), "--connect", endpoint(port),
            "--sequence", 'DoorClosed, HandleSeen(side="left")', "--sequence", "DoorClosed",
            "--exit-when-done", "--duration", "60",
        )  # fmt: skip
        asked = ktbt_run(
            "peer", "ask", "--vocabulary", str(vocabulary), "--connect", endpoint(port),
            "--sequence", "DoorClosed", "--timeout", "10",
        )  # fmt: skip
        assert server.poll() is None
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'learned DoorClosed, HandleSeen(side="left") from cpp' in done.stdout
    assert "learned DoorClosed from cpp" in done.stdout
    assert asked.returncode == 0, asked.stdout + asked.stderr
    assert "<msq>" in asked.stdout and "GraspHandle" in asked.stdout


def test_a_skill_the_vocabulary_cannot_execute_is_refused_before_serving(tmp_path: Path) -> None:
    vocabulary, _, _ = _door(tmp_path)
    skills = tmp_path / "skills.xml"
    skills.write_text(
        SKILLS_XML.replace(
            "<Push/>\n    </ReactiveSequence>", "<Fly/>\n    </ReactiveSequence>", 1
        ).replace('<Action ID="Push"/>', '<Action ID="Push"/><Action ID="Fly"/>')
    )
    done = ktbt_run("peer", "serve", "--vocabulary", str(vocabulary), "--knowledge", str(skills))
    assert done.returncode == 2, done.stdout + done.stderr
    [line] = done.stderr.splitlines()
    assert (
        line.startswith(f"error: --knowledge {skills}:") and "SBT306 unknown action 'Fly'" in line
    )
