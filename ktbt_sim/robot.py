"""The search-and-rescue robot as the library sees it: its control tree, the knowledge of each
robot type, and the behaviours its tree names.

Behaviours are thin: conditions read flags that sensing wrote on the robot's blackboard, and
actions only choose what the actuators do (a motion mode, a pick, a place). The world turns
motion modes into velocities for every robot at once, so re-ticking a tree whose flags have not
changed changes nothing: the world relies on that to skip such ticks (see ``World.step``).
"""

from __future__ import annotations

from collections.abc import Iterable
from functools import cache
from importlib.resources import files
from typing import TYPE_CHECKING

import numpy as np

import ktbt_proto as kp
from ktbt_proto.knowledge import sequence_key

from .kernel import jit

if TYPE_CHECKING:
    from .world import World

CONTROL_TREE = files("ktbt_sim") / "trees" / "sar_control.sbt"
"""The paper's control tree with ``common``, ``prior`` and ``new`` placeholders."""

KINDS = {"I": (), "M": (1, 2, 3, 4), "R": (1,), "G": (2,), "Y": (3,), "B": (4,)}
"""Robot types of the paper's tables and the colours (1 red .. 4 blue) each knows at start."""

# Motion modes an action selects; the world writes every robot's resultant velocity by its
# mode each iteration, as the release's actions do each tick (release-behaviour.md §4).
from .motion import AVOID, STOP, TO_ZONE, WALK  # noqa: E402

# Blackboard keys written by sensing.
COLLISION = "_collisionDetectedF"
WAIT = "_waitF"
CARRYING = "_treasureOnBoardF"
IN_ZONE = "_inZoneF"
SEEN = "seen"
"""The colour (1..4) of the target the target sensor has registered, 0 for none (§5.1)."""
INDEX = "index"


@cache
def sequence(colour: int) -> tuple[kp.Condition, ...]:
    """The condition sequence of colour ``colour``'s knowledge: a target of that colour seen."""
    return (kp.Condition("TargetSeen", args=(("colour", colour),)),)


@cache
def sequence_of(colour: int) -> str:
    """Canonical key of :func:`sequence` (what robots ask about)."""
    return sequence_key(sequence(colour))


@cache
def skill(colour: int) -> kp.Node:
    """The action subtree of colour ``colour``: pick the target up, head for its zone."""
    return kp.parse(
        f"<sq><a>(PickTreasure, colour={colour})<a>(AssignCollectionPoint, colour={colour})<e>"
    ).root


@cache
def base_tree() -> kp.Tree:
    return kp.parse(CONTROL_TREE.read_text(encoding="utf-8"))


@cache
def control_tree(known: tuple[int, ...]) -> kp.Tree:
    """The control tree of a robot built knowing colours ``known`` (shared: trees are values)."""
    tree = base_tree()
    for colour in known:
        tree = kp.merge(tree, skill(colour), "prior", when=sequence(colour))
    return tree


def registry(world: World) -> kp.Registry:
    """The behaviours of ``world``'s robots; the robot is found through ``bb["index"]``."""
    reg = kp.Registry()
    set_mode = world.set_mode

    @reg.condition("_collisionDetectedF")
    def collision(bb: kp.Blackboard) -> bool:
        return bool(bb[COLLISION])

    @reg.condition("_waitF")
    def waiting(bb: kp.Blackboard) -> bool:
        return bool(bb[WAIT])

    @reg.condition("_treasureOnBoardF")
    def carrying(bb: kp.Blackboard) -> bool:
        return bool(bb[CARRYING])

    @reg.condition("_inZoneF")
    def in_zone(bb: kp.Blackboard) -> bool:
        return bool(bb[IN_ZONE])

    @reg.condition("TargetSeen")
    def target_seen(bb: kp.Blackboard, colour: int) -> bool:
        return bool(bb[SEEN] == colour)

    def moving(name: str, value: int) -> None:
        def act(bb: kp.Blackboard) -> kp.Status:
            set_mode(bb[INDEX], value)
            return kp.SUCCESS

        reg.add_action(name, act)

    moving("CollisionAvoidance", AVOID)
    moving("StopWalk", STOP)
    moving("WalkToCollection", TO_ZONE)
    moving("RandomWalk", WALK)

    @reg.action("PickTreasure")
    def pick(bb: kp.Blackboard, colour: int | None = None) -> kp.Status:
        return kp.SUCCESS if world.pick(bb[INDEX], colour) else kp.FAILURE

    @reg.action("AssignCollectionPoint")
    def assign(bb: kp.Blackboard, colour: int) -> kp.Status:
        world.set_goal(bb[INDEX], int(colour))
        return kp.SUCCESS

    @reg.action("PlaceTreasure")
    def place(bb: kp.Blackboard) -> kp.Status:
        return kp.SUCCESS if world.place(bb[INDEX]) else kp.FAILURE

    return reg


def kinds(counts: Iterable[tuple[str, int]]) -> list[str]:
    """One type letter per robot, in the order of the paper's (I, M, R, G, Y, B) tuple."""
    return [kind for kind, n in counts for _ in range(n)]


@jit
def signature(
    collision: np.ndarray,
    wait_end: np.ndarray,
    call: int,
    carrying: np.ndarray,
    in_zone: np.ndarray,
    colour_of: np.ndarray,
    tsr: np.ndarray,
    known: np.ndarray,
) -> np.ndarray:
    """Every robot's tree inputs packed in one integer: collision, waiting, carrying, in its
    zone, the registered target's colour, the colours it knows."""
    n = collision.shape[0]
    out = np.empty(n, np.int64)
    for i in range(n):
        bits = np.int64(0)
        for c in range(4):
            if known[i, c]:
                bits |= np.int64(1) << c
        out[i] = (
            np.int64(collision[i])
            | np.int64(wait_end[i] >= call) << 1
            | np.int64(carrying[i] >= 0) << 2
            | np.int64(in_zone[i]) << 3
            | colour_of[tsr[i]] << 4
            | bits << 7
        )
    return out
