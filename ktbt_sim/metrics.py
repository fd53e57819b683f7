"""Numbers the paper reports, computed from finished trials (pure numpy, no plotting).

Heterogeneity follows Twu, Mostofi and Egerstedt (ACC 2014), as the paper's section "Knowledge
and Functional Heterogeneity" does: heterogeneity = complexity x disparity, where complexity is
the Shannon entropy of the species proportions and disparity is Rao's quadratic entropy over the
distances between species. A species is a set of colours known (16 sets, ``set_*`` columns):
the paper counts 10 R + 10 G + 10 Y + 10 B robots as "four different types" at the start, which
only sets distinguish, and its distance "g0 to g1 is 1, g0 to g4 is 4" is the number of colours
in which two sets differ. Grouping by level only (``knows_0`` .. ``knows_4``, the paper's
g0..g4, ``level_distance``) is available too; both coincide for 39I-1M.

Defaults, and why:

- **log base e** (``base=math.e``): the paper writes ``log`` without a base and Twu et al. use
  the natural logarithm; with five species complexity then lies in [0, ln 5].
- **exponent 1** (``exponent=1.0``): Rao's quadratic entropy is ``sum_i sum_j p_i p_j d(i, j)``.
  The paper prints ``p_ij d(i,j)^2``, which reads as a typo for that (``p_ij`` is not defined
  there either); ``exponent=2`` reproduces the printed form.
- **distance = |level_i - level_j| x 0.25** (``level_distance()``): the paper gives distances in
  colours (g0 to g4 is 4) but also scales knowledge so that the whole ability sums to unity
  (``ks = 0.25`` a colour). Measuring the distance in that same unit keeps disparity in [0, 0.5]
  and heterogeneity comparable with the mean knowledge score, which is plotted beside it.
  ``level_distance(unit=1.0)`` with ``exponent=2`` gives the paper's printed numbers.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from ktbt_sim.records import set_name
from ktbt_sim.results import Results

Array = npt.NDArray[np.float64]

LEVELS = 5
"""Knowledge levels g0..g4: how many of the four colours a robot knows."""
KNOWLEDGE_SCORE = 0.25
"""The paper's ``ks`` of one colour: four equally hard colours, whole ability summing to one."""
LEVEL_COLUMNS = tuple(f"knows_{k}" for k in range(LEVELS))
MODE_COLUMNS = ("learned_direct", "learned_buffered", "learned_passive", "forgotten", "messages")
"""What the memory and passive modes change (spec/simulator.md §9), where a run records it."""
SETS = 16
"""Species: the sets of colours a robot knows, bit k-1 for colour k (red 1 .. blue 4)."""


SET_COLUMNS = tuple(set_name(b) for b in range(SETS))


def set_distance(unit: float = KNOWLEDGE_SCORE) -> Array:
    """Colours in which two sets differ, times ``unit``."""
    bits = np.arange(SETS)
    xor = bits[:, None] ^ bits[None, :]
    differ = sum((xor >> k) & 1 for k in range(4))
    return np.asarray(differ, dtype=np.float64) * unit


def level_distance(levels: int = LEVELS, unit: float = KNOWLEDGE_SCORE) -> Array:
    """Distances between knowledge levels, ``|i - j| * unit`` (see the module's defaults)."""
    k = np.arange(levels, dtype=np.float64)
    return np.abs(k[:, None] - k[None, :]) * unit


