"""The release's rules, one test each (``spec/simulator.md``, section in each name).

Each test builds the smallest real situation that shows its rule: real pymunk shapes and
callbacks, real agents exchanging query and response messages, the world's own step.
"""

from __future__ import annotations

import math

import numpy as np
import pymunk

from ktbt_sim import motion, sensing, teaching
from ktbt_sim import robot as rb
from ktbt_sim.scenario import Mode, Robots, Scenario, Targets, TeachingRule
from ktbt_sim.state import total
from ktbt_sim.timers import Timers
from ktbt_sim.world import World

# -- §7: wait and cool-down ------------------------------------------------------------------


def flags_at_end_of(timers: Timers, iteration: int) -> tuple[bool, bool]:
    """(waiting, cooling) as the release's CSV samples them, at the end of an iteration."""
    call = 2 * iteration + 2
    waiting = bool(timers.waiting(call)[0])
    return waiting, bool(timers.busy(call)[0]) and not waiting


def count(timers: Timers, start: int, flag: int) -> int:
    return sum(flags_at_end_of(timers, t)[flag] for t in range(start, start + 3000))


def test_s7_a_query_waits_501_iterations_then_cools_500() -> None:
    timers = Timers(1)
    timers.start(0, 2 * 100 + 1)  # a query, right after RegLearnBT's call of iteration 100
    assert count(timers, 100, 0) == 501
    assert count(timers, 100, 1) == 500
    assert not timers.busy(2 * 1101 + 1)[0] and timers.busy(2 * 1100 + 1)[0]  # asks again at 1101


def test_s7_a_teach_waits_501_and_a_delivery_500() -> None:
    teach, deliver = Timers(1), Timers(1)
    teach.start(0, 2 * 50 + 2)
    deliver.start(0, 2 * 50)
    assert count(teach, 50, 0) == 501
    assert count(deliver, 50, 0) == 500
    assert count(deliver, 50, 1) == 500


def test_s7_a_delivery_during_a_cool_down_ends_its_wait_at_once_and_cools_again() -> None:
    timers = Timers(1)
    timers.start(0, 2 * 10 + 1)  # a query: waiting until 510, cooling until 1010
    timers.start(0, 2 * 800)  # a delivery while cooling down
    assert not timers.waiting(2 * 800 + 1)[0]
    assert count(timers, 800, 0) == 0
    assert count(timers, 800, 1) == 500


def test_s7_sensing_is_off_only_between_the_end_of_the_wait_and_the_end_of_the_cool_down() -> None:
    timers = Timers(1)
    timers.start(0, 1)
    off = [bool(timers.sensing_off(c)[0]) for c in range(0, 3000)]
    assert off.index(True) == 1003  # the wait ended at call 1002
    assert off.count(True) == 1000


# -- §4.1: the actuator -----------------------------------------------------------------------


def test_s4_1_drives_only_within_5_degrees_and_turns_4_degrees_an_iteration() -> None:
    act = motion.Actuator(300.0, math.radians(200.0 * 0.02), math.radians(5.0))
    rv = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 0.0]])
    heading = np.radians([4.9, 30.0, 90.0])
    out = np.zeros((3, 2))
    motion.actuate(rv, heading, out, *act)
    assert np.allclose(out[0], [300.0, 0.0])  # aligned: full speed along rv, no turn
    assert math.isclose(math.degrees(heading[0]), 4.9)
    assert np.allclose(out[1], 0.0) and math.isclose(math.degrees(heading[1]), 26.0)
    assert np.allclose(out[2], 0.0) and math.isclose(math.degrees(heading[2]), 86.0)  # to +x


# -- §4.2: the random walk ---------------------------------------------------------------------


def small(**changes: object) -> Scenario:
    base = Scenario(
        mode=Mode.KT_BT,
        robots=Robots.of(3, 0, 0, 0, 0, 0),
        targets=Targets.each(0),
        iterations=1,
    )
    return base.with_(**changes) if changes else base


