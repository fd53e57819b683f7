"""Hot merge into a live tree: takes effect at the next tick, disturbs nothing else, and leaves
the tree exactly as it was when the knowledge is refused."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any, ClassVar

import pytest

import ktbt_proto as kp

CONTROL = """<sl>
    <sq><c>(Danger)<a>(Avoid)<e>
    <k>(new)<e>
    <a>(Walk)
<e>"""


class Walk:
    """A stateful action: counts its own ticks and halts; RUNNING forever."""

    instances: ClassVar[list[Walk]] = []

    def __init__(self, bb: kp.Blackboard) -> None:
        self.ticks = 0
        self.halts = 0
        Walk.instances.append(self)

    def tick(self) -> kp.Status:
        self.ticks += 1
        return kp.RUNNING

    def halt(self) -> None:
        self.halts += 1


def registry(log: list[str]) -> kp.Registry:
    reg = kp.Registry()
    reg.flags("Danger", "SeesRed", "SeesBlue")
    reg.add_action("Walk", Walk)

    @reg.action("Avoid")
    def avoid(bb: kp.Blackboard) -> kp.Status:
        log.append("Avoid")
        return kp.RUNNING

    @reg.action("Pick")
    def pick(bb: kp.Blackboard, colour: str = "any") -> kp.Status:
        log.append(f"Pick {colour}")
        return kp.RUNNING

    return reg


@pytest.fixture
def live() -> Any:
    Walk.instances.clear()
    log: list[str] = []
    tree = kp.LiveTree(CONTROL, registry(log))
    tree.log = log  # type: ignore[attr-defined]
    return tree


def test_running_action_outside_the_placeholder_is_not_disturbed(live: Any) -> None:
    for _ in range(3):
        assert live.tick() is kp.RUNNING
    walk = Walk.instances[0]
    assert (walk.ticks, walk.halts) == (3, 0)
    assert live.merge('<a>(Pick, colour="red")', when=["SeesRed"]) is True
    for _ in range(2):
        live.tick()
    # Same instance, never halted or restarted: its count simply goes on.
    assert Walk.instances == [walk]
    assert (walk.ticks, walk.halts) == (5, 0)
    # The new knowledge works, and preempts the walk (which is then halted once).
    live.blackboard["SeesRed"] = True
    live.tick()
    assert live.log == ["Pick red"]
    assert (walk.ticks, walk.halts) == (5, 1)


def test_merge_takes_effect_at_the_next_tick(live: Any) -> None:
    live.blackboard["SeesRed"] = True
    live.tick()
    assert live.log == []
    live.merge('<a>(Pick, colour="red")', when=["SeesRed"])
    assert '<k>(new)<sq><c>(SeesRed)<a>(Pick,colour="red")<e><e>' in kp.format_tree(
        live.tree, "compact"
    )
    assert live.log == []  # nothing ran in between
    live.tick()
    assert live.log == ["Pick red"]


def test_duplicate_knowledge_is_a_no_op(live: Any) -> None:
    assert live.merge("<a>(Pick)", when=["SeesRed"]) is True
    tree = live.tree
    assert live.merge("<a>(Pick)", when=["SeesRed"]) is False
    assert live.tree is tree


@pytest.mark.parametrize(
    ("knowledge", "when", "code"),
    [
        ("<a>(Teleport)", ["SeesRed"], "SBT306"),
        ("<a>(Pick)", ["Unknown"], "SBT305"),
        ("<a>(Pick, hue=1)", ["SeesRed"], "SBT311"),
        ("<a>(Pick", ["SeesRed"], "SBT104"),
        ("<neg><a>(Pick)<a>(Pick)<e>", ["SeesRed"], "SBT301"),
        ("<sl><k>(new)<e><a>(Pick)<e>", ["SeesRed"], "SBT304"),
        ("<sq>" * 130 + "<a>(Pick)" + "<e>" * 130, ["SeesRed"], "SBT202"),
        ("<sq>" * 126 + "<a>(Pick)" + "<e>" * 126, ["SeesRed"], "SBT202"),
    ],
)
def test_refused_knowledge_leaves_everything_as_it_was(
    live: Any, knowledge: str, when: list[str], code: str
) -> None:
    live.tick()
    before = kp.format_tree(live.tree, "compact")
    with pytest.raises(kp.StringBTError) as info:
        live.merge(knowledge, when=when)
    assert info.value.code.value == code
    assert kp.format_tree(live.tree, "compact") == before
    live.blackboard["SeesRed"] = True
    assert live.tick() is kp.RUNNING
    assert live.log == []  # the refused knowledge never ran
    assert (Walk.instances[0].ticks, Walk.instances[0].halts) == (2, 0)


def test_conflicting_knowledge_is_refused(live: Any) -> None:
    live.merge("<a>(Pick)", when=["SeesRed"])
    with pytest.raises(kp.MergeError):
        live.merge("<a>(Avoid)", when=["SeesRed"])


def test_merges_from_another_thread_while_ticking() -> None:
    Walk.instances.clear()
    log: list[str] = []
    reg = registry(log)
    colours = [f"C{i}" for i in range(40)]
    reg.flags(*colours)
    live = kp.LiveTree(CONTROL, reg)
    stop = threading.Event()
    errors: list[BaseException] = []

    def ticker() -> None:
        try:
            while not stop.is_set():
                live.tick()
        except BaseException as exc:  # surfaced below
            errors.append(exc)

    thread = threading.Thread(target=ticker)
    thread.start()
    try:
        for colour in colours:
            assert live.merge(f'<a>(Pick, colour="{colour}")', when=[colour])
    finally:
        stop.set()
        thread.join(timeout=30)
    assert not thread.is_alive() and errors == []
    live.tick()
    for colour in reversed(colours):
        live.blackboard[colour] = True
    log.clear()
    live.tick()
    assert log == ["Pick C0"]  # merged in order: the first learned comes first
    live.blackboard["C0"] = False
    live.tick()
    assert log == ["Pick C0", "Pick C1"]
    assert kp.format_tree(live.tree, "compact").count("<a>(Pick") == 40


def test_live_tree_from_file_and_tree_objects() -> None:
    reg = kp.Registry()
    reg.flags("_collisionDetectedF", "_waitF", "_treasureOnBoardF", "_inZoneF")
    for name in [
        "CollisionAvoidance",
        "StopWalk",
        "PlaceTreasure",
        "WalkToCollection",
        "RandomWalk",
    ]:
        reg.add_action(name, lambda bb: kp.RUNNING)
    text = (Path(__file__).resolve().parents[2] / "examples" / "paper_control.sbt").read_text()
    assert kp.LiveTree(kp.parse(text), reg).tick() is kp.RUNNING
    assert kp.LiveTree(kp.parse(text).root, reg).tick() is kp.RUNNING
    with pytest.raises(kp.MergeError):  # the paper's tree has no placeholder
        kp.LiveTree(text, reg).merge("<a>(RandomWalk)", when=["_waitF"])
