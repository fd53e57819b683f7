"""What a robot senses (``spec/simulator.md`` §4.5, §4.6, §5), after every physics step.

The release's sensors are trigger callbacks that fire after the physics step. Ours are the same:
pymunk sensor shapes with begin/separate callbacks for targets and walls (only what changed costs
anything), and one distance matrix per step for the robot-to-robot sensors (the collision sensor
and the comms sphere), which every robot needs every step anyway.
"""

from __future__ import annotations

import numpy as np
import pymunk

from .kernel import jit

# Collision types and filter categories.
BODY, WALL, TARGET, TARGET_SENSOR, WALL_SENSOR = 1, 2, 4, 8, 16


class TargetSensor:
    """The target sensor's event semantics (§5.1), for every robot.

    ``tsr[i]`` is the target robot ``i`` has registered, or -1. On enter of a target still
    lying: if sensing is on, it is registered (the most recent enter wins); if sensing is off
    (carrying or cooling down), the registration is *cleared*. On exit of any target, the
    registration is cleared, even if other targets are still inside. Nothing is registered again
    while it stays inside. A picked target leaves every sensor it was in (its exit clears them).
    """

    def __init__(self, space: pymunk.Space, robots: int, targets: int) -> None:
        self.tsr = np.full(robots, -1, dtype=np.int64)
        self.enabled = np.ones(robots, dtype=bool)
        """Whether each robot's sensing is on at trigger time (the world sets it every step)."""
        self.watchers: list[set[int]] = [set() for _ in range(targets)]
        self.changed: set[int] = set()
        """Robots whose registration changed since the world last looked."""
        self.robot_of: dict[pymunk.Shape, int] = {}
        self.target_of: dict[pymunk.Shape, int] = {}
        space.on_collision(TARGET_SENSOR, TARGET, begin=self._enter, separate=self._exit)

    def _enter(self, arbiter: pymunk.Arbiter, _space: pymunk.Space, _data: object) -> None:
        eyes, target = arbiter.shapes
        i, t = self.robot_of[eyes], self.target_of[target]
        self.watchers[t].add(i)
        self.tsr[i] = t if self.enabled[i] else -1
        self.changed.add(i)

    def _exit(self, arbiter: pymunk.Arbiter, _space: pymunk.Space, _data: object) -> None:
        eyes, target = arbiter.shapes
        i, t = self.robot_of.get(eyes, -1), self.target_of.get(target, -1)
        if i < 0 or t < 0 or i not in self.watchers[t]:  # the space is being torn down
            return
        self.watchers[t].discard(i)
        self.tsr[i] = -1
        self.changed.add(i)

    def picked(self, t: int) -> None:
        """Target ``t`` was taken away: an exit from every sensor it was in. pymunk reports the
        separation when the shape is removed; this makes the rule independent of that."""
        for i in self.watchers[t]:
            self.tsr[i] = -1
            self.changed.add(i)
        self.watchers[t].clear()


WALL_SLOTS = 16
"""At most this many wall segments in one robot's collision sensor (a 75-radius sphere
overlaps a handful at a corner)."""


class WallSensor:
    """The collision sensor's walls (§4.6): the segments each robot's 75-radius sphere overlaps,
    each entering the avoidance sum through its centre."""

    def __init__(self, space: pymunk.Space, robots: int) -> None:
        self.contacts: list[dict[int, tuple[float, float]]] = [{} for _ in range(robots)]
        self.count = np.zeros(robots, dtype=np.int64)
        self.centres = np.zeros((robots, WALL_SLOTS, 2))
        """The centres of the segments each robot's sensor overlaps, in order of entry."""
        self.robot_of: dict[pymunk.Shape, int] = {}
        self.segment_of: dict[pymunk.Shape, tuple[int, float, float]] = {}
        self.changed: set[int] = set()
        space.on_collision(WALL_SENSOR, WALL, begin=self._enter, separate=self._exit)

    def _enter(self, arbiter: pymunk.Arbiter, _space: pymunk.Space, _data: object) -> None:
        bumper, wall = arbiter.shapes
        i = self.robot_of[bumper]
        k, x, y = self.segment_of[wall]
        self.contacts[i][k] = (x, y)
        self._sync(i)

    def _exit(self, arbiter: pymunk.Arbiter, _space: pymunk.Space, _data: object) -> None:
        bumper, wall = arbiter.shapes
        i = self.robot_of.get(bumper, -1)
        segment = self.segment_of.get(wall)
        if i < 0 or segment is None:
            return
        self.contacts[i].pop(segment[0], None)
        self._sync(i)

    def _sync(self, i: int) -> None:
        held = list(self.contacts[i].values())[:WALL_SLOTS]
        self.count[i] = len(held)
        if held:
            self.centres[i, : len(held)] = held
        self.changed.add(i)


