"""What a robot senses (``release-behaviour.md`` §4.5, §4.6, §5), after every physics step.

The release's sensors are trigger callbacks that fire after the physics step. Ours are the same:
pymunk sensor shapes with begin/separate callbacks for targets and walls (only what changed costs
anything), and one distance matrix per step for the robot-to-robot sensors (the collision sensor
and the comms sphere), which every robot needs every step anyway.
"""

from __future__ import annotations

import numpy as np
import pymunk

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


class WallSensor:
    """The collision sensor's walls (§4.6): the segments each robot's 75-radius sphere overlaps,
    each entering the avoidance sum through its centre."""

    def __init__(self, space: pymunk.Space, robots: int) -> None:
        self.contacts: list[dict[int, tuple[float, float]]] = [{} for _ in range(robots)]
        self.count = np.zeros(robots, dtype=np.int64)
        self.robot_of: dict[pymunk.Shape, int] = {}
        self.segment_of: dict[pymunk.Shape, tuple[int, float, float]] = {}
        self.changed: set[int] = set()
        space.on_collision(WALL_SENSOR, WALL, begin=self._enter, separate=self._exit)

    def _enter(self, arbiter: pymunk.Arbiter, _space: pymunk.Space, _data: object) -> None:
        bumper, wall = arbiter.shapes
        i = self.robot_of[bumper]
        k, x, y = self.segment_of[wall]
        self.contacts[i][k] = (x, y)
        self.count[i] = len(self.contacts[i])
        self.changed.add(i)

    def _exit(self, arbiter: pymunk.Arbiter, _space: pymunk.Space, _data: object) -> None:
        bumper, wall = arbiter.shapes
        i = self.robot_of.get(bumper, -1)
        segment = self.segment_of.get(wall)
        if i < 0 or segment is None:
            return
        self.contacts[i].pop(segment[0], None)
        self.count[i] = len(self.contacts[i])
        self.changed.add(i)

    def away(self, i: int, x: float, y: float) -> tuple[float, float]:
        """Σ(robot - segment centre) over the segments robot ``i``'s sensor overlaps."""
        vx = vy = 0.0
        for cx, cy in self.contacts[i].values():
            vx += x - cx
            vy += y - cy
        return vx, vy


class _Ranges:
    """The squared distances at which robots sense each other (§4.6, §5.3)."""

    def __init__(self, n: int, sensor: float, body: float, radius: float, comms: bool) -> None:
        self.n = n
        self.touch2 = (2 * sensor) ** 2
        self.body2 = (sensor + body) ** 2
        self.radius2 = radius**2
        self.comms = comms
        self.count = np.zeros(n, dtype=np.int64)
        """How many robots each robot's collision sensor holds (a robot counted once)."""
        self.has_neighbours = np.zeros(n, dtype=bool)
        self.newly: np.ndarray = np.zeros((0, 2), dtype=np.int64)
        """Pairs (i, j) that came into comms range in the last update."""


