"""The sidecar export beside Nav2's own trees (spec/stringbt.md section 12.2): each learned item
a whole BT.CPP document whose tree ID a ``NavigateToPose`` goal can name, given or derived, never
an ID another file of the folder holds. The folder is loaded the way Nav2 loads its
``bt_search_directories`` through the ``behaviortreepy`` wheel (BehaviorTree.CPP 4.8.2 compiled;
leaves without ports); ``make interop`` does the same in C++ against the from-source build
(``tests/interop/test_btcpp_nav2.py``)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

import ktbt_proto as kp
from ktbt_proto.exchange.knowledge import Knowledge
from ktbt_proto.interop.btcpp import document_tree_ids
from ktbt_proto.interop.sidecar import LearnedExport, read_skills, tree_id
from ktbt_proto.items import sequence_key, split_item
from ktbt_proto.tools.cli import app

NAV2_TREE = """\
<root BTCPP_format="4" main_tree_to_execute="NavigateToPose">
  <BehaviorTree ID="NavigateToPose">
    <RetryUntilSuccessful num_attempts="3">
      <Sequence>
        <ComputePathToPose/>
        <FollowPath/>
      </Sequence>
    </RetryUntilSuccessful>
  </BehaviorTree>
</root>
"""
"""A stand-in for the trees Nav2 ships in its search directory (a retry stringBT lacks)."""

OPEN = "<sq><c>(DoorClosed)<a>(GraspHandle)<a>(Push)<e>"
OPEN_AGAIN = "<sq><c>(DoorClosed)<a>(Push)<e>"  # the same sequence, another subtree
DOCK = "<sq><c>(BatteryLow)<a>(Dock)<e>"
LEAVES = {"conditions": ["DoorClosed", "BatteryLow"], "actions": ["GraspHandle", "Push", "Dock"]}
DOOR = sequence_key("<c>(DoorClosed)")


def learned(text: str) -> Knowledge:
    split = split_item(kp.parse(text).root)
    assert split is not None
    return Knowledge(split[0], split[1], "new", source="teacher")


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    """Nav2's search directory, holding its own tree."""
    (tmp_path / "navigate_to_pose.xml").write_text(NAV2_TREE)
    return tmp_path


def nav2_load(folders: list[Path], ident: str) -> tuple[list[str], list[str]]:
    """Nav2's ``BtActionServer::loadBehaviorTree`` for a goal naming ``ident``, through the
    wheel: every ``.xml`` file registered unless one of its IDs is registered already, then
    ``createTree(ID)``, ticked until it is no longer RUNNING. The calls and the files skipped."""
    bt = pytest.importorskip("behaviortreepy", reason="pip install 'ktbt[btcpp]'")
    calls: list[str] = []
    factory = bt.BehaviorTreeFactory()

    def leaf(name: str) -> Any:
        def tick(node: Any) -> Any:
            calls.append(name)
            return bt.NodeStatus.SUCCESS

        return tick

    for name in LEAVES["conditions"]:
        factory.register_simple_condition(name, leaf(name))
    for name in ["ComputePathToPose", "FollowPath", *LEAVES["actions"]]:
        factory.register_simple_action(name, leaf(name))
    registered: set[str] = set()
    conflicting: list[str] = []
    for directory in folders:
        for path in directory.iterdir():
            if path.suffix != ".xml":
                continue
            ids, _ = document_tree_ids(path.read_bytes())
            if not ids or registered & set(ids):
                conflicting.append(path.name)
                continue
            # The wheel's register_behavior_tree_from_file cannot be called (its binding lacks
            # pybind11's std::filesystem::path caster): the file's text, which BT.CPP's
            # registerBehaviorTreeFromFile reads and loads the same, <include> paths aside.
            factory.register_behavior_tree_from_text(path.read_text(encoding="utf-8"))
            registered.update(ids)
    tree = factory.create_tree(ident)
    assert tree.tick_while_running() == bt.NodeStatus.SUCCESS
    return calls, conflicting


def test_nav2_builds_a_learned_tree_by_the_id_given_or_derived(folder: Path) -> None:
    export = LearnedExport(folder, {DOOR: "OpenDoor"})
    door, dock = learned(OPEN), learned(DOCK)
    export.sync([door, dock])
    derived = tree_id(dock)
    assert derived.startswith("ktbt-new-")
    trees: dict[str, str] = {}
    for path in sorted(folder.glob("*.xml")):
        ids, main = document_tree_ids(path.read_bytes())
        assert len(ids) == 1 and main == ids[0]  # whole documents, one tree each
        assert ids[0] not in trees  # no ID twice: Nav2 would skip one of the files
        trees[ids[0]] = path.name
    assert set(trees) == {"NavigateToPose", "OpenDoor", derived}
    assert trees["OpenDoor"].startswith("000001-new-")
    skills = read_skills((folder / trees["OpenDoor"]).read_bytes())
    assert [item.subtree for item in skills] == [door.subtree]  # our own reader reads it back
    assert nav2_load([folder], "OpenDoor") == (["DoorClosed", "GraspHandle", "Push"], [])
    assert nav2_load([folder], derived)[0] == ["BatteryLow", "Dock"]
    assert nav2_load([folder], "NavigateToPose")[0] == ["ComputePathToPose", "FollowPath"]


