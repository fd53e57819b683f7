"""Scenarios of the search-and-rescue simulator: pydantic models, TOML/JSON files, the paper's
presets.

Units: lengths in world units (the release's arena is 8000 by 8000), speeds per second, time in
iterations of ``dt`` seconds. A scenario keeps the paper's numbers (communication range 100 to
1000, iterations, targets) and names the physical values they stand for in the release
(``comm_radius``, ``seconds``). Every default is the release's, with its section of
``spec/simulator.md``.
"""

from __future__ import annotations

import json
import tomllib
from enum import StrEnum
from pathlib import Path
from typing import Any, NamedTuple

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

COLOURS = ("red", "green", "yellow", "blue")
"""Target colours in the release's order (colour 1 to 4)."""


class Mode(StrEnum):
    NO_TRANSFER = "no-transfer"
    """The release's NL: no queries, no teaching (§9.2)."""
    KT_BT = "kt-bt"
    """The release's RL: query, answer, merge (§8)."""
    EPHEMERAL = "el"
    """The release's EL: RL whose learned knowledge is forgotten after ``memory_duration``
    random-walk ticks without a pick-up or a lesson, and whose ``memory_size`` caps lessons
    (§9.3)."""
    PASSIVE_BUFFER = "plb"
    """The release's PLB: RL that also keeps the answers it overhears and uses one, without
    asking, when it meets its condition (§9.4, §9.5)."""
    PASSIVE = "pl"
    """The release's PL: RL that also learns every answer it overhears at once (§9.4, §9.6)."""


class TeachingRule(StrEnum):
    """Who answers a query (§8.2)."""

    RELEASE = "release"
    """Each free knower considers only its first untaught querying neighbour (in order of
    entry into range) and answers nobody if it cannot answer that one: the release's rule."""
    BROADCAST = "broadcast"
    """Any free knower in range answers the first untaught querying neighbour whose question
    it can answer: the rule of a broadcast protocol, and ours before the release was read."""


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
    """The release's arena (§2): walls at ±4000, zones at the corners (zone 4 at x = 2812),
    robots and targets spawned in [-2000, 2000]². Only the obstacle flag is a choice."""

    obstacles: bool = Field(default=False, description="the release's 47 wall segments")
    scale: float = Field(
        default=1.0,
        ge=1.0,
        description="every length of the arena (walls, zones, spawn square, obstacle centres)"
        " times this; 1 is the release's arena. For groups larger than the paper's 40 robots"
        " at the same density (benchmarks)",
    )


class RobotSpec(_Model):
    body: float = Field(default=66.0, gt=0, description="the body box's side (§2)")
    contact_radius: float = Field(
        default=36.0,
        gt=0,
        description="the body as a disc for contacts, the collision sensor and the comms range"
        " (the release's body is a 66 x 66 box: 33 to 47 from its centre; spec section 12)",
    )
    max_speed: float = Field(default=300.0, gt=0, description="units per second (§4.1)")
    max_turn_deg: float = Field(default=200.0, gt=0, description="degrees per second (§4.1)")
    heading_tolerance_deg: float = Field(
        default=5.0, ge=0, description="drives only when the heading error is below this (§4.1)"
    )
    target_sensor: float = Field(default=60.0, gt=0, description="sphere radius (§2, §5.1)")
    collision_sensor: float = Field(default=75.0, gt=0, description="sphere radius (§4.6)")
    zone_sensor: float = Field(default=90.0, gt=0, description="sphere radius (§4.5)")
    avoid_turn_deg: tuple[int, int] = Field(
        default=(70, 79), description="avoidance turns Σ(self - other) by U{a..b} degrees (§4.6)"
    )
    carry_jitter_deg: tuple[int, int] = Field(
        default=(-5, 4), description="a carrier's aim turns by U{a..b} degrees a tick (§4.4)"
    )


class Timing(_Model):
    dt: float = Field(default=0.02, gt=0, description="seconds per iteration (§1)")
    wait_limit: int = Field(default=1000, ge=0, description="waitLimit (§7)")
    cooldown_limit: int = Field(default=1000, ge=0, description="coolDownLimit (§7)")
    walk_first_max_s: float = Field(
        default=5.0, ge=0, description="the first random-walk leg lasts U(0, this) s (§4.2)"
    )
    walk_goal_min_s: float = Field(
        default=1.0, ge=0, description="later legs last U(min, max) s of random walking (§4.2)"
    )
    walk_goal_max_s: float = Field(default=5.0, gt=0)
    walk_goal_span: int = Field(
        default=10_000, gt=0, description="goals are integer points in [-span, span - 1]² (§4.2)"
    )