class Proximity(_Ranges):
    """Robot-to-robot sensing from one distance matrix a step (small groups).

    - Collision sensor (§4.6): another robot counts once when the two 75-radius spheres touch
      (centre distance below 150) and twice when its body is inside this robot's sphere (below
      75 + the body's radius): the release lists the other's sphere and its body separately.
    - Comms (§5.3): the neighbour list holds the robots whose body the comms sphere overlaps
      (centre distance at most ``radius``), in order of entry; ``entered[i, j]`` is the
      iteration at which ``j`` last came into range of ``i`` (simultaneous entries in index
      order).

    :class:`SparseProximity` gives the same answers from pairs in nearby cells, for large groups.
    """

    def __init__(self, n: int, sensor: float, body: float, radius: float, comms: bool) -> None:
        super().__init__(n, sensor, body, radius, comms)
        self.weight = np.zeros((n, n))
        self.in_range = np.zeros((n, n), dtype=bool)
        self.entered = np.zeros((n, n), dtype=np.int64)
        self._none = self.newly

    def update(self, pos: np.ndarray, iteration: int) -> None:
        x, y = pos[:, 0], pos[:, 1]
        dx = x[:, None] - x
        dy = y[:, None] - y
        d2 = dx * dx
        d2 += dy * dy
        np.fill_diagonal(d2, np.inf)
        near = d2 < self.touch2
        weight = near.astype(np.float64)
        weight += d2 < self.body2  # a body inside the sphere is inside the other sphere too
        self.weight = weight
        self.count = near.sum(axis=1)
        if self.comms:
            now = d2 <= self.radius2
            new = now > self.in_range
            if new.any():
                self.entered[new] = iteration
                self.newly = np.argwhere(new)
            else:
                self.newly = self._none
            self.in_range = now
            self.has_neighbours = now.any(axis=1)

    def away(self, pos: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Σ(self - other) over the robots each of ``rows`` senses, each counted once or twice."""
        w = self.weight[rows]
        out: np.ndarray = w.sum(axis=1)[:, None] * pos[rows] - w @ pos
        return out

    def neighbours(self, i: int) -> np.ndarray:
        """The robots in robot ``i``'s comms range."""
        return np.flatnonzero(self.in_range[i])

    def requesters(
        self, open_: np.ndarray, knows: np.ndarray | None = None, asked: np.ndarray | None = None
    ) -> np.ndarray:
        """For each robot, its earliest-entered neighbour with an open query (-1: none); with
        ``knows`` (n, 4) and ``asked`` (n,), only one whose colour it knows."""
        candidates = self.in_range & open_[None, :]
        if knows is not None and asked is not None:
            candidates &= knows[:, np.where(open_, asked - 1, 0)]
        big = np.iinfo(np.int64).max
        keyed = np.where(candidates, self.entered, big)
        pick = keyed.argmin(axis=1)
        out: np.ndarray = np.where(candidates.any(axis=1), pick, -1)
        return out


class SparseProximity(_Ranges):
    """:class:`Proximity` for large groups: pairs come only from the 3 x 3 cells around each
    robot (cells as wide as the longest sensing distance), so a step costs in proportion to
    the robots and their neighbours, not to the square of the group."""

    def __init__(self, n: int, sensor: float, body: float, radius: float, comms: bool) -> None:
        super().__init__(n, sensor, body, radius, comms)
        self.cell = max(2 * sensor, radius if comms else 0.0)
        empty = np.zeros(0, dtype=np.int64)
        self._near: tuple[np.ndarray, np.ndarray, np.ndarray] = (empty, empty, np.zeros(0))
        self._keys = empty
        """Sorted ``i * n + j`` of every ordered pair in comms range."""
        self._entered = empty

    def _pairs(self, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every ordered pair of robots in the same or adjacent cells, with its squared
        distance. Cells are keyed column by column, so the three cells of a neighbouring
        column are one run of the sorted keys: three ranges a robot."""
        n, span = self.n, 1 << 21
        cells = np.floor(pos / self.cell).astype(np.int64) + span // 2
        keys = cells[:, 0] * span + cells[:, 1]
        order = np.argsort(keys, kind="stable")
        ordered = keys[order]
        robots = np.arange(n)
        found_i, found_j = [], []
        for dx in (-1, 0, 1):
            column = keys + dx * span
            lo = np.searchsorted(ordered, column - 1, side="left")
            hi = np.searchsorted(ordered, column + 1, side="right")
            many = hi - lo
            total = int(many.sum())
            if not total:
                continue
            starts = np.repeat(lo - (np.cumsum(many) - many), many)
            found_i.append(np.repeat(robots, many))
            found_j.append(order[starts + np.arange(total)])
        i, j = np.concatenate(found_i), np.concatenate(found_j)
        other = i != j
        i, j = i[other], j[other]
        d = pos[i] - pos[j]
        return i, j, np.einsum("ij,ij->i", d, d)

    def update(self, pos: np.ndarray, iteration: int) -> None:
        i, j, d2 = self._pairs(pos)
        near = d2 < self.touch2
        ci, cj = i[near], j[near]
        self._near = (ci, cj, 1.0 + (d2[near] < self.body2))
        self.count = np.bincount(ci, minlength=self.n)
        if not self.comms:
            return
        inside = d2 <= self.radius2
        keys = np.sort(i[inside] * self.n + j[inside])
        old, entered = self._keys, self._entered
        at = np.minimum(np.searchsorted(old, keys), max(len(old) - 1, 0))
        kept = (old[at] == keys) if len(old) else np.zeros(len(keys), dtype=bool)
        self._entered = np.where(kept, entered[at] if len(old) else 0, iteration)
        self._keys = keys
        fresh = keys[~kept]
        self.newly = np.stack((fresh // self.n, fresh % self.n), axis=1)
        self.has_neighbours = np.bincount(keys // self.n, minlength=self.n) > 0

    def away(self, pos: np.ndarray, rows: np.ndarray) -> np.ndarray:
        ci, cj, w = self._near
        mask = np.isin(ci, rows)
        total = np.zeros((self.n, 2))
        np.add.at(total, ci[mask], w[mask, None] * (pos[ci[mask]] - pos[cj[mask]]))
        out: np.ndarray = total[rows]
        return out

    def neighbours(self, i: int) -> np.ndarray:
        lo, hi = np.searchsorted(self._keys, (i * self.n, (i + 1) * self.n))
        out: np.ndarray = self._keys[lo:hi] % self.n
        return out

    def requesters(
        self, open_: np.ndarray, knows: np.ndarray | None = None, asked: np.ndarray | None = None
    ) -> np.ndarray:
        keys, n = self._keys, self.n
        i, j = keys // n, keys % n
        mask = open_[j]
        if knows is not None and asked is not None:
            mask &= knows[i, np.where(open_[j], asked[j] - 1, 0)]
        i, j, entered = i[mask], j[mask], self._entered[mask]
        out = np.full(n, -1, dtype=np.int64)
        if len(i):
            order = np.lexsort((j, entered, i))
            firsts = np.unique(i[order], return_index=True)[1]
            out[i[order][firsts]] = j[order][firsts]
        return out


DENSE_UP_TO = 200
"""Groups up to this size use the distance matrix, which is faster there."""


def proximity(
    n: int, sensor: float, body: float, radius: float, comms: bool
) -> Proximity | SparseProximity:
    kind = Proximity if n <= DENSE_UP_TO else SparseProximity
    return kind(n, sensor, body, radius, comms)


def zone_events(
    pos: np.ndarray,
    centres: np.ndarray,
    goal: np.ndarray,
    count_half: float,
    place_half: float,
    place_reach: float,
) -> tuple[np.ndarray, np.ndarray]:
    """For carriers at ``pos`` heading to zone ``goal`` (1..4): whether the carried cube is in
    the zone's outer box (it counts there, §4.5) and whether the zone detector overlaps the
    inner square (the robot may place)."""
    c = centres[goal - 1]
    counted = np.all(np.abs(pos - c) <= count_half, axis=1)
    d = np.maximum(np.abs(pos - c) - place_half, 0.0)
    inside = np.hypot(d[:, 0], d[:, 1]) <= place_reach
    return counted, inside
