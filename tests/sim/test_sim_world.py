"""The search-and-rescue world as a whole: invariants, determinism, lazy ticking, who learns."""

from __future__ import annotations

import numpy as np
import pytest

from ktbt_sim import geometry
from ktbt_sim import robot as rb
from ktbt_sim.scenario import Mode, Robots, Scenario, Targets, preset
from ktbt_sim.state import total
from ktbt_sim.world import RECORD_COLUMNS, World


def rows(world: World, steps: int, every: int = 50) -> list[dict[str, int]]:
    out = []
    for _ in range(steps // every):
        world.run(every)
        out.append(world.record())
    return out


def check_invariants(world: World) -> None:
    limit = geometry.HALF - geometry.SEGMENT_THICKNESS / 2 - world.radius + 2.0
    assert np.all(np.abs(world.pos) <= limit), "a robot left the arena"
    carried = world.carrying[world.carrying >= 0]
    assert len(carried) == len(set(carried.tolist())), "two robots carry one target"
    assert not np.any(world.target_free[carried]), "a carried target still lies on the floor"
    taken = ~world.target_free
    assert world.counted.sum() == world.collected.sum()
    assert np.all(taken[world.counted]), "a counted target is still lying"
    by_colour = np.bincount(world.target_colour[world.counted] - 1, minlength=4)
    assert by_colour.tolist() == world.collected.tolist()
    assert world.delivered <= world.collected.sum()
    assert total(world, "responses_sent") <= total(world, "queries_sent")
    assert np.all(world.known.sum(axis=1) <= 4)


@pytest.mark.parametrize("name", ["ktbt-obstacles", "bl1", "calibration-rl"])
def test_world_invariants_hold_every_step(name: str) -> None:
    world = World(preset(name), seed=3)
    for _ in range(60):
        world.run(50)
        check_invariants(world)
    assert world.collected.sum() > 0


def test_same_seed_same_run_bit_for_bit() -> None:
    scenario = preset("ktbt")
    a = rows(World(scenario, seed=7), 2000)
    b = rows(World(scenario, seed=7), 2000)
    c = rows(World(scenario, seed=8), 2000)
    assert a == b
    assert a != c
    assert tuple(a[0]) == RECORD_COLUMNS


@pytest.mark.parametrize("name", ["ktbt", "opportunities-100", "ktbt-broadcast"])
def test_skipping_ticks_changes_nothing(name: str) -> None:
    """The world ticks only the robots whose tree inputs changed; ticking every robot every
    iteration must give exactly the same run."""
    scenario = preset(name)
    lazy = World(scenario, seed=5)
    eager = World(scenario, seed=5, lazy=False)
    for _ in range(30):
        lazy.run(100)
        eager.run(100)
        assert lazy.record() == eager.record()
        assert np.array_equal(lazy.pos, eager.pos)
    assert lazy.record()["queries"] > 0


def test_no_transfer_robots_never_learn() -> None:
    world = World(preset("bl2"), seed=2)
    known = world.known.copy()
    world.run(3000)
    assert np.array_equal(world.known, known)
    assert world.record()["queries"] == 0
    assert all(not a.metrics.learned for a in world.agents)


def test_robots_learn_by_real_messages() -> None:
    """Every learned colour is in the learner's agent's knowledge base, merged into its live
    control tree, and taught by a robot named in its metrics."""
    world = World(preset("calibration-rl"), seed=4)
    start = world.known.sum()
    world.run(6000)
    assert world.known.sum() > start
    learned = 0
    for i, agent in enumerate(world.agents):
        for c in range(4):
            assert world.known[i, c] == (rb.sequence_of(c + 1) in agent.knowledge)
        for _when, teacher in agent.metrics.learned.values():
            assert teacher in world.names and teacher != world.names[i]
            learned += 1
    assert learned == total(world, "learned_direct") == total(world, "responses_sent") > 0


def test_out_of_range_nobody_learns_and_queries_are_lost() -> None:
    """Range 0 leaves a comms radius of one body (36): robots never get that close."""
    world = World(preset("ktbt").with_(comm_range=0.0), seed=6)
    world.run(3000)
    record = world.record()
    assert record["queries"] > 0 and record["responses"] == 0
    assert record["lost"] == record["queries"]
    assert all(not a.metrics.learned for a in world.agents)


def test_each_robot_type_starts_with_its_colours() -> None:
    world = World(Scenario(robots=Robots.of(1, 1, 1, 1, 1, 1)), seed=0)
    assert world.kinds == ["I", "M", "R", "G", "Y", "B"]
    assert world.known.sum(axis=1).tolist() == [0, 4, 1, 1, 1, 1]
    assert [c + 1 for c in np.flatnonzero(world.known[2:].any(axis=0))] == [1, 2, 3, 4]


def test_the_release_arena() -> None:
    world = World(preset("ktbt-obstacles"), seed=9)
    assert len(world.obstacles) == 47
    assert len(world.walls) == 160 + 47
    assert world.zone_centres.tolist()[3] == [2812.0, -2800.0]
    assert np.all(np.abs(world.target_pos) <= geometry.SPAWN_HALF)
    assert len(World(preset("ktbt"), seed=9).walls) == 160


def test_memory_size_caps_teaching() -> None:
    """A learner that knows ``memory_size`` colours is never taught (§8.2)."""
    scenario = Scenario(
        mode=Mode.KT_BT,
        robots=Robots.of(39, 1, 0, 0, 0, 0),
        targets=Targets.each(100),
        memory_size=1,
        iterations=1,
    )
    world = World(scenario, seed=1)
    world.run(8000)
    assert world.known[:39].sum(axis=1).max() <= 1
    assert total(world, "queries_sent") > total(world, "responses_sent") > 0