def test_s4_2_a_walker_keeps_its_velocity_between_draws_toward_far_points() -> None:
    world = World(small(robots=Robots.of(1, 0, 0, 0, 0, 0)), seed=3)
    draws = []
    previous = world.rv.copy()
    for _ in range(2000):
        world.step()
        if not np.array_equal(world.rv, previous):
            draws.append(world.iteration)
            goal = world.rv[0] + world.pos[0]  # rv = goal - position at the draw
            previous = world.rv.copy()
            assert np.all(np.abs(goal) > 0) and np.all(np.abs(goal) < 10_001)
    gaps = np.diff(draws)
    assert len(draws) > 5
    assert gaps.min() >= 49 and gaps.max() <= 251  # a new goal every U(1, 5) s of walking
    assert draws[0] <= 251  # the first leg lasts U(0, 5) s


# -- §5.1: the target sensor -------------------------------------------------------------------


class SensorRig:
    """One robot's 60-radius target sensor and some 20-unit target cubes in a real space."""

    def __init__(self, targets: list[tuple[float, float]]) -> None:
        self.space = pymunk.Space()
        self.sensor = sensing.TargetSensor(self.space, 1, len(targets))
        self.body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
        eyes = pymunk.Circle(self.body, 60.0)
        eyes.sensor = True
        eyes.collision_type = sensing.TARGET_SENSOR
        self.sensor.robot_of[eyes] = 0
        self.space.add(self.body, eyes)
        self.shapes = []
        for t, (x, y) in enumerate(targets):
            box = pymunk.Poly.create_box(self.space.static_body, (20.0, 20.0))
            box = pymunk.Poly(
                self.space.static_body, [(x + a, y + b) for a, b in box.get_vertices()]
            )
            box.sensor = True
            box.collision_type = sensing.TARGET
            self.sensor.target_of[box] = t
            self.space.add(box)
            self.shapes.append(box)

    def at(self, x: float, y: float) -> int:
        self.body.position = (x, y)
        self.space.reindex_shapes_for_body(self.body)
        self.space.step(0.02)
        return int(self.sensor.tsr[0])


def test_s5_1_registers_at_70_to_74_between_centres() -> None:
    rig = SensorRig([(0.0, 0.0)])
    assert rig.at(-71.0, 0.0) == -1
    assert rig.at(-69.0, 0.0) == 0  # face on: 60 + 10
    corner = SensorRig([(0.0, 0.0)])
    assert corner.at(-53.0, -53.0) == -1  # 75 away, corner on: not yet
    assert corner.at(-52.0, -52.0) == 0  # 73.5 away, corner on (60 + 10 sqrt 2 = 74.1)


def test_s5_1_the_last_enter_wins_and_any_exit_clears() -> None:
    rig = SensorRig([(0.0, 0.0), (120.0, 0.0)])
    assert rig.at(40.0, 0.0) == 0
    assert rig.at(52.0, 0.0) == 1  # the second enters: it wins, the first still inside
    assert rig.at(45.0, 0.0) == -1  # the second leaves: cleared although the first is inside
    assert rig.at(44.0, 0.0) == -1  # no re-registration while the first stays inside


def test_s5_1_an_enter_while_sensing_is_off_clears() -> None:
    rig = SensorRig([(0.0, 0.0), (120.0, 0.0)])
    assert rig.at(40.0, 0.0) == 0
    rig.sensor.enabled[0] = False
    assert rig.at(52.0, 0.0) == -1
    rig.sensor.enabled[0] = True
    assert rig.at(53.0, 0.0) == -1  # both still inside: nothing registers


# -- §4.5: counting and placing ----------------------------------------------------------------


def test_s4_5_a_target_counts_at_510_and_the_robot_places_at_490() -> None:
    centres = np.array([[2800.0, 2800.0]] * 4)
    xs = np.array([[2800.0 - d, 2800.0] for d in (511.0, 509.0, 491.0, 489.0)])
    counted, inside = zone_events(xs, centres, 510.0, 400.0, 90.0)
    assert counted.tolist() == [False, True, True, True]
    assert inside.tolist() == [False, False, False, True]


