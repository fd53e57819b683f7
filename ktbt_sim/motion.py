"""How the release's robots move (``spec/simulator.md`` §4), for every robot at once.

The behaviours choose only a motion mode per robot; every iteration :func:`behave` turns each
robot's mode into its resultant velocity ``rv`` (each branch one of the release's methods) and
:func:`actuate` turns ``rv`` into motion. Both are one compiled loop over the robots; their
random draws come from the trial's own generator, robot by robot in index order.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ktbt_sim.kernel import generator, jit

STOP, WALK, TO_ZONE, AVOID, IDLE = 0, 1, 2, 3, 4
"""The motion modes an action selects. IDLE: the last tick ran a pick or a place, which leave
the velocity as it was."""

BIAS = 1e-4
"""``ActuatorControl`` adds (0.0001, 0, 0) to the normalised heading, so a zero ``rv`` faces
+x (§4.1)."""


class Actuator(NamedTuple):
    """Stop-and-turn velocity control (§4.1): a robot whose heading is within ``tolerance``
    (radians) of ``rv`` drives at ``speed`` along ``rv`` and does not turn; any other robot
    stands still and turns toward ``rv`` by at most ``turn`` (radians) an iteration."""

    speed: float
    turn: float
    tolerance: float


class Walk(NamedTuple):
    """The random walk's and the turns' constants (§4.2, §4.4, §4.6)."""

    dt: float
    goal_span: int
    """New goals have each coordinate uniform in [-goal_span, goal_span - 1]."""
    leg_min_s: float
    leg_max_s: float
    carry_jitter_deg: tuple[int, int]
    avoid_turn_deg: tuple[int, int]


@jit
def actuate(
    rv: np.ndarray, heading: np.ndarray, out: np.ndarray, speed: float, turn: float, tol: float
) -> None:
    """Write each robot's velocity into ``out`` (n, 2) and turn ``heading`` in place (§4.1)."""
    for i in range(rv.shape[0]):
        x, y = rv[i, 0], rv[i, 1]
        norm = np.hypot(x, y)
        want = np.arctan2(y, x + BIAS * norm)  # the angle of unit(rv) + (BIAS, 0)
        error = (want - heading[i] + np.pi) % (2 * np.pi) - np.pi
        if abs(error) < tol:
            gain = speed / norm if norm > 0.0 else 0.0
            out[i, 0] = x * gain
            out[i, 1] = y * gain
        else:
            out[i, 0] = 0.0
            out[i, 1] = 0.0
            heading[i] += min(max(error, -turn), turn)


@jit
def turn(rng: np.random.Generator, x: float, y: float, lo: int, hi: int) -> tuple[float, float]:
    """(x, y) turned counter-clockwise by a whole number of degrees drawn from {lo, …, hi}:
    ``WalkToCollection``'s jitter (§4.4) and ``CollisionAvoidance``'s sideways turn (§4.6)."""
    a = np.radians(np.float64(rng.integers(lo, hi + 1)))
    c, s = np.cos(a), np.sin(a)
    return x * c - y * s, x * s + y * c


