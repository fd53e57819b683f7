"""What a trial records, in our columns and in the release's 35 (``spec/simulator.md`` §10).

Ours (``COLUMNS``), every ``record_every`` iterations: targets collected per colour; robots now
querying, teaching, with the random-walk flag, carrying, avoiding, waiting, cooling down; the
cumulative queries, responses, queries lost (queries - responses, the release's definition),
deliveries and learns (direct, buffered, passive); robots knowing exactly k colours, robots
knowing each colour, and robots per exact set of colours (``set_RG``: exactly red and green).

The release's (``RELEASE_HEADER``), a row every 10 iterations, can be written too
(:func:`write_release_csv`) and read (:func:`read_release_csv`; a whole folder with
``results.read_release_folder``), so that its own tools and ours read each other's runs. Its
header labels the three two-colour columns after ``Cur. 4 Cond. Known`` "RG, RY, RB", but it
writes RY, RB, RG there (§10): we write the same header and the same order, so a file of ours
reads exactly as one of theirs, and we read both by the order the values are really in.
"""

from __future__ import annotations

import csv
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ktbt_proto.files import write_atomic
from ktbt_sim.scenario import COLOURS, Mode, Robots, Scenario, Targets, TeachingRule
from ktbt_sim.state import total

if TYPE_CHECKING:
    from ktbt_sim.state import Trial


def set_name(bits: int) -> str:
    """``set_RG`` for red and green, ``set_none`` for nothing."""
    return "set_" + ("".join(c for k, c in enumerate("RGYB") if bits >> k & 1) or "none")


COLUMNS = (
    "iteration",
    *(f"collected_{c}" for c in COLOURS),
    "collected",
    "querying",
    "teaching",
    "walking",
    "carrying",
    "avoiding",
    "waiting",
    "cooling",
    "queries",
    "responses",
    "lost",
    "delivered",
    "learned_direct",
    "learned_buffered",
    "learned_passive",
    "forgotten",
    "messages",
    *(f"knows_{k}" for k in range(5)),
    *(f"knows_{c}" for c in COLOURS),
    *(set_name(b) for b in range(16)),
)

SET_BITS = np.array([1, 2, 4, 8])


def row(world: Trial) -> dict[str, int]:
    """One row of ``COLUMNS`` from a world's state."""
    from ktbt_sim.motion import AVOID

    call = 2 * world.iteration + 2
    known = world.known
    levels = np.bincount(known.sum(axis=1), minlength=5)
    per_colour = known.sum(axis=0)
    sets = np.bincount(known @ SET_BITS, minlength=16)
    waiting = world.timers.waiting(call)
    out = {"iteration": world.iteration}
    for c, name in enumerate(COLOURS):
        out[f"collected_{name}"] = int(world.collected[c])
    out["collected"] = int(world.collected.sum())
    out["querying"] = int(world.querying.sum())
    out["teaching"] = int(world.answering.sum())
    out["walking"] = int(world.walk_flag.sum())
    out["carrying"] = int((world.carrying >= 0).sum())
    out["avoiding"] = int((world.drive == AVOID).sum())
    out["waiting"] = int(waiting.sum())
    out["cooling"] = int((world.timers.busy(call) & ~waiting).sum())
    queries, responses = total(world, "queries_sent"), total(world, "responses_sent")
    out["queries"] = queries
    out["responses"] = responses
    out["lost"] = queries - responses
    out["delivered"] = world.delivered
    for kind in ("direct", "buffered", "passive"):
        out[f"learned_{kind}"] = total(world, f"learned_{kind}")
    out["forgotten"] = world.forgotten
    out["messages"] = world.network.delivered
    for level in range(5):
        out[f"knows_{level}"] = int(levels[level])
    for c, name in enumerate(COLOURS):
        out[f"knows_{name}"] = int(per_colour[c])
    for bits in range(16):
        out[set_name(bits)] = int(sets[bits])
    return out


# -- the release's format --------------------------------------------------------------------

