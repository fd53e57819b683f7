"""The paper's search-and-rescue control tree, ticked through a scripted scenario."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import ktbt_proto as kp

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
FLAGS = ("_collisionDetectedF", "_waitF", "_treasureOnBoardF", "_inZoneF")
ACTIONS = (
    "CollisionAvoidance",
    "StopWalk",
    "PlaceTreasure",
    "WalkToCollection",
    "RandomWalk",
    "PickTreasure",
)


def sar_vocabulary(log: list[str]) -> kp.Registry:
    reg = kp.Registry()
    reg.flags(*FLAGS)

    def recorder(name: str) -> tuple[Callable[[kp.Blackboard], kp.Status], Callable[..., None]]:
        def tick(bb: kp.Blackboard) -> kp.Status:
            log.append(name)
            return kp.RUNNING

        def halt(bb: kp.Blackboard) -> None:
            log.append(f"halt {name}")

        return tick, halt

    for name in ACTIONS:
        tick, halt = recorder(name)
        reg.add_action(name, tick, halt=halt)

    @reg.condition("TargetSeen")
    def target_seen(bb: kp.Blackboard, colour: int) -> bool:
        return bool(bb.get("target") == colour)

    @reg.action("AssignCollectionPoint")
    def assign(bb: kp.Blackboard, colour: int) -> kp.Status:
        log.append(f"Assign {colour}")
        return kp.SUCCESS

    return reg


def run(live: kp.LiveTree, log: list[str], **flags: object) -> list[str]:
    log.clear()
    for name in FLAGS:
        live.blackboard[name] = False
    live.blackboard.update(flags)
    assert live.tick() is kp.RUNNING
    return list(log)


def test_paper_control_tree_scenario() -> None:
    log: list[str] = []
    live = kp.LiveTree((EXAMPLES / "paper_control.sbt").read_text(), sar_vocabulary(log))
    # Nothing sensed: the fallback random walk.
    assert run(live, log) == ["RandomWalk"]
    assert run(live, log) == ["RandomWalk"]
    # A collision: avoidance preempts the walk, which is halted on the same tick.
    assert run(live, log, _collisionDetectedF=True) == ["CollisionAvoidance", "halt RandomWalk"]
    assert run(live, log, _collisionDetectedF=True) == ["CollisionAvoidance"]
    # Waiting (querying or teaching) stops the robot.
    assert run(live, log, _waitF=True) == ["halt CollisionAvoidance", "StopWalk"]
    # Carrying a target: walk to the collection zone, then place it.
    assert run(live, log, _treasureOnBoardF=True) == ["halt StopWalk", "WalkToCollection"]
    assert run(live, log, _treasureOnBoardF=True, _inZoneF=True) == [
        "PlaceTreasure",
        "halt WalkToCollection",
    ]
    # A collision while carrying: critical first.
    assert run(live, log, _treasureOnBoardF=True, _collisionDetectedF=True) == [
        "CollisionAvoidance",
        "halt PlaceTreasure",
    ]
    assert run(live, log) == ["halt CollisionAvoidance", "RandomWalk"]


def test_prior_and_learned_knowledge() -> None:
    log: list[str] = []
    live = kp.LiveTree((EXAMPLES / "sar_control.sbt").read_text(), sar_vocabulary(log))
    assert run(live, log) == ["RandomWalk"]
    # Prior knowledge: red (colour 1) targets are picked up.
    assert run(live, log, target=1) == ["PickTreasure", "halt RandomWalk"]
    # A green target is unknown: the robot walks on.
    assert run(live, log, target=2) == ["halt PickTreasure", "RandomWalk"]
    live.merge(
        "<sq><a>(PickTreasure)<a>(AssignCollectionPoint, colour=2)<e>",
        when=["TargetSeen(colour=2)"],
    )
    assert run(live, log, target=2) == ["PickTreasure", "halt RandomWalk"]