class Proximity:
    """Robot-to-robot sensing (§4.6, §5.3), from the robots in the 3 x 3 cells around each
    robot (cells as wide as the longest sensing distance), compiled: a step costs in proportion
    to the robots and their neighbours.

    - Collision sensor (§4.6): another robot counts once when the two 75-radius spheres touch
      (centre distance below 150) and twice when its body is inside this robot's sphere (below
      75 + the body's radius): the release lists the other's sphere and its body separately.
    - Comms (§5.3): the neighbour list holds the robots whose body the comms sphere overlaps
      (centre distance at most ``radius``); ``entered`` is the iteration at which each pair of
      ``keys`` (``i * n + j``, sorted) last came into range (simultaneous entries in index
      order).
    """

    def __init__(self, n: int, sensor: float, body: float, radius: float, comms: bool) -> None:
        self.n = n
        self.touch2 = (2 * sensor) ** 2
        self.body2 = (sensor + body) ** 2
        self.radius2 = radius**2
        self.comms = comms
        self.cell = max(2 * sensor, radius if comms else 0.0)
        empty = np.zeros(0, dtype=np.int64)
        self.count = np.zeros(n, dtype=np.int64)
        """How many robots each robot's collision sensor holds (a robot counted once)."""
        self.start = np.zeros(n + 1, dtype=np.int64)
        self.others = empty
        self.weights = np.zeros(0)
        """Robot ``i``'s collision pairs: ``others[start[i]:start[i + 1]]``, each weighted 1 or
        2."""
        self.has_neighbours = np.zeros(n, dtype=bool)
        self.newly: np.ndarray = np.zeros((0, 2), dtype=np.int64)
        """Pairs (i, j) that came into comms range in the last update."""
        self.keys = empty
        self.entered = empty

    def update(self, pos: np.ndarray, iteration: int) -> None:
        self.start, self.others, self.weights, keys = find_pairs(
            pos, self.cell, self.touch2, self.body2, self.radius2, self.comms
        )
        self.count = np.diff(self.start)
        if self.comms:
            self.entered, self.newly, self.has_neighbours = entries(
                self.keys, self.entered, keys, iteration, self.n
            )
            self.keys = keys

    def weight(self, i: int) -> np.ndarray:
        """Robot ``i``'s collision weight of every robot (0, 1 or 2)."""
        out = np.zeros(self.n)
        lo, hi = self.start[i], self.start[i + 1]
        out[self.others[lo:hi]] = self.weights[lo:hi]
        return out

    def neighbours(self, i: int) -> np.ndarray:
        """The robots in robot ``i``'s comms range, in index order."""
        lo, hi = np.searchsorted(self.keys, (i * self.n, (i + 1) * self.n))
        out: np.ndarray = self.keys[lo:hi] % self.n
        return out

    def in_range(self, i: int, j: int) -> bool:
        """Whether robot ``j`` is in robot ``i``'s comms range."""
        key = i * self.n + j
        at = int(np.searchsorted(self.keys, key))
        return at < len(self.keys) and int(self.keys[at]) == key

    def requesters(
        self, open_: np.ndarray, knows: np.ndarray | None = None, asked: np.ndarray | None = None
    ) -> np.ndarray:
        """For each robot, its earliest-entered neighbour with an open query (-1: none); with
        ``knows`` (n, 4) and ``asked`` (n,), only one whose colour it knows."""
        only = knows is not None and asked is not None
        if knows is None or asked is None:
            knows, asked = _NO_KNOWS, _NO_ASKED
        out: np.ndarray = first_requesters(
            self.keys, self.entered, self.n, open_, knows, asked, only
        )
        return out


_NO_KNOWS = np.zeros((0, 4), dtype=bool)
_NO_ASKED = np.zeros(0, dtype=np.int64)


