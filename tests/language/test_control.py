"""The control-tree contract (``ktbt_proto.control``, spec/protocol.md section 4.4): what an
agent needs of the tree it learns into, held by both backends alike, the compiled ``LiveTree``
and a py_trees ``BehaviourTree`` (``PyTreesControl``). Every rule is checked on each."""

from __future__ import annotations

from collections.abc import Callable

import py_trees
import pytest

import ktbt_proto as kp
from ktbt_proto.control import ControlFactory, ControlTree
from ktbt_proto.interop.pytrees_control import py_trees_control

ITEM = "<sq><c>(Seen)<a>(Act)<e>"
WHEN = ["Seen"]


def registry() -> kp.Registry:
    reg = kp.Registry()

    @reg.condition("Seen")
    def seen(bb: kp.Blackboard) -> bool:
        return bool(bb.get("seen", False))

    @reg.action("Act")
    def act(bb: kp.Blackboard) -> kp.Status:
        bb["acts"] = bb.get("acts", 0) + 1
        return kp.SUCCESS

    @reg.action("Idle")
    def idle(bb: kp.Blackboard) -> kp.Status:
        return kp.RUNNING

    return reg


def live(reg: kp.Registry, bb: kp.Blackboard, ticks: Callable[[], int]) -> ControlTree:
    return kp.LiveTree("<sl><k>(new)<e><a>(Idle)<e>", reg, bb, ticks=ticks)


def pytrees(reg: kp.Registry, bb: kp.Blackboard, ticks: Callable[[], int]) -> ControlTree:
    class Idle(py_trees.behaviour.Behaviour):
        def update(self) -> py_trees.common.Status:
            return py_trees.common.Status.RUNNING

    root = py_trees.composites.Selector("root", memory=False)
    root.add_children([py_trees.composites.Selector("k:new", memory=False), Idle("Idle")])
    factory: ControlFactory = py_trees_control(py_trees.trees.BehaviourTree(root))
    return factory(reg, bb, ticks)


BACKENDS = {"LiveTree": live, "py_trees": pytrees}


class Robot:
    """A backend with its own blackboard and tick counter, ticked as an agent ticks it."""

    def __init__(self, backend: str) -> None:
        self.bb = kp.Blackboard()
        self.bb["seen"] = True
        self.now = 0
        self.control = BACKENDS[backend](registry(), self.bb, lambda: self.now)

    def tick(self) -> kp.Status:
        self.now += 1
        return self.control.tick()


@pytest.fixture(params=sorted(BACKENDS))
def robot(request: pytest.FixtureRequest) -> Robot:
    return Robot(request.param)


def test_both_backends_are_control_trees(robot: Robot) -> None:
    assert isinstance(robot.control, ControlTree)


def test_a_merge_takes_effect_at_the_next_tick_boundary(robot: Robot) -> None:
    robot.tick()
    assert robot.control.merge(ITEM, "new", when=None) is True
    assert robot.control.knows("new", WHEN)  # pending counts as known
    assert robot.bb.get("acts", 0) == 0  # nothing ran between ticks
    robot.tick()
    assert robot.bb["acts"] == 1
    assert "<c>(Seen)" in kp.format_tree(robot.control.tree, "compact")


def test_the_same_item_again_changes_nothing(robot: Robot) -> None:
    assert robot.control.merge(ITEM, "new") is True
    robot.tick()
    before = kp.format_tree(robot.control.tree, "compact")
    assert robot.control.merge(ITEM, "new") is False
    robot.tick()
    assert kp.format_tree(robot.control.tree, "compact") == before


def test_a_merge_that_does_not_fit_raises_and_changes_nothing(robot: Robot) -> None:
    before = kp.format_tree(robot.control.tree, "compact")
    with pytest.raises(kp.StringBTError):
        robot.control.merge(ITEM, "nowhere")
    with pytest.raises(kp.StringBTError):
        robot.control.merge("<sq><c>(Seen)<a>(Fly)<e>", "new")  # the registry has no Fly
    robot.tick()
    assert kp.format_tree(robot.control.tree, "compact") == before


def test_forget_removes_the_item_at_a_tick_boundary(robot: Robot) -> None:
    robot.control.merge(ITEM, "new")
    robot.tick()
    assert robot.control.forget("new", WHEN) is True
    robot.tick()
    assert not robot.control.knows("new", WHEN)
    assert robot.bb["acts"] == 1  # forgotten before the second tick ran it
    assert robot.control.forget("new", WHEN) is False


def test_last_used_follows_the_ticks_that_ran_the_item(robot: Robot) -> None:
    assert robot.control.last_used("new", WHEN) is None  # no such item
    robot.control.merge(ITEM, "new")
    robot.tick()
    assert robot.control.last_used("new", WHEN) == robot.now
    robot.bb["seen"] = False  # the item's condition fails from now on
    used = robot.now
    robot.tick()
    robot.tick()
    assert robot.control.last_used("new", WHEN) == used
