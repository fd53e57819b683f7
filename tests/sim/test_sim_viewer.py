"""The viewer: real pixels of rendered frames, the keyboard controls, and headless recording."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pygame
import pytest
from PIL import Image

from ktbt_sim import geometry
from ktbt_sim.scenario import preset
from ktbt_sim.viewer import (
    BACKGROUND,
    FLOOR,
    LIGHT_QUERYING,
    LIGHT_TEACHING,
    LIGHT_WALKING,
    OBSTACLE,
    ROBOT,
    ZONE_RGB,
    Controls,
    Viewer,
    hud_lines,
    record,
    render,
    run,
)
from ktbt_sim.world import World

SIZE = 400


@pytest.fixture(autouse=True)
def _headless(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """No window may open on a test machine: SDL's dummy driver stands in for a display."""
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    yield


@pytest.fixture(scope="module")
def world() -> World:
    return World(preset("ktbt").with_(iterations=100), seed=1)


def pixel(surface: pygame.Surface, at: tuple[int, int]) -> tuple[int, int, int]:
    c = surface.get_at(at)
    return (c.r, c.g, c.b)


def lone_robot(world: World, viewer: Viewer) -> int:
    """A robot with no other robot or free target near enough to cover its centre pixel."""
    clear = 4 * world.scenario.robot.body
    for i in range(world.n):
        others = np.delete(world.pos, i, axis=0)
        near_robot = (np.hypot(*(others - world.pos[i]).T) < clear).any()
        near_target = (np.hypot(*(world.target_pos - world.pos[i]).T) < clear).any()
        x, y = viewer.to_screen(*world.pos[i])
        under_hud = x < SIZE // 2 and y < SIZE // 4
        if not (near_robot or near_target or under_hud):
            return i
    raise AssertionError("no isolated robot in this layout")


def test_zones_floor_and_background_have_their_colours(world: World) -> None:
    viewer = Viewer(world, SIZE)
    surface = viewer.draw()
    assert surface.get_size() == (SIZE, SIZE)
    for colour, (cx, cy) in zip(ZONE_RGB, world.zone_centres, strict=True):
        assert pixel(surface, viewer.to_screen(cx, cy)) == colour
    h = geometry.HALF
    assert pixel(surface, (SIZE - 1, SIZE - 1)) == BACKGROUND  # outside the walls
    assert pixel(surface, viewer.to_screen(0.0, h - 300)) == FLOOR  # between the top zones
    # The outer ring of a zone is tinted, lighter than the zone itself.
    ring = (geometry.ZONE_INNER + geometry.ZONE_OUTER) / 4
    cx, cy = world.zone_centres[0]
    tinted = pixel(surface, viewer.to_screen(cx + ring, cy))
    assert tinted not in (FLOOR, ZONE_RGB[0]) and tinted[0] > tinted[1]


def test_world_y_points_up_on_screen(world: World) -> None:
    viewer = Viewer(world, SIZE)
    h = geometry.HALF
    assert viewer.to_screen(-h, h)[1] < viewer.to_screen(-h, -h)[1]
    assert viewer.to_screen(-h, 0)[0] < viewer.to_screen(h, 0)[0]
    left, top = viewer.to_screen(-h, h)
    right, bottom = viewer.to_screen(h, -h)
    assert 0 < left < right < SIZE and 0 < top < bottom < SIZE


def test_free_targets_are_drawn_in_their_colour_until_picked(world: World) -> None:
    viewer = Viewer(world, SIZE)
    free = world.target_free.copy()
    clear = 3 * world.scenario.robot.body
    lonely = [
        t
        for t in range(len(world.target_colour))
        if (np.hypot(*(world.target_pos - world.target_pos[t]).T) < clear).sum() == 1
        and not (np.hypot(*(world.pos - world.target_pos[t]).T) < clear).any()
    ]
    t = lonely[0]
    at = viewer.to_screen(*world.target_pos[t])
    assert pixel(viewer.draw(), at) == ZONE_RGB[int(world.target_colour[t]) - 1]
    try:
        world.target_free[t] = False
        assert pixel(viewer.draw(), at) == FLOOR
    finally:
        world.target_free[:] = free


