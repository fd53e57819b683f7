"""Small timing helpers shared by the benchmark modules (standard library only)."""

from __future__ import annotations

import gc
import json
import platform
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

RESULTS_DIR = Path(__file__).resolve().parent / "results"


@dataclass(frozen=True, slots=True)
class Stats:
    """Summary of one case's samples, in nanoseconds per call."""

    median_ns: float
    p90_ns: float
    samples: int

    @classmethod
    def of(cls, samples_ns: Sequence[int]) -> Stats:
        ordered = sorted(samples_ns)
        return cls(percentile(ordered, 0.5), percentile(ordered, 0.9), len(ordered))

    @property
    def median_us(self) -> float:
        return self.median_ns / 1_000

    @property
    def p90_us(self) -> float:
        return self.p90_ns / 1_000


def percentile(ordered: Sequence[int], q: float) -> float:
    """The ``q`` quantile (0..1) of already sorted samples, interpolating linearly."""
    if not ordered:
        raise ValueError("no samples")
    pos = q * (len(ordered) - 1)
    low = int(pos)
    high = min(low + 1, len(ordered) - 1)
    return ordered[low] + (ordered[high] - ordered[low]) * (pos - low)


@contextmanager
def gc_paused() -> Iterator[None]:
    """Collect, then keep the cyclic garbage collector off for the block (restored after)."""
    was_enabled = gc.isenabled()
    gc.collect()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


def interleaved(
    cases: Mapping[str, Callable[[], object]],
    *,
    rounds: int,
    warmup: int = 20,
    collect_every: int = 100,
) -> dict[str, Stats]:
    """Time every case once per round, rotating the order each round, so that machine noise
    (other processes, frequency changes) falls on all cases alike. Each sample is one call.

    The cyclic collector is off while timing; it runs between blocks of ``collect_every`` rounds,
    outside the timed calls.
    """
    names = list(cases)
    calls = [cases[name] for name in names]
    samples: list[list[int]] = [[] for _ in names]
    clock = time.perf_counter_ns
    with gc_paused():
        for _ in range(warmup):
            for call in calls:
                call()
        for r in range(rounds):
            if r and r % collect_every == 0:
                gc.collect()
            shift = r % len(calls)
            for i in range(shift, shift + len(calls)):
                j = i % len(calls)
                call = calls[j]
                start = clock()
                call()
                samples[j].append(clock() - start)
    return {name: Stats.of(s) for name, s in zip(names, samples, strict=True)}


def time_once(call: Callable[[], object]) -> int:
    """Nanoseconds of one call of a slow operation, with the cyclic collector off."""
    with gc_paused():
        start = time.perf_counter_ns()
        call()
        return time.perf_counter_ns() - start


def machine() -> str:
    """One line naming the interpreter and machine."""
    return (
        f"{platform.python_implementation()} {platform.python_version()} "
        f"on {platform.system()} {platform.machine()}"
    )


def markdown_table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A GitHub-flavoured Markdown table, first column left-aligned, the others right-aligned."""
    widths = [max(len(h), *(len(row[i]) for row in rows)) for i, h in enumerate(headers)]

    def line(cells: Sequence[str]) -> str:
        padded = [
            c.ljust(w) if i == 0 else c.rjust(w)
            for i, (c, w) in enumerate(zip(cells, widths, strict=True))
        ]
        return "| " + " | ".join(padded) + " |"

    rule = ["-" * w if i == 0 else "-" * (w - 1) + ":" for i, w in enumerate(widths)]
    return "\n".join([line(headers), line(rule), *(line(row) for row in rows)])


def write_json(name: str, data: Mapping[str, Any]) -> Path:
    """Write ``data`` to ``benchmarks/results/<name>.json`` and return the path."""
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    path = RESULTS_DIR / f"{name}.json"
    path.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    return path
