"""Scenarios of the search-and-rescue simulator: pydantic models, TOML/JSON files, the paper's
presets.

Units: lengths in world units (the release's arena is 8000 by 8000), speeds per second, time in
iterations of ``dt`` seconds (0.01 s, as in the release). Where the paper is silent, defaults are
the values read off the authors' release.
"""

from __future__ import annotations

import json
import tomllib
from enum import StrEnum
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

COLOURS = ("red", "green", "yellow", "blue")
"""Target colours in the release's order (colour 1 to 4)."""


class Mode(StrEnum):
    NO_TRANSFER = "no-transfer"
    KT_BT = "kt-bt"


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Robots(_Model):
    """How many robots of each type: the paper's (I, M, R, G, Y, B) combination."""

    ignorant: int = Field(default=0, ge=0, description="I: knows no colour")
    multi: int = Field(default=0, ge=0, description="M: knows every colour")
    red: int = Field(default=0, ge=0)
    green: int = Field(default=0, ge=0)
    yellow: int = Field(default=0, ge=0)
    blue: int = Field(default=0, ge=0)

    @property
    def total(self) -> int:
        return self.ignorant + self.multi + self.red + self.green + self.yellow + self.blue

    @classmethod
    def of(cls, i: int, m: int, r: int, g: int, y: int, b: int) -> Robots:
        return cls(ignorant=i, multi=m, red=r, green=g, yellow=y, blue=b)

    def label(self) -> str:
        """The paper's notation, e.g. ``39I-1M`` or ``10R-10G-10Y-10B``."""
        parts = zip(
            (self.ignorant, self.multi, self.red, self.green, self.yellow, self.blue),
            "IMRGYB",
            strict=True,
        )
        return "-".join(f"{n}{t}" for n, t in parts if n)


class Targets(_Model):
    """Targets of each colour, scattered uniformly over the spawn area."""

    red: int = Field(default=25, ge=0)
    green: int = Field(default=25, ge=0)
    yellow: int = Field(default=25, ge=0)
    blue: int = Field(default=25, ge=0)

    @property
    def total(self) -> int:
        return self.red + self.green + self.yellow + self.blue

    @classmethod
    def each(cls, n: int) -> Targets:
        return cls(red=n, green=n, yellow=n, blue=n)


class Arena(_Model):
    half_size: float = Field(default=4000.0, gt=0, description="walls at x, y = ±half_size")
    spawn_half: float = Field(default=2000.0, gt=0, description="robots and targets spawn here")
    zone_centre: float = Field(default=2800.0, gt=0, description="zones centred at (±c, ±c)")
    zone_outer: float = Field(default=1000.0, gt=0)
    zone_inner: float = Field(default=800.0, gt=0)
    obstacles: bool = Field(default=False, description="the release's 47 wall blocks")

    @model_validator(mode="after")
    def _fits(self) -> Arena:
        if self.spawn_half >= self.half_size or self.zone_centre + self.zone_outer / 2 > (
            self.half_size
        ):
            raise ValueError("spawn area and zones must lie inside the walls")
        if self.zone_inner > self.zone_outer:
            raise ValueError("zone_inner must not exceed zone_outer")
        return self


class RobotSpec(_Model):
    body: float = Field(default=66.0, gt=0)
    max_speed: float = Field(default=300.0, gt=0, description="units per second")
    max_turn_deg: float = Field(default=200.0, gt=0, description="degrees per second")
    heading_tolerance_deg: float = Field(default=5.0, ge=0, description="drives only when aligned")
    target_sensor: float = Field(default=60.0, gt=0)
    collision_sensor: float = Field(default=75.0, gt=0)
    zone_sensor: float = Field(default=90.0, gt=0)


class Timing(_Model):
    dt: float = Field(default=0.01, gt=0, description="seconds of simulated time per iteration")
    wait_ticks: int = Field(default=1000, ge=0, description="stopped after a query or a teach")
    cooldown_ticks: int = Field(default=1000, ge=0, description="no sensing, asking or teaching")
    walk_goal_min_s: float = Field(
        default=1.0, gt=0, description="random walk: a new goal point every U(min, max) s"
    )
    walk_goal_max_s: float = Field(default=5.0, gt=0)
    repeat_every: int = Field(
        default=10,
        ge=0,
        description="a waiting learner repeats its query this often, so a knower that comes"
        " into range during the wait can teach it (the release's rule); 0: ask once",
    )