def zone_events(
    pos: np.ndarray, centres: np.ndarray, count_half: float, place_half: float, reach: float
) -> tuple[np.ndarray, np.ndarray]:
    """Four carriers at ``pos`` heading to zone 1, each carrying its own target: which count
    and which may place, from ``sensing.zones`` on fresh state."""
    n = len(pos)
    counted, collected = np.zeros(n, dtype=bool), np.zeros(4, dtype=np.int64)
    inside = np.zeros(n, dtype=bool)
    sensing.zones(
        pos, np.arange(n), np.ones(n, dtype=np.int64), centres, counted, collected, inside,
        np.ones(n, dtype=np.int64), count_half, place_half, reach,
    )  # fmt: skip
    assert collected[0] == counted.sum()
    return counted, inside


# -- §4.6: collision avoidance -----------------------------------------------------------------


def test_s4_6_avoidance_starts_at_150_and_counts_a_body_inside_twice() -> None:
    prox = sensing.Proximity(3, 75.0, 36.0, 600.0, comms=False)
    pos = np.array([[0.0, 0.0], [149.0, 0.0], [0.0, 100.0]])
    prox.update(pos, 1)
    assert prox.weight(0).tolist() == [0.0, 1.0, 2.0]
    prox.update(np.array([[0.0, 0.0], [151.0, 0.0], [0.0, 1000.0]]), 2)
    assert prox.count[0] == 0


def test_s4_6_avoidance_turns_sideways_70_to_79_degrees_counter_clockwise() -> None:
    rng = np.random.default_rng(0)
    turned = np.array([motion.turn(rng, 1.0, 0.0, 70, 79) for _ in range(2000)])
    angles = np.degrees(np.arctan2(turned[:, 1], turned[:, 0]))
    assert set(np.round(angles).astype(int).tolist()) == set(range(70, 80))


# -- §8: asking and who answers ----------------------------------------------------------------


def place(world: World, i: int, x: float, y: float) -> None:
    world.bodies[i].position = (x, y)
    world.pos[i] = (x, y)


def rig(kinds: Robots, positions: list[tuple[float, float]], **changes: object) -> World:
    """A world with robots where the test puts them, and one red target to ask about."""
    world = World(small(robots=kinds, targets=Targets(red=1, green=1), **changes), seed=0)
    for i, (x, y) in enumerate(positions):
        place(world, i, x, y)
    world.proximity.update(world.pos, 0)
    world.proximity.entered[:] = 0
    return world


def see(world: World, i: int, colour: int) -> None:
    """Robot ``i`` has registered a target of ``colour``."""
    world.sensor.tsr[i] = int(np.flatnonzero(world.target_colour == colour)[0])


def enter_in_order(world: World, order: list[int], at: int) -> None:
    """Robots ``order`` came into robot ``at``'s range in that order (and it into theirs)."""
    prox = world.proximity
    for k, j in enumerate(order):
        for key in (at * prox.n + j, j * prox.n + at):
            index = int(np.searchsorted(prox.keys, key))
            assert prox.keys[index] == key, "not in range"
            prox.entered[index] = k + 1


def test_s8_1_a_free_robot_asks_about_an_unknown_colour_at_once() -> None:
    world = rig(Robots.of(1, 1, 0, 0, 0, 0), [(0.0, 0.0), (3000.0, 3000.0)])
    see(world, 0, 1)
    see(world, 1, 1)  # knows red: no question
    teaching.step(world, 1)
    assert world.querying.tolist() == [True, False]
    assert world.agents[0].open_query is not None
    assert world.agents[0].metrics.queries_sent == 1


