"""A BehaviorTree.CPP robot learns through a KT-BT agent beside it (``make interop``).

``ktbt peer serve`` teaches the colour skills over zenoh on loopback; ``ktbt peer run
--export-learned DIR`` learns the green one and writes it into DIR; the C++ program
``examples/btcpp/learner.cpp``, built against BehaviorTree.CPP and ``ktbt_btcpp/``,
watches DIR,
rebuilds its tree at a tick boundary and then runs the learned skill. The test then removes the
item's file itself, as the agent does when it forgets the item, and the robot rebuilds without
it and walks again.

A robot with its own node names, the door robot of ``tests/door_robot.py``, runs the same
program: its leaves are the conditions and actions its control document's ``<TreeNodesModel>``
declares, scripted, and it runs the door skill its agent (``peer run --vocabulary --control``)
learned from the catalog of a ``peer serve`` of the skill.
"""

from __future__ import annotations

import os
import subprocess
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from ktbt_proto.interop import to_xml
from ktbt_proto.syntax import parse
from tests.btcpp import build
from tests.door_robot import MEMORY, VOCABULARY
from tests.zenoh_helpers import (
    ROOT,
    end,
    endpoint,
    free_port,
    ktbt_process,
    ktbt_run,
    serving,
    wait_until,
)

pytestmark = pytest.mark.skipif(
    not os.environ.get("KTBT_INTEROP"),
    reason="builds BehaviorTree.CPP from source (minutes): run with make interop",
)

EXAMPLE = ROOT / "examples" / "btcpp"


@contextmanager
def robot(
    folder: Path, *options: str, control: Path = EXAMPLE / "control.xml"
) -> Iterator[tuple[subprocess.Popen[str], list[str]]]:
    """The C++ learner, its output collected line by line; stopped by its pid at the end."""
    program = build.program("learner", EXAMPLE / "learner.cpp")
    proc = subprocess.Popen(
        [str(program), str(control), str(folder), *options],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines: list[str] = []
    assert proc.stdout is not None
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stdout.readline, "")))  # type: ignore[union-attr]
    reader.start()
    try:
        yield proc, lines
    finally:
        end(proc)
        reader.join(timeout=15)
        proc.stdout.close()


def after(lines: list[str], marker: str) -> list[str]:
    """The lines after the last ``marker`` (stripped)."""
    shown = [line.strip() for line in lines]
    return shown[len(shown) - shown[::-1].index(marker) :] if marker in shown else []


def test_a_btcpp_robot_runs_what_its_agent_learned(tmp_path: Path) -> None:
    folder = tmp_path / "learned"
    folder.mkdir()
    port = free_port()
    with serving(port), robot(folder, "--target", "2") as (proc, lines):
        assert wait_until(lambda: "call RandomWalk" in [x.strip() for x in lines], 30), lines
        assert "rebuilt 0 learned" in lines[0]
        with ktbt_process(
            "peer", "run", "--id", "robot", "--connect", endpoint(port),
            "--export-learned", str(folder), "--sequence", "TargetSeen(colour=2)",
            "--exit-when-done", "--duration", "60",
        ) as agent:  # fmt: skip
            assert agent.wait(timeout=90) == 0
        [learned] = [p.name for p in folder.iterdir()]
        assert learned.startswith("000001-new-")
        # The robot rebuilt its tree at a tick boundary and runs the green skill.
        assert wait_until(
            lambda: "call AssignCollectionPoint colour=2" in after(lines, "rebuilt 1 learned"), 30
        ), lines
        assert wait_until(lambda: "call DeliverToZone" in after(lines, "rebuilt 1 learned"), 30)
        rebuilt = [line.strip() for line in lines].index("rebuilt 1 learned")
        assert lines[rebuilt - 1].strip() == "halt RandomWalk"  # a rebuild halts the old tree
        # The file goes (the test removes it, as the agent does on a forget): the robot walks.
        (folder / learned).unlink()
        assert wait_until(lambda: [x.strip() for x in lines].count("rebuilt 0 learned") == 2, 30)
        assert wait_until(lambda: "call RandomWalk" in after(lines, "rebuilt 0 learned"), 30)
        assert "call PickTreasure" not in after(lines, "rebuilt 0 learned")
        assert proc.poll() is None


