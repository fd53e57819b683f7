"""The simulator's step, against a bare pymunk step of the same world in the same run.

Run with ``python -m benchmarks.bench_sim`` (or ``python -m benchmarks`` for every module).
Prints a Markdown table and writes ``benchmarks/results/sim.json``.

Three sizes, KT-BT mode, no obstacles, range 200, in the release's 8000 by 8000 arena for the
paper's 40 robots (10 of each colour, 25 targets a colour), then 10 and 100 times that (400 and
4,000 robots, targets scaled alike, in an arena scaled to keep the paper's density). After a
warm-up, each sample is one ``World.step`` (sense,
tick the agents that need it, move, physics). The anchor is a second world built from the same
seed whose space is only stepped (``space.step(dt)``: the same bodies, sensors and contacts,
and no robot control at all); the two alternate step by step. The mean over the timed steps is
reported beside the median, since steps with many queries and answers are the slow ones.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Sequence
from typing import Any

from ktbt_sim.scenario import Arena, Robots, Targets, preset
from ktbt_sim.world import World

from .timing import gc_paused, machine, markdown_table, percentile, write_json

SIZES = {40: (3000, 4000), 400: (400, 400), 4000: (40, 60)}
"""Robots -> (warm-up steps, timed steps)."""
TARGET_40_US = 50.0
TARGET_4000_STEPS_PER_S = 250.0
TARGET_4000_RATIO = 2.5
"""4,000 robots: at least 250 steps/s and within 2.5 times a bare pymunk step."""


def world(robots: int, seed: int = 0) -> World:
    """The paper's group scaled ``k`` times, in an arena scaled to keep the paper's density
    (its authors kept 40 robots "to maintain sufficient space for movement")."""
    k = robots // 40
    side = math.sqrt(k)
    arena = Arena(scale=side)
    scenario = preset("ktbt").with_(
        name=f"bench-{robots}",
        robots=Robots.of(0, 0, 10 * k, 10 * k, 10 * k, 10 * k),
        targets=Targets.each(25 * k),
        arena=arena,
    )
    return World(scenario, seed=seed)


def measure(robots: int, warmup: int, steps: int) -> dict[str, Any]:
    built = time.perf_counter()
    ours, bare = world(robots), world(robots)
    build_s = (time.perf_counter() - built) / 2
    ours.run(warmup)
    clock = time.perf_counter_ns
    dt = bare.dt
    ours_ns: list[int] = []
    bare_ns: list[int] = []
    with gc_paused():
        for _ in range(steps):
            start = clock()
            ours.step()
            ours_ns.append(clock() - start)
            start = clock()
            bare.space.step(dt)
            bare_ns.append(clock() - start)
    ours_sorted, bare_sorted = sorted(ours_ns), sorted(bare_ns)
    mean_us = sum(ours_ns) / len(ours_ns) / 1000
    median_us = percentile(ours_sorted, 0.5) / 1000
    bare_us = percentile(bare_sorted, 0.5) / 1000
    return {
        "robots": robots,
        "warmup_steps": warmup,
        "timed_steps": steps,
        "build_s": round(build_s, 3),
        "median_us": round(median_us, 1),
        "p90_us": round(percentile(ours_sorted, 0.9) / 1000, 1),
        "mean_us": round(mean_us, 1),
        "steps_per_s": round(1e6 / mean_us, 1),
        "bare_pymunk_median_us": round(bare_us, 1),
        "ratio_to_bare": round(median_us / bare_us, 1),
    }


def report(rows: list[dict[str, Any]]) -> str:
    table = markdown_table(
        ["robots", "step median", "p90", "mean", "steps/s", "bare pymunk", "x bare"],
        [
            [
                str(r["robots"]),
                f"{r['median_us']:,.0f} µs",
                f"{r['p90_us']:,.0f} µs",
                f"{r['mean_us']:,.0f} µs",
                f"{r['steps_per_s']:,.0f}",
                f"{r['bare_pymunk_median_us']:,.0f} µs",
                f"{r['ratio_to_bare']:.1f}",
            ]
            for r in rows
        ],
    )
    by = {r["robots"]: r for r in rows}
    lines = [f"Simulator step, KT-BT mode ({machine()})", "", table, ""]
    if 40 in by:
        verdict = "met" if by[40]["median_us"] <= TARGET_40_US else "missed"
        lines.append(
            f"40 robots: median {by[40]['median_us']:.0f} µs, target ≤ {TARGET_40_US:.0f} µs: "
            f"{verdict}"
        )
    if 4000 in by:
        rate, ratio = by[4000]["steps_per_s"], by[4000]["ratio_to_bare"]
        met = rate >= TARGET_4000_STEPS_PER_S and ratio <= TARGET_4000_RATIO
        lines.append(
            f"4,000 robots: {rate:.0f} steps/s at {ratio:.1f}x bare, target ≥ "
            f"{TARGET_4000_STEPS_PER_S:.0f} within {TARGET_4000_RATIO}x: "
            f"{'met' if met else 'missed'}"
        )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_sim")
    parser.add_argument("--sizes", type=int, nargs="*", default=list(SIZES))
    parser.add_argument("--no-json", action="store_true", help="do not write results/sim.json")
    args = parser.parse_args(argv)
    rows = [measure(n, *SIZES.get(n, (100, 100))) for n in args.sizes]
    print(report(rows))
    if not args.no_json:
        path = write_json("sim", {"machine": machine(), "rows": rows})
        print(f"\nWrote {path.relative_to(path.parents[2])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