def test_s8_2_a_teacher_answers_only_its_first_requester() -> None:
    """T (knows red only) has L1 then L2 in range. L1 asks about green, L2 about red: T
    answers nobody, since its first requester asks what it does not know."""
    world = rig(Robots.of(2, 0, 1, 0, 0, 0), [(0.0, 0.0), (100.0, 300.0), (0.0, 300.0)])
    enter_in_order(world, [0, 1], at=2)
    see(world, 0, 2)
    see(world, 1, 1)
    teaching.step(world, 1)  # both ask
    for t in range(2, 400):
        teaching.step(world, t)
    assert world.requester[2] == 0
    assert total(world, "responses_sent") == 0 and not world.taught.any()


def test_s8_2_the_broadcast_rule_answers_the_first_question_it_can() -> None:
    world = rig(
        Robots.of(2, 0, 1, 0, 0, 0),
        [(0.0, 0.0), (100.0, 300.0), (0.0, 300.0)],
        teaching=TeachingRule.BROADCAST,
    )
    enter_in_order(world, [0, 1], at=2)
    see(world, 0, 2)
    see(world, 1, 1)
    teaching.step(world, 1)
    teaching.step(world, 2)
    assert world.requester[2] == 1
    assert total(world, "responses_sent") == 1 and world.taught.tolist() == [False, True, False]
    assert world.known[1, 0] and rb.sequence_of(1) in world.agents[1].knowledge


def test_s8_2_one_teacher_per_query() -> None:
    world = rig(Robots.of(1, 2, 0, 0, 0, 0), [(0.0, 0.0), (200.0, 0.0), (-200.0, 0.0)])
    see(world, 0, 1)
    teaching.step(world, 1)
    teaching.step(world, 2)
    assert total(world, "responses_sent") == 1
    assert sum(a.metrics.responses_sent for a in world.agents) == 1
    assert world.agents[0].metrics.responses_received == 1


def test_s8_2_a_query_stays_answerable_for_the_whole_wait() -> None:
    """Nobody is in range when L asks; a teacher coming into range 400 iterations later hears
    the question (L sends it to newcomers) and answers it."""
    world = rig(Robots.of(1, 1, 0, 0, 0, 0), [(0.0, 0.0), (3000.0, 0.0)])
    see(world, 0, 1)
    teaching.step(world, 1)
    for t in range(2, 400):
        teaching.step(world, t)
    assert total(world, "responses_sent") == 0
    place(world, 1, 300.0, 0.0)
    world.proximity.update(world.pos, 400)
    teaching.came_into_range(world, world.proximity.newly)
    teaching.step(world, 401)
    assert total(world, "responses_sent") == 1 and world.known[0, 0]


def test_s8_2_a_query_is_not_answerable_after_the_wait() -> None:
    world = rig(Robots.of(1, 1, 0, 0, 0, 0), [(0.0, 0.0), (3000.0, 0.0)])
    see(world, 0, 1)
    teaching.step(world, 1)
    for t in range(2, 503):
        teaching.step(world, t)
    assert not world.querying[0]
    assert world.agents[0].metrics.queries_lost == 1
    place(world, 1, 300.0, 0.0)
    world.proximity.update(world.pos, 503)
    teaching.came_into_range(world, world.proximity.newly)
    teaching.step(world, 504)
    assert total(world, "responses_sent") == 0 and not world.known[0, 0]


def test_s8_3_a_taught_learner_keeps_waiting_and_its_teacher_waits_too() -> None:
    world = rig(Robots.of(1, 1, 0, 0, 0, 0), [(0.0, 0.0), (200.0, 0.0)])
    see(world, 0, 1)
    teaching.step(world, 1)
    teaching.step(world, 2)
    assert world.taught[0] and world.answering[1]
    assert world.timers.waiting(2 * 400)[0] and world.timers.waiting(2 * 400)[1]
    assert world.timers.wait_end[0] == 2 * 1 + 1 + 1001  # not shortened by the answer


