"""The sidecar export beside Nav2's own trees (spec/stringbt.md section 12.2): each learned item
a whole BT.CPP document whose tree ID a ``NavigateToPose`` goal can name, given or derived, never
an ID another file of the folder holds. The folder is loaded the way Nav2 loads its
``bt_search_directories`` through the ``behaviortreepy`` wheel (BehaviorTree.CPP 4.8.2 compiled;
leaves without ports); ``make interop`` does the same in C++ against the from-source build
(``tests/interop/test_btcpp_nav2.py``)."""

from __future__ import annotations

import logging
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

import ktbt_proto as kp
from ktbt_proto import files
from ktbt_proto.exchange.knowledge import Knowledge
from ktbt_proto.interop import to_xml
from ktbt_proto.interop.btcpp import document_tree_ids
from ktbt_proto.interop.sidecar import LearnedExport, read_skills, tree_id, tree_ids
from ktbt_proto.items import item_digest, sequence_key, split_item
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
    assert trees["OpenDoor"] == "OpenDoor.xml"  # a given ID: a path that stays
    assert trees[derived].startswith("000001-new-")  # derived: numbered in learning order
    skills = read_skills((folder / trees["OpenDoor"]).read_bytes())
    assert [item.subtree for item in skills] == [door.subtree]  # our own reader reads it back
    assert nav2_load([folder], "OpenDoor") == (["DoorClosed", "GraspHandle", "Push"], [])
    assert nav2_load([folder], derived)[0] == ["BatteryLow", "Dock"]
    assert nav2_load([folder], "NavigateToPose")[0] == ["ComputePathToPose", "FollowPath"]


def test_learning_again_keeps_one_file_per_tree_id(folder: Path) -> None:
    export = LearnedExport(folder, {DOOR: "OpenDoor"})
    export.sync([learned(OPEN)])
    stable = folder / "OpenDoor.xml"
    first = stable.read_text()
    export.sync([learned(OPEN)])  # the same item again: nothing new
    export.sync([])  # forgotten ...
    assert not stable.exists()
    export.sync([learned(OPEN)])  # ... and learned again: one file, the same tree
    assert stable.read_text() == first and not list(folder.glob("0*.xml"))
    export.sync([learned(OPEN_AGAIN)])  # the sequence learned with another subtree
    assert sorted(folder.glob("*.xml")) == [stable, folder / "navigate_to_pose.xml"]
    assert document_tree_ids(stable.read_bytes())[0] == ["OpenDoor"]
    assert nav2_load([folder], "OpenDoor") == (["DoorClosed", "Push"], [])
    # A restart adopts its file (its second line names the item), and another ID for the
    # sequence moves the item to that ID's file.
    assert LearnedExport(folder, {DOOR: "OpenDoor"}).files == export.files
    moved = LearnedExport(folder, {DOOR: "PushDoor"})
    moved.sync([learned(OPEN_AGAIN)])
    assert not stable.exists()
    assert document_tree_ids((folder / "PushDoor.xml").read_bytes()) == (["PushDoor"], "PushDoor")
    # Without a given ID the item goes back to its numbered file, under its derived ID.
    LearnedExport(folder).sync([learned(OPEN_AGAIN)])
    [numbered] = folder.glob("0*.xml")
    assert not (folder / "PushDoor.xml").exists()
    assert document_tree_ids(numbered.read_bytes())[0] == [tree_id(learned(OPEN_AGAIN))]