class Scenario(_Model):
    """One configuration of the simulator; a study runs it for ``trials`` seeds."""

    name: str = "custom"
    mode: Mode = Mode.KT_BT
    robots: Robots = Robots.of(0, 0, 10, 10, 10, 10)
    targets: Targets = Targets()
    comm_range: float = Field(
        default=200.0,
        ge=0,
        description="the paper's and the launcher's range (100 to 1000); the radius in units is"
        " comm_radius (§5.3)",
    )
    teaching: TeachingRule = Field(default=TeachingRule.RELEASE, description="who answers (§8.2)")
    memory_duration: int | None = Field(
        default=None,
        ge=1,
        description="EL: random-walk ticks without a pick-up or a lesson after which"
        " everything learned is forgotten (§9.3); None: never",
    )
    memory_when_full: str = Field(
        default="refuse",
        pattern="^(refuse|evict)$",
        description="a learner at memory_size: refuse the lesson (the release) or evict its"
        " least recently used learned colour (our library's alternative)",
    )
    overhear_window: str = Field(
        default="wait",
        pattern="^(wait|answer)$",
        description="PLB and PL: a teacher is overheard for its whole teaching wait (the"
        " release) or only by the robots in range when it answers (our variant, a radio's)",
    )
    memory_size: int = Field(
        default=4, ge=0, description="a learner with this many known colours is not taught (§8.2)"
    )
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

    @property
    def comm_radius(self) -> float:
        """The communication radius in units, measured from a robot's centre to the other's
        body: the release sets its comms sphere's local radius to the range on a robot scaled
        by 3 (§5.3)."""
        return 3.0 * self.comm_range + self.robot.contact_radius

    @property
    def seconds(self) -> float:
        """Simulated seconds of the whole run."""
        return self.iterations * self.timing.dt

    def derived(self) -> dict[str, float]:
        """The physical values the scenario's numbers stand for (``ktbt sim scenario``)."""
        t = self.timing
        checks = 2  # RegLearnBT and TeachBT each advance the counters once per iteration (§7)
        return {
            "seconds_per_iteration": t.dt,
            "simulated_seconds": self.seconds,
            "comm_radius_units": self.comm_radius,
            "speed_units_per_iteration": self.robot.max_speed * t.dt,
            "turn_deg_per_iteration": self.robot.max_turn_deg * t.dt,
            "wait_iterations": (t.wait_limit + 2) // checks,
            "cooldown_iterations": t.cooldown_limit // checks,
        }

    def with_(self, **changes: Any) -> Scenario:
        """A copy with some fields changed, validated again (ValueError with one line)."""
        try:
            return Scenario.model_validate({**self.model_dump(), **changes})
        except ValidationError as exc:
            raise ValueError(_one_line(exc)) from None

    @classmethod
    def load(cls, path: str | Path) -> Scenario:
        """A TOML or JSON scenario file (the one loader). A ValueError names every problem in
        it, on one line, so that one run of the command is enough to fix the file."""
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
            data = tomllib.loads(text) if path.suffix == ".toml" else json.loads(text)
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            raise ValueError(f"{path}: {reason}") from None
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            problems = [
                f"{'.'.join(str(p) for p in e['loc']) or 'scenario'}: {e['msg']}"
                for e in exc.errors()
            ]
            count = f"{len(problems)} problems: " if len(problems) > 1 else ""
            raise ValueError(f"{path}: {count}{'; '.join(problems)}") from None

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


LONG_RUN = 100_000
"""The heterogeneity and opportunities presets' length: the paper's heterogeneity figures run
well past 50,000 iterations (its 39I-1M curve stagnates "beyond 70k"), and with 50 or 100
targets a colour collection has not ended by 50,000. Their tables report 50,000 beside the end."""