def test_s8_2_the_first_requester_is_by_order_of_entry_not_by_index() -> None:
    """L2 came into T's range before L1: T answers L2's question about red, although L1 (a
    lower index, asking about green) is querying too."""
    world = rig(Robots.of(2, 0, 1, 0, 0, 0), [(0.0, 0.0), (100.0, 300.0), (0.0, 300.0)])
    enter_in_order(world, [1, 0], at=2)
    see(world, 0, 2)
    see(world, 1, 1)
    teaching.step(world, 1)
    teaching.step(world, 2)
    assert world.requester[2] == 1
    assert total(world, "responses_sent") == 1 and world.taught.tolist() == [False, True, False]


def test_s8_2_a_taught_querier_no_longer_holds_the_teachers_attention() -> None:
    """The first-entered querying neighbour is already taught: the teacher answers the next."""
    world = rig(Robots.of(2, 1, 0, 0, 0, 0), [(0.0, 0.0), (100.0, 300.0), (0.0, 300.0)])
    enter_in_order(world, [0, 1], at=2)
    see(world, 0, 1)
    see(world, 1, 1)
    teaching.step(world, 1)
    world.taught[0] = True  # taught by somebody else meanwhile
    teaching.step(world, 2)
    assert world.requester[2] == 1 and world.taught[1]


def test_s8_2_a_stale_requester_is_answered_out_of_range() -> None:
    """T's neighbour list empties while L waits: T keeps L as its requester and, once free,
    answers it wherever it is; a new question from L reaches T too."""
    world = rig(Robots.of(1, 0, 1, 0, 0, 0), [(0.0, 0.0), (300.0, 0.0)])
    see(world, 0, 2)  # green: T (red only) cannot answer, but L is its requester
    teaching.step(world, 1)
    teaching.step(world, 2)
    assert world.requester[1] == 0 and total(world, "responses_sent") == 0
    world.sensor.tsr[0] = -1  # L loses sight of the green target
    place(world, 0, 3000.0, 3000.0)
    world.proximity.update(world.pos, 3)
    for t in range(3, 1200):  # L's wait and cool-down pass; nobody is in T's range
        teaching.step(world, t)
    assert world.requester[1] == 0 and not world.proximity.has_neighbours[1]
    see(world, 0, 1)  # now red, from out of range
    teaching.step(world, 1200)
    assert total(world, "responses_sent") == 1 and world.known[0, 0]


def test_s4_5_the_worlds_zone_counts_at_510_and_places_at_490() -> None:
    world = World(small(), seed=0)
    count_half, place_half, reach = world._zone
    centres = world.zone_centres
    xs = np.array([[2800.0 - d, 2800.0] for d in (511.0, 509.0, 491.0, 489.0)])
    counted, inside = zone_events(xs, centres, count_half, place_half, reach)
    assert counted.tolist() == [False, True, True, True]
    assert inside.tolist() == [False, False, False, True]


def test_s4_1_the_worlds_actuator_has_the_releases_constants() -> None:
    world = World(small(), seed=0)
    assert math.isclose(world.actuator.tolerance, math.radians(5.0))
    assert math.isclose(world.actuator.turn, math.radians(4.0))
    assert world.actuator.speed * world.dt == 6.0


def test_s4_6_walls_enter_avoidance_through_their_segment_centres() -> None:
    """A robot 60 from the top wall's inner face: its sensor overlaps the segments whose boxes
    it reaches, and it steers 70 to 79 degrees counter-clockwise off the sum of (robot - centre)."""
    world = World(small(robots=Robots.of(1, 0, 0, 0, 0, 0)), seed=0)
    place(world, 0, 0.0, 3980.0 - 60.0)
    world.space.reindex_shapes_for_body(world.bodies[0])
    world.step()
    contacts = world.wall_sensor.contacts[0]
    assert {(x, y) for x, y in contacts.values()} == {(-100.0, 4000.0), (100.0, 4000.0)}
    world.step()  # the tree sees the collision and avoids
    x, y = world.pos[0]
    away = np.array([(x + 100.0) + (x - 100.0), 2 * (y - 4000.0)])
    angle = math.degrees(math.atan2(world.rv[0, 1], world.rv[0, 0]) - math.atan2(away[1], away[0]))
    assert 69.9 <= angle % 360 <= 79.1


