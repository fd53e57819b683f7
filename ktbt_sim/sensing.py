"""What a robot senses (``spec/simulator.md`` §4.5, §4.6, §5), after every physics step.

The release's sensors are trigger callbacks that fire after the physics step. Ours are the same:
pymunk sensor shapes with begin/separate callbacks for targets and walls (only what changed costs
anything), and one distance matrix per step for the robot-to-robot sensors (the collision sensor
and the comms sphere), which every robot needs every step anyway.
"""

from __future__ import annotations

import numpy as np
import pymunk

from ktbt_sim.kernel import jit

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
        (
            self.start, self.others, self.weights, self.count, keys, entered, newly, has
        ) = sense_robots(
            pos, self.cell, self.touch2, self.body2, self.radius2, self.comms, self.keys,
            self.entered, iteration,
        )  # fmt: skip
        if self.comms:
            self.entered, self.newly, self.has_neighbours, self.keys = entered, newly, has, keys

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
"""Groups up to this size look at every pair, which is faster there than sorting into cells."""

GRID_CELLS_PER_ROBOT = 64
"""The cell grid has at most this many cells a robot (plus a constant): a group spread far
beyond its arena (it cannot be, inside walls) gets wider cells, which find the same pairs."""


@jit
def find_pairs(
    pos: np.ndarray, cell: float, touch2: float, body2: float, radius2: float, comms: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The robot-to-robot sensors of every robot (§4.6, §5.3).

    Returns the collision sensor's pairs as ``start`` (n + 1 offsets) and ``other``, ``weight``
    (each robot's pairs in index order; a robot counts once when the spheres touch, twice when
    its body is inside the sphere), and the sorted keys ``i * n + j`` of the comms pairs.

    Each pair is looked at once (:func:`_near_pairs`). A small group looks at every pair; a
    large one only at the robots in the 3 x 3 cells around each (cells ``cell`` wide, so every
    pair in range is in neighbouring cells), sorted into a grid by a counting sort. Each pair
    is then written to both robots' lists, and each list (a handful) sorted."""
    n = pos.shape[0]
    cx = np.zeros(n, np.int64)
    cy = np.zeros(n, np.int64)
    width = 1
    height = 1
    x0 = np.int64(0)
    y0 = np.int64(0)
    if n > DENSE_UP_TO:
        size = cell
        while True:
            for i in range(n):
                cx[i] = np.int64(np.floor(pos[i, 0] / size))
                cy[i] = np.int64(np.floor(pos[i, 1] / size))
            x0, y0 = cx.min(), cy.min()
            width = cx.max() - x0 + 1
            height = cy.max() - y0 + 1
            if width * height <= GRID_CELLS_PER_ROBOT * n + 4096:
                break
            size *= 2.0
        cx -= x0
        cy -= y0
    # Counting sort into cells (column-major), robots in index order within a cell.
    first_in = np.zeros(width * height + 1, np.int64)
    for i in range(n):
        first_in[cx[i] * height + cy[i] + 1] += 1
    for c in range(width * height):
        first_in[c + 1] += first_in[c]
    order = np.empty(n, np.int64)
    fill = first_in[:-1].copy()
    for i in range(n):
        c = cx[i] * height + cy[i]
        order[fill[c]] = i
        fill[c] += 1
    # The robots' positions in cell order, so that each visit reads memory in order.
    near = np.empty((n, 2))
    for a in range(n):
        near[a, 0] = pos[order[a], 0]
        near[a, 1] = pos[order[a], 1]
    # Every pair in reach, looked at once; then each robot's share of them, written to both.
    pair_i, pair_j, pair_d2 = _near_pairs(
        near, cx, cy, height, width, first_in, order, touch2, radius2 if comms else -1.0
    )
    start = np.zeros(n + 1, np.int64)
    talk = np.zeros(n + 1, np.int64)
    for p in range(pair_i.shape[0]):
        i, j, d2 = pair_i[p], pair_j[p], pair_d2[p]
        if d2 < touch2:
            start[i + 1] += 1
            start[j + 1] += 1
        if comms and d2 <= radius2:
            talk[i + 1] += 1
            talk[j + 1] += 1
    for i in range(n):
        start[i + 1] += start[i]
        talk[i + 1] += talk[i]
    others = np.empty(start[n], np.int64)
    weights = np.empty(start[n], np.float64)
    heard = np.empty(talk[n], np.int64)
    at = start[:n].copy()
    talk_at = talk[:n].copy()
    for p in range(pair_i.shape[0]):
        i, j, d2 = pair_i[p], pair_j[p], pair_d2[p]
        if d2 < touch2:
            w = 2.0 if d2 < body2 else 1.0
            others[at[i]], weights[at[i]] = j, w
            at[i] += 1
            others[at[j]], weights[at[j]] = i, w
            at[j] += 1
        if comms and d2 <= radius2:
            heard[talk_at[i]] = j
            talk_at[i] += 1
            heard[talk_at[j]] = i
            talk_at[j] += 1
    # Each robot's pairs in index order: an insertion sort of each robot's handful, inline (a
    # call a robot would cost more than the sorting).
    for i in range(n):
        for a in range(start[i] + 1, start[i + 1]):
            j, w = others[a], weights[a]
            b = a - 1
            while b >= start[i] and others[b] > j:
                others[b + 1], weights[b + 1] = others[b], weights[b]
                b -= 1
            others[b + 1], weights[b + 1] = j, w
    keys = np.empty(talk[n], np.int64)
    for i in range(n):
        for a in range(talk[i] + 1, talk[i + 1]):
            j = heard[a]
            b = a - 1
            while b >= talk[i] and heard[b] > j:
                heard[b + 1] = heard[b]
                b -= 1
            heard[b + 1] = j
        for b in range(talk[i], talk[i + 1]):
            keys[b] = i * n + heard[b]
    return start, others, weights, keys


@jit
def _near_pairs(
    near: np.ndarray,
    cx: np.ndarray,
    cy: np.ndarray,
    height: int,
    width: int,
    first_in: np.ndarray,
    order: np.ndarray,
    touch2: float,
    radius2: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every pair of robots closer than the collision sensors' touch or within ``radius2`` (-1:
    no comms), each once, and its squared distance. The robots are visited in cell order
    (``near``: their positions in that order): robot ``a`` with the later robots of its own
    cell and of the cell above it, then with the three cells of the next column (two runs of
    the sorted robots)."""
    n = near.shape[0]
    capacity = 0
    for a in range(n):  # how many pairs the visit looks at: room for all of them
        i = order[a]
        c = cx[i] * height + cy[i]
        capacity += (first_in[c + 2] if cy[i] + 1 < height else first_in[c + 1]) - a - 1
        if cx[i] + 1 < width:
            lo = first_in[c + height - 1] if cy[i] > 0 else first_in[c + height]
            hi = first_in[c + height + 2] if cy[i] + 1 < height else first_in[c + height + 1]
            capacity += hi - lo
    pair_i = np.empty(capacity, np.int64)
    pair_j = np.empty(capacity, np.int64)
    pair_d2 = np.empty(capacity, np.float64)
    m = 0
    for a in range(n):
        i = order[a]
        gx, gy = cx[i], cy[i]
        c = gx * height + gy
        xi, yi = near[a, 0], near[a, 1]
        for run in range(2):
            if run == 0:
                lo = a + 1
                hi = first_in[c + 2] if gy + 1 < height else first_in[c + 1]
            elif gx + 1 < width:
                lo = first_in[c + height - 1] if gy > 0 else first_in[c + height]
                hi = first_in[c + height + 2] if gy + 1 < height else first_in[c + height + 1]
            else:
                break
            for b in range(lo, hi):
                dx = xi - near[b, 0]
                dy = yi - near[b, 1]
                d2 = dx * dx + dy * dy
                # Written always, kept if in reach: no branch to mispredict.
                pair_i[m] = i
                pair_j[m] = order[b]
                pair_d2[m] = d2
                m += (d2 < touch2) | (d2 <= radius2)
    return pair_i[:m], pair_j[:m], pair_d2[:m]


@jit
def sense_robots(
    pos: np.ndarray,
    cell: float,
    touch2: float,
    body2: float,
    radius2: float,
    comms: bool,
    old_keys: np.ndarray,
    old_entered: np.ndarray,
    iteration: int,
) -> tuple[
    np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray
]:
    """One update of ``Proximity`` in one call: :func:`find_pairs`, each robot's collision
    count, and with ``comms`` :func:`entries` (else the old keys and entry iterations)."""
    n = pos.shape[0]
    start, others, weights, keys = find_pairs(pos, cell, touch2, body2, radius2, comms)
    count = np.empty(n, np.int64)
    for i in range(n):
        count[i] = start[i + 1] - start[i]
    if comms:
        entered, newly, has = entries(old_keys, old_entered, keys, iteration, n)
    else:
        entered, newly, has = old_entered, np.zeros((0, 2), np.int64), np.zeros(n, np.bool_)
    return start, others, weights, count, keys, entered, newly, has


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
def after_physics(
    robots: np.ndarray,
    walls: np.ndarray,
    collision: np.ndarray,
    newly: np.ndarray,
    querying: np.ndarray,
    taught: np.ndarray,
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
) -> np.ndarray:
    """What the sensors give after the physics step, besides the trigger callbacks, in one
    call: each robot's collision flag (a robot or a wall in its collision sensor, §4.6), the
    zones (:func:`zones`), and of the pairs ``newly`` in comms range (§5.3) those whose first
    robot has an open query (querying, not yet taught): it sends its query to the second
    (§8.1)."""
    for i in range(collision.shape[0]):
        collision[i] = robots[i] > 0 or walls[i] > 0
    zones(
        pos, carrying, goal, centres, counted, collected, in_zone, target_colour, count_half,
        place_half, reach,
    )  # fmt: skip
    out = np.empty((newly.shape[0], 2), np.int64)
    k = 0
    for m in range(newly.shape[0]):
        i = newly[m, 0]
        if querying[i] and not taught[i]:
            out[k, 0] = i
            out[k, 1] = newly[m, 1]
            k += 1
    return out[:k]


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
