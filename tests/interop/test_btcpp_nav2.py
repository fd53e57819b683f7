"""Nav2 picks a learned tree by its ID (``make interop``; spec/stringbt.md section 12.2).

``examples/btcpp/nav2_loader.cpp``, built against BehaviorTree.CPP 4.8.2 from source,
loads a folder as Nav2's bt_navigator loads its ``bt_search_directories`` for a
``NavigateToPose`` goal naming a tree ID (``registerBehaviorTreeFromFile`` for each ``.xml``
file whose IDs are not registered yet, then ``createTree(ID)``) and ticks the tree. The folder
holds a stand-in for Nav2's own tree beside what the sidecar exported: a door skill that a
``ktbt peer run --export-learned DIR --tree-id OpenLeftDoor=...`` learned over zenoh from a
``ktbt peer serve``. Nav2's plugins are stood in for by scripted leaves that a model document
declares.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

import ktbt_proto as kp
from ktbt_proto.interop import to_xml
from ktbt_proto.interop.sidecar import LearnedExport
from tests.btcpp import build
from tests.door_robot import MEMORY
from tests.interop.test_btcpp_learner import EXAMPLE, LEFT_HANDLE, calls, door_robot
from tests.interop.test_sidecar_nav2 import NAV2_TREE, learned
from tests.zenoh_helpers import endpoint, free_port, ktbt_process, ktbt_run

pytestmark = pytest.mark.skipif(
    not os.environ.get("KTBT_INTEROP"),
    reason="builds BehaviorTree.CPP from source (minutes): run with make interop",
)

# Every leaf the robot's Nav2 has (its plugins), declared with their ports by the model
# `ktbt convert` writes for a tree using them.
MODEL = (
    '<sl><sq><c>(DoorClosed)<c>(HandleSeen, side="left")<a>(GraspHandle)'
    "<a>(TurnHandle, degrees=60)<a>(Push)<e><a>(ComputePathToPose)<a>(FollowPath)<e>"
)
DOOR = 'DoorClosed, HandleSeen(side="left")'


def nav2(tmp_path: Path, tree: str, *folders: Path) -> tuple[int, list[str]]:
    """Nav2 loading ``tree`` by ID from ``folders``, the door robot's handle on the left."""
    model = tmp_path / "model.xml"
    model.write_text(to_xml(kp.parse(MODEL)))
    program = build.program("nav2_loader", EXAMPLE / "nav2_loader.cpp")
    done = subprocess.run(
        [str(program), str(model), tree, *map(str, folders), *LEFT_HANDLE],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert "Traceback" not in done.stderr and done.returncode in (0, 1), done.stderr
    return done.returncode, done.stdout.splitlines()


def test_nav2_runs_the_tree_a_goal_names_beside_its_own(tmp_path: Path) -> None:
    vocabulary, control, _ = door_robot(tmp_path)
    knowledge = tmp_path / "door.sbt"
    knowledge.write_text(f"<k>(prior)\n    {MEMORY}\n<e>\n")
    folder = tmp_path / "behavior_trees"
    folder.mkdir()
    (folder / "navigate_to_pose.xml").write_text(NAV2_TREE)
    port = free_port()
    with ktbt_process(
        "peer", "serve", "--id", "doors", "--vocabulary", str(vocabulary),
        "--knowledge", str(knowledge), "--listen", endpoint(port), ready="serving",
    ):  # fmt: skip
        done = ktbt_run(
            "peer", "run", "--id", "nav2bot", "--vocabulary", str(vocabulary),
            "--control", str(control), "--connect", endpoint(port),
            "--export-learned", str(folder), "--tree-id", f"OpenLeftDoor={DOOR}",
            "--exit-when-done", "--duration", "60",
        )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"learned {DOOR} from doors" in done.stdout
    [learned_file] = [p.name for p in folder.glob("0*.xml")]
    code, lines = nav2(tmp_path, "OpenLeftDoor", folder)
    assert code == 0, lines
    assert sorted(line for line in lines if line.startswith("registered ")) == [
        f"registered {learned_file}",
        "registered navigate_to_pose.xml",
    ]
    assert "created OpenLeftDoor" in lines
    assert calls(lines) == ["call GraspHandle", "call TurnHandle degrees=60", "call Push"]
    assert lines[-1] == "result SUCCESS"
    # Nav2's own tree is built as before, the learned file beside it.
    code, lines = nav2(tmp_path, "NavigateToPose", folder)
    assert code == 0 and calls(lines) == ["call ComputePathToPose", "call FollowPath"], lines


def test_why_the_export_refuses_a_tree_id_held_twice_or_a_node_nav2_lacks(tmp_path: Path) -> None:
    folder = tmp_path / "behavior_trees"
    folder.mkdir()
    (folder / "navigate_to_pose.xml").write_text(NAV2_TREE)
    LearnedExport(folder).sync([learned(MEMORY)])
    [exported] = folder.glob("0*.xml")
    # Two files holding one ID: Nav2 registers one of them (in the folder's order) and skips
    # the other, so the export never writes an ID another file holds.
    (folder / "copy.xml").write_text(exported.read_text())
    code, lines = nav2(tmp_path, "NavigateToPose", folder)
    assert code == 0 and any(line.startswith("conflicting files not loaded: ") for line in lines)
    (folder / "copy.xml").unlink()
    # A learned tree naming a node Nav2's plugins lack fails every goal, whatever tree it
    # names: the agent beside Nav2 learns only what its vocabulary (Nav2's nodes) executes.
    LearnedExport(folder).sync([learned(MEMORY), learned("<sq><c>(DoorClosed)<a>(Kick)<e>")])
    code, lines = nav2(tmp_path, "NavigateToPose", folder)
    assert code == 1 and "Unknown node type: Kick" in lines[-1], lines
    assert lines[-1].startswith("error Exception registering behavior trees: ")