def _study_2() -> dict[str, Scenario]:
    """Opportunities (Table IV): 39 ignorant + 1 multi-target robot, 10 to 100 per colour, run
    until collection ends (``LONG_RUN``)."""
    robots = Robots.of(39, 1, 0, 0, 0, 0)
    return {
        f"opportunities-{n}": Scenario(
            name=f"opportunities-{n}", robots=robots, targets=Targets.each(n), iterations=LONG_RUN
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
    """Heterogeneity: 39I-1M and 10RGYB with 100 targets per colour, at the paper's length."""
    return {
        "heterogeneity-39i1m": Scenario(
            name="heterogeneity-39i1m",
            robots=Robots.of(39, 1, 0, 0, 0, 0),
            targets=Targets.each(100),
            iterations=LONG_RUN,
        ),
        "heterogeneity-10rgyb": Scenario(
            name="heterogeneity-10rgyb",
            robots=Robots.of(0, 0, 10, 10, 10, 10),
            targets=Targets.each(100),
            iterations=LONG_RUN,
        ),
    }


def _calibration() -> dict[str, Scenario]:
    """The release's two published runs (its public `SimData` folders), at their size."""
    rgyb = Robots.of(0, 0, 10, 10, 10, 10)
    return {
        "calibration-nl": Scenario(
            name="calibration-nl",
            mode=Mode.NO_TRANSFER,
            robots=rgyb,
            targets=Targets(red=45, green=18, yellow=19, blue=18),
            iterations=100_000,
        ),
        "calibration-rl": Scenario(
            name="calibration-rl", robots=rgyb, targets=Targets.each(100), iterations=100_000
        ),
    }


def _teaching() -> dict[str, Scenario]:
    """Our finding, not the paper's: the broadcast teaching rule beside the release's."""
    return {
        "ktbt-broadcast": Scenario(name="ktbt-broadcast", teaching=TeachingRule.BROADCAST),
        "heterogeneity-39i1m-broadcast": Scenario(
            name="heterogeneity-39i1m-broadcast",
            robots=Robots.of(39, 1, 0, 0, 0, 0),
            targets=Targets.each(100),
            teaching=TeachingRule.BROADCAST,
            iterations=LONG_RUN,
        ),
    }


MODE_GROUPS = {"10rgyb": Robots.of(0, 0, 10, 10, 10, 10), "39i1m": Robots.of(39, 1, 0, 0, 0, 0)}
"""The two groups the modes study compares, 25 targets a colour each."""


class Variant(NamedTuple):
    """One entry of the modes study: what it changes in a scenario, and its label."""

    label: str
    changes: dict[str, Any]


MODE_VARIANTS: dict[str, Variant] = {
    "nl": Variant("NL: no transfer", {"mode": Mode.NO_TRANSFER}),
    "rl": Variant("RL: KT-BT", {"mode": Mode.KT_BT}),
    "el": Variant(
        "EL: ephemeral (3 colours, 5,000 idle ticks)",
        {"mode": Mode.EPHEMERAL, "memory_duration": 5_000, "memory_size": 3},
    ),
    "el-evict": Variant(
        "EL, evicting the least used",
        {
            "mode": Mode.EPHEMERAL,
            "memory_duration": 5_000,
            "memory_size": 3,
            "memory_when_full": "evict",
        },
    ),
    "plb": Variant("PLB: overheard, buffered", {"mode": Mode.PASSIVE_BUFFER}),
    "pl": Variant("PL: overheard, learned at once", {"mode": Mode.PASSIVE}),
    "pl-answer": Variant(
        "PL, heard only at the answer", {"mode": Mode.PASSIVE, "overhear_window": "answer"}
    ),
}
"""The release's five modes (EL with a memory of 3 colours forgotten after 5,000 idle
random-walk ticks), our eviction variant of EL, and our eavesdropping variant of PL (only the
robots in range at the moment of an answer hear it): the one list of the modes study."""


def _modes() -> dict[str, Scenario]:
    """The release's hidden modes (§9) and the release's own EL configurations."""
    out = {
        f"modes-{group}-{variant}": Scenario(
            name=f"modes-{group}-{variant}", robots=robots, **changes
        )
        for group, robots in MODE_GROUPS.items()
        for variant, (_, changes) in MODE_VARIANTS.items()
    }
    out["el-25i-25m"] = Scenario(
        name="el-25i-25m",
        mode=Mode.EPHEMERAL,
        robots=Robots.of(25, 25, 0, 0, 0, 0),
        memory_duration=20_000,
        memory_size=2,
        iterations=20_000,
    )
    out["el-1i-1m-12rgyb"] = Scenario(
        name="el-1i-1m-12rgyb",
        mode=Mode.EPHEMERAL,
        robots=Robots.of(1, 1, 12, 12, 12, 12),
        memory_duration=20_000,
        memory_size=3,
        iterations=20_000,
    )
    return out


PRESETS: dict[str, Scenario] = {
    **_study_1(),
    **_study_2(),
    **_study_3(),
    **_heterogeneity(),
    **_calibration(),
    **_teaching(),
    **_modes(),
}
"""Every configuration of the paper's tables, by name."""


STUDIES: dict[str, tuple[str, ...]] = {
    "transfer": ("bl1", "bl2", "ktbt", "bl1-obstacles", "bl2-obstacles", "ktbt-obstacles"),
    "opportunities": tuple(f"opportunities-{n}" for n in (10, 25, 50, 100)),
    "range": (*(f"range-{r}" for r in (100, 200, 500, 800, 1000)), "bl1"),
    "heterogeneity": ("heterogeneity-39i1m", "heterogeneity-10rgyb"),
    "demo": ("bl1", "bl2", "ktbt"),
}
"""The paper's studies by name, each a list of presets (``range`` includes BL1 to compare)."""
STUDIES["all"] = tuple(dict.fromkeys(name for study in STUDIES.values() for name in study))
STUDIES["calibration"] = ("calibration-nl", "calibration-rl")
"""The release's two published runs, at their size (100,000 iterations): ``ktbt sim compare``
holds ours against its data."""
STUDIES["modes"] = tuple(
    f"modes-{group}-{variant}" for group in MODE_GROUPS for variant in MODE_VARIANTS
)
"""The release's five modes and our eviction variant, on 10RGYB and 39I-1M."""
STUDIES["teaching"] = (
    "ktbt",
    "ktbt-broadcast",
    "heterogeneity-39i1m",
    "heterogeneity-39i1m-broadcast",
)
"""Our finding, not the paper's: the release's first-requester rule against a broadcast rule."""


def preset(name: str) -> Scenario:
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"no preset {name!r}; presets: {', '.join(sorted(PRESETS))}") from None