def test_status_lights_follow_the_robots_state(world: World) -> None:
    viewer = Viewer(world, SIZE)
    i = lone_robot(world, viewer)
    at = viewer.to_screen(*world.pos[i])
    saved = (world.walk_flag[i], world.querying[i], world.answering[i])
    try:
        world.walk_flag[i], world.querying[i], world.answering[i] = False, False, False
        assert pixel(viewer.draw(), at) == ROBOT  # no light
        world.querying[i] = True
        assert pixel(render(world, SIZE), at) == LIGHT_QUERYING
        world.answering[i] = True
        assert pixel(viewer.draw(), at) == LIGHT_TEACHING
        world.querying[i] = world.answering[i] = False
        world.walk_flag[i] = True
        assert pixel(viewer.draw(), at) == LIGHT_WALKING
    finally:
        world.walk_flag[i], world.querying[i], world.answering[i] = saved


def test_a_carrying_robot_shows_its_target_and_no_walking_light(world: World) -> None:
    viewer = Viewer(world, SIZE)
    i = lone_robot(world, viewer)
    at = viewer.to_screen(*world.pos[i])
    saved = (world.walk_flag[i], world.carrying[i])
    t = int(np.flatnonzero(world.target_colour == 4)[0])
    try:
        world.walk_flag[i], world.carrying[i] = True, t
        surface = viewer.draw()
        assert pixel(surface, at) == ROBOT  # walking, but not at random: no light
        assert pixel(surface, viewer.to_screen(*viewer.carried_at(i))) == ZONE_RGB[3]
    finally:
        world.walk_flag[i], world.carrying[i] = saved


def test_obstacles_are_drawn() -> None:
    world = World(preset("ktbt-obstacles").with_(iterations=100), seed=1)
    viewer = Viewer(world, SIZE)
    surface = viewer.draw()
    x, y = world.walls[160][:2]  # the first obstacle segment, after the perimeter's
    assert pixel(surface, viewer.to_screen(x, y)) == OBSTACLE


def test_counters_report_progress_and_knowledge_levels(world: World) -> None:
    lines = hud_lines(world, "paused")
    assert lines[0] == f"iteration {world.iteration}"
    assert lines[1].startswith(f"collected 0 / {len(world.target_colour)}")
    assert lines[2] == "knows 0..4: 0 40 0 0 0"  # 10 robots of each single colour
    assert lines[-1] == "paused"


def key(k: int, text: str = "") -> pygame.event.Event:
    return pygame.event.Event(pygame.KEYDOWN, key=k, unicode=text)


def test_keys_pause_step_change_speed_and_quit() -> None:
    controls = Controls(steps_per_frame=8)
    assert controls.steps() == 8
    controls.handle(key(pygame.K_SPACE, " "))
    assert controls.paused and controls.steps() == 0
    controls.handle(key(pygame.K_RIGHT))
    controls.handle(key(pygame.K_PERIOD, "."))
    assert controls.steps() == 2 and controls.steps() == 0
    controls.handle(key(pygame.K_EQUALS, "+"))
    controls.handle(key(pygame.K_PLUS, "+"))
    assert controls.steps_per_frame == 32
    for _ in range(10):
        controls.handle(key(pygame.K_MINUS, "-"))
    assert controls.steps_per_frame == 1
    controls.handle(key(pygame.K_SPACE, " "))
    assert not controls.paused and controls.steps() == 1
    controls.handle(key(pygame.K_RIGHT))  # stepping only while paused
    assert controls.single_steps == 0
    assert not controls.quit
    controls.handle(key(pygame.K_q, "q"))
    assert controls.quit
    for event in (key(pygame.K_ESCAPE), pygame.event.Event(pygame.QUIT)):
        other = Controls()
        other.handle(event)
        assert other.quit


def test_run_stops_at_max_iterations() -> None:
    world = World(preset("ktbt").with_(iterations=100), seed=2)
    run(world, steps_per_frame=2, fps=0, max_iterations=5, size=200)
    assert world.iteration == 5


def test_record_gif_has_every_frame(tmp_path: Path) -> None:
    world = World(preset("ktbt").with_(iterations=100), seed=3)
    out = record(world, tmp_path / "trial.gif", frames=3, every=2, size=160)
    assert world.iteration == 4
    with Image.open(out) as gif:
        assert gif.format == "GIF"
        assert gif.size == (160, 160)
        assert getattr(gif, "n_frames", 1) == 3


def test_record_png_frames_into_a_directory(tmp_path: Path) -> None:
    world = World(preset("ktbt").with_(iterations=100), seed=3)
    out = tmp_path / "frames"
    record(world, out, frames=2, every=1, size=160)
    assert sorted(p.name for p in out.iterdir()) == ["frame-0000.png", "frame-0001.png"]
    with Image.open(out / "frame-0001.png") as png:
        assert png.size == (160, 160)
    with pytest.raises(ValueError):
        record(world, out, frames=0, every=1)