def test_s4_2_the_walk_timer_runs_only_on_random_walk_ticks() -> None:
    """A wait in the middle of a leg delays the next goal by the wait's length."""
    free = World(small(robots=Robots.of(1, 0, 0, 0, 0, 0)), seed=5)
    held = World(small(robots=Robots.of(1, 0, 0, 0, 0, 0)), seed=5)

    def draws(world: World, wait_at: int | None) -> list[int]:
        out, previous = [], world.rv.copy()
        for _ in range(1500):
            if world.iteration == wait_at:
                world.timers.start(0, 2 * (world.iteration + 1))  # as a delivery would
            world.step()
            if not np.array_equal(world.rv, previous) and world.drive[0] == motion.WALK:
                out.append(world.iteration)
            previous = world.rv.copy()
        return out

    first = draws(free, None)[0]
    held_draws = draws(held, first - 10)
    assert first > 10 and held_draws[0] >= first + 499


def test_s4_3_a_registered_target_of_a_known_colour_is_taken_the_next_tick() -> None:
    world = World(small(robots=Robots.of(0, 1, 0, 0, 0, 0), targets=Targets(red=1)), seed=0)
    x, y = world.target_pos[0]
    place(world, 0, float(x) - 69.0, float(y))
    world.space.reindex_shapes_for_body(world.bodies[0])
    world.step()  # physics: the sensor registers the target
    assert world.sensor.tsr[0] == 0 and world.carrying[0] == -1
    world.step()  # the tree picks it, wherever it is in the sensor
    assert world.carrying[0] == 0 and not world.target_free[0]


# -- §9: the release's hidden modes --------------------------------------------------------


def test_s9_3_el_forgets_everything_learned_after_its_random_walk_ticks() -> None:
    world = rig(
        Robots.of(1, 1, 0, 0, 0, 0),
        [(0.0, 0.0), (200.0, 0.0)],
        mode=Mode.EPHEMERAL,
        memory_duration=50,
        memory_size=4,
    )
    see(world, 0, 1)
    teaching.step(world, 1)
    teaching.step(world, 2)
    assert world.known[0, 0] and world.memory_iter[0] == 0
    world.drive[0] = motion.STOP  # waiting: the timer does not run
    for _ in range(100):
        world._move()
    assert world.memory_iter[0] == 0 and world.known[0, 0]
    world.drive[0] = motion.WALK
    for _ in range(49):
        world._move()
    assert world.known[0, 0] and world.memory_iter[0] == 49
    world._move()  # the 50th random-walk tick
    assert not world.known[0].any() and world.forgotten == 1
    assert rb.sequence_of(1) not in world.agents[0].knowledge
    assert world.known[1].all()  # innate knowledge is never forgotten


def test_s9_3_a_pick_up_resets_els_timer() -> None:
    world = rig(Robots.of(0, 1, 0, 0, 0, 0), [(0.0, 0.0)], mode=Mode.EPHEMERAL, memory_duration=50)
    world.memory_iter[0] = 30
    see(world, 0, 1)
    assert rb.pick(world, 0, 1) and world.memory_iter[0] == 0


def learn_two(when_full: str) -> World:
    """An ignorant robot with room for one colour learns red, then asks about green."""
    world = rig(
        Robots.of(1, 1, 0, 0, 0, 0),
        [(0.0, 0.0), (200.0, 0.0)],
        mode=Mode.EPHEMERAL,
        memory_size=1,
        memory_when_full=when_full,
    )
    see(world, 0, 1)
    for t in range(1, 1103):  # red is taught; both wait and cool down
        teaching.step(world, t)
    world.sensor.tsr[0] = -1
    assert world.known[0].tolist() == [True, False, False, False]
    see(world, 0, 2)
    for t in range(1103, 1106):
        teaching.step(world, t)
    return world


