"""Nav2 runs a learned tree, on Jazzy and on the distributions that load by ID (``make
interop``; spec/stringbt.md sections 12.2 and 12.3).

``examples/btcpp/nav2_loader.cpp``, built against BehaviorTree.CPP 4.8.2 from source, loads
trees as Nav2's bt_navigator does, read from navigation2's source: on Jazzy, a file path
(``default_nav_to_pose_bt_xml``, or a goal's ``behavior_tree``) with ``createTreeFromFile``,
whose ``<include>`` is read relative to the file; on newer Nav2, by ID from its
``bt_search_directories`` (``registerBehaviorTreeFromFile`` for each ``.xml`` file whose IDs
are not registered yet, then ``createTree(ID)``). Either way it first registers the plugin
libraries it is given by name (``registerFromPlugin(getOSName(NAME))``, as for Nav2's
``plugin_lib_names``): KT-BT's ``KTBT_`` nodes come from ``libktbt_nodes.so``
(``examples/btcpp/ktbt_nodes.cpp``, its ``BT_REGISTER_NODES``). Nav2's own nodes are stood in
for by scripted leaves that a model document declares.

The robot's own navigation tree is ``examples/btcpp/navigate_with_learned.xml``: it includes
the item its agent exports under a given tree ID at a stable path (``learned/<ID>.xml``) and
runs it as a ``<SubTree>``, wired to Nav2's goal on the blackboard. The learned items come from
the export (``LearnedExport``), and once over zenoh, a door skill that a ``ktbt peer run
--export-learned DIR --tree-id OpenLeftDoor=...`` learned from a ``ktbt peer serve``.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

import ktbt_proto as kp
from ktbt_proto.interop import to_xml
from ktbt_proto.interop.sidecar import LearnedExport, tree_ids
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
# `ktbt convert` writes for a tree using them: for Nav2's own tree (NAV2_TREE) ...
MODEL = (
    '<sl><sq><c>(DoorClosed)<c>(HandleSeen, side="left")<a>(GraspHandle)'
    "<a>(TurnHandle, degrees=60)<a>(Push)<e><a>(ComputePathToPose)<a>(FollowPath)<e>"
)
# ... and for the robot's navigation tree that runs what it learned, whose nodes take the goal.
NAV_MODEL = (
    '<sl><sq><c>(DoorClosed)<c>(HandleSeen, side="left")<a>(GraspHandle)'
    '<a>(TurnHandle, degrees=60)<a>(Push)<a>(DriveThrough, goal="{goal}")<e>'
    '<a>(ComputePathToPose, goal="{goal}")<a>(FollowPath, goal="{goal}")<e>'
)
DOOR = 'DoorClosed, HandleSeen(side="left")'
GIVEN = tree_ids([f"OpenLeftDoor={DOOR}"])
# The door skill that waits a tick for the door to swing (KTBT_WaitTicks, from the plugin) and
# drives through towards Nav2's goal ({goal}, a blackboard reference); then learned again
# without turning the handle.
SKILL = (
    '<sq><c>(DoorClosed)<c>(HandleSeen, side="left")<msq><a>(GraspHandle)'
    '<a>(TurnHandle, degrees=60)<a>(Push)<w>(1)<a>(DriveThrough, goal="{goal}")<e><e>'
)
SKILL_AGAIN = (
    '<sq><c>(DoorClosed)<c>(HandleSeen, side="left")<msq><a>(Push)<w>(1)'
    '<a>(DriveThrough, goal="{goal}")<e><e>'
)
THROUGH_THE_DOOR = [
    "call ComputePathToPose goal=door_b",
    "call GraspHandle",
    "call TurnHandle degrees=60",
    "call Push",
    "call DriveThrough goal=door_b",
    "call FollowPath goal=door_b",
]
PLUGIN = "ktbt_nodes"


def nav2(
    tmp_path: Path,
    *args: str,
    model: str = MODEL,
    plugins: tuple[str, ...] = (PLUGIN,),
    options: tuple[str, ...] = LEFT_HANDLE,
) -> tuple[int, list[str]]:
    """Nav2 loading a tree, ``args`` ``--jazzy FILE`` or ``TREE DIR...``, with the plugin
    libraries named (found on ``LD_LIBRARY_PATH``) and Nav2's nodes from ``model``; the door
    robot's handle is on the left unless ``options`` say otherwise."""
    document = tmp_path / "model" / "model.xml"  # a folder of its own: no search directory
    document.parent.mkdir(exist_ok=True)
    document.write_text(to_xml(kp.parse(model)))
    program = build.program("nav2_loader", EXAMPLE / "nav2_loader.cpp")
    library = build.plugin(PLUGIN, EXAMPLE / "ktbt_nodes.cpp")
    named = [arg for name in plugins for arg in ("--plugin", name)]
    done = subprocess.run(
        [str(program), str(document), *args, *named, *options],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "LD_LIBRARY_PATH": str(library.parent)},
    )
    assert "Traceback" not in done.stderr and done.returncode in (0, 1), done.stderr
    return done.returncode, done.stdout.splitlines()


