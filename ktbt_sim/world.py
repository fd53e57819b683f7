"""The search-and-rescue world: a pymunk arena with walls, zones, targets, obstacles and robots,
each robot a ``ktbt_proto`` agent on an in-memory network limited by communication range.

Speed comes from doing per robot only what changed. Sensors are pymunk sensor shapes whose
begin/separate callbacks keep counts up to date, so nothing is searched per step; flags are
packed into one integer per robot with numpy; a robot's agent is ticked only when its flags
changed, when a message reached it, or at the tick its agent names (``Agent.next_due``: a wait
or cool-down ending, a query to repeat), because the behaviours keep no state, a tick with
unchanged inputs would change nothing, and every timer reads the agent's clock. Motion is
computed for all robots at once and written to pymunk in one batch call.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable

import numpy as np
import pymunk
import pymunk.batch

from ktbt_proto import Condition
from ktbt_proto.agent import COOLING_DOWN, QUERYING, TEACHING, Agent
from ktbt_proto.messages import Query
from ktbt_proto.transport.memory import MemoryNetwork

from . import robot as rb
from .metrics import set_name
from .obstacles import layout
from .scenario import COLOURS, Mode, Scenario

# Collision types and filter categories.
BODY, WALL, TARGET, TARGET_SENSOR, COLLISION_SENSOR = 1, 2, 4, 8, 16
TARGET_RADIUS = 10.0
"""Targets are 20-unit cubes in the release; here discs of that width."""

SET_BITS = np.array([1, 2, 4, 8])

ESCAPE_S = 2.0
"""After a collision, the random walk first leads this many seconds away from it."""

ZONE_SIGNS = ((-1, 1), (1, 1), (-1, -1), (1, -1))
"""Zone corner of colour 1..4: red top left, green top right, yellow bottom left, blue bottom
right."""


RECORD_COLUMNS = (
    "iteration",
    *(f"collected_{c}" for c in COLOURS),
    "collected",
    "querying",
    "teaching",
    "walking",
    "carrying",
    "avoiding",
    "cooling",
    "queries",
    "responses",
    "lost",
    *(f"knows_{k}" for k in range(5)),
    *(f"knows_{c}" for c in COLOURS),
    *(set_name(b) for b in range(16)),
)
"""The per-step record, every ``record_every`` iterations. Per colour: targets collected and
robots that know it. Now: robots querying, teaching, walking at random, carrying, avoiding a
collision, cooling down. Cumulative: queries sent, responses sent, queries lost (a learner's wait
ran out). ``knows_k``: robots that know exactly k colours; ``set_RG``: robots that know exactly
red and green (``set_none``: nothing), one column per set of colours."""


def _filter(category: int, mask: int) -> pymunk.ShapeFilter:
    return pymunk.ShapeFilter(categories=category, mask=mask)


class World:
    """One trial of a scenario. ``seed`` (default: the scenario's) fixes everything random:
    placements, random walks and who meets whom, so the same seed replays bit for bit."""

    def __init__(
        self,
        scenario: Scenario,
        seed: int | np.random.SeedSequence | None = None,
        *,
        lazy: bool = True,
    ):
        self.scenario = scenario
        self.lazy = lazy
        """Tick only the agents whose inputs changed, that have mail or whose agent is due;
        ``False`` ticks every agent every step (slow; the tests use it to show that skipping
        changes nothing)."""
        root = np.random.SeedSequence(scenario.seed) if seed is None else seed
        self.rng = np.random.default_rng(
            root if isinstance(root, np.random.SeedSequence) else np.random.SeedSequence(root)
        )
        self.iteration = 0
        self.kt_bt = scenario.mode is Mode.KT_BT
        arena, spec, timing = scenario.arena, scenario.robot, scenario.timing
        r = scenario.robots
        self.kinds = rb.kinds(
            zip("IMRGYB", (r.ignorant, r.multi, r.red, r.green, r.yellow, r.blue), strict=True)
        )
        n = self.n = len(self.kinds)
        self.radius = spec.body / 2
        self.dt = timing.dt
        self.space = pymunk.Space()
        self.obstacles = layout(arena) if arena.obstacles else []
        self._build_walls()

        # Targets: colour 1..4, position, still lying (not picked).
        counts = scenario.targets
        self.target_colour = np.repeat(
            np.arange(1, 5), (counts.red, counts.green, counts.yellow, counts.blue)
        ).astype(np.int64)
        self.target_pos = self._free_points(len(self.target_colour), TARGET_RADIUS + 5)
        self.target_free = np.ones(len(self.target_colour), dtype=bool)
        self._target_shapes: list[pymunk.Shape] = []
        self._shape_target: dict[pymunk.Shape, int] = {}
        for t, (x, y) in enumerate(self.target_pos):
            shape = pymunk.Circle(self.space.static_body, TARGET_RADIUS, (float(x), float(y)))
            shape.sensor = True
            shape.collision_type = TARGET
            shape.filter = _filter(TARGET, TARGET_SENSOR)
            self._target_shapes.append(shape)
            self._shape_target[shape] = t
            self.space.add(shape)

        # Robots: state arrays, bodies and sensors.
        self.pos = self._free_points(n, self.radius + 5)
        self.heading = self.rng.uniform(-math.pi, math.pi, n)
        self.mode = np.full(n, rb.WALK, dtype=np.int64)
        self.walk_goal = np.zeros((n, 2))
        self.walk_until = np.zeros(n, dtype=np.int64)
        self.goal = np.zeros(n, dtype=np.int64)  # zone colour assigned, 0: none
        self._aim = self.walk_goal.copy()
        """Where each robot heads: its zone's centre once assigned, else its walk goal."""
        self._has_goal = np.zeros(n, dtype=bool)
        self._moving = np.ones(n, dtype=bool)
        self._avoiding: set[int] = set()
        self._next_walk = 0
        self.carrying = np.full(n, -1, dtype=np.int64)
        self.cooling = np.zeros(n, dtype=bool)
        # What the control tree reads, kept in Python lists: they are read one robot at a time.
        self._collisions = [0] * n
        self._seen = [[0, 0, 0, 0] for _ in range(n)]
        self._waiting = [False] * n
        self._cooling = [False] * n
        self._in_zone = np.zeros(n, dtype=bool)
        self._carriers: set[int] = set()
        self._touched: set[int] = set(range(n))
        """Robots whose control-tree inputs may have changed since their last tick."""
        self.querying = np.zeros(n, dtype=bool)
        self.teaching = np.zeros(n, dtype=bool)
        self.known = np.zeros((n, 4), dtype=bool)
        self.collected = np.zeros(4, dtype=np.int64)
        self.delivered_to = np.zeros(len(self.target_colour), dtype=np.int64)
        self.picked = 0
        self._visible: list[set[int]] = [set() for _ in range(n)]
        self._watchers: list[set[int]] = [set() for _ in self.target_colour]
        """Who sees each target: pymunk does not always report a separation when a sensor's
        partner is removed, so a pick clears the target from every watcher itself."""
        self._contacts: list[dict[pymunk.Shape, int]] = [{} for _ in range(n)]
        self._shape_robot: dict[pymunk.Shape, int] = {}
        self.bodies: list[pymunk.Body] = []
        for i in range(n):
            self._add_robot(i)
        self._handlers()
        self._pos_list: list[list[float]] = []
        self._velocities = np.zeros(2 * (n + 1))  # the space's static body comes last
        self._out = pymunk.batch.Buffer()
        # pymunk writes positions straight into this array. It reallocates an array that is
        # about to fill, so leave room; the world never adds bodies after this point.
        self._positions = np.zeros(2 * (n + 1) + 4)
        self._positions[: 2 * n] = self.pos.ravel()
        self._out.set_float_buf(self._positions)  # pymunk writes positions straight into it
        self.pos = self._positions[: 2 * n].reshape(n, 2)
        self._in = pymunk.batch.Buffer()
        self._in.set_float_buf(self._velocities)

        # Agents on a network limited by communication range.
        self.network = MemoryNetwork(
            in_range=self._in_range, audience=self._audience, on_deliver=self._delivered
        )
        self.names = [f"r{i}" for i in range(n)]
        self._index = {name: i for i, name in enumerate(self.names)}
        self.registry = rb.registry(self)
        self.agents: list[Agent] = []
        self._taught: list[str] = [""] * n
        self._learned = [0] * n
        for i, kind in enumerate(self.kinds):
            agent = Agent(
                self.names[i],
                rb.control_tree(rb.KINDS[kind]),
                self.registry,
                self.network.join(self.names[i]),
                wait_ticks=timing.wait_ticks,
                cooldown_ticks=timing.cooldown_ticks,
                teach_if=self._teacher(i),
                repeat_every=timing.repeat_every,
            )
            agent.blackboard[rb.INDEX] = i
            self.agents.append(agent)
            for colour in rb.KINDS[kind]:
                self.known[i, colour - 1] = True
        self._mail: set[int] = set()
        self._wake: dict[int, int] = {}
        self._wakeups: list[tuple[int, int]] = []
        self._due: list[int] = []
        self._current = n
        self._signature = [-1] * n
        self._keys = [rb.sequence_of(c) for c in range(1, 5)]
        self._zone_centre = np.array(
            [(sx * arena.zone_centre, sy * arena.zone_centre) for sx, sy in ZONE_SIGNS]
        )
        self._zone_half = arena.zone_inner / 2 - self.radius
        self._turn = math.radians(spec.max_turn_deg) * timing.dt
        self._aligned = self._turn + math.radians(spec.heading_tolerance_deg)

    # -- construction ---------------------------------------------------------------------

    def _build_walls(self) -> None:
        h = self.scenario.arena.half_size
        corners = [(-h, -h), (h, -h), (h, h), (-h, h)]
        static = self.space.static_body
        shapes: list[pymunk.Shape] = []
        for a, b in zip(corners, corners[1:] + corners[:1], strict=True):
            shapes.append(pymunk.Segment(static, a, b, 5.0))
        boxes = [
            (min(a[0], b[0]), min(a[1], b[1]), max(a[0], b[0]), max(a[1], b[1]))
            for a, b in zip(corners, corners[1:] + corners[:1], strict=True)
        ]
        for x0, y0, x1, y1 in self.obstacles:
            shapes.append(pymunk.Poly(static, [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]))
            boxes.append((x0, y0, x1, y1))
        self._box_of = dict(zip(shapes, boxes, strict=True))
        """Each wall and obstacle as a box, for the nearest point of a collision."""
        for shape in shapes:
            shape.collision_type = WALL
            shape.filter = _filter(WALL, BODY | COLLISION_SENSOR)
            shape.friction = 0.0
        self.space.add(*shapes)

    def _free_points(self, count: int, margin: float) -> np.ndarray:
        """``count`` points uniform in the spawn area, none inside an obstacle."""
        half = self.scenario.arena.spawn_half
        points = self.rng.uniform(-half, half, (count, 2))
        if self.obstacles:
            boxes = np.array(self.obstacles)
            for _ in range(1000):
                x, y = points[:, 0:1], points[:, 1:2]
                bad = (
                    (x > boxes[:, 0] - margin)
                    & (x < boxes[:, 2] + margin)
                    & (y > boxes[:, 1] - margin)
                    & (y < boxes[:, 3] + margin)
                ).any(axis=1)
                if not bad.any():
                    break
                points[bad] = self.rng.uniform(-half, half, (int(bad.sum()), 2))
        return points

    def _add_robot(self, i: int) -> None:
        spec = self.scenario.robot
        body = pymunk.Body(1.0, math.inf)
        body.position = (float(self.pos[i, 0]), float(self.pos[i, 1]))
        hull = pymunk.Circle(body, self.radius)
        hull.collision_type = BODY
        hull.filter = _filter(BODY, BODY | WALL | COLLISION_SENSOR)
        hull.friction = 0.0
        eyes = pymunk.Circle(body, spec.target_sensor)
        eyes.sensor = True
        eyes.collision_type = TARGET_SENSOR
        eyes.filter = _filter(TARGET_SENSOR, TARGET)
        bumper = pymunk.Circle(body, spec.collision_sensor)
        bumper.sensor = True
        bumper.collision_type = COLLISION_SENSOR
        bumper.filter = _filter(COLLISION_SENSOR, BODY | WALL)
        for shape in (hull, eyes, bumper):
            self._shape_robot[shape] = i
        self.space.add(body, hull, eyes, bumper)
        self.bodies.append(body)

    def _handlers(self) -> None:
        robot_of, target_of = self._shape_robot, self._shape_target
        seen, visible, colour = self._seen, self._visible, self.target_colour.tolist()
        touched = self._touched
        watchers = self._watchers
        collisions, contacts = self._collisions, self._contacts

        def saw(arbiter: pymunk.Arbiter, _space: pymunk.Space, _data: object) -> None:
            eyes, target = arbiter.shapes
            i, t = robot_of[eyes], target_of[target]
            if t not in visible[i]:
                visible[i].add(t)
                watchers[t].add(i)
                seen[i][colour[t] - 1] += 1
                touched.add(i)

        def lost(arbiter: pymunk.Arbiter, _space: pymunk.Space, _data: object) -> None:
            eyes, target = arbiter.shapes
            i, t = robot_of.get(eyes, -1), target_of.get(target, -1)
            if i >= 0 and t in visible[i]:
                visible[i].discard(t)
                watchers[t].discard(i)
                seen[i][colour[t] - 1] -= 1
                touched.add(i)

        def touch(arbiter: pymunk.Arbiter, _space: pymunk.Space, _data: object) -> None:
            bumper, other = arbiter.shapes
            i = robot_of[bumper]
            contacts[i][other] = contacts[i].get(other, 0) + 1
            collisions[i] += 1
            touched.add(i)

        def untouch(arbiter: pymunk.Arbiter, _space: pymunk.Space, _data: object) -> None:
            bumper, other = arbiter.shapes
            i = robot_of.get(bumper, -1)
            if i < 0 or other not in contacts[i]:  # the space is being torn down
                return
            left = contacts[i][other] - 1
            if left > 0:
                contacts[i][other] = left
            else:
                contacts[i].pop(other, None)
            collisions[i] -= 1
            touched.add(i)

        self.space.on_collision(TARGET_SENSOR, TARGET, begin=saw, separate=lost)
        self.space.on_collision(COLLISION_SENSOR, BODY, begin=touch, separate=untouch)
        self.space.on_collision(COLLISION_SENSOR, WALL, begin=touch, separate=untouch)

    # -- communication ----------------------------------------------------------------------

    def _in_range(self, sender: str, receiver: str) -> bool:
        a, b = self.pos[self._index[sender]], self.pos[self._index[receiver]]
        return bool((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 <= self.scenario.comm_range**2)

    def _audience(self, sender: str) -> list[str]:
        i = self._index[sender]
        d2 = ((self.pos - self.pos[i]) ** 2).sum(axis=1)
        near = np.flatnonzero(d2 <= self.scenario.comm_range**2)
        return [self.names[j] for j in near if j != i]

    def _delivered(self, receiver: str) -> None:
        j = self._index[receiver]
        self._mail.add(j)
        if j > self._current:
            heapq.heappush(self._due, j)

    def _teacher(self, i: int) -> Callable[[Query], bool]:
        """The release's teaching rule for robot ``i``: it teaches only when not carrying a
        target, and only a learner nobody is teaching yet (the knowledge check is the agent's)."""
        taught, index, carrying = self._taught, self._index, self.carrying

        def teach_if(query: Query) -> bool:
            learner = index.get(query.sender)
            if learner is None or carrying[i] >= 0 or taught[learner] == query.id:
                return False
            taught[learner] = query.id
            return True

        return teach_if

    # -- the actuators' side of actions -----------------------------------------------------

    def pick(self, i: int, colour: int | None) -> bool:
        """Pick up the nearest visible target (of ``colour``, if given); False if none."""
        if self.carrying[i] >= 0:
            return False
        best, best_d = -1, math.inf
        x, y = self.pos[i]
        for t in self._visible[i]:
            if colour is not None and self.target_colour[t] != int(colour):
                continue
            tx, ty = self.target_pos[t]
            d = (tx - x) ** 2 + (ty - y) ** 2
            if d < best_d or (d == best_d and t < best):
                best, best_d = t, d
        if best < 0:
            return False
        self.carrying[i] = best
        self.target_free[best] = False
        self.picked += 1
        self.space.remove(self._target_shapes[best])
        k = int(self.target_colour[best]) - 1
        for j in self._watchers[best]:
            self._visible[j].discard(best)
            self._seen[j][k] -= 1
        self._touched |= self._watchers[best]
        self._touched.add(i)
        self._watchers[best].clear()
        self._carriers.add(i)
        return True

    def place(self, i: int) -> bool:
        """Deliver the carried target: only inside the zone of the target's own colour."""
        t = int(self.carrying[i])
        if t < 0 or not self._inside_zone(i, int(self.target_colour[t])):
            return False
        self.carrying[i] = -1
        self.set_goal(i, 0)
        self._carriers.discard(i)
        self._in_zone[i] = False
        self._touched.add(i)
        self.collected[self.target_colour[t] - 1] += 1
        self.delivered_to[t] += 1
        return True

    def set_mode(self, i: int, mode: int) -> None:
        self.mode[i] = mode
        self._moving[i] = mode != rb.STOP
        if mode == rb.AVOID:
            self._avoiding.add(i)
        else:
            self._avoiding.discard(i)
            if mode == rb.WALK:
                self._next_walk = min(self._next_walk, int(self.walk_until[i]))

    def set_goal(self, i: int, colour: int) -> None:
        """Assign zone ``colour`` (0: none, back to walking at random)."""
        self.goal[i] = colour
        self._has_goal[i] = colour > 0
        self._aim[i] = self._zone_centre[colour - 1] if colour else self.walk_goal[i]

    def _inside_zone(self, i: int, colour: int) -> bool:
        cx, cy = self._zone_centre[colour - 1]
        x, y = self.pos[i]
        return bool(abs(x - cx) <= self._zone_half and abs(y - cy) <= self._zone_half)

    # -- one step -------------------------------------------------------------------------

    def signature(self, i: int) -> int:
        """Robot ``i``'s control-tree inputs packed in one integer: collision, waiting,
        carrying, in its zone, cooling down, then one bit per colour in view (none while
        cooling down: sensing is off)."""
        seen = 0
        if not self._cooling[i]:
            s = self._seen[i]
            seen = (s[0] > 0) | (s[1] > 0) << 1 | (s[2] > 0) << 2 | (s[3] > 0) << 3
        return (
            (self._collisions[i] > 0)
            | self._waiting[i] << 1
            | (i in self._carriers) << 2
            | bool(self._in_zone[i]) << 3
            | self._cooling[i] << 4
            | seen << 5
        )

    def step(self) -> None:
        """Sense, tick the agents that need it, move, and advance the physics by ``dt``."""
        self.iteration += 1
        self.network.step()
        if self._carriers:
            # Only carriers with a zone assigned can be in "their" zone.
            near = np.abs(self.pos - self._aim) <= self._zone_half
            inside = near[:, 0] & near[:, 1] & self._has_goal
            for i in np.flatnonzero(inside != self._in_zone).tolist():
                self._in_zone[i] = inside[i]
                self._touched.add(i)
        due = set(self._touched)  # the sensor callbacks hold this very set: keep it
        self._touched.clear()
        now = self.iteration
        woken = self._mail
        self._mail = set()
        wakeups, wake = self._wakeups, self._wake
        while wakeups and wakeups[0][0] <= now:
            when, i = heapq.heappop(wakeups)
            if wake.get(i) == when:
                del wake[i]
                woken.add(i)
        due |= woken
        if not self.lazy:
            due = set(range(self.n))
        last = self._signature
        # Robots tick in index order. Mail sent in this step to a robot further on makes it
        # due in this step too, exactly as if every robot were ticked (``_mail`` pushes it).
        self._due = heap = sorted(due)
        previous = -1
        while heap:
            i = heapq.heappop(heap)
            if i == previous:
                continue
            self._current = previous = i
            signature = self.signature(i)
            control = signature != last[i] or not self.lazy
            if control or i in woken or i in self._mail:
                last[i] = signature
                self._tick(i, signature, control)
        self._current = self.n
        self._move()
        self.space.step(self.dt)
        self._read_positions()

    def _tick(self, i: int, signature: int, control: bool) -> None:
        agent = self.agents[i]
        bb = agent.blackboard
        if control:
            bb[rb.COLLISION] = signature & 1
            bb[rb.WAIT] = signature >> 1 & 1
            bb[rb.CARRYING] = signature >> 2 & 1
            bb[rb.IN_ZONE] = signature >> 3 & 1
            bb[rb.SEEN] = seen = signature >> 5
            if self.kt_bt:
                agent.encounter(self._unknown(i, seen, signature))
        agent.tick(control=control, now=self.iteration)
        cooling = bool(bb.get(COOLING_DOWN))
        querying = bool(bb.get(QUERYING))
        teaching = bool(bb.get(TEACHING))
        waiting = querying or teaching
        self.querying[i], self.teaching[i] = querying, teaching
        if cooling != self._cooling[i] or waiting != self._waiting[i]:  # the signature's inputs
            self._cooling[i] = self.cooling[i] = cooling
            self._waiting[i] = waiting
            self._touched.add(i)
        self._mail.discard(i)
        due = agent.next_due()
        if due is None:
            self._wake.pop(i, None)
        elif self._wake.get(i) != due:
            self._wake[i] = due
            heapq.heappush(self._wakeups, (due, i))
        learned = len(agent.metrics.learned)
        if learned != self._learned[i]:
            self._learned[i] = learned
            for c, key in enumerate(self._keys):
                self.known[i, c] = key in agent.knowledge

    def _unknown(self, i: int, seen: int, signature: int) -> tuple[Condition, ...] | None:
        """The sequence robot ``i`` faces and does not know: a target colour in view, while it
        carries nothing (a robot busy carrying does not attend to other targets)."""
        if signature & 4:
            return None
        for c in range(4):
            if seen >> c & 1 and not self.known[i, c]:
                return rb.sequence(c + 1)
        return None

    def _move(self) -> None:
        """Turn every robot towards where it heads, at most ``max_turn`` a second, and drive
        at full speed once aligned (the release's rule); all robots in one go."""
        spec, n = self.scenario.robot, self.n
        if self.iteration >= self._next_walk:
            self._new_walk_goals()
        to = self._aim - self.pos
        want = np.arctan2(to[:, 1], to[:, 0])
        if self._avoiding:
            self._pos_list = self.pos.tolist()
            escape = self.scenario.robot.max_speed * ESCAPE_S
            for i in self._avoiding:
                away = want[i] = self._away(i)
                # A collision ends the current random-walk leg; the next one leads away.
                x, y = self._pos_list[i]
                self.walk_goal[i] = (x + escape * math.cos(away), y + escape * math.sin(away))
                self.walk_until[i] = self.iteration + int(ESCAPE_S / self.dt)
                if not self._has_goal[i]:
                    self._aim[i] = self.walk_goal[i]
        error = want - self.heading
        error += math.pi
        error %= 2 * math.pi
        error -= math.pi
        turn = self._turn
        self.heading += np.minimum(np.maximum(error, -turn), turn)
        go = np.abs(error) <= self._aligned
        go &= self._moving
        speed = go * spec.max_speed
        v = self._velocities[: 2 * n].reshape(n, 2)
        np.multiply(speed, np.cos(self.heading), out=v[:, 0])
        np.multiply(speed, np.sin(self.heading), out=v[:, 1])
        pymunk.batch.set_space_bodies(self.space, pymunk.batch.BodyFields.VELOCITY, self._in)

    def _new_walk_goals(self) -> None:
        """A new random goal in the search area for every walker whose leg is over."""
        due = self.walk_until <= self.iteration
        due &= self.mode == rb.WALK
        if due.any():
            k = int(due.sum())
            half = self.scenario.arena.spawn_half
            self.walk_goal[due] = self.rng.uniform(-half, half, (k, 2))
            timing = self.scenario.timing
            span = self.rng.uniform(timing.walk_goal_min_s, timing.walk_goal_max_s, k) / self.dt
            self.walk_until[due] = self.iteration + span.astype(np.int64)
            free = due & ~self._has_goal
            self._aim[free] = self.walk_goal[free]
        walking = self.walk_until[self.mode == rb.WALK]
        self._next_walk = int(walking.min()) if len(walking) else self.iteration + 1

    def _away(self, i: int) -> float:
        """Heading away from V_c, the sum of the vectors to every object in collision range."""
        pos = self._pos_list
        x, y = pos[i]
        vx = vy = 0.0
        robot_of, box_of = self._shape_robot, self._box_of
        for shape in self._contacts[i]:
            j = robot_of.get(shape)
            if j is not None:
                cx, cy = pos[j]
            else:
                x0, y0, x1, y1 = box_of[shape]
                cx = x0 if x < x0 else x1 if x > x1 else x
                cy = y0 if y < y0 else y1 if y > y1 else y
            vx += cx - x
            vy += cy - y
        if vx == 0.0 and vy == 0.0:
            return float(self.heading[i])
        return math.atan2(-vy, -vx)

    def _read_positions(self) -> None:
        out = self._out
        out.clear()  # refills ``self._positions``, of which ``self.pos`` is a view
        pymunk.batch.get_space_bodies(self.space, pymunk.batch.BodyFields.POSITION, out)

    # -- what an experiment reads -----------------------------------------------------------

    def run(self, iterations: int) -> None:
        for _ in range(iterations):
            self.step()

    def record(self) -> dict[str, int]:
        """One row of the per-step record (see ``RECORD_COLUMNS``)."""
        m = [a.metrics for a in self.agents]
        levels = np.bincount(self.known.sum(axis=1), minlength=5)
        known = self.known.sum(axis=0)
        mode, carrying = self.mode, self.carrying >= 0
        row = {"iteration": self.iteration}
        for c, name in enumerate(COLOURS):
            row[f"collected_{name}"] = int(self.collected[c])
        row["collected"] = int(self.collected.sum())
        row["querying"] = int(self.querying.sum())
        row["teaching"] = int(self.teaching.sum())
        row["walking"] = int(((mode == rb.WALK) & ~carrying).sum())
        row["carrying"] = int(carrying.sum())
        row["avoiding"] = int((mode == rb.AVOID).sum())
        row["cooling"] = int(self.cooling.sum())
        row["queries"] = sum(x.queries_sent for x in m)
        row["responses"] = sum(x.responses_sent for x in m)
        row["lost"] = sum(x.queries_lost for x in m)
        for level in range(5):
            row[f"knows_{level}"] = int(levels[level])
        for c, name in enumerate(COLOURS):
            row[f"knows_{name}"] = int(known[c])
        sets = np.bincount(self.known @ SET_BITS, minlength=16)
        for bits in range(16):
            row[set_name(bits)] = int(sets[bits])
        return row
