"""``ktbt sim compare OURS THEIRS``: two runs of one configuration side by side.

Either side may be a scenario folder of ``ktbt sim run`` or a release ``SimData`` scenario
folder (``…_Tr_N.csv`` files, ``results.read_release_folder``). The table gives, for each, the
mean and standard deviation over trials of the headline numbers the calibration is held to
(iterations to 50 / 95 / 99 % collected, queries, answers, queries lost, robots knowing 4 / 3 / 2
colours at the end of the shorter run) and our mean's difference from theirs; the figure draws
both on the same axes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.figure import Figure

from ktbt_sim import metrics
from ktbt_sim.results import Results, load_folder, read_release_folder

matplotlib.use("Agg")


def load_any(path: str | Path) -> Results:
    """Our scenario folder or a release one; ValueError with one line if it is neither."""
    path = Path(path)
    if not path.is_dir():
        raise ValueError(f"{path} is not a folder")
    if (path / "scenario.json").exists():
        results = load_folder(path)
        if results is None:
            raise ValueError(f"{path} holds no finished trial")
        return results
    if any(path.glob("*_Tr_*.csv")):
        return read_release_folder(path)
    raise ValueError(f"{path}: neither a `ktbt sim run` scenario folder nor a release one")


@dataclass(frozen=True)
class Line:
    """One row of the comparison: a quantity's mean and s.d. on each side."""

    name: str
    ours: tuple[float, float, int]
    theirs: tuple[float, float, int]
    tolerance: str
    """How close counts as a match: ``10%`` of theirs, or ``2`` in absolute terms."""
    trials: tuple[int, int] = (0, 0)
    """Trials on each side; a mean over fewer (those that reached a fraction) holds only if
    the same share of trials got there on both sides."""

    @property
    def difference(self) -> float:
        a, b = self.ours[0], self.theirs[0]
        return (a - b) / b * 100.0 if b else math.nan

    @property
    def holds(self) -> bool:
        a, b = self.ours[0], self.theirs[0]
        if math.isnan(a) or math.isnan(b):
            return math.isnan(a) and math.isnan(b)  # neither run got there
        mine, theirs = self.trials
        if mine and theirs and self.ours[2] * theirs != self.theirs[2] * mine:
            return False
        if self.tolerance.endswith("%"):
            return abs(a - b) <= abs(b) * float(self.tolerance[:-1]) / 100.0
        return abs(a - b) <= float(self.tolerance)


def _at(results: Results, column: str, iteration: int) -> np.ndarray:
    k = int(np.searchsorted(results.iterations, iteration, side="right")) - 1
    return np.asarray(results[column][:, max(k, 0)], dtype=np.float64)


def _stats(values: np.ndarray) -> tuple[float, float, int]:
    v = values[~np.isnan(values)]
    if not v.size:
        return math.nan, math.nan, 0
    return float(v.mean()), float(metrics.std(v)), int(v.size)


def lines(ours: Results, theirs: Results) -> list[Line]:
    """The comparison's rows; end-of-run numbers are read at the last iteration both have."""
    end = int(min(ours.iterations[-1], theirs.iterations[-1]))
    out = []
    for fraction in (0.5, 0.95, 0.99):

        def t(r: Results, f: float = fraction) -> np.ndarray:
            return metrics.t_fraction(r["collected"], r.total_targets, r.iterations, f)

        out.append(Line(f"iterations to {fraction:.0%}", _stats(t(ours)), _stats(t(theirs)), "10%"))
    if ours.scenario.mode.value != "no-transfer" or theirs.scenario.mode.value != "no-transfer":
        for column, label in (("queries", "queries"), ("responses", "answers")):
            out.append(
                Line(
                    f"{label} at {end:,}",
                    _stats(_at(ours, column, end)),
                    _stats(_at(theirs, column, end)),
                    "10%",
                )
            )
        lost_o = _at(ours, "queries", end) - _at(ours, "responses", end)
        lost_t = _at(theirs, "queries", end) - _at(theirs, "responses", end)
        out.append(Line(f"queries lost at {end:,}", _stats(lost_o), _stats(lost_t), "10%"))
        for level in (4, 3, 2):
            out.append(
                Line(
                    f"robots knowing {level} at {end:,}",
                    _stats(_at(ours, f"knows_{level}", end)),
                    _stats(_at(theirs, f"knows_{level}", end)),
                    "2",
                )
            )
    return out