def robot(tmp_path: Path) -> tuple[Path, Path]:
    """The robot's navigation tree (the example) and the folder its agent exports into, beside
    it, which also holds a stand-in for Nav2's own tree: ``(tree, learned folder)``."""
    nav = tmp_path / "nav"
    (nav / "learned").mkdir(parents=True)
    tree = Path(shutil.copy(EXAMPLE / "navigate_with_learned.xml", nav))
    (nav / "learned" / "navigate_to_pose.xml").write_text(NAV2_TREE)
    return tree, nav / "learned"


def test_nav2_runs_the_tree_a_goal_names_beside_its_own(tmp_path: Path) -> None:
    vocabulary, control, _ = door_robot(tmp_path)
    knowledge = tmp_path / "door.sbt"
    knowledge.write_text(f"<k>(prior)\n    {MEMORY}\n<e>\n")
    tree, folder = robot(tmp_path)
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
    assert sorted(p.name for p in folder.iterdir()) == ["OpenLeftDoor.xml", "navigate_to_pose.xml"]
    code, lines = nav2(tmp_path, "OpenLeftDoor", str(folder))
    assert code == 0, lines
    assert sorted(line for line in lines if line.startswith("registered ")) == [
        "registered OpenLeftDoor.xml",
        "registered navigate_to_pose.xml",
    ]
    assert "created OpenLeftDoor" in lines
    assert calls(lines) == ["call GraspHandle", "call TurnHandle degrees=60", "call Push"]
    assert lines[-1] == "result SUCCESS"
    # Nav2's own tree is built as before, the learned file beside it.
    code, lines = nav2(tmp_path, "NavigateToPose", str(folder))
    assert code == 0 and calls(lines) == ["call ComputePathToPose", "call FollowPath"], lines
    # On Jazzy, the robot's navigation tree runs the skill as its <SubTree>.
    code, lines = nav2(tmp_path, "--jazzy", str(tree), "--goal", "door_b", model=NAV_MODEL)
    assert code == 0 and calls(lines) == [
        "call ComputePathToPose goal=door_b",
        "call GraspHandle",
        "call TurnHandle degrees=60",
        "call Push",
        "call FollowPath goal=door_b",
    ], lines


def test_jazzy_runs_the_learned_item_as_a_subtree_of_the_navigation_tree(tmp_path: Path) -> None:
    tree, folder = robot(tmp_path)
    jazzy = ("--jazzy", str(tree), "--goal", "door_b")
    # Not learned yet: the file the navigation tree includes is not there, nor is the tree.
    code, lines = nav2(tmp_path, *jazzy, model=NAV_MODEL)
    assert code == 1 and "XML_ERROR_FILE_NOT_FOUND" in lines[-1], lines
    assert f"filename={folder / 'OpenLeftDoor.xml'}" in lines[-1]
    export = LearnedExport(folder, GIVEN)
    export.sync([learned(SKILL)])
    code, lines = nav2(tmp_path, *jazzy, model=NAV_MODEL)
    assert code == 0, lines
    assert lines[:2] == [f"plugin {PLUGIN}", f"created {tree}"]
    assert calls(lines) == THROUGH_THE_DOOR and lines[-1] == "result SUCCESS"
    # Learned again with another subtree: the same path, which the same tree now includes.
    export.sync([learned(SKILL_AGAIN)])
    assert sorted(p.name for p in folder.iterdir()) == ["OpenLeftDoor.xml", "navigate_to_pose.xml"]
    code, lines = nav2(tmp_path, *jazzy, model=NAV_MODEL)
    assert code == 0 and calls(lines) == [
        "call ComputePathToPose goal=door_b",
        "call Push",
        "call DriveThrough goal=door_b",
        "call FollowPath goal=door_b",
    ], lines
    # No closed door: the skill does not apply, the robot follows its path.
    code, lines = nav2(tmp_path, *jazzy, model=NAV_MODEL, options=())
    assert code == 0 and calls(lines) == [THROUGH_THE_DOOR[0], THROUGH_THE_DOOR[-1]], lines
    # Jazzy takes a goal's behavior_tree for a file path, never for an ID.
    code, lines = nav2(tmp_path, "--jazzy", "OpenLeftDoor", model=NAV_MODEL)
    assert code == 1 and lines[-1] == "error Couldn't open input XML file: OpenLeftDoor", lines


