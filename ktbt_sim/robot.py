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
from ktbt_proto.items import sequence_key
from ktbt_proto.tree import Node
from ktbt_sim.kernel import jit

if TYPE_CHECKING:
    from ktbt_sim.state import Trial

CONTROL_TREE = files("ktbt_sim") / "trees" / "sar_control.sbt"
"""The paper's control tree with ``common``, ``prior`` and ``new`` placeholders."""

KINDS = {"I": (), "M": (1, 2, 3, 4), "R": (1,), "G": (2,), "Y": (3,), "B": (4,)}
"""Robot types of the paper's tables and the colours (1 red .. 4 blue) each knows at start."""

# Motion modes an action selects; the world writes every robot's resultant velocity by its
# mode each iteration, as the release's actions do each tick (spec/simulator.md §4).
from ktbt_sim.motion import AVOID, IDLE, STOP, TO_ZONE, WALK  # noqa: E402

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
def skill(colour: int) -> Node:
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


def registry(trial: Trial) -> kp.Registry:
    """The behaviours of ``trial``'s robots; the robot is found through ``bb["index"]``. Each
    action writes its effect into the trial's arrays."""
    reg = kp.Registry()
    drive = trial.drive

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
            drive[bb[INDEX]] = value
            return kp.SUCCESS

        reg.add_action(name, act)

    moving("CollisionAvoidance", AVOID)
    moving("StopWalk", STOP)
    moving("WalkToCollection", TO_ZONE)
    moving("RandomWalk", WALK)

    @reg.action("PickTreasure")
    def pick_up(bb: kp.Blackboard, colour: int | None = None) -> kp.Status:
        return kp.SUCCESS if pick(trial, bb[INDEX], colour) else kp.FAILURE

    @reg.action("AssignCollectionPoint")
    def assign(bb: kp.Blackboard, colour: int) -> kp.Status:
        trial.goal[bb[INDEX]] = int(colour)  # AssignCPk: the zone the target goes to
        return kp.SUCCESS

    @reg.action("PlaceTreasure")
    def put_down(bb: kp.Blackboard) -> kp.Status:
        return kp.SUCCESS if place(trial, bb[INDEX]) else kp.FAILURE

    return reg


def pick(trial: Trial, i: int, colour: int | None) -> bool:
    """``PickTreasure`` (§4.3): take the registered target at once, wherever it is in the sensor
    (no approach); clears the random-walk flag, disables sensing, forgets the requester. The
    world takes the target out of the space and of every sensor after the tick."""
    t = int(trial.sensor.tsr[i])
    if trial.carrying[i] >= 0 or t < 0 or not trial.target_free[t]:
        return False
    if colour is not None and int(trial.target_colour[t]) != int(colour):
        return False
    trial.carrying[i] = t
    trial.target_free[t] = False
    trial.picked.append(t)
    trial.walk_flag[i] = False
    trial.requester[i] = -1
    trial.memory_iter[i] = 0
    trial.drive[i] = IDLE
    return True


def place(trial: Trial, i: int) -> bool:
    """``PlaceTreasure`` (§4.5): the target already belongs to the zone; the robot starts a
    wait and a cool-down (after every delivery, in every mode: §7)."""
    if trial.carrying[i] < 0 or not trial.in_zone[i]:
        return False
    trial.carrying[i] = -1
    trial.goal[i] = 0
    trial.in_zone[i] = False
    trial.sensor.tsr[i] = -1
    trial.walk_flag[i] = False
    trial.drive[i] = IDLE
    trial.delivered += 1
    trial.timers.start(i, 2 * trial.iteration)
    return True


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


@jit
def due(
    collision: np.ndarray,
    wait_end: np.ndarray,
    call: int,
    carrying: np.ndarray,
    in_zone: np.ndarray,
    colour_of: np.ndarray,
    tsr: np.ndarray,
    known: np.ndarray,
    drive: np.ndarray,
    last: np.ndarray,
    every: bool,
) -> np.ndarray:
    """The robots whose tree must tick (all of them with ``every``): those whose
    :func:`signature` differs from ``last``, the one they last ticked with, and those whose last
    tick ran a pick or a place (``drive`` IDLE), which changed their inputs. When any is due,
    ``last`` becomes every robot's signature."""
    now = signature(collision, wait_end, call, carrying, in_zone, colour_of, tsr, known)
    n = now.shape[0]
    out = np.empty(n, np.int64)
    k = 0
    for i in range(n):
        if every or now[i] != last[i] or drive[i] == IDLE:
            out[k] = i
            k += 1
    if k:
        last[:] = now
    return out[:k]