BAD_PORTS = ["colour=3000000000", 'colour="red"', "colour=3, speed=2"]  # not an int; no port


def test_a_file_the_robot_cannot_load_is_refused_and_the_rest_runs(tmp_path: Path) -> None:
    folder = tmp_path / "learned"
    folder.mkdir()
    bad = folder / f"000001-new-{'0' * 16}.xml"
    bad.write_text('<root BTCPP_format="4"><BehaviorTree ID="x"><Fly/></BehaviorTree></root>')
    for number, args in enumerate(BAD_PORTS, 2):
        skill = parse(f"<sq><c>(TargetSeen, {args})<a>(PickTreasure)<e>")
        path = folder / f"00000{number}-new-{str(number) * 16}.xml"
        path.write_text(to_xml(skill, tree_id=f"ktbt-new-{number}"))
    elsewhere = folder / f"000005-nowhere-{'1' * 16}.xml"
    skill = parse("<sq><c>(TargetSeen, colour=3)<a>(PickTreasure)<e>")
    elsewhere.write_text(to_xml(skill, tree_id="ktbt-nowhere-1"))
    good = folder / f"1000000-new-{'2' * 16}.xml"  # seven digits: after all the others
    good.write_text(to_xml(skill, tree_id="ktbt-new-good"))
    with robot(folder, "--target", "3") as (proc, lines):
        assert wait_until(lambda: any("call PickTreasure" in x for x in lines), 30), lines
        refused = [x for x in lines if x.startswith("refused")]
        assert len(refused) == 5, lines
        assert "Fly" in refused[0] and "k:nowhere" in refused[4]
        assert ["converted to int" in x for x in refused[1:3]] == [True, True]
        assert "speed" in refused[3]
        assert "rebuilt 1 learned" in [x.strip() for x in lines]
        # A file it cannot load arrives while the tree runs: the running tree is kept until the
        # new one is built, and the new one is built without it.
        late = folder / f"1000001-new-{'3' * 16}.xml"
        late.write_text((folder / f"000004-new-{'4' * 16}.xml").read_text())
        assert wait_until(lambda: sum("refused 1000001" in x for x in lines) == 1, 30), lines
        assert wait_until(lambda: [x.strip() for x in lines].count("rebuilt 1 learned") == 2, 30)
        assert proc.poll() is None, lines


HAND_WRITTEN = """<?xml version='1.0'?>
<root main_tree_to_execute='MainTree' BTCPP_format='4'>
 <BehaviorTree ID='MainTree'><ReactiveFallback>
  <!-- written by hand: single quotes, a comment, an innate item inside the placeholder -->
  <ReactiveFallback _description='learned skills' name='k:new'
    ><ReactiveSequence><Carrying/><ReactiveFallback><DeliverToZone/></ReactiveFallback
    ></ReactiveSequence></ReactiveFallback>
  <RandomWalk/>
 </ReactiveFallback></BehaviorTree>
</root>
"""


def test_items_are_placed_in_a_control_tree_laid_out_by_hand(tmp_path: Path) -> None:
    control = tmp_path / "control.xml"
    control.write_text(HAND_WRITTEN)
    folder = tmp_path / "learned"
    folder.mkdir()
    skill = parse("<sq><c>(TargetSeen, colour=3)<a>(AssignCollectionPoint, colour=3)<e>")
    (folder / f"000001-new-{'1' * 16}.xml").write_text(to_xml(skill, tree_id="ktbt-new-1"))
    with robot(folder, "--target", "3", control=control) as (proc, lines):
        assert wait_until(lambda: any("AssignCollectionPoint colour=3" in x for x in lines), 30)
        assert "rebuilt 1 learned" in [x.strip() for x in lines] and proc.poll() is None


# The door robot's control tree: the door it knows opens with the handle on the right; what it
# learns goes first.
DOOR_CONTROL = """<sl>
    <k>(new)<e>
    <sq>
        <c>(DoorClosed)
        <c>(HandleSeen, side="right")
        <a>(GraspHandle)
        <a>(TurnHandle, degrees=45)
        <a>(Push)
    <e>
<e>
"""
LEFT_HANDLE = ("--true", "DoorClosed", "--true", "HandleSeen side=left")