def test_newer_nav2_builds_the_navigation_tree_or_the_item_by_id(tmp_path: Path) -> None:
    tree, folder = robot(tmp_path)
    LearnedExport(folder, GIVEN).sync([learned(SKILL)])
    directories = (str(tree.parent), str(folder))  # bt_search_directories
    code, lines = nav2(tmp_path, "NavigateWithLearned", *directories, "--goal", "door_b",
                       model=NAV_MODEL)  # fmt: skip
    assert code == 0 and calls(lines) == THROUGH_THE_DOOR, lines
    assert "created NavigateWithLearned" in lines and lines[-1] == "result SUCCESS"
    # A goal naming the navigation tree's file: registered first, then the folders' files.
    code, lines = nav2(tmp_path, str(tree), str(folder), "--goal", "door_b", model=NAV_MODEL)
    assert code == 0 and calls(lines) == THROUGH_THE_DOOR, lines
    # The item alone, the goal's tree: its reference reads Nav2's goal on the root blackboard.
    code, lines = nav2(tmp_path, "OpenLeftDoor", str(folder), "--goal", "door_b", model=NAV_MODEL)
    assert code == 0 and calls(lines) == THROUGH_THE_DOOR[1:-1], lines


def test_the_ktbt_nodes_come_from_their_plugin_library(tmp_path: Path) -> None:
    tree, folder = robot(tmp_path)
    LearnedExport(folder, GIVEN).sync([learned(SKILL)])
    # Without the library among the plugins, no KTBT_ node: neither way loads the tree.
    code, lines = nav2(tmp_path, "--jazzy", str(tree), model=NAV_MODEL, plugins=())
    assert code == 1 and lines[-1].startswith("error Exception when loading BT: "), lines
    assert "Node not recognized: KTBT_WaitTicks" in lines[-1]
    code, lines = nav2(tmp_path, "OpenLeftDoor", str(folder), model=NAV_MODEL, plugins=())
    assert code == 1 and "KTBT_WaitTicks" in lines[-1], lines
    assert lines[-1].startswith("error Exception registering behavior trees: ")
    # A library that is not there stops the load as it stops Nav2's bt_navigator.
    code, lines = nav2(tmp_path, "--jazzy", str(tree), model=NAV_MODEL, plugins=("ktbt_none",))
    assert code == 1 and lines[-1].startswith("error plugin_lib_names: Could not load library: ")
    assert "libktbt_none.so" in lines[-1]


def test_a_navigation_tree_wires_every_key_the_item_refers_to(tmp_path: Path) -> None:
    tree, folder = robot(tmp_path)
    LearnedExport(folder, GIVEN).sync([learned(SKILL)])
    jazzy = ("--jazzy", str(tree), "--goal", "door_b")
    text = tree.read_text()
    # The item's <SubTree> model declares {goal}: a tree that does not wire it does not load.
    tree.write_text(text.replace('<SubTree ID="OpenLeftDoor" goal="{goal}"/>',
                                 '<SubTree ID="OpenLeftDoor"/>'))  # fmt: skip
    code, lines = nav2(tmp_path, *jazzy, model=NAV_MODEL)
    assert code == 1 and "mandatory port called [goal]" in lines[-1], lines
    # _autoremap="true" wires every key to the entry of the same name.
    tree.write_text(text.replace('<SubTree ID="OpenLeftDoor" goal="{goal}"/>',
                                 '<SubTree ID="OpenLeftDoor" _autoremap="true"/>'))  # fmt: skip
    code, lines = nav2(tmp_path, *jazzy, model=NAV_MODEL)
    assert code == 0 and calls(lines) == THROUGH_THE_DOOR, lines
    # Or to another key of the navigation tree's blackboard, by name.
    door = "<Sequence><Script code=\"door := 'door_c'\"/>"
    tree.write_text(text.replace('<SubTree ID="OpenLeftDoor" goal="{goal}"/>',
                                 '<SubTree ID="OpenLeftDoor" goal="{door}"/>')
                    .replace("<Sequence>", door, 1))  # fmt: skip
    code, lines = nav2(tmp_path, *jazzy, model=NAV_MODEL)
    assert code == 0 and "call DriveThrough goal=door_c" in calls(lines), lines


def test_why_the_export_refuses_a_tree_id_held_twice_or_a_node_nav2_lacks(tmp_path: Path) -> None:
    folder = tmp_path / "behavior_trees"
    folder.mkdir()
    (folder / "navigate_to_pose.xml").write_text(NAV2_TREE)
    LearnedExport(folder).sync([learned(MEMORY)])
    [exported] = folder.glob("0*.xml")
    # Two files holding one ID: Nav2 registers one of them (in the folder's order) and skips
    # the other, so the export never writes an ID another file holds.
    (folder / "copy.xml").write_text(exported.read_text())
    code, lines = nav2(tmp_path, "NavigateToPose", str(folder))
    assert code == 0 and any(line.startswith("conflicting files not loaded: ") for line in lines)
    (folder / "copy.xml").unlink()
    # A learned tree naming a node Nav2's plugins lack fails every goal, whatever tree it
    # names: the agent beside Nav2 learns only what its vocabulary (Nav2's nodes) executes.
    LearnedExport(folder).sync([learned(MEMORY), learned("<sq><c>(DoorClosed)<a>(Kick)<e>")])
    code, lines = nav2(tmp_path, "NavigateToPose", str(folder))
    assert code == 1 and "Unknown node type: Kick" in lines[-1], lines
    assert lines[-1].startswith("error Exception registering behavior trees: ")
