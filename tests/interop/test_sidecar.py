"""The sidecar export: one BehaviorTree.CPP document per learned item, removed when forgotten
(spec/stringbt.md section 12.1), for real agents learning over the in-memory network. The C++
program that reads the folder is tested in ``tests/interop/test_btcpp_learner.py``."""

from __future__ import annotations

from pathlib import Path

import ktbt_proto as kp
from ktbt_proto.exchange.agent import Agent, Timing
from ktbt_proto.exchange.knowledge import Knowledge
from ktbt_proto.interop import from_xml, to_xml
from ktbt_proto.interop.sidecar import LearnedExport
from ktbt_proto.items import item_digest, split_item
from ktbt_proto.tools.vocabulary import load_vocabulary
from ktbt_proto.transport import MemoryNetwork
from tests.door_robot import FLAT as DOOR_FLAT
from tests.door_robot import SEQUENCE as DOOR_SEQUENCE
from tests.door_robot import VOCABULARY, door_blackboard, door_registry
from tests.exchange.test_agent import KNOWER, SEQUENCE, agent, run

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "btcpp"
GREEN = "<sq><c>(TargetSeen,colour=2)<a>(Pick,colour=2)<e>"


def learned(tmp_path: Path) -> tuple[MemoryNetwork, Agent, Agent]:
    net = MemoryNetwork()
    teacher, learner = agent(net, "k", KNOWER), agent(net, "i")
    learner.encounter(SEQUENCE)
    run(net, [teacher, learner], 4)
    assert learner.knows(SEQUENCE)
    return net, teacher, learner