class Scenario(_Model):
    """One configuration of the simulator; a study runs it for ``trials`` seeds."""

    name: str = "custom"
    mode: Mode = Mode.KT_BT
    robots: Robots = Robots.of(0, 0, 10, 10, 10, 10)
    targets: Targets = Targets()
    comm_range: float = Field(default=200.0, ge=0, description="who can hear whom, in units")
    iterations: int = Field(default=50_000, gt=0)
    trials: int = Field(default=20, gt=0)
    record_every: int = Field(default=10, gt=0, description="iterations between two metric rows")
    seed: int = Field(default=0, ge=0, description="root seed of all trials")
    arena: Arena = Arena()
    robot: RobotSpec = RobotSpec()
    timing: Timing = Timing()

    @model_validator(mode="after")
    def _sane(self) -> Scenario:
        if self.robots.total == 0:
            raise ValueError("a scenario needs at least one robot")
        if self.robots.total > 10_000:
            raise ValueError("at most 10,000 robots")
        return self

    def with_(self, **changes: Any) -> Scenario:
        """A copy with some fields changed, validated again (ValueError with one line)."""
        try:
            return Scenario.model_validate({**self.model_dump(), **changes})
        except ValidationError as exc:
            raise ValueError(_one_line(exc)) from None

    @classmethod
    def load(cls, path: str | Path) -> Scenario:
        """Read a TOML or JSON scenario file; raises ValueError with a one-line reason."""
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
            data = tomllib.loads(text) if path.suffix == ".toml" else json.loads(text)
            return cls.model_validate(data)
        except (OSError, UnicodeDecodeError, ValueError, tomllib.TOMLDecodeError) as exc:
            if isinstance(exc, ValidationError):
                raise ValueError(f"{path}: {_one_line(exc)}") from None
            raise ValueError(f"{path}: {exc}") from None

    def dump(self) -> str:
        return self.model_dump_json(indent=2)


def _one_line(exc: ValidationError) -> str:
    first = exc.errors()[0]
    where = ".".join(str(p) for p in first["loc"]) or "scenario"
    return f"{where}: {first['msg']}"


def _study_1() -> dict[str, Scenario]:
    """No transfer vs KT-BT (paper Table III), with and without obstacles."""
    out: dict[str, Scenario] = {}
    groups = {
        "bl1": (Mode.NO_TRANSFER, Robots.of(0, 40, 0, 0, 0, 0)),
        "bl2": (Mode.NO_TRANSFER, Robots.of(0, 0, 10, 10, 10, 10)),
        "ktbt": (Mode.KT_BT, Robots.of(0, 0, 10, 10, 10, 10)),
    }
    for key, (mode, robots) in groups.items():
        for obstacles in (False, True):
            name = f"{key}{'-obstacles' if obstacles else ''}"
            out[name] = Scenario(
                name=name, mode=mode, robots=robots, arena=Arena(obstacles=obstacles)
            )
    return out


def _study_2() -> dict[str, Scenario]:
    """Opportunities (Table IV): 39 ignorant + 1 multi-target robot, 10 to 100 per colour."""
    robots = Robots.of(39, 1, 0, 0, 0, 0)
    return {
        f"opportunities-{n}": Scenario(
            name=f"opportunities-{n}", robots=robots, targets=Targets.each(n)
        )
        for n in (10, 25, 50, 100)
    }


def _study_3() -> dict[str, Scenario]:
    """Communication range (Table V): the same group, 25 per colour, ranges 100 to 1000."""
    robots = Robots.of(39, 1, 0, 0, 0, 0)
    return {
        f"range-{r}": Scenario(name=f"range-{r}", robots=robots, comm_range=float(r))
        for r in (100, 200, 500, 800, 1000)
    }


def _heterogeneity() -> dict[str, Scenario]:
    """Heterogeneity: 39I-1M and 10RGYB with 100 targets per colour."""
    return {
        "heterogeneity-39i1m": Scenario(
            name="heterogeneity-39i1m",
            robots=Robots.of(39, 1, 0, 0, 0, 0),
            targets=Targets.each(100),
        ),
        "heterogeneity-10rgyb": Scenario(
            name="heterogeneity-10rgyb",
            robots=Robots.of(0, 0, 10, 10, 10, 10),
            targets=Targets.each(100),
        ),
    }


PRESETS: dict[str, Scenario] = {**_study_1(), **_study_2(), **_study_3(), **_heterogeneity()}
"""Every configuration of the paper's tables, by name."""


def preset(name: str) -> Scenario:
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"no preset {name!r}; presets: {', '.join(sorted(PRESETS))}") from None