DENSE_UP_TO = 200
"""Groups up to this size look at every pair, which is faster there than sorting cells."""


@jit
def _cells(pos: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each robot's cell key (column-major: the three cells of a column are one run of the
    sorted keys), the robots in key order and the sorted keys."""
    n = pos.shape[0]
    span = 1 << 21
    keys = np.empty(n, np.int64)
    for i in range(n):
        cx = np.int64(np.floor(pos[i, 0] / cell)) + span // 2
        cy = np.int64(np.floor(pos[i, 1] / cell)) + span // 2
        keys[i] = cx * span + cy
    order = np.argsort(keys, kind="mergesort")
    return keys, order, keys[order]


@jit
def find_pairs(
    pos: np.ndarray, cell: float, touch2: float, body2: float, radius2: float, comms: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The robot-to-robot sensors of every robot (§4.6, §5.3).

    Returns the collision sensor's pairs as ``start`` (n + 1 offsets) and ``other``, ``weight``
    (each robot's pairs in index order; a robot counts once when the spheres touch, twice when
    its body is inside the sphere), and the sorted keys ``i * n + j`` of the comms pairs. A
    small group looks at every pair; a large one only at the robots in the 3 x 3 cells around
    each, counted in one pass and written in a second."""
    n = pos.shape[0]
    near = np.zeros(n + 1, np.int64)
    talk = np.zeros(n + 1, np.int64)
    if n <= DENSE_UP_TO:
        order = np.arange(n)
        cells = order
    else:
        cells, order, _ = _cells(pos, cell)
    none_i, none_f = np.empty(0, np.int64), np.empty(0, np.float64)
    _sweep(pos, order, cells, touch2, body2, radius2, comms, near, talk, none_i, none_f, none_i)
    start = np.cumsum(near)
    first = np.cumsum(talk)
    others = np.empty(start[n], np.int64)
    weights = np.empty(start[n], np.float64)
    heard = np.empty(first[n], np.int64)
    fill = start[:n].copy()
    fill_c = first[:n].copy()
    _sweep(pos, order, cells, touch2, body2, radius2, comms, fill, fill_c, others, weights, heard)
    if n > DENSE_UP_TO:  # each robot's pairs in index order
        for i in range(n):
            _sort_pairs(others, weights, start[i], start[i + 1], True)
            _sort_pairs(heard, weights, first[i], first[i + 1], False)
    keys = np.empty(heard.shape[0], np.int64)
    for i in range(n):
        for b in range(first[i], first[i + 1]):
            keys[b] = i * n + heard[b]
    return start, others, weights, keys


@jit
def _sweep(
    pos: np.ndarray,
    order: np.ndarray,
    cells: np.ndarray,
    touch2: float,
    body2: float,
    radius2: float,
    comms: bool,
    near: np.ndarray,
    talk: np.ndarray,
    others: np.ndarray,
    weights: np.ndarray,
    heard: np.ndarray,
) -> None:
    """Visit every pair once from each side. With empty output arrays, count each robot's pairs
    into ``near`` and ``talk`` (at index i + 1); with them, write each pair at robot i's next
    free place (``near[i]``, ``talk[i]``). A large group is visited in the order of its sorted
    cell keys, so the three runs of neighbouring columns move forward only."""
    n = pos.shape[0]
    dense = n <= DENSE_UP_TO
    count = others.shape[0] == 0 and heard.shape[0] == 0
    span = np.int64(1 << 21)
    lo = np.zeros(3, np.int64)
    hi = np.zeros(3, np.int64)
    for r in range(n):
        i = order[r]
        if dense:
            lo[0], hi[0] = 0, n
            lanes = 1
        else:
            lanes = 3
            for d in range(3):
                column = cells[i] + (d - 1) * span
                while lo[d] < n and cells[order[lo[d]]] < column - 1:
                    lo[d] += 1
                if hi[d] < lo[d]:
                    hi[d] = lo[d]
                while hi[d] < n and cells[order[hi[d]]] <= column + 1:
                    hi[d] += 1
        xi, yi = pos[i, 0], pos[i, 1]
        for d in range(lanes):
            for k in range(lo[d], hi[d]):
                j = order[k]
                if j == i:
                    continue
                dx = xi - pos[j, 0]
                dy = yi - pos[j, 1]
                d2 = dx * dx + dy * dy
                if d2 < touch2:
                    if count:
                        near[i + 1] += 1
                    else:
                        others[near[i]] = j
                        weights[near[i]] = 2.0 if d2 < body2 else 1.0
                        near[i] += 1
                if comms and d2 <= radius2:
                    if count:
                        talk[i + 1] += 1
                    else:
                        heard[talk[i]] = j
                        talk[i] += 1