def entropy(p: npt.ArrayLike, base: float = math.e) -> Array:
    """Shannon entropy of proportions along the last axis (complexity); ``0 log 0 = 0``.

    Proportions are taken as given, not renormalised, so a caller passing counts by mistake
    gets an obviously wrong number rather than a silently right one.
    """
    if base <= 0 or base == 1:
        raise ValueError(f"log base must be positive and not 1, got {base}")
    q = np.asarray(p, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(q > 0, q * np.log(np.where(q > 0, q, 1.0)), 0.0)
    return np.asarray(-terms.sum(axis=-1) / math.log(base))


def rao(p: npt.ArrayLike, distance: npt.ArrayLike, exponent: float = 1.0) -> Array:
    """Rao's quadratic entropy ``sum_i sum_j p_i p_j d(i, j)^exponent`` along the last axis.

    The sum runs over ordered pairs, so two species half and half at distance 1 give 0.5: the
    expected distance between two members drawn at random, which is what makes it a disparity.
    """
    q = np.asarray(p, dtype=np.float64)
    d = np.asarray(distance, dtype=np.float64) ** exponent
    if d.shape != (q.shape[-1], q.shape[-1]):
        raise ValueError(f"distance must be {q.shape[-1]}x{q.shape[-1]}, got {d.shape}")
    return np.asarray(np.einsum("...i,ij,...j->...", q, d, q))


def proportions(counts: npt.ArrayLike) -> Array:
    """Counts along the last axis as proportions; NaN where the population is empty."""
    c = np.asarray(counts, dtype=np.float64)
    total = c.sum(axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(np.where(total > 0, c / np.where(total > 0, total, 1.0), np.nan))


def heterogeneity(
    levels_counts: npt.ArrayLike,
    base: float = math.e,
    exponent: float = 1.0,
    distance: npt.ArrayLike | None = None,
) -> tuple[Array, Array, Array]:
    """(complexity, disparity, heterogeneity) of robots counted by knowledge level.

    ``levels_counts`` is ``(..., 5)``: any leading axes (trials, rows) are kept, so a whole
    study is one call. ``distance`` defaults to ``level_distance()``.
    """
    p = proportions(levels_counts)
    d = level_distance(p.shape[-1]) if distance is None else np.asarray(distance)
    complexity = entropy(p, base)
    disparity = rao(p, d, exponent)
    return complexity, disparity, np.asarray(complexity * disparity)


def mean_knowledge_score(levels_counts: npt.ArrayLike, score: float = KNOWLEDGE_SCORE) -> Array:
    """The paper's ``sum_i ks_i / P``: a robot at level k scores ``k * 0.25``; 1 = all know all."""
    c = np.asarray(levels_counts, dtype=np.float64)
    k = np.arange(c.shape[-1], dtype=np.float64)
    total = c.sum(axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(np.where(total > 0, (c * k * score).sum(axis=-1) / total, np.nan))


def knowledge_levels(known: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """Robots at each level g0..g4 from a ``(robots, 4)`` table of known colours."""
    table = np.asarray(known, dtype=bool)
    return np.bincount(table.sum(axis=-1), minlength=table.shape[-1] + 1).astype(np.int64)


def needed(total: int, fraction: float) -> int:
    """Targets that make ``fraction`` of ``total``, rounded up so 99 % of 100 is 99, not 98.

    Rounded to 9 places first: ``0.29 * 100`` is 28.999999999999996 in floating point and must
    still need 29.
    """
    return math.ceil(round(fraction * total, 9))


def t_fraction(
    collected: npt.ArrayLike, total: int, iterations: npt.ArrayLike, fraction: float = 0.99
) -> Array:
    """Per trial, the first recorded iteration with ``collected >= ceil(fraction * total)``.

    ``collected`` is ``(trials, rows)`` and ``iterations`` ``(rows,)``. NaN marks a trial that
    never got there: it is censored at the run length, and averaging it in would hide that.
    """
    c = np.asarray(collected)
    its = np.asarray(iterations, dtype=np.float64)
    reached = c >= needed(total, fraction)
    first = reached.argmax(axis=-1)
    return np.asarray(np.where(reached.any(axis=-1), its[first], np.nan))


def std(values: npt.ArrayLike, axis: int = 0) -> Array:
    """Sample standard deviation (ddof 1); NaN below two values, since one trial has no spread
    to estimate and 0 would claim there is none."""
    v = np.asarray(values, dtype=np.float64)
    if v.shape[axis] < 2:
        return np.asarray(np.full(np.delete(v.shape, axis), np.nan))
    return np.asarray(v.std(axis=axis, ddof=1))


def percent_collected(results: Results) -> Array:
    """``(trials, rows)`` percentage of the scenario's targets delivered."""
    total = results.total_targets
    collected = np.asarray(results["collected"], dtype=np.float64)
    return collected * 100.0 / total if total else np.full_like(collected, np.nan)


def set_counts(results: Results) -> npt.NDArray[np.int64] | None:
    """``(trials, rows, 16)`` robots per set of colours known; None for records without sets."""
    if SET_COLUMNS[0] not in results.data:
        return None
    return np.stack([results[c] for c in SET_COLUMNS], axis=-1).astype(np.int64)


def level_counts(results: Results) -> npt.NDArray[np.int64]:
    """``(trials, rows, 5)`` robots at each knowledge level, ready for ``heterogeneity``."""
    return np.stack([results[c] for c in LEVEL_COLUMNS], axis=-1).astype(np.int64)


def _stats(values: npt.ArrayLike) -> tuple[float, float]:
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        return math.nan, math.nan
    return float(v.mean()), float(std(v))


def summary(results: Results, at: int | None = None) -> dict[str, Any]:
    """Means and sample standard deviations across trials of what the paper's tables report.

    Keys: ``trials``; ``collected_pct``, ``queries``, ``responses``, ``lost``, ``knows_0`` ..
    ``knows_4``, ``knowledge_score`` and, where recorded, the :data:`MODE_COLUMNS` at the last
    recorded row (or the last at or before
    iteration ``at``), each as ``<key>_mean`` and ``<key>_std``; ``t95``, ``t99`` and ``t100``
    as ``_mean`` and ``_std`` over the trials that reached the fraction only, with
    ``_reached`` saying how many did; ``knows_4_end`` (``_mean``, ``_std``): robots knowing
    all four colours when collection ended, over the trials in which it did.
    """
    last = -1 if at is None else int(np.searchsorted(results.iterations, at, side="right")) - 1
    out: dict[str, Any] = {
        "trials": len(results.trials),
        "iteration": int(results.iterations[last]),
    }
    finals: dict[str, npt.ArrayLike] = {
        "collected_pct": percent_collected(results)[:, last],
        **{c: results[c][:, last] for c in ("queries", "responses", "lost", *LEVEL_COLUMNS)},
        **{c: results[c][:, last] for c in MODE_COLUMNS if c in results.data},
        "knowledge_score": mean_knowledge_score(level_counts(results)[:, last]),
    }
    for key, values in finals.items():
        out[f"{key}_mean"], out[f"{key}_std"] = _stats(values)
    for key, fraction in (("t95", 0.95), ("t99", 0.99), ("t100", 1.0)):
        t = t_fraction(results["collected"], results.total_targets, results.iterations, fraction)
        reached = t[~np.isnan(t)]
        out[f"{key}_mean"], out[f"{key}_std"] = _stats(reached)
        out[f"{key}_reached"] = int(reached.size)
    done = results["collected"] >= results.total_targets
    ended = done.any(axis=1)
    first = done.argmax(axis=1)
    knows = results["knows_4"][np.flatnonzero(ended), first[ended]]
    out["knows_4_end_mean"], out["knows_4_end_std"] = _stats(knows)
    return out
