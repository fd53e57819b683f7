"""The search-and-rescue world: the authors' release, mechanism by mechanism, on pymunk.

One :class:`World` is one trial. Its iteration follows ``spec/simulator.md`` §8.5: every
robot's behaviour tree is ticked, the actuators turn the resultant velocities into motion, the
comms scan chooses each teacher's requester, robots ask, teachers answer, physics advances 0.02 s,
and the sensors fire. Each mechanism lives in its own module: ``geometry`` (§2), ``motion`` (§4),
``sensing`` (§4.5, §4.6, §5), ``timers`` (§7), ``teaching`` (§8), ``records`` (§10).

Every robot is a ``ktbt_proto`` agent: its control tree is a live stringBT tree, and knowledge
moves only as real query and response messages on an in-memory network, merged by the learner's
agent after the library's checks. Speed comes from doing per robot only what changed: a robot's
tree is ticked only when one of its inputs changed (its behaviours keep no state, so a tick with
the same inputs would choose the same thing), and everything that runs every iteration runs for
all robots at once with numpy.
"""

from __future__ import annotations

import math

import numpy as np
import pymunk
import pymunk.batch

from ktbt_proto.exchange.application import ApplicationTimedAgent
from ktbt_proto.exchange.memory_policy import MemoryPolicy, WhenFull
from ktbt_proto.exchange.overhearing import Overhear, Overhearing
from ktbt_proto.transport.memory import MemoryNetwork
from ktbt_sim import geometry, motion, records, teaching
from ktbt_sim import robot as rb
from ktbt_sim.kernel import generator_pointers
from ktbt_sim.scenario import Mode, Scenario
from ktbt_sim.sensing import (
    BODY,
    TARGET,
    TARGET_SENSOR,
    WALL,
    WALL_SENSOR,
    Proximity,
    TargetSensor,
    WallSensor,
    after_physics,
    enable,
)
from ktbt_sim.state import forget_learned
from ktbt_sim.timers import Timers

RECORD_COLUMNS = records.COLUMNS


def _filter(category: int, mask: int) -> pymunk.ShapeFilter:
    return pymunk.ShapeFilter(categories=category, mask=mask)