def test_learning_again_keeps_one_file_per_tree_id(folder: Path) -> None:
    export = LearnedExport(folder, {DOOR: "OpenDoor"})
    export.sync([learned(OPEN)])
    first = sorted(folder.glob("0*.xml"))
    export.sync([learned(OPEN)])  # the same item again: nothing new
    export.sync([])  # forgotten ...
    export.sync([learned(OPEN)])  # ... and learned again: one file, the same tree
    [again] = sorted(folder.glob("0*.xml"))
    assert len(first) == 1 and document_tree_ids(again.read_bytes())[0] == ["OpenDoor"]
    export.sync([learned(OPEN_AGAIN)])  # the sequence learned with another subtree
    [other] = sorted(folder.glob("0*.xml"))
    assert other != again and document_tree_ids(other.read_bytes())[0] == ["OpenDoor"]
    assert nav2_load([folder], "OpenDoor") == (["DoorClosed", "Push"], [])
    # A restart with another ID for the sequence rewrites the same file with it.
    LearnedExport(folder, {DOOR: "PushDoor"}).sync([learned(OPEN_AGAIN)])
    assert sorted(folder.glob("0*.xml")) == [other]
    assert document_tree_ids(other.read_bytes()) == (["PushDoor"], "PushDoor")


def test_an_id_held_by_another_file_or_a_bad_folder_is_one_clear_error(
    folder: Path, caplog: pytest.LogCaptureFixture
) -> None:
    with pytest.raises(ValueError, match=r"'NavigateToPose' is already the tree of .*navigate"):
        LearnedExport(folder, {DOOR: "NavigateToPose"})
    dock = sequence_key("<c>(BatteryLow)")
    with pytest.raises(ValueError, match="'Go' is given to two sequences"):
        LearnedExport(folder, {DOOR: "Go", dock: "Go"})
    for bad in ("open.xml", "ktbt-new-x", "9lives", ""):
        with pytest.raises(ValueError, match="a letter or _"):
            LearnedExport(folder, {DOOR: bad})
    with pytest.raises(ValueError, match="built-in"):
        LearnedExport(folder, {DOOR: "Sequence"})
    with pytest.raises(OSError, match=r"navigate_to_pose\.xml"):
        LearnedExport(folder / "navigate_to_pose.xml")  # a file, not a folder
    # A file that comes later with an item's ID: the item is refused, logged once, not written.
    export = LearnedExport(folder, {DOOR: "OpenDoor"})
    (folder / "mine.xml").write_text(NAV2_TREE.replace("NavigateToPose", "OpenDoor"))
    with caplog.at_level(logging.WARNING, logger="ktbt_proto.interop.sidecar"):
        export.sync([learned(OPEN)])
        export.sync([learned(OPEN)])
    [record] = [r for r in caplog.records if "not exported" in r.getMessage()]
    assert "'OpenDoor' is the tree of" in record.getMessage()
    assert not list(folder.glob("0*.xml")) and len(export.refused) == 1
    export.sync([])  # forgotten: so is its refusal
    assert export.refused == {}


def test_the_command_line_names_the_option_at_fault(folder: Path) -> None:
    runner = CliRunner()
    run = ["peer", "run", "--connect", "tcp/127.0.0.1:9", "--duration", "1"]
    cases = {
        ("--export-learned", str(folder / "navigate_to_pose.xml")): "error: --export-learned: ",
        ("--export-learned", str(folder), "--tree-id", "NavigateToPose=DoorClosed"): (
            "error: --tree-id: tree ID 'NavigateToPose' is already the tree of"
        ),
        ("--tree-id", "OpenDoor=DoorClosed"): "error: --tree-id: names the tree",
        ("--export-learned", str(folder), "--tree-id", "OpenDoor"): "write ID=CONDITIONS",
        ("--export-learned", str(folder), "--tree-id", "Open=Door(("): "error: --tree-id 'Door((",
    }
    for args, message in cases.items():
        result = runner.invoke(app, [*run, *args])
        assert result.exit_code == 2, (args, result.output)
        assert message in result.output and "Traceback" not in result.output