def door_robot(tmp_path: Path) -> tuple[Path, Path, Path]:
    """The door robot's vocabulary, control tree and what ``ktbt convert`` makes of it."""
    vocabulary, control = tmp_path / "door.toml", tmp_path / "door_control.sbt"
    vocabulary.write_text(VOCABULARY)
    control.write_text(DOOR_CONTROL)
    xml = tmp_path / "door_control.xml"
    converted = ktbt_run("convert", str(control), str(xml))
    assert converted.returncode == 0, converted.stdout + converted.stderr
    return vocabulary, control, xml


def calls(lines: list[str]) -> list[str]:
    return [line.strip() for line in lines if line.startswith("call ")]


def test_a_btcpp_robot_with_its_own_nodes_runs_the_door_skill_its_agent_learned(
    tmp_path: Path,
) -> None:
    vocabulary, control, xml = door_robot(tmp_path)
    knowledge = tmp_path / "door.sbt"
    knowledge.write_text(f"<k>(prior)\n    {MEMORY}\n<e>\n")
    folder = tmp_path / "learned"
    folder.mkdir()
    port = free_port()
    with (
        ktbt_process("peer", "serve", "--id", "doors", "--vocabulary", str(vocabulary),
                     "--knowledge", str(knowledge), "--listen", endpoint(port), ready="serving"),
        robot(folder, *LEFT_HANDLE, control=xml) as (proc, lines),
    ):  # fmt: skip
        assert wait_until(lambda: "rebuilt 0 learned" in [x.strip() for x in lines], 30), lines
        # Learned without --sequence: the sequence the server's catalog lists.
        done = ktbt_run(
            "peer", "run", "--id", "cppbot", "--vocabulary", str(vocabulary),
            "--control", str(control), "--connect", endpoint(port),
            "--export-learned", str(folder), "--exit-when-done", "--duration", "60",
        )  # fmt: skip
        assert done.returncode == 0, done.stdout + done.stderr
        assert 'learned DoorClosed, HandleSeen(side="left") from doors' in done.stdout
        [learned] = [p.name for p in folder.iterdir()]
        assert learned.startswith("000001-new-")
        assert wait_until(lambda: len(calls(after(lines, "rebuilt 1 learned"))) >= 3, 30), lines
        # Before, its handle was not on the right: nothing ran. Now the learned skill runs, with
        # its ports, in order.
        assert calls(lines[: [x.strip() for x in lines].index("rebuilt 1 learned")]) == []
        assert calls(after(lines, "rebuilt 1 learned"))[:3] == [
            "call GraspHandle",
            "call TurnHandle degrees=60",
            "call Push",
        ]
        assert proc.poll() is None


def test_the_door_robot_refuses_a_node_or_a_value_its_model_does_not_have(tmp_path: Path) -> None:
    _, _, xml = door_robot(tmp_path)
    folder = tmp_path / "learned"
    folder.mkdir()
    skills = [
        "<sq><c>(DoorClosed)<a>(Fly)<e>",  # its model does not declare Fly
        '<sq><c>(DoorClosed)<a>(TurnHandle, degrees="sixty")<e>',  # not an int
        '<sq><c>(DoorClosed)<c>(HandleSeen, side="right")<a>(Push)<e>',  # does not hold
        "<sq><c>(DoorClosed)<a>(TurnHandle, degrees=30)<e>",
    ]
    for number, skill in enumerate(skills, 1):
        path = folder / f"00000{number}-new-{str(number) * 16}.xml"
        path.write_text(to_xml(parse(skill), tree_id=f"ktbt-new-{number}"))
    with robot(folder, *LEFT_HANDLE, control=xml) as (proc, lines):
        assert wait_until(lambda: "call TurnHandle degrees=30" in calls(lines), 30), lines
        refused = [x for x in lines if x.startswith("refused")]
        assert len(refused) == 2, lines
        assert "Fly" in refused[0] and "converted to int" in refused[1]
        assert "rebuilt 2 learned" in [x.strip() for x in lines]
        assert set(calls(lines)) == {"call TurnHandle degrees=30"}
        assert proc.poll() is None