def test_a_relearned_item_replaces_its_file_in_one_rename(
    folder: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Learned again with another subtree, the item under a given ID replaces its file whole:
    a program reading ``OpenDoor.xml`` at any moment reads the old item or the new one, never
    no file (spec/stringbt.md section 12.2)."""
    export = LearnedExport(folder, {DOOR: "OpenDoor"})
    export.sync([learned(OPEN)])
    stable = folder / "OpenDoor.xml"
    seen: list[tuple[str, bool]] = []
    write = files.write_atomic

    def watched(path: Path, data: str | bytes) -> None:
        seen.append(("write", stable.exists()))
        write(path, data)

    unlink = Path.unlink

    def watched_unlink(path: Path, missing_ok: bool = False) -> None:
        seen.append((f"unlink {path.name}", stable.exists()))
        unlink(path, missing_ok=missing_ok)

    monkeypatch.setattr("ktbt_proto.interop.sidecar.write_atomic", watched)
    monkeypatch.setattr(Path, "unlink", watched_unlink)
    export.sync([learned(OPEN_AGAIN)])
    assert seen == [("write", True)]  # replaced where it was, nothing removed
    [item] = read_skills(stable.read_bytes())
    assert item.subtree == learned(OPEN_AGAIN).subtree
    digest = item_digest(DOOR, learned(OPEN_AGAIN).subtree)
    assert stable.read_text().splitlines()[1].startswith(f"<!-- ktbt learned item new {digest}:")
    assert export.files == {("new", digest): stable}


def test_a_file_of_an_earlier_export_is_taken_over(folder: Path) -> None:
    # A numbered file holding a given ID (what the export wrote before IDs had their own
    # path), and the same item's <ID>.xml beside it (a run killed between writing one and
    # removing the other): the restart keeps one file for the item, at its ID's path.
    item = learned(OPEN)
    key = ("new", item_digest(item.key, item.subtree))
    old = folder / f"000003-new-{key[1]}.xml"
    old.write_text(to_xml(item.item(), tree_id="OpenDoor"))
    export = LearnedExport(folder, {DOOR: "OpenDoor"})
    export.sync([item])
    assert not old.exists() and export.files == {key: folder / "OpenDoor.xml"}
    old.write_text(to_xml(item.item(), tree_id="OpenDoor"))
    again = LearnedExport(folder, {DOOR: "OpenDoor"})
    again.sync([item])
    assert not old.exists() and sorted(p.name for p in folder.glob("*.xml")) == [
        "OpenDoor.xml",
        "navigate_to_pose.xml",
    ]
    # The earlier file's item relearned with another subtree: never two files with the ID
    # (the old one goes first), then the new item under it.
    (folder / "OpenDoor.xml").unlink()
    old.write_text(to_xml(item.item(), tree_id="OpenDoor"))
    third = LearnedExport(folder, {DOOR: "OpenDoor"})
    third.sync([learned(OPEN_AGAIN)])
    assert not old.exists()
    third.sync([learned(OPEN_AGAIN)])
    [skill] = read_skills((folder / "OpenDoor.xml").read_bytes())
    assert skill.subtree == learned(OPEN_AGAIN).subtree and not list(folder.glob("0*.xml"))


def test_an_id_file_the_export_did_not_write_is_never_replaced(
    folder: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # navigate_to_pose.xml holds NavigateToPose: as a tree ID it is held, as a file name (the
    # ID navigate_to_pose) it is someone else's file.
    with pytest.raises(ValueError, match=r"its file .*navigate_to_pose\.xml is another file"):
        LearnedExport(folder, {DOOR: "navigate_to_pose"})
    export = LearnedExport(folder, {DOOR: "OpenDoor"})
    mine = folder / "OpenDoor.xml"
    mine.write_text(NAV2_TREE.replace("NavigateToPose", "SomethingElse"))  # written by hand
    with caplog.at_level(logging.WARNING, logger="ktbt_proto.interop.sidecar"):
        export.sync([learned(OPEN)])
    assert "OpenDoor.xml is another file of the folder" in caplog.text
    assert "SomethingElse" in mine.read_text() and len(export.refused) == 1
    # A restart does not take a file without the export's mark for its own.
    with pytest.raises(ValueError, match="is another file of the folder"):
        LearnedExport(folder, {DOOR: "OpenDoor"})


EXAMPLE_TREE = (
    Path(__file__).resolve().parents[2] / "examples" / "btcpp" / "navigate_with_learned.xml"
)


def test_the_example_navigation_tree_runs_the_learned_id_as_a_subtree(tmp_path: Path) -> None:
    """``examples/btcpp/navigate_with_learned.xml``: the file Jazzy's bt_navigator loads by
    path, including the learned item's stable file and running it as a ``<SubTree>`` wired to
    Nav2's goal (spec/stringbt.md section 12.3); ``make interop`` loads it in BT.CPP."""
    ids, main = document_tree_ids(EXAMPLE_TREE.read_bytes())
    assert ids == ["NavigateWithLearned"] and main == "NavigateWithLearned"
    root = ET.parse(EXAMPLE_TREE).getroot()
    [include] = [el.get("path", "") for el in root.iterfind("include")]
    [subtree] = root.iter("SubTree")
    # What an agent given --tree-id OpenLeftDoor=... exports beside the tree, into learned/,
    # is the file the tree includes, holding the tree its <SubTree> names, and every key the
    # learned item refers to is a port the <SubTree> wires.
    given = tree_ids(['OpenLeftDoor=DoorClosed, HandleSeen(side="left")'])
    skill = learned(
        '<sq><c>(DoorClosed)<c>(HandleSeen, side="left")'
        '<msq><a>(GraspHandle)<a>(Push)<a>(DriveThrough, goal="{goal}")<e><e>'
    )
    LearnedExport(tmp_path / "learned", given).sync([skill])
    exported = tmp_path / include
    assert document_tree_ids(exported.read_bytes()) == ([subtree.get("ID")], subtree.get("ID"))
    model = ET.parse(exported).getroot().find(f"TreeNodesModel/SubTree[@ID='{subtree.get('ID')}']")
    assert model is not None
    assert {port.get("name") for port in model} <= set(subtree.attrib) - {"ID"}
    assert subtree.get("goal") == "{goal}"


def test_the_export_keeps_a_learned_reference_for_the_including_tree_to_wire(
    tmp_path: Path,
) -> None:
    folder = tmp_path / "learned"
    export = LearnedExport(folder, {DOOR: "OpenDoor"})
    export.sync([learned('<sq><c>(DoorClosed)<a>(Push)<a>(DriveThrough, goal="{goal}")<e>')])
    text = (folder / "OpenDoor.xml").read_text()
    assert '<DriveThrough goal="{goal}"/>' in text
    assert '<SubTree ID="OpenDoor">\n      <inout_port name="goal"/>' in text
    [item] = read_skills(text)
    assert dict(item.subtree.children[1].args)["goal"] == "{goal}"  # type: ignore[attr-defined]


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