class World:
    """One trial of a scenario. ``seed`` (default: the scenario's) fixes everything random:
    placements, random walks, jitter and who meets whom, so the same seed replays bit for bit."""

    def __init__(
        self,
        scenario: Scenario,
        seed: int | np.random.SeedSequence | None = None,
        *,
        lazy: bool = True,
    ):
        self.scenario = scenario
        self.lazy = lazy
        """Tick only the robots whose tree inputs changed; ``False`` ticks every robot every
        iteration (slow; the tests use it to show that skipping changes nothing)."""
        root = np.random.SeedSequence(scenario.seed) if seed is None else seed
        self._rng = np.random.default_rng(
            root if isinstance(root, np.random.SeedSequence) else np.random.SeedSequence(root)
        )
        self._rng_pointers = generator_pointers(self._rng)
        self.iteration = 0
        self.kt_bt = scenario.mode is not Mode.NO_TRANSFER
        """Whether robots ask and teach: every mode but the release's NL (§9.1)."""
        spec, timing = scenario.robot, scenario.timing
        self.dt = timing.dt
        r = scenario.robots
        self.kinds = rb.kinds(
            zip("IMRGYB", (r.ignorant, r.multi, r.red, r.green, r.yellow, r.blue), strict=True)
        )
        n = self.n = len(self.kinds)
        self.radius = spec.contact_radius
        self.space = pymunk.Space()
        scale = self.scale = scenario.arena.scale
        self.walls = geometry.segments(scenario.arena.obstacles, scale)
        first = len(geometry.perimeter(scale))
        self.obstacles = [geometry.corners(*w) for w in self.walls[first:]]
        """Each obstacle segment as its four corners (for drawing)."""
        self.zone_centres = geometry.zone_centres(scale)

        # Targets, then robots, each uniform in the spawn area without rejection (§3).
        counts = scenario.targets
        self.target_colour = np.repeat(
            np.arange(1, 5), (counts.red, counts.green, counts.yellow, counts.blue)
        ).astype(np.int64)
        half = geometry.SPAWN_HALF * scale
        self.target_pos = self.rng.uniform(-half, half, (len(self.target_colour), 2))
        self.target_free = np.ones(len(self.target_colour), dtype=bool)
        self.colour_of = np.append(self.target_colour, 0)
        """Colour of target ``t``, and 0 at index -1 (no target registered)."""
        self.counted = np.zeros(len(self.target_colour), dtype=bool)
        self.sensor = TargetSensor(self.space, n, len(self.target_colour))
        self.wall_sensor = WallSensor(self.space, n)
        self._build_walls()
        self._target_shapes: list[pymunk.Shape] = []
        s = geometry.TARGET_SIZE / 2
        for t, (x, y) in enumerate(self.target_pos.tolist()):
            box = [(x - s, y - s), (x + s, y - s), (x + s, y + s), (x - s, y + s)]
            shape = pymunk.Poly(self.space.static_body, box)
            shape.sensor = True
            shape.collision_type = TARGET
            shape.filter = _filter(TARGET, TARGET_SENSOR)
            self._target_shapes.append(shape)
            self.sensor.target_of[shape] = t
            self.space.add(shape)

        start = self.rng.uniform(-half, half, (n, 2))
        self.heading = np.full(n, math.pi / 2)  # spawned facing Unity's +z (§3)
        self.rv = np.zeros((n, 2))
        """The resultant velocity each robot's behaviours last wrote (§4.1)."""
        self.drive = np.full(n, motion.IDLE, dtype=np.int64)
        self.walk_flag = np.ones(n, dtype=bool)  # on at start (§3)
        """The release's random-walk flag (its CSV's ``Cur. RandomWalk States``, §10)."""
        self.walk_time = np.zeros(n)
        self.walk_span = self.rng.uniform(0.0, timing.walk_first_max_s, n)
        self.carrying = np.full(n, -1, dtype=np.int64)
        self.goal = np.zeros(n, dtype=np.int64)
        self.in_zone = np.zeros(n, dtype=bool)
        self.known = np.zeros((n, 4), dtype=bool)
        for i, kind in enumerate(self.kinds):
            for colour in rb.KINDS[kind]:
                self.known[i, colour - 1] = True
        self.collected = np.zeros(4, dtype=np.int64)
        self.delivered = 0
        self.timers = Timers(n, timing.wait_limit, timing.cooldown_limit)
        self.querying = np.zeros(n, dtype=bool)
        self.answering = np.zeros(n, dtype=bool)
        self.taught = np.zeros(n, dtype=bool)
        self.asked = np.zeros(n, dtype=np.int64)
        """The colour each robot last asked about."""
        self.requester = np.full(n, -1, dtype=np.int64)
        """Each teacher's ``requestingRobot`` (§8.2), -1 for none."""
        self.forgotten = 0
        """Learned colours forgotten at once when EL's memory timer ran out (§9.3); an eviction
        to make room for a new colour (our variant) is not counted here."""
        self.memory_iter = np.zeros(n, dtype=np.int64)
        """EL's memory timer: random-walk ticks since the last pick-up or lesson (§9.3)."""
        self.heard_from: dict[int, set[int]] = {}
        self.answered_at: dict[int, int] = {}
        """Who has overheard each teacher's current answer (§9.4)."""
        self.collision = np.zeros(n, dtype=bool)
        """Whether each robot's collision sensor holds a robot or a wall (§4.6), as the
        sensors last fired (none before the first physics step)."""
        self.proximity = Proximity(
            n, spec.collision_sensor, spec.contact_radius, scenario.comm_radius, self.kt_bt
        )
        self.bodies: list[pymunk.Body] = []
        for i in range(n):
            self._add_robot(i, float(start[i, 0]), float(start[i, 1]))
        self._velocities = np.zeros(2 * (n + 1))  # the space's static body comes last
        self._in = pymunk.batch.Buffer()
        self._in.set_float_buf(self._velocities)
        self._vel = self._velocities[: 2 * n].reshape(n, 2)
        self._out = pymunk.batch.Buffer()
        # pymunk writes positions straight into this array; it reallocates an array about to
        # fill, so leave room (no body is added after this point).
        self._positions = np.zeros(2 * (n + 1) + 4)
        self._positions[: 2 * n] = start.ravel()
        self._out.set_float_buf(self._positions)
        self.pos = self._positions[: 2 * n].reshape(n, 2)
        self.actuator = motion.Actuator(
            spec.max_speed,
            math.radians(spec.max_turn_deg * self.dt),
            math.radians(spec.heading_tolerance_deg),
        )
        self.walk = motion.Walk(
            self.dt, timing.walk_goal_span, timing.walk_goal_min_s, timing.walk_goal_max_s,
            spec.carry_jitter_deg, spec.avoid_turn_deg,
        )  # fmt: skip
        self._memory_duration = scenario.memory_duration or 0
        self.proximity.update(self.pos, 0)

        # Agents on a network whose broadcasts reach the comms neighbours; a teacher's answer
        # reaches its learner wherever it is, as the release's teaching does (spec section 12).
        self.network = MemoryNetwork(audience=self._audience)
        self.names = [f"r{i}" for i in range(n)]
        self.registry = rb.registry(self)
        """The behaviours: they write their effects into this world's arrays (``state``)."""
        self.agents: list[ApplicationTimedAgent] = []
        modes = {Mode.PASSIVE_BUFFER: Overhear.BUFFER, Mode.PASSIVE: Overhear.UPDATE}
        overhear = modes.get(scenario.mode, Overhear.OFF)
        for i, kind in enumerate(self.kinds):
            agent = ApplicationTimedAgent(
                self.names[i],
                rb.control_tree(rb.KINDS[kind]),
                self.registry,
                self.network.join(self.names[i]),
                ear=Overhearing(overhear, buffer_size=4),  # at most one answer a colour (§9.4)
            )
            if scenario.memory_when_full == "evict":
                # The release counts known colours; the tree's common item (carry to the zone)
                # is knowledge too, but not a colour: it does not take a colour's place.
                others = len(agent.knowledge) - len(rb.KINDS[kind])
                agent.memory = MemoryPolicy(
                    capacity=scenario.memory_size + others, when_full=WhenFull.EVICT
                )
            agent.blackboard[rb.INDEX] = i
            self.agents.append(agent)
        self._signature = np.full(n, -1, dtype=np.int64)
        self.sequence_keys = [rb.sequence_of(c) for c in range(1, 5)]
        self.picked: list[int] = []
        half_count = geometry.ZONE_OUTER * scale / 2 + geometry.TARGET_SIZE / 2
        self._zone = (half_count, geometry.ZONE_INNER * scale / 2, spec.zone_sensor)

    @property
    def rng(self) -> np.random.Generator:
        """The trial's generator. Read-only: the compiled motion draws from it through its
        addresses (``kernel.generator_pointers``), so a replaced one would not be drawn from."""
        return self._rng

    # -- construction ---------------------------------------------------------------------

    def _build_walls(self) -> None:
        static = self.space.static_body
        for k, (x, y, angle, length) in enumerate(self.walls):
            shape = pymunk.Poly(static, geometry.corners(x, y, angle, length))
            shape.collision_type = WALL
            shape.filter = _filter(WALL, BODY | WALL_SENSOR)
            shape.friction = 0.0
            self.wall_sensor.segment_of[shape] = (k, x, y)
            self.space.add(shape)

    def _add_robot(self, i: int, x: float, y: float) -> None:
        spec = self.scenario.robot
        body = pymunk.Body(10.0, math.inf)
        body.position = (x, y)
        hull = pymunk.Circle(body, self.radius)
        hull.collision_type = BODY
        hull.filter = _filter(BODY, BODY | WALL)
        hull.friction = 0.0
        eyes = pymunk.Circle(body, spec.target_sensor)
        eyes.sensor = True
        eyes.collision_type = TARGET_SENSOR
        eyes.filter = _filter(TARGET_SENSOR, TARGET)
        bumper = pymunk.Circle(body, spec.collision_sensor)
        bumper.sensor = True
        bumper.collision_type = WALL_SENSOR
        bumper.filter = _filter(WALL_SENSOR, WALL)
        self.sensor.robot_of[eyes] = i
        self.wall_sensor.robot_of[bumper] = i
        self.space.add(body, hull, eyes, bumper)
        self.bodies.append(body)

    def _audience(self, sender: str) -> list[str]:
        i = int(sender[1:])
        return [self.names[j] for j in self.proximity.neighbours(i).tolist()]

    # -- one iteration ----------------------------------------------------------------------

    def step(self) -> None:
        self.iteration += 1
        t = self.iteration
        self._tick_trees()
        self._move()
        if self.kt_bt:
            teaching.step(self, t)
        timers = self.timers
        enable(self.sensor.enabled, self.carrying, timers.wait_end, timers.cool_end, 2 * t + 2)
        pymunk.batch.set_space_bodies(self.space, pymunk.batch.BodyFields.VELOCITY, self._in)
        self.space.step(self.dt)
        self._out.clear()  # refills ``self._positions``, of which ``self.pos`` is a view
        pymunk.batch.get_space_bodies(self.space, pymunk.batch.BodyFields.POSITION, self._out)
        self._sense(t)

    def _tick_trees(self) -> None:
        timers, sensor = self.timers, self.sensor
        due = rb.due(
            self.collision, timers.wait_end, 2 * self.iteration, self.carrying, self.in_zone,
            self.colour_of, sensor.tsr, self.known, self.drive, self._signature, not self.lazy,
        )  # fmt: skip
        if not len(due):
            return
        signature = self._signature
        for i in due.tolist():
            s = int(signature[i])
            agent = self.agents[i]
            bb = agent.blackboard
            bb[rb.COLLISION] = s & 1
            bb[rb.WAIT] = s >> 1 & 1
            bb[rb.CARRYING] = s >> 2 & 1
            bb[rb.IN_ZONE] = s >> 3 & 1
            bb[rb.SEEN] = s >> 4 & 7
            agent.control.tick()
        for t in self.picked:  # taken away: out of the space and of every sensor it was in
            self.space.remove(self._target_shapes[t])
            sensor.picked(t)
        self.picked.clear()

    def _move(self) -> None:
        """Every behaviour writes its robot's resultant velocity, then the actuators act."""
        prox, walls, walk = self.proximity, self.wall_sensor, self.walk
        spent = motion.move(
            self.drive, self.rv, self.pos, self.walk_flag, self.walk_time, self.walk_span,
            self.memory_iter, self._memory_duration, self.goal, self.zone_centres,
            prox.start, prox.others, prox.weights, walls.count, walls.centres, self._rng_pointers,
            walk.dt, walk.goal_span, walk.leg_min_s, walk.leg_max_s, *walk.carry_jitter_deg,
            *walk.avoid_turn_deg, self.heading, self._vel, *self.actuator,
        )  # fmt: skip
        for i in spent.tolist():
            forget_learned(self, i)

    def _sense(self, t: int) -> None:
        """The trigger callbacks have run inside the physics step; now the robot-to-robot
        sensors and the zones (§4.5, §4.6, §5.3)."""
        prox = self.proximity
        prox.update(self.pos, t)
        count_half, place_half, reach = self._zone
        heard = after_physics(
            prox.count, self.wall_sensor.count, self.collision, prox.newly, self.querying,
            self.taught, self.pos, self.carrying, self.goal, self.zone_centres, self.counted,
            self.collected, self.in_zone, self.target_colour, count_half, place_half, reach,
        )  # fmt: skip
        if self.kt_bt and len(heard):
            teaching.came_into_range(self, heard)

    # -- what an experiment reads -----------------------------------------------------------

    def run(self, iterations: int) -> None:
        for _ in range(iterations):
            self.step()

    def record(self) -> dict[str, int]:
        """One row of the record (``records.COLUMNS``)."""
        return records.row(self)