def files(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_each_learned_item_is_a_document_and_leaves_when_forgotten(tmp_path: Path) -> None:
    folder = tmp_path / "learned"
    export = LearnedExport(folder)
    export.sync(agent(MemoryNetwork(), "x").knowledge)
    assert files(folder) == []  # nothing learned, nothing written (innate items are not)
    _, _, learner = learned(tmp_path)
    export.sync(learner.knowledge)
    [name] = files(folder)
    assert name.startswith("000001-new-") and name.endswith(".xml")
    text = (folder / name).read_text()
    assert '<BehaviorTree ID="ktbt-new-' in text
    assert kp.format_tree(from_xml(text), "compact") == GREEN
    export.sync(learner.knowledge)  # nothing changed: nothing rewritten
    assert files(folder) == [name]
    assert learner.forget(SEQUENCE)
    export.sync(learner.knowledge)
    assert files(folder) == []


BOTH = (
    "<sl><k>(prior)<sq><c>(TargetSeen, colour=2)<a>(Pick, colour=2)<e>"
    "<sq><c>(TargetSeen, colour=4)<a>(Pick, colour=4)<e><e><k>(new)<e><a>(Walk)<e>"
)
BLUE = ["TargetSeen(colour=4)"]


def test_items_are_numbered_in_learning_order_and_a_restart_adopts_them(tmp_path: Path) -> None:
    folder = tmp_path / "learned"
    (folder / "notes").mkdir(parents=True)  # not ours: left alone
    net = MemoryNetwork()
    teacher, learner = agent(net, "k", BOTH), agent(net, "i")
    export = LearnedExport(folder)
    for sequence in (SEQUENCE, BLUE):
        learner.encounter(sequence)
        run(net, [teacher, learner], 12)
        assert learner.knows(sequence)
        export.sync(learner.knowledge)
    first, second = [n for n in files(folder) if n != "notes"]
    assert first.startswith("000001-new-") and second.startswith("000002-new-")
    assert "colour=4" in kp.format_tree(from_xml((folder / second).read_text()), "compact")
    again = LearnedExport(folder)  # a restart: the same files, the same numbers
    again.sync(learner.knowledge)
    assert files(folder) == sorted([first, second, "notes"])
    learner.forget(SEQUENCE)
    again.sync(learner.knowledge)
    assert files(folder) == sorted([second, "notes"])
    (folder / second).unlink()
    learner.forget(BLUE)
    again.sync(learner.knowledge)  # its file was gone already: no error
    assert files(folder) == ["notes"] and again.errors == 0
    learner.encounter(SEQUENCE)
    run(net, [teacher, learner], 12)
    again.sync(learner.knowledge)  # learned again: a new number, after the others
    assert [n[:6] for n in files(folder) if n != "notes"] == ["000003"]


def test_a_file_that_cannot_be_written_is_counted_and_tried_again(tmp_path: Path) -> None:
    folder = tmp_path / "learned"
    export = LearnedExport(folder)
    _, _, learner = learned(tmp_path)
    [item] = [k for k in learner.knowledge if k.source is not None]
    blocker = folder / f"000001-new-{item_digest(item.key, item.subtree)}.xml"
    (blocker / "inside").mkdir(parents=True)  # a folder where the file should go
    export.sync(learner.knowledge)
    assert export.errors == 1
    assert [p.name for p in folder.iterdir()] == [blocker.name] and blocker.is_dir()
    (blocker / "inside").rmdir()
    blocker.rmdir()
    export.sync(learner.knowledge)
    assert files(folder) == [blocker.name] and blocker.is_file() and export.errors == 1


def test_an_item_btcpp_cannot_load_is_refused_once_and_the_rest_written(tmp_path: Path) -> None:
    folder = tmp_path / "learned"
    export = LearnedExport(folder)
    sleep = Knowledge((kp.Condition("Tired"),), kp.Action("Sleep"), "new", "k")  # a BT.CPP ID
    rest = Knowledge((kp.Condition("Hungry"),), kp.Action("Eat"), "new", "k")
    export.sync([sleep, rest])
    export.sync([sleep, rest])
    [name] = files(folder)
    assert "Eat" in (folder / name).read_text()
    assert list(export.refused.values()) == [
        "SBT303 'Sleep' is a BT.CPP built-in or reserved node ID"
    ]
    export.sync([rest])
    export.sync([])
    assert files(folder) == [] and export.errors == 0


def test_the_example_robots_control_tree_is_the_export() -> None:
    tree = kp.parse((EXAMPLE / "control.sbt").read_text())
    assert (EXAMPLE / "control.xml").read_text() == to_xml(tree)


def item(action: str, colour: int = 2, segment: str = "new") -> Knowledge:
    conditions = (kp.Condition("TargetSeen", args=(("colour", colour),)),)
    return Knowledge(conditions, kp.Action(action), segment, "k")


def test_a_file_of_another_subtree_for_the_same_sequence_is_replaced(tmp_path: Path) -> None:
    folder = tmp_path / "learned"
    old, new = item("PickTreasure"), item("DeliverToZone")
    LearnedExport(folder).sync([old])  # a previous run knew PickTreasure for colour 2
    [stale] = files(folder)
    again = LearnedExport(folder)  # the restarted agent knows DeliverToZone for it
    again.sync([new])
    [name] = files(folder)
    assert name != stale and name.startswith("000002-new-")
    assert "DeliverToZone" in (folder / name).read_text()
    # Forgotten and learned again with another subtree between two syncs: rewritten too.
    again.sync([old])
    assert "PickTreasure" in (folder / files(folder)[0]).read_text()


def test_a_refused_item_is_forgotten_with_its_refusal(tmp_path: Path) -> None:
    export = LearnedExport(tmp_path)
    export.sync([item("Sleep")])
    assert list(export.refused) and files(tmp_path) == []
    export.sync([])
    assert export.refused == {}


def test_a_placeholder_that_is_not_a_name_is_refused(tmp_path: Path) -> None:
    folder = tmp_path / "learned"
    export = LearnedExport(folder)
    export.sync([item("Pick", segment="../../x"), item("Pick", 3)])
    assert [n[:11] for n in files(folder)] == ["000001-new-"] and files(tmp_path) == ["learned"]
    assert ["not a stringBT name" in why for why in export.refused.values()] == [True]


def test_numbers_are_reserved_per_item_and_may_grow_past_six_digits(tmp_path: Path) -> None:
    folder = tmp_path / "learned"
    first, second = item("Pick"), item("Pick", 3)
    export = LearnedExport(folder)
    blocker = folder / f"000001-new-{item_digest(first.key, first.subtree)}.xml"
    (blocker / "inside").mkdir(parents=True)
    export.sync([first, second])  # the first write fails: the second does not take its number
    assert (
        export.errors == 1
        and f"000002-new-{item_digest(second.key, second.subtree)}.xml" in files(folder)
    )
    (blocker / "inside").rmdir()
    blocker.rmdir()
    export.sync([first, second])
    assert [n[:7] for n in files(folder)] == ["000001-", "000002-"]
    late = folder / f"9999999-new-{item_digest(second.key, second.subtree)}.xml"
    (folder / files(folder)[1]).rename(late)
    again = LearnedExport(folder)  # seven digits: adopted, and the next number follows it
    again.sync([first, second, item("Pick", 4)])
    assert [n.split("-")[0] for n in files(folder)] == ["000001", "10000000", "9999999"]


def test_temporary_files_left_by_a_crash_are_removed(tmp_path: Path) -> None:
    name = f"000001-new-{'a' * 16}.xml"
    left = tmp_path / f".{name}.4242.0badc0de.tmp"
    other = tmp_path / ".notes.txt.4242.0badc0de.tmp"  # not one of ours
    left.write_text("<root")
    other.write_text("")
    LearnedExport(tmp_path)
    assert files(tmp_path) == [other.name]


def test_an_agent_with_only_a_vocabulary_file_learns_and_exports(tmp_path: Path) -> None:
    """A C++ robot's agent has no Python behaviours: its registry is its vocabulary file
    (spec/stringbt.md section 5.1). It checks answers as a Python registry would, learns and
    exports the item; the BT.CPP program runs it."""
    vocabulary = tmp_path / "door.toml"
    vocabulary.write_text(VOCABULARY + "\n[actions.Idle]\n", encoding="utf-8")
    net = MemoryNetwork()
    teacher = Agent(
        "t", f"<sl><k>(new){DOOR_FLAT}<e><e>", door_registry(), net.join("t"),
        timing=Timing(wait=20, cooldown=5), blackboard=door_blackboard(),
    )  # fmt: skip
    learner = Agent(
        "l", "<sl><k>(new)<e><a>(Idle)<e>", load_vocabulary(str(vocabulary)), net.join("l"),
        timing=Timing(wait=20, cooldown=5),
    )  # fmt: skip
    export = LearnedExport(tmp_path / "learned")
    learner.encounter(DOOR_SEQUENCE)
    for _ in range(10):
        teacher.tick()
        learner.tick()
        export.sync(learner.knowledge)
    assert learner.knows(DOOR_SEQUENCE) and learner.metrics.refused == 0
    [name] = files(tmp_path / "learned")
    text = (tmp_path / "learned" / name).read_text()
    assert split_item(from_xml(text).root) == split_item(kp.parse(DOOR_FLAT).root)  # same item