@jit
def behave(
    mode: np.ndarray,
    rv: np.ndarray,
    pos: np.ndarray,
    walk_flag: np.ndarray,
    walk_time: np.ndarray,
    walk_span: np.ndarray,
    memory_iter: np.ndarray,
    memory_duration: int,
    goal: np.ndarray,
    zone_centres: np.ndarray,
    start: np.ndarray,
    others: np.ndarray,
    weights: np.ndarray,
    wall_count: np.ndarray,
    wall_centres: np.ndarray,
    rng_pointers: np.ndarray,
    dt: float,
    goal_span: int,
    leg_min: float,
    leg_max: float,
    jitter_lo: int,
    jitter_hi: int,
    avoid_lo: int,
    avoid_hi: int,
) -> np.ndarray:
    """Every robot's behaviour writes its resultant velocity by its mode; returns the robots
    whose EL memory timer ran out (random-walk ticks since the last pick-up or lesson, §9.3).
    The draws come from the trial's generator, given by its ``kernel.generator_pointers``.

    - ``RandomWalk`` (§4.2): sets the random-walk flag; the leg's clock runs only on its ticks;
      when the leg is over, ``rv`` aims at a new far goal and the next leg lasts U(leg_min,
      leg_max) s.
    - ``StopWalk``: ``rv`` = 0.
    - ``WalkToCollection`` (§4.4): aim at the zone's centre, turned by the jitter.
    - ``CollisionAvoidance`` (§4.6): Σ(self - collider) over the robots the collision sensor
      holds (each counted once or twice, see ``sensing.Proximity``) and the wall segments'
      centres, turned sideways.
    """
    rng = generator(rng_pointers)
    n = mode.shape[0]
    spent = np.empty(n, np.int64)
    ns = 0
    for i in range(n):
        m = mode[i]
        if m == WALK:
            walk_flag[i] = True
            elapsed = walk_time[i] + dt
            if elapsed > walk_span[i]:
                rv[i, 0] = np.float64(rng.integers(-goal_span, goal_span)) - pos[i, 0]
                rv[i, 1] = np.float64(rng.integers(-goal_span, goal_span)) - pos[i, 1]
                elapsed = 0.0
                walk_span[i] = rng.uniform(leg_min, leg_max)
            walk_time[i] = elapsed
            if memory_duration > 0:
                memory_iter[i] += 1
                if memory_iter[i] >= memory_duration:
                    spent[ns] = i
                    ns += 1
        elif m == STOP:
            rv[i, 0] = 0.0
            rv[i, 1] = 0.0
            walk_flag[i] = False
        elif m == TO_ZONE:
            walk_flag[i] = False
            c = goal[i] - 1
            x = zone_centres[c, 0] - pos[i, 0]
            y = zone_centres[c, 1] - pos[i, 1]
            rv[i, 0], rv[i, 1] = turn(rng, x, y, jitter_lo, jitter_hi)
        elif m == AVOID:
            x = 0.0
            y = 0.0
            for k in range(start[i], start[i + 1]):
                j = others[k]
                x += weights[k] * (pos[i, 0] - pos[j, 0])
                y += weights[k] * (pos[i, 1] - pos[j, 1])
            for k in range(wall_count[i]):
                x += pos[i, 0] - wall_centres[i, k, 0]
                y += pos[i, 1] - wall_centres[i, k, 1]
            rv[i, 0], rv[i, 1] = turn(rng, x, y, avoid_lo, avoid_hi)
    return spent[:ns].copy()


@jit
def move(
    mode: np.ndarray,
    rv: np.ndarray,
    pos: np.ndarray,
    walk_flag: np.ndarray,
    walk_time: np.ndarray,
    walk_span: np.ndarray,
    memory_iter: np.ndarray,
    memory_duration: int,
    goal: np.ndarray,
    zone_centres: np.ndarray,
    start: np.ndarray,
    others: np.ndarray,
    weights: np.ndarray,
    wall_count: np.ndarray,
    wall_centres: np.ndarray,
    rng_pointers: np.ndarray,
    dt: float,
    goal_span: int,
    leg_min: float,
    leg_max: float,
    jitter_lo: int,
    jitter_hi: int,
    avoid_lo: int,
    avoid_hi: int,
    heading: np.ndarray,
    velocity: np.ndarray,
    speed: float,
    turn: float,
    tolerance: float,
) -> np.ndarray:
    """:func:`behave` then :func:`actuate`, in one call; returns the robots whose EL memory
    timer ran out (what they forget changes nothing the actuators read)."""
    spent = behave(
        mode, rv, pos, walk_flag, walk_time, walk_span, memory_iter, memory_duration, goal,
        zone_centres, start, others, weights, wall_count, wall_centres, rng_pointers, dt,
        goal_span, leg_min, leg_max, jitter_lo, jitter_hi, avoid_lo, avoid_hi,
    )  # fmt: skip
    actuate(rv, heading, velocity, speed, turn, tolerance)
    return spent