def test_el_evict_variant_teaches_a_full_learner_who_drops_its_least_used_colour() -> None:
    assert learn_two("evict").known[0].tolist() == [False, True, False, False]
    assert learn_two("refuse").known[0].tolist() == [True, False, False, False]  # the release


def overhear_rig(mode: Mode) -> World:
    """L (0) asks T (3, knows all) about red; O (1) listens nearby; F (2) is far away."""
    world = rig(
        Robots.of(3, 1, 0, 0, 0, 0),
        [(0.0, 0.0), (0.0, 200.0), (3000.0, 3000.0), (200.0, 0.0)],
        mode=mode,
    )
    see(world, 0, 1)
    teaching.step(world, 1)
    teaching.step(world, 2)
    assert world.answering.tolist() == [False, False, False, True]
    return world


def test_s9_4_a_teacher_is_overheard_by_robots_not_asking_for_its_whole_teaching_wait() -> None:
    world = overhear_rig(Mode.PASSIVE_BUFFER)
    key = rb.sequence_of(1)
    assert world.agents[1].buffered == [key] and not world.known[1, 0]
    assert world.agents[2].buffered == []
    place(world, 2, 100.0, 200.0)  # F comes into range while T still teaches
    world.proximity.update(world.pos, 300)
    teaching.step(world, 300)
    assert world.agents[2].buffered == [key]
    for t in range(301, 700):  # the teaching wait ends
        teaching.step(world, t)
    assert not world.answering.any()


def test_s9_4_a_robot_asking_does_not_overhear() -> None:
    world = rig(
        Robots.of(2, 1, 0, 0, 0, 0),
        [(0.0, 0.0), (0.0, 200.0), (200.0, 0.0)],
        mode=Mode.PASSIVE_BUFFER,
    )
    see(world, 0, 1)
    see(world, 1, 2)  # robot 1 asks about green at the same time
    teaching.step(world, 1)
    teaching.step(world, 2)
    assert world.answering[2] and world.querying[1]
    assert world.agents[1].buffered == []  # it was asking while robot 2 taught


def test_s9_5_plb_uses_a_buffered_answer_without_a_query_or_a_wait() -> None:
    world = overhear_rig(Mode.PASSIVE_BUFFER)
    queries = total(world, "queries_sent")
    see(world, 1, 1)  # the listener now registers a red target
    teaching.step(world, 3)
    assert world.known[1, 0] and total(world, "learned_buffered") == 1
    assert total(world, "queries_sent") == queries and not world.querying[1]
    assert world.agents[1].buffered == []


def test_s9_6_pl_learns_what_it_overhears_at_once() -> None:
    world = overhear_rig(Mode.PASSIVE)
    assert world.known[1, 0] and total(world, "learned_passive") == 1
    assert world.agents[1].metrics.learned_passive == 1
    assert world.agents[1].metrics.queries_sent == 0


def test_s9_1_el_robots_do_not_overhear() -> None:
    world = overhear_rig(Mode.EPHEMERAL)
    assert not world.known[1, 0] and world.agents[1].buffered == []


def test_our_eavesdrop_variant_is_heard_only_at_the_moment_of_the_answer() -> None:
    world = rig(
        Robots.of(3, 1, 0, 0, 0, 0),
        [(0.0, 0.0), (0.0, 200.0), (3000.0, 3000.0), (200.0, 0.0)],
        mode=Mode.PASSIVE,
        overhear_window="answer",
    )
    see(world, 0, 1)
    teaching.step(world, 1)
    teaching.step(world, 2)
    assert world.known[1, 0]  # in range at the answer
    place(world, 2, 100.0, 200.0)  # comes into range during the teaching wait
    world.proximity.update(world.pos, 300)
    teaching.step(world, 300)
    assert not world.known[2, 0]  # the release's rule would have let it hear