@jit
def _sort_pairs(others: np.ndarray, weights: np.ndarray, lo: int, hi: int, both: bool) -> None:
    """Insertion sort of ``others[lo:hi]`` (a handful), ``weights`` alongside if ``both``."""
    for a in range(lo + 1, hi):
        j = others[a]
        w = weights[a] if both else 0.0
        b = a - 1
        while b >= lo and others[b] > j:
            others[b + 1] = others[b]
            if both:
                weights[b + 1] = weights[b]
            b -= 1
        others[b + 1] = j
        if both:
            weights[b + 1] = w


@jit
def entries(
    old_keys: np.ndarray, old_entered: np.ndarray, keys: np.ndarray, iteration: int, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """When each comms pair came into range (kept from the last step, or now), the pairs that
    are new this step, and whether each robot has a neighbour."""
    out = np.empty(keys.shape[0], np.int64)
    fresh = np.empty(keys.shape[0], np.int64)
    has = np.zeros(n, np.bool_)
    nf = 0
    a = 0
    for b in range(keys.shape[0]):
        key = keys[b]
        while a < old_keys.shape[0] and old_keys[a] < key:
            a += 1
        if a < old_keys.shape[0] and old_keys[a] == key:
            out[b] = old_entered[a]
        else:
            out[b] = iteration
            fresh[nf] = key
            nf += 1
        has[key // n] = True
    newly = np.empty((nf, 2), np.int64)
    for m in range(nf):
        newly[m, 0] = fresh[m] // n
        newly[m, 1] = fresh[m] % n
    return out, newly, has


@jit
def first_requesters(
    keys: np.ndarray,
    entered: np.ndarray,
    n: int,
    open_: np.ndarray,
    knows: np.ndarray,
    asked: np.ndarray,
    only_known: bool,
) -> np.ndarray:
    """For each robot, its earliest-entered neighbour with an open query (ties: the lowest
    index), -1 for none; with ``only_known``, only one whose asked colour it knows
    (§8.2)."""
    out = np.full(n, -1, np.int64)
    best = np.zeros(n, np.int64)
    for b in range(keys.shape[0]):
        i = keys[b] // n
        j = keys[b] % n
        if not open_[j]:
            continue
        if only_known and not knows[i, asked[j] - 1]:
            continue
        if out[i] < 0 or entered[b] < best[i]:
            out[i] = j
            best[i] = entered[b]
    return out


@jit
def zones(
    pos: np.ndarray,
    carrying: np.ndarray,
    goal: np.ndarray,
    centres: np.ndarray,
    counted: np.ndarray,
    collected: np.ndarray,
    in_zone: np.ndarray,
    target_colour: np.ndarray,
    count_half: float,
    place_half: float,
    reach: float,
) -> None:
    """For every carrier: the carried cube counts once it is in its zone's outer box, and the
    robot may place once its zone detector overlaps the inner square (§4.5)."""
    for i in range(pos.shape[0]):
        t = carrying[i]
        if t < 0:
            continue
        c = goal[i] - 1
        dx = abs(pos[i, 0] - centres[c, 0])
        dy = abs(pos[i, 1] - centres[c, 1])
        if dx <= count_half and dy <= count_half and not counted[t]:
            counted[t] = True
            collected[target_colour[t] - 1] += 1
        ex = max(dx - place_half, 0.0)
        ey = max(dy - place_half, 0.0)
        if np.hypot(ex, ey) <= reach:
            in_zone[i] = True


@jit
def enable(
    enabled: np.ndarray, carrying: np.ndarray, wait_end: np.ndarray, cool_end: np.ndarray, call: int
) -> None:
    """Target sensing is on for robots that carry nothing and whose cool-down does not keep it
    off after counter call ``call - 1`` (between the end of the wait and the end of the
    cool-down, §7)."""
    for i in range(enabled.shape[0]):
        off = wait_end[i] < call <= cool_end[i]
        enabled[i] = carrying[i] < 0 and not off
