"""Watching a search-and-rescue trial: a top view of the arena drawn with pygame, live in a
window (``run``) or headless into an animated GIF or numbered PNG files (``record``).

The picture follows the paper's figures: four coloured collection zones in the corners, targets
as small squares, robots as discs with a status light on top (magenta while teaching, white
while querying, cyan while walking at random: colours no target or zone has), so knowledge
spreading through the swarm can be seen as it happens. A legend under the counters names them.
Drawing reads the world's arrays and never changes them, so watching a trial does not change
its outcome: the same seed replays the same run with or without a viewer.
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import numpy as np
import pygame

from ktbt_sim import geometry
from ktbt_sim.world import World

RGB = tuple[int, int, int]

ZONE_RGB: tuple[RGB, RGB, RGB, RGB] = (
    (215, 40, 40),
    (30, 160, 70),
    (235, 195, 20),
    (40, 90, 215),
)
"""Colours 1..4 (red, green, yellow, blue): zones, targets and carried targets."""

BACKGROUND: RGB = (24, 26, 32)
"""Outside the walls, so the arena's edge is plain at any window size."""
FLOOR: RGB = (236, 236, 228)
WALL: RGB = (70, 70, 78)
OBSTACLE: RGB = (120, 120, 128)
ROBOT: RGB = (45, 45, 55)
TICK: RGB = (0, 0, 0)
TEXT: RGB = (20, 20, 24)

LIGHT_TEACHING: RGB = (235, 0, 235)
LIGHT_QUERYING: RGB = (255, 255, 255)
LIGHT_WALKING: RGB = (0, 225, 225)
"""The paper's status lights, in colours no zone or target has (the paper's red and blue lights
read as red and blue targets), each bright on the dark robot body."""

LEGEND: tuple[tuple[RGB, str], ...] = (
    (LIGHT_TEACHING, "teaching"),
    (LIGHT_QUERYING, "asking"),
    (LIGHT_WALKING, "searching"),
)
"""The status lights, named under the counters."""

ZONE_TINT = 0.25
"""How much of the zone's colour the outer square takes: enough to show where a zone begins
without hiding what lies in it."""

DEFAULT_SIZE = 800
MAX_STEPS_PER_FRAME = 4096
KEYS_HELP = "space pause · →/. step · +/- speed · q quit"

_headless_env = {"set": False}
"""Whether this module chose the dummy video driver, so ``run`` can take it back for a real
window when the same process rendered headless first."""


def _headless() -> None:
    """Choose SDL's dummy video driver unless the user chose one: recording needs no window and
    must work on a machine without a display."""
    if "SDL_VIDEODRIVER" not in os.environ:
        os.environ["SDL_VIDEODRIVER"] = "dummy"
        _headless_env["set"] = True


def _windowed() -> None:
    """Undo ``_headless`` before a window opens, or the window would be invisible."""
    if _headless_env["set"] and not pygame.display.get_init():
        os.environ.pop("SDL_VIDEODRIVER", None)
        _headless_env["set"] = False


def _blend(colour: RGB, base: RGB, amount: float) -> RGB:
    r, g, b = (round(base[k] + (colour[k] - base[k]) * amount) for k in range(3))
    return (r, g, b)


def light_colour(world: World, i: int) -> RGB | None:
    """Robot ``i``'s status light, or None when it is off. TeachingRule wins over querying (a robot
    does not do both, but the picture must be decided), and the walking light marks only a robot
    searching with empty hands, as in the paper."""
    if world.answering[i]:
        return LIGHT_TEACHING
    if world.querying[i]:
        return LIGHT_QUERYING
    if world.walk_flag[i] and world.carrying[i] < 0:
        return LIGHT_WALKING
    return None


def hud_lines(world: World, status: str = "") -> list[str]:
    """The live counters: progress of the trial and how far knowledge has spread (robots that
    know 0, 1, .. 4 colours), the numbers the paper's plots follow over time."""
    levels = np.bincount(world.known.sum(axis=1), minlength=5)
    per_colour = " ".join(f"{c[0]}{int(n)}" for c, n in zip("rgyb", world.collected, strict=True))
    lines = [
        f"iteration {world.iteration}",
        f"collected {int(world.collected.sum())} / {len(world.target_colour)}  ({per_colour})",
        "knows 0..4: " + " ".join(str(int(n)) for n in levels[:5]),
    ]
    if status:
        lines.append(status)
    return lines