RELEASE_HEADER = (
    "Iteration,T-Red Collected,T- Green Collected,T- Yellow Collected,T- Blue Collected,"
    "Cur. Lrn Req.,Cur. Teach Resp.,Cur. RandomWalk States,Cur. Target Carry States,"
    "Cum. Lrn. Req.,Cum. Teach. Resp.,Direct Learn Cum,Buf Learn Cum.,Cum. Pass Learn,"
    "Cum Targets Carried,Cur. Known St. Red,Cur. Known St. Green,Cur. Known St. Yellow,"
    "Cur. Known St. Blue,Cur. 0 Cond. Known,Cur. 1 Cond. Known,Cur. 2 Cond. Known,"
    "Cur. 3 Cond. Known,Cur. 4 Cond. Known, Known St. RG, Known St. RY, Known St. RB,"
    " Known St. GY, Known St. GB, Known St. YB, Known St. RGY, Known St. RGB, Known St. RYB,"
    " Known St. GYB, Known St. RGYB"
)
"""The release's header, spelling and spaces included (§10)."""

COMBINATIONS = ("RY", "RB", "RG", "GY", "GB", "YB", "RGY", "RGB", "RYB", "GYB", "RGYB")
"""What columns 25 to 35 really hold, in order: robots knowing at least these colours."""

_DIRECT = (
    ("collected_red", "collected_green", "collected_yellow", "collected_blue"),
    ("querying", "teaching", "walking", "carrying", "queries", "responses"),
    ("learned_direct", "learned_buffered", "learned_passive", "delivered"),
    tuple(f"knows_{c}" for c in COLOURS),
    tuple(f"knows_{k}" for k in range(5)),
)
RELEASE_FIELDS = tuple(name for group in _DIRECT for name in group)
"""Our column for each of the release's columns 2 to 24."""


def _bits(colours: str) -> int:
    return sum(1 << "RGYB".index(c) for c in colours)


def at_least(sets: np.ndarray) -> np.ndarray:
    """Robots knowing at least each of ``COMBINATIONS``, from exact-set counts (..., 16)."""
    out = []
    for combo in COMBINATIONS:
        b = _bits(combo)
        members = [s for s in range(16) if s & b == b]
        out.append(sets[..., members].sum(axis=-1))
    return np.stack(out, axis=-1)