def table(rows: list[Line], ours: str = "ours", theirs: str = "release") -> str:
    """Markdown: mean ± sample s.d. (trials) on each side, the difference, whether it holds."""

    def cell(v: tuple[float, float, int]) -> str:
        mean, sd, n = v
        if n == 0:
            return "not reached"
        spread = "" if math.isnan(sd) else f" ± {sd:,.1f}"
        return f"{mean:,.1f}{spread} ({n})"

    out = [
        f"| quantity | {ours}: mean ± s.d. (trials) | {theirs} | difference | within |",
        "| --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        diff = "" if math.isnan(r.difference) else f"{r.difference:+.1f} %"
        mark = "yes" if r.holds else "**no**"
        out.append(
            f"| {r.name} | {cell(r.ours)} | {cell(r.theirs)} | {diff} | {r.tolerance}: {mark} |"
        )
    return "\n".join(out)


def figure(ours: Results, theirs: Results, labels: tuple[str, str] = ("ours", "release")) -> Figure:
    """Collected, cumulative queries and answers, and knowledge levels over time, both runs."""
    transfer = "no-transfer" not in (ours.scenario.mode.value, theirs.scenario.mode.value)
    panels = 3 if transfer else 1
    fig = Figure(figsize=(5.0 * panels, 4.0), layout="constrained")
    axes = fig.subplots(1, panels, squeeze=False)[0]
    styles = (("C0", "-"), ("k", "--"))
    for (res, label), (colour, style) in zip(
        ((ours, labels[0]), (theirs, labels[1])), styles, strict=True
    ):
        n = len(res.trials)
        _band(
            axes[0],
            res.iterations,
            metrics.percent_collected(res),
            f"{label} (n={n})",
            colour,
            style,
        )
        if transfer:
            _band(axes[1], res.iterations, res["queries"], f"{label}: queries", colour, style)
            _band(axes[1], res.iterations, res["responses"], f"{label}: answers", colour, ":")
            for level, shade in ((4, "C2"), (3, "C1"), (2, "C3")):
                tag = f"{label}: knows {level}" if style == "-" else None
                _band(axes[2], res.iterations, res[f"knows_{level}"], tag, shade, style)
    axes[0].set(xlabel="iterations", ylabel="targets collected (%)", ylim=(0, 105))
    axes[0].legend(loc="lower right", fontsize="small")
    if transfer:
        axes[1].set(xlabel="iterations", ylabel="cumulative count")
        axes[1].legend(fontsize="small")
        axes[2].set(xlabel="iterations", ylabel="robots (dashed: release)")
        axes[2].legend(fontsize="small")
    fig.suptitle(
        f"{ours.scenario.name} against {theirs.scenario.name} (mean ± 1 s.d.)", fontsize="medium"
    )
    return fig


def _band(
    ax: object, x: np.ndarray, y: np.ndarray, label: str | None, colour: str, style: str
) -> None:
    from matplotlib.axes import Axes

    if not isinstance(ax, Axes):
        raise TypeError(f"a matplotlib Axes was expected, not {type(ax).__name__}")
    values = np.asarray(y, dtype=np.float64)
    mean, spread = values.mean(axis=0), metrics.std(values)
    ax.plot(x, mean, style, color=colour, label=label, linewidth=1.3)
    if not np.all(np.isnan(spread)):
        ax.fill_between(x, mean - spread, mean + spread, color=colour, alpha=0.15)


def compare(ours_path: str | Path, theirs_path: str | Path, out: str | Path | None = None) -> str:
    """The comparison as Markdown; with ``out``, also ``out``.png/.svg and ``out``.md."""
    ours, theirs = load_any(ours_path), load_any(theirs_path)
    text = table(lines(ours, theirs))
    if out is not None:
        stem = Path(out)
        stem.parent.mkdir(parents=True, exist_ok=True)
        fig = figure(ours, theirs)
        with matplotlib.rc_context({"svg.hashsalt": "ktbt"}):
            fig.savefig(stem.with_suffix(".png"), dpi=130)
        stem.with_suffix(".md").write_text(text + "\n", encoding="utf-8")
    return text