class Viewer:
    """Draws one world into a square picture. The mapping from world to screen is fixed by the
    arena at construction, so a frame's pixels can be located from world coordinates (tests and
    overlays rely on ``to_screen``)."""

    def __init__(self, world: World, size: int = DEFAULT_SIZE) -> None:
        if size < 64:
            raise ValueError(f"size must be at least 64 pixels, not {size}")
        self.world = world
        self.size = size
        self.half = geometry.HALF * world.scale
        self.margin = max(4, size // 80)
        self.scale = (size - 2 * self.margin) / (2 * self.half)
        """Pixels per world unit."""
        pygame.font.init()
        self.font = pygame.font.Font(None, max(12, size // 44))

    def to_screen(self, x: float, y: float) -> tuple[int, int]:
        """The pixel showing world point (x, y): world y points up, screen y down."""
        sx, sy = self._to_screen(x, y)
        return (math.floor(sx), math.floor(sy))

    def _to_screen(self, x: float, y: float) -> tuple[float, float]:
        return (
            self.margin + (x + self.half) * self.scale,
            self.margin + (self.half - y) * self.scale,
        )

    def _rect(self, x0: float, y0: float, x1: float, y1: float) -> pygame.Rect:
        """The screen rectangle of a world box, rounded outwards so thin boxes stay visible."""
        left, top = self._to_screen(x0, y1)
        right, bottom = self._to_screen(x1, y0)
        ix, iy = math.floor(left), math.floor(top)
        return pygame.Rect(ix, iy, max(1, math.ceil(right) - ix), max(1, math.ceil(bottom) - iy))

    def _square(self, x: float, y: float, side: float) -> pygame.Rect:
        return self._rect(x - side / 2, y - side / 2, x + side / 2, y + side / 2)

    @property
    def robot_radius(self) -> int:
        """Body radius in pixels. Drawn to scale a robot is 3 pixels wide in an 800-pixel
        window, too small to read its light or heading; so at least 1/100 of the window."""
        return max(3, self.size // 100, round(self.world.scenario.robot.body / 2 * self.scale))

    @property
    def light_radius(self) -> int:
        return max(2, round(self.robot_radius / 2))

    def draw(self, surface: pygame.Surface | None = None, status: str = "") -> pygame.Surface:
        """Draw the current state onto ``surface`` (a new display-free one by default)."""
        if surface is None:
            surface = pygame.Surface((self.size, self.size))
        surface.fill(BACKGROUND)
        self._arena(surface)
        self._zones(surface)
        self._obstacles(surface)
        self._targets(surface)
        self._robots(surface)
        self._hud(surface, status)
        return surface

    def _arena(self, surface: pygame.Surface) -> None:
        h = self.half
        floor = self._rect(-h, -h, h, h)
        surface.fill(FLOOR, floor)
        pygame.draw.rect(surface, WALL, floor, width=max(2, round(10 * self.scale)))

    def _zones(self, surface: pygame.Surface) -> None:
        outer = geometry.ZONE_OUTER * self.world.scale
        inner = geometry.ZONE_INNER * self.world.scale
        for colour, (cx, cy) in zip(ZONE_RGB, self.world.zone_centres, strict=True):
            x, y = float(cx), float(cy)
            surface.fill(_blend(colour, FLOOR, ZONE_TINT), self._square(x, y, outer))
            surface.fill(colour, self._square(x, y, inner))

    def _obstacles(self, surface: pygame.Surface) -> None:
        for corners in self.world.obstacles:
            points = [self.to_screen(x, y) for x, y in corners]
            pygame.draw.polygon(surface, OBSTACLE, points)

    def _targets(self, surface: pygame.Surface) -> None:
        world = self.world
        side = self.target_side
        for t in np.flatnonzero(world.target_free).tolist():
            x, y = world.target_pos[t]
            colour = ZONE_RGB[int(world.target_colour[t]) - 1]
            surface.fill(colour, self._square(float(x), float(y), side))

    @property
    def target_side(self) -> float:
        """Side of a target's square in world units, at least 3 pixels so a target stays visible
        in a small window."""
        return max(3 / self.scale, geometry.TARGET_SIZE)

    def carried_at(self, i: int) -> tuple[float, float]:
        """World point where robot ``i``'s carried target is drawn: just ahead of the body, as
        if held in front, so its colour is never mistaken for the status light on top."""
        world = self.world
        reach = self.robot_radius / self.scale + self.target_side / 2
        a = float(world.heading[i])
        return (
            float(world.pos[i, 0]) + reach * math.cos(a),
            float(world.pos[i, 1]) + reach * math.sin(a),
        )

    def _robots(self, surface: pygame.Surface) -> None:
        """Bodies first, lights last: where robots crowd, every light stays visible. The heading
        tick starts off the centre, which belongs to the light; a carried target covers the tick,
        showing the heading itself."""
        world = self.world
        r = self.robot_radius
        tick = 1.6 * r
        centres: list[tuple[int, int]] = []
        for i in range(world.n):
            centre = self.to_screen(float(world.pos[i, 0]), float(world.pos[i, 1]))
            centres.append(centre)
            pygame.draw.circle(surface, ROBOT, centre, r)
            dx, dy = math.cos(float(world.heading[i])), -math.sin(float(world.heading[i]))
            start = (round(centre[0] + 0.6 * r * dx), round(centre[1] + 0.6 * r * dy))
            end = (round(centre[0] + tick * dx), round(centre[1] + tick * dy))
            pygame.draw.line(surface, TICK, start, end, max(1, r // 3))
            t = int(world.carrying[i])
            if t >= 0:
                colour = ZONE_RGB[int(world.target_colour[t]) - 1]
                surface.fill(colour, self._square(*self.carried_at(i), self.target_side))
        lr = self.light_radius
        for i, centre in enumerate(centres):
            light = light_colour(world, i)
            if light is not None:
                pygame.draw.circle(surface, light, centre, lr)

    def _hud(self, surface: pygame.Surface, status: str) -> None:
        """Counters, then a one-line legend of the status lights, on a translucent panel in the
        top-left corner (above the red zone's centre), so robots passing under it stay
        visible."""
        lines = [self.font.render(text, True, TEXT) for text in hud_lines(self.world, status)]
        step = self.font.get_linesize()
        swatch = max(3, step // 2 - 1)
        gap = max(3, step // 3)
        legend = [self.font.render(text, True, TEXT) for _, text in LEGEND]
        row = sum(2 * swatch + gap + label.get_width() + 2 * gap for label in legend)
        pad = max(2, self.size // 200)
        width = max(row, *(line.get_width() for line in lines))
        panel = pygame.Surface(
            (width + 2 * pad, step * (len(lines) + 1) + 2 * pad), pygame.SRCALPHA
        )
        panel.fill((255, 255, 255, 190))
        for k, line in enumerate(lines):
            panel.blit(line, (pad, pad + k * step))
        x, top = pad, pad + len(lines) * step
        for (colour, _), label in zip(LEGEND, legend, strict=True):
            centre = (x + swatch, top + step // 2)
            pygame.draw.circle(panel, ROBOT, centre, swatch)
            pygame.draw.circle(panel, colour, centre, max(2, swatch * 2 // 3))
            x += 2 * swatch + gap
            panel.blit(label, (x, top))
            x += label.get_width() + 2 * gap
        corner = self.margin + pad
        surface.blit(panel, (corner, corner))


def no_display() -> str | None:
    """Why no window can be shown here, or None. A driver the user chose (``SDL_VIDEODRIVER``)
    is respected; otherwise a Linux or BSD machine without X11 or Wayland has no display, and
    SDL would quietly draw into nothing."""
    if os.environ.get("SDL_VIDEODRIVER") and not _headless_env["set"]:
        return None
    if sys.platform in ("darwin", "win32", "cygwin"):
        return None
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return None
    return "no display to open a window on (DISPLAY and WAYLAND_DISPLAY are not set)"


def render(world: World, size: int = DEFAULT_SIZE) -> pygame.Surface:
    """One frame of ``world`` as a Surface, without opening a window (for pictures and tests)."""
    _headless()
    return Viewer(world, size).draw()


@dataclass
class Controls:
    """The keyboard state of ``run``, apart from the window so it can be driven by plain events.

    Speed doubles and halves rather than stepping by one: a trial runs for tens of thousands of
    iterations, and a few key presses must reach any useful pace."""

    steps_per_frame: int = 10
    paused: bool = False
    quit: bool = False
    single_steps: int = 0
    """Steps asked for one at a time while paused, not yet taken."""

    def handle(self, event: pygame.event.Event) -> None:
        if event.type == pygame.QUIT:
            self.quit = True
        if event.type != pygame.KEYDOWN:
            return
        key, text = event.key, getattr(event, "unicode", "")
        if key in (pygame.K_q, pygame.K_ESCAPE):
            self.quit = True
        elif key == pygame.K_SPACE:
            self.paused = not self.paused
        elif key in (pygame.K_RIGHT, pygame.K_PERIOD, pygame.K_KP_PERIOD) or text == ".":
            if self.paused:
                self.single_steps += 1
        elif key in (pygame.K_PLUS, pygame.K_EQUALS, pygame.K_KP_PLUS) or text == "+":
            self.steps_per_frame = min(MAX_STEPS_PER_FRAME, self.steps_per_frame * 2)
        elif key in (pygame.K_MINUS, pygame.K_KP_MINUS) or text == "-":
            self.steps_per_frame = max(1, self.steps_per_frame // 2)

    def steps(self) -> int:
        """Iterations to take before the next frame; consumes the single steps asked for."""
        if not self.paused:
            return self.steps_per_frame
        steps, self.single_steps = self.single_steps, 0
        return steps

    def status(self) -> str:
        return "paused" if self.paused else f"{self.steps_per_frame} steps/frame"


def run(
    world: World,
    *,
    steps_per_frame: int = 10,
    fps: int = 30,
    max_iterations: int | None = None,
    size: int = DEFAULT_SIZE,
) -> None:
    """Watch ``world`` in a window until the user quits or, when ``max_iterations`` is given, the
    world reaches that iteration. Keys: space pause/resume, right arrow or ``.`` one step while
    paused, ``+``/``=`` faster, ``-`` slower, ``q``/Escape quit. ``fps`` 0: as fast as drawing
    allows."""
    if steps_per_frame < 1:
        raise ValueError(f"steps_per_frame must be at least 1, not {steps_per_frame}")
    _windowed()
    chosen = os.environ.get("SDL_VIDEODRIVER")
    pygame.display.init()
    try:
        screen = pygame.display.set_mode((size, size))
        driver = pygame.display.get_driver()
        if driver in ("dummy", "offscreen") and not chosen:
            raise RuntimeError(
                f"no window can be shown here (SDL fell back to its {driver} driver); "
                "record the run instead: --record run.gif"
            )
        pygame.display.set_caption(f"KT-BT {world.scenario.name}: {KEYS_HELP}")
        viewer = Viewer(world, size)
        controls = Controls(steps_per_frame=steps_per_frame)
        clock = pygame.time.Clock()
        while not controls.quit:
            for event in pygame.event.get():
                controls.handle(event)
            steps = controls.steps()
            if max_iterations is not None:
                steps = min(steps, max(0, max_iterations - world.iteration))
            for _ in range(steps):
                world.step()
            viewer.draw(screen, controls.status())
            pygame.display.flip()
            if max_iterations is not None and world.iteration >= max_iterations:
                break
            clock.tick(fps)
    finally:
        pygame.display.quit()


def record(
    world: World,
    out: Path,
    *,
    frames: int,
    every: int,
    size: int = DEFAULT_SIZE,
    fps: float = 15.0,
) -> Path:
    """Render ``frames`` frames headless, the first of the world as it is and ``every``
    iterations between two frames, into an animated GIF when ``out`` ends in ``.gif`` (played at
    ``fps``), else into ``out/frame-0000.png``, ... Returns ``out``.

    ``every`` must be positive: Pillow merges identical consecutive GIF frames, so a GIF of an
    unmoving world would have fewer frames than asked for."""
    if frames < 1:
        raise ValueError(f"frames must be at least 1, not {frames}")
    if every < 1:
        raise ValueError(f"every must be at least 1, not {every}")
    out = Path(out)
    gif = out.suffix.lower() == ".gif"
    if gif:
        try:
            from PIL import Image
        except ImportError as exc:  # pragma: no cover - Pillow comes with matplotlib
            raise RuntimeError("writing a GIF needs Pillow (pip install pillow)") from exc
        out.parent.mkdir(parents=True, exist_ok=True)
    else:
        out.mkdir(parents=True, exist_ok=True)
    _headless()
    viewer = Viewer(world, size)
    surface = pygame.Surface((size, size))
    images: list[Image.Image] = []
    for k in range(frames):
        if k:
            for _ in range(every):
                world.step()
        viewer.draw(surface)
        if gif:
            data = pygame.image.tobytes(surface, "RGB")
            images.append(Image.frombytes("RGB", (size, size), data))
        else:
            pygame.image.save(surface, str(out / f"frame-{k:04d}.png"))
    if gif:
        images[0].save(
            out,
            save_all=True,
            append_images=images[1:],
            duration=round(1000 / fps),
            loop=0,
        )
    return out