def exact_sets(per_colour: np.ndarray, combos: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """Exact-set counts (..., 16) from the release's "at least" columns: a Möbius inversion over
    the subsets of colours. Singletons come from the per-colour columns and the empty set from
    ``Cur. 0 Cond. Known``."""
    at: dict[int, np.ndarray] = {}
    for k in range(4):
        at[1 << k] = per_colour[..., k]
    for idx, combo in enumerate(COMBINATIONS):
        at[_bits(combo)] = combos[..., idx]
    total = levels.sum(axis=-1)
    at[0] = total
    out = np.zeros((*levels.shape[:-1], 16), dtype=np.int64)
    for s in range(16):
        value = np.zeros_like(total)
        for t in range(16):
            if t & s == s:
                sign = -1 if bin(t ^ s).count("1") % 2 else 1
                value = value + sign * at[t]
        out[..., s] = value
    return out


def release_rows(rows: dict[str, list[int]]) -> list[list[int]]:
    """Our rows as the release's 35 columns (rows at multiples of 10 only, as it writes them)."""
    sets = np.array([rows[set_name(b)] for b in range(16)]).T
    combos = at_least(sets)
    out = []
    for k, iteration in enumerate(rows["iteration"]):
        if iteration == 0 or iteration % 10:
            continue
        values = [iteration, *(rows[name][k] for name in RELEASE_FIELDS)]
        out.append(values + [int(v) for v in combos[k]])
    return out


def write_release_csv(path: Path, rows: dict[str, list[int]]) -> None:
    """One trial in the release's CSV format: its header, a row every 10 iterations, each row
    ending with a comma as the release's do (without its blank lines)."""
    lines = [RELEASE_HEADER]
    lines += [",".join(str(v) for v in r) + "," for r in release_rows(rows)]
    write_atomic(path, "\n".join(lines) + "\n")


def read_release_csv(path: Path) -> dict[str, np.ndarray]:
    """A release CSV (theirs or ours) as our columns. Blank lines are skipped; a duplicated
    iteration keeps its first row (the release's writer sometimes repeats one)."""
    with path.open(encoding="utf-8", newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None or header[0] != "Iteration" or len(header) < 35:
            raise ValueError(f"{path}: not a release CSV (no 35-column header)")
        seen: set[int] = set()
        data: list[list[int]] = []
        for record in reader:
            values = [v for v in record if v.strip() != ""]
            if not values:
                continue
            if len(values) < 35:
                raise ValueError(f"{path}: a row with {len(values)} of 35 values")
            numbers = [int(float(v)) for v in values[:35]]
            if numbers[0] in seen:
                continue
            seen.add(numbers[0])
            data.append(numbers)
    table = np.array(data, dtype=np.int64)
    out = {"iteration": table[:, 0]}
    for k, name in enumerate(RELEASE_FIELDS):
        out[name] = table[:, k + 1]
    per_colour = table[:, 15:19]
    levels = table[:, 19:24]
    sets = exact_sets(per_colour, table[:, 24:35], levels)
    for b in range(16):
        out[set_name(b)] = sets[:, b]
    out["collected"] = table[:, 1:5].sum(axis=1)
    out["lost"] = out["queries"] - out["responses"]
    return out


_FOLDER = re.compile(
    r"(?P<mode>NL|RL|EL|PLB|PL)_(?P<robots>\d+_\d+_\d+_\d+_\d+_\d+)_(?P<obst>[YN])_"
    r"(?P<targets>\d+_\d+_\d+_\d+)_(?P<range>\d+)_(?P<memory>-?\d+)$"
)


def release_scenario(folder: Path, iterations: int) -> Scenario:
    """The scenario a release folder's name encodes
    (``MODE_I_M_R_G_Y_B_Obstacles_nR_nG_nY_nB_range_memoryDuration``); the name does not
    carry the memory size, which keeps its default."""
    match = _FOLDER.match(folder.name)
    if match is None:
        raise ValueError(f"{folder}: not a release scenario folder name")
    mode = next(m for m, name in RELEASE_MODES.items() if name == match["mode"])
    memory = int(match["memory"])
    i, m, r, g, y, b = (int(v) for v in match["robots"].split("_"))
    tr, tg, ty, tb = (int(v) for v in match["targets"].split("_"))
    from ktbt_sim.scenario import Arena

    return Scenario(
        name=f"release {folder.name}",
        mode=mode,
        memory_duration=None if memory < 0 else memory,
        robots=Robots.of(i, m, r, g, y, b),
        targets=Targets(red=tr, green=tg, yellow=ty, blue=tb),
        comm_range=float(match["range"]),
        arena=Arena(obstacles=match["obst"] == "Y"),
        iterations=max(iterations, 1),
    )


RELEASE_MODES: dict[Mode, str] = {
    Mode.NO_TRANSFER: "NL",
    Mode.KT_BT: "RL",
    Mode.EPHEMERAL: "EL",
    Mode.PASSIVE_BUFFER: "PLB",
    Mode.PASSIVE: "PL",
}
"""Each mode's name in the release's folder names (spec/simulator.md, the release's records)."""


def release_name(scenario: Scenario) -> str:
    """The release's folder name for a scenario:
    ``MODE_I_M_R_G_Y_B_Obstacles_nR_nG_nY_nB_range_memoryDuration`` (-1: no memory duration).
    A ValueError for our own variants, which the release has no name for: a folder named as
    the release's mode would pass our variant's data off as the release's."""
    variants = []
    if scenario.teaching is not TeachingRule.RELEASE:
        variants.append(f"teaching {scenario.teaching.value}")
    if scenario.memory_when_full != "refuse":
        variants.append(f"memory_when_full {scenario.memory_when_full}")
    if scenario.overhear_window != "wait":
        variants.append(f"overhear_window {scenario.overhear_window}")
    if variants:
        raise ValueError(
            f"{scenario.name}: the release has no such variant ({', '.join(variants)})"
        )
    r, t = scenario.robots, scenario.targets
    robots = (r.ignorant, r.multi, r.red, r.green, r.yellow, r.blue)
    targets = (t.red, t.green, t.yellow, t.blue)
    memory = -1 if scenario.memory_duration is None else scenario.memory_duration
    parts = [RELEASE_MODES[scenario.mode], *map(str, robots)]
    parts += ["Y" if scenario.arena.obstacles else "N", *map(str, targets)]
    parts += [f"{scenario.comm_range:g}", str(memory)]
    return "_".join(parts)
