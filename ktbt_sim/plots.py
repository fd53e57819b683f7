"""The paper's figures, drawn from whatever finished trials a study folder holds.

Every figure is drawn only when at least one of its scenarios has results, so a partial sweep
still gives partial figures; each is written as PNG (to look at) and SVG (to edit). Spreads are
one sample standard deviation across trials everywhere, the same as in ``summary.md``, so a
figure and the table can be read against each other.

Figures are built on ``matplotlib.figure.Figure`` without pyplot: nothing is registered with a
GUI or kept alive between calls, so plotting a long sweep does not leak figures.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from pathlib import Path

import matplotlib
import numpy as np
import numpy.typing as npt
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from ktbt_sim import metrics
from ktbt_sim.results import Results, load
from ktbt_sim.scenario import MODE_GROUPS, MODE_VARIANTS, PRESETS
from ktbt_sim.scenario import STUDIES as SCENARIOS

matplotlib.use("Agg")

GROUPS = ("bl1", "bl2", "ktbt")
GROUP_LABELS = {
    "bl1": "bl1: 40M, no transfer",
    "bl2": "bl2: 10RGYB, no transfer",
    "ktbt": "ktbt: 10RGYB, KT-BT",
}
OBSTACLES = tuple(f"{g}-obstacles" for g in GROUPS)
OPPORTUNITIES = SCENARIOS["opportunities"]
RANGES = tuple(n for n in SCENARIOS["range"] if n.startswith("range-"))
HETEROGENEITY = SCENARIOS["heterogeneity"]
MODES = frozenset(SCENARIOS["modes"])
TEACHING = (
    ("10R-10G-10Y-10B, 25 a colour", "ktbt", "ktbt-broadcast"),
    ("39I-1M, 100 a colour", "heterogeneity-39i1m", "heterogeneity-39i1m-broadcast"),
)
"""Our finding, not the paper's: each group under the release's rule and the broadcast rule."""
COLOURS = {g: f"C{i}" for i, g in enumerate(GROUPS)}

STUDIES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "performance": (("collection", "t99"), GROUPS + OBSTACLES),
    "opportunities": (("opportunities",), OPPORTUNITIES),
    "range": (("range", "queries_lost"), (*RANGES, "bl1")),
    "heterogeneity": (HETEROGENEITY, HETEROGENEITY),
    "teaching": (("teaching",), tuple(n for _, *names in TEACHING for n in names)),
    "modes": (("modes",), SCENARIOS["modes"]),
}
"""Each study's figures and scenarios: ``plot(study=...)`` draws only those figures and tables
only those scenarios (the range study compares against bl1, so it keeps that too)."""

SPREAD = "mean ± 1 s.d. over trials"
Drawer = Callable[[Mapping[str, Results]], Figure | None]


# -- helpers ---------------------------------------------------------------------------------


def _present(results: Mapping[str, Results], names: Sequence[str]) -> list[Results]:
    return [results[n] for n in names if n in results]


def _figure(width: float = 7.0, height: float = 4.5) -> Figure:
    return Figure(figsize=(width, height), layout="constrained")


def _mean_band(
    ax: Axes,
    x: npt.ArrayLike,
    y: npt.ArrayLike,
    label: str,
    colour: str | None = None,
    style: str = "-",
    alpha: float = 0.2,
) -> None:
    """A mean line over trials with its ±1 s.d. band (no band for a single trial)."""
    values = np.asarray(y, dtype=np.float64)
    mean, spread = values.mean(axis=0), metrics.std(values)
    (line,) = ax.plot(x, mean, style, color=colour, label=label, linewidth=1.5)
    if not np.all(np.isnan(spread)):
        ax.fill_between(x, mean - spread, mean + spread, color=line.get_color(), alpha=alpha)


def _label(res: Results) -> str:
    name = res.scenario.name
    return GROUP_LABELS.get(name.removesuffix("-obstacles"), name) + f" (n={len(res.trials)})"


def _save(fig: Figure, directory: Path, stem: str) -> list[Path]:
    """PNG and SVG; the SVG carries no date and fixed ids, so reruns diff cleanly."""
    paths = [directory / f"{stem}.png", directory / f"{stem}.svg"]
    with matplotlib.rc_context({"svg.hashsalt": "ktbt"}):
        fig.savefig(paths[0], dpi=150)
        fig.set_layout_engine("none")  # laid out by the first save; skip doing it again
        fig.savefig(paths[1], metadata={"Date": None})
    return paths


def _base_name(base: float) -> str:
    return "e" if base == math.e else f"{base:g}"


# -- figures ---------------------------------------------------------------------------------


def draw_collection(results: Mapping[str, Results]) -> Figure | None:
    """Study 1: does KT-BT close the gap to bl1's all-knowing robots, with and without walls?"""
    panels = [
        (title, runs)
        for title, names in (("no obstacles", GROUPS), ("with obstacles", OBSTACLES))
        if (runs := _present(results, names))
    ]
    if not panels:
        return None
    fig = _figure(width=6.0 * len(panels))
    axes = fig.subplots(1, len(panels), sharey=True, squeeze=False)[0]
    for ax, (title, runs) in zip(axes, panels, strict=True):
        for res in runs:
            colour = COLOURS[res.scenario.name.removesuffix("-obstacles")]
            _mean_band(ax, res.iterations, metrics.percent_collected(res), _label(res), colour)
        ax.set(title=title, xlabel="iterations", ylim=(0, 105))
        ax.legend(loc="lower right", fontsize="small")
    axes[0].set_ylabel("targets collected (%)")
    fig.suptitle(f"Targets collected over time ({SPREAD})")
    return fig


def _t99_bar(ax: Axes, x: float, res: Results, colour: str, obstacles: bool) -> None:
    """One bar: mean over the trials that reached 99 %, labelled with how many did. If none
    did, a hatched outline up to the run length says "not within the run" instead."""
    t = metrics.t_fraction(res["collected"], res.total_targets, res.iterations, 0.99)
    done, n = t[~np.isnan(t)], len(t)
    width = 0.38
    if done.size:
        spread = float(metrics.std(done)) if done.size > 1 else 0.0
        alpha = 0.5 if obstacles else 1.0
        ax.bar(x, done.mean(), width, yerr=spread, color=colour, alpha=alpha, capsize=4)
        ax.bar(x, done.mean(), width, fill=False, edgecolor="black", hatch=".." * obstacles)
        top = done.mean() + spread
    else:
        top = float(res.iterations[-1])
        ax.bar(x, top, width, fill=False, edgecolor=colour, hatch="xx")
    ax.annotate(
        f"{done.size}/{n}\nreached",
        (x, top),
        xytext=(0, 3),
        textcoords="offset points",
        ha="center",
        fontsize="x-small",
    )


def draw_t99(results: Mapping[str, Results]) -> Figure | None:
    """Study 1: time to collect 99 %, with the trials that never did shown rather than dropped."""
    if not _present(results, GROUPS + OBSTACLES):
        return None
    fig = _figure()
    ax = fig.subplots()
    for i, group in enumerate(GROUPS):
        for offset, name in ((-0.2, group), (0.2, f"{group}-obstacles")):
            if name in results:
                _t99_bar(ax, i + offset, results[name], COLOURS[group], name != group)
    ax.set_xticks(range(len(GROUPS)), [GROUP_LABELS[g] for g in GROUPS], fontsize="small")
    ax.set_ylabel("iterations to collect 99 % of targets")
    ax.margins(y=0.15)
    ax.legend(
        handles=[
            Patch(facecolor="grey", edgecolor="black", label="no obstacles"),
            Patch(facecolor="grey", alpha=0.5, edgecolor="black", hatch="..", label="obstacles"),
            Patch(
                fill=False,
                edgecolor="grey",
                hatch="xx",
                label="none reached 99 %: bar = run length",
            ),
        ],
        fontsize="small",
    )
    ax.set_title(
        "Iterations to 99 % collected: mean ± 1 s.d. over the trials that reached it",
        fontsize="medium",
    )
    return fig


def draw_opportunities(results: Mapping[str, Results]) -> Figure | None:
    """Study 2: more targets, more chances to meet a teacher, so more robots end knowing all."""
    runs = _present(results, OPPORTUNITIES)
    if not runs:
        return None
    fig = _figure()
    ax = fig.subplots()
    levels = np.arange(metrics.LEVELS)
    width = 0.8 / len(runs)
    for i, res in enumerate(runs):
        final = metrics.level_counts(res)[:, -1, :]
        spread = np.nan_to_num(metrics.std(final))
        x = levels - 0.4 + width * (i + 0.5)
        per_colour = res.scenario.targets.red
        label = f"{per_colour} per colour ({res.total_targets} targets, n={len(res.trials)})"
        ax.bar(x, final.mean(axis=0), width, yerr=spread, capsize=3, label=label)
    ax.set_xticks(levels, [f"g{k}: {k} colour{'s' * (k != 1)}" for k in range(metrics.LEVELS)])
    ax.set(xlabel="knowledge level at the end of the run", ylabel="robots")
    ax.legend(fontsize="small", title="targets")
    ax.set_title(f"Robots at each knowledge level at the end ({SPREAD})", fontsize="medium")
    return fig


def draw_range(results: Mapping[str, Results]) -> Figure | None:
    """Study 3: collection over time as the communication range grows, against bl1's ideal."""
    runs = _present(results, RANGES)
    if not runs:
        return None
    fig = _figure()
    ax = fig.subplots()
    for res in runs:
        label = f"range {res.scenario.comm_range:g} (n={len(res.trials)})"
        _mean_band(ax, res.iterations, metrics.percent_collected(res), label, alpha=0.1)
    if "bl1" in results:
        bl1 = results["bl1"]
        _mean_band(ax, bl1.iterations, metrics.percent_collected(bl1), _label(bl1), "k", "--")
    ax.set(xlabel="iterations", ylabel="targets collected (%)", ylim=(0, 105))
    ax.legend(loc="lower right", fontsize="small")
    ax.set_title(f"Targets collected by communication range, 39I-1M ({SPREAD})", fontsize="medium")
    return fig


def draw_queries_lost(results: Mapping[str, Results]) -> Figure | None:
    """Study 3: queries nobody answered before the learner gave up, by range."""
    runs = _present(results, RANGES)
    if not runs:
        return None
    fig = _figure()
    ax = fig.subplots()
    lost = [np.asarray(res["lost"][:, -1], dtype=np.float64) for res in runs]
    labels = [f"{res.scenario.comm_range:g}\n(n={len(res.trials)})" for res in runs]
    ax.boxplot(lost, tick_labels=labels)
    ax.plot(range(1, len(runs) + 1), [v.mean() for v in lost], "D", color="C3", label="mean")
    ax.set(xlabel="communication range (units)", ylabel="queries lost by the end (cumulative)")
    ax.legend(fontsize="small")
    ax.set_title("Queries lost per trial: box = quartiles, whiskers = 1.5 IQR", fontsize="medium")
    return fig


def draw_heterogeneity(
    res: Results | None, base: float = math.e, exponent: float = 1.0
) -> Figure | None:
    """Complexity, disparity, heterogeneity and mean knowledge score over time, each computed
    per trial and then averaged, so a trial's own mix of levels is never blended away."""
    if res is None:
        return None
    counts = metrics.level_counts(res)
    sets = metrics.set_counts(res)
    if sets is None:
        species, distance, unit = counts, metrics.level_distance(), "|Δlevel|"
    else:
        species, distance, unit = sets, metrics.set_distance(), "colours differing"
    complexity, disparity, hetero = metrics.heterogeneity(species, base, exponent, distance)
    panels = (
        (f"complexity (entropy, log base {_base_name(base)})", complexity),
        (f"disparity (Rao, d = 0.25·{unit}, exponent {exponent:g})", disparity),
        ("heterogeneity = complexity · disparity", hetero),
        ("mean knowledge score (0.25 per colour)", metrics.mean_knowledge_score(counts)),
    )
    fig = _figure(width=10.0, height=6.5)
    axes = fig.subplots(2, 2, sharex=True).ravel()
    for i, (ax, (title, values)) in enumerate(zip(axes, panels, strict=True)):
        _mean_band(ax, res.iterations, values, title, f"C{i}")
        ax.set_title(title, fontsize="small")
    for ax in axes[2:]:
        ax.set_xlabel("iterations")
    scenario = res.scenario
    fig.suptitle(
        f"{scenario.name} ({scenario.robots.label()}, {scenario.targets.total} targets, "
        f"n={len(res.trials)}): species {'g0..g4' if sets is None else 'sets of colours'}, "
        f"log base {_base_name(base)}, "
        f"exponent {exponent:g}; {SPREAD}",
        fontsize="medium",
    )
    return fig


# -- summary table ---------------------------------------------------------------------------


def _pm(mean: float, spread: float, digits: int = 0) -> str:
    if math.isnan(mean):
        return "—"
    if math.isnan(spread):
        return f"{mean:.{digits}f}"
    return f"{mean:.{digits}f} ± {spread:.{digits}f}"


def _ordered(results: Mapping[str, Results]) -> list[Results]:
    """The paper's order for presets, then anything else by name."""
    known = [results[n] for n in PRESETS if n in results]
    return known + [results[n] for n in sorted(results) if n not in PRESETS]


PAPER_LENGTH = 50_000
"""The paper's run length: longer scenarios are reported at it too."""


def summary_table(results: Mapping[str, Results]) -> str:
    """One Markdown row per scenario, the numbers of ``metrics.summary``; then, for the
    scenarios run longer than the paper's 50,000 iterations, the same numbers at 50,000."""
    head = (
        "| scenario | robots | mode | targets | iterations | trials | collected % "
        "| t95 (iterations) | t99 (iterations) | t100 (iterations) | queries | responses | lost "
        "| robots knowing 4 | robots knowing 4 when collection ended |"
    )
    lines = [
        "# Summary",
        "",
        "Mean ± sample standard deviation over trials, at the last recorded iteration. t100, t99 "
        "and t95 average only the trials that collected all (99 %, 95 %) of the targets; "
        "`reached/N` says how many. The last column is read at t100, over the trials that "
        "reached it. Modes: no-transfer is the release's NL, kt-bt its RL.",
        "",
        head,
        "|" + " --- |" * (head.count("|") - 1),
    ]
    ordered = _ordered(results)
    for res in ordered:
        s, sc = metrics.summary(res), res.scenario
        t95, t99, t100 = (
            f"{_pm(s[f'{k}_mean'], s[f'{k}_std'])} ({s[f'{k}_reached']}/{s['trials']})"
            for k in ("t95", "t99", "t100")
        )
        cells = [
            sc.name,
            sc.robots.label(),
            sc.mode.value + (" (broadcast)" if sc.teaching.value == "broadcast" else ""),
            str(sc.targets.total),
            f"{s['iteration']:,}",
            str(s["trials"]),
            _pm(s["collected_pct_mean"], s["collected_pct_std"], 1),
            t95,
            t99,
            t100,
            *(_pm(s[f"{k}_mean"], s[f"{k}_std"]) for k in ("queries", "responses", "lost")),
            _pm(s["knows_4_mean"], s["knows_4_std"], 1),
            f"{_pm(s['knows_4_end_mean'], s['knows_4_end_std'], 1)} ({s['t100_reached']}/"
            f"{s['trials']})",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    longer = [res for res in ordered if res.iterations[-1] > PAPER_LENGTH]
    if longer:
        head = "| scenario | collected % | queries | responses | lost | robots knowing 4 |"
        lines += [
            "",
            f"## At {PAPER_LENGTH:,} iterations",
            "",
            f"The scenarios run longer than the paper's {PAPER_LENGTH:,} iterations, read at "
            f"{PAPER_LENGTH:,}.",
            "",
            head,
            "|" + " --- |" * (head.count("|") - 1),
        ]
        for res in longer:
            s = metrics.summary(res, at=PAPER_LENGTH)
            cells = [
                res.scenario.name,
                _pm(s["collected_pct_mean"], s["collected_pct_std"], 1),
                *(_pm(s[f"{k}_mean"], s[f"{k}_std"]) for k in ("queries", "responses", "lost")),
                _pm(s["knows_4_mean"], s["knows_4_std"], 1),
            ]
            lines.append("| " + " | ".join(cells) + " |")
    lines += _modes_table(ordered)
    return "\n".join(lines) + "\n"


def _modes_table(ordered: list[Results]) -> list[str]:
    """The modes study's own columns (how robots learned, what they forgot, the messages, who
    knows three or four colours), for the scenarios of ``ktbt sim run modes`` present."""
    runs = [r for r in ordered if r.scenario.name in MODES and "messages" in r.data]
    if not runs:
        return []
    head = (
        "| scenario | robots | mode | trials | collected % | t95 (iterations) | queries "
        "| answers | learns: direct / buffered / passive | forgotten | messages (thousands) "
        "| robots knowing 3 or 4 |"
    )
    lines = ["", "## Modes", "", "Means over trials at the last recorded iteration.", "", head]
    lines.append("|" + " --- |" * (head.count("|") - 1))
    for res in runs:
        s, sc = metrics.summary(res), res.scenario
        t95 = f"{s['t95_mean']:,.0f}" if s["t95_reached"] else "—"
        learns = " / ".join(
            f"{s[f'learned_{k}_mean']:.0f}" for k in ("direct", "buffered", "passive")
        )
        cells = [
            sc.name, sc.robots.label(), sc.mode.value, str(s["trials"]),
            f"{s['collected_pct_mean']:.1f}", f"{t95} ({s['t95_reached']}/{s['trials']})",
            f"{s['queries_mean']:.0f}", f"{s['responses_mean']:.0f}", learns,
            f"{s['forgotten_mean']:.0f}", f"{s['messages_mean'] / 1000:.1f}",
            f"{s['knows_3_mean'] + s['knows_4_mean']:.1f}",
        ]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def draw_teaching(results: Mapping[str, Results]) -> Figure | None:
    """Who answers a query: the release's first-requester rule against a broadcast rule (any
    free knower in range answers), on the KT-BT group and on 39I-1M."""
    rows = [
        (title, runs) for title, *names in TEACHING if len(runs := _present(results, names)) == 2
    ]
    if not rows:
        return None
    fig = _figure(width=13.0, height=3.6 * len(rows))
    axes = fig.subplots(len(rows), 3, squeeze=False)
    for row, (title, runs) in zip(axes, rows, strict=True):
        for res, colour, rule in zip(
            runs, ("C0", "C3"), ("release rule", "broadcast rule"), strict=True
        ):
            label = f"{rule} (n={len(res.trials)})"
            _mean_band(row[0], res.iterations, metrics.percent_collected(res), label, colour)
            _mean_band(row[1], res.iterations, res["responses"], label, colour)
            _mean_band(row[2], res.iterations, res["knows_4"], label, colour)
        row[0].set(ylabel=f"{title}\ntargets collected (%)", ylim=(0, 105))
        row[1].set(ylabel="queries answered (cumulative)")
        row[2].set(ylabel="robots knowing all 4 colours")
        for ax in row:
            ax.set_xlabel("iterations")
            ax.legend(fontsize="small", loc="lower right")
    fig.suptitle(f"Who answers a query: the release's rule and a broadcast rule ({SPREAD})")
    return fig


def draw_modes(results: Mapping[str, Results]) -> Figure | None:
    """The release's hidden modes (and our eviction variant) on two groups: collection, the
    messages it took, and how far knowledge spread."""
    groups = [
        (group, runs)
        for group in MODE_GROUPS
        if (
            runs := [
                (m, results[f"modes-{group}-{m}"])
                for m in MODE_VARIANTS
                if f"modes-{group}-{m}" in results
            ]
        )
    ]
    if not groups:
        return None
    fig = _figure(width=15.0, height=3.8 * len(groups))
    axes = fig.subplots(len(groups), 3, squeeze=False)
    for row, (group, runs) in zip(axes, groups, strict=True):
        for k, (mode, res) in enumerate(runs):
            label = f"{MODE_VARIANTS[mode].label} (n={len(res.trials)})"
            colour = f"C{k}"
            _mean_band(row[0], res.iterations, metrics.percent_collected(res), label, colour)
            if "messages" in res.data:
                _mean_band(row[1], res.iterations, res["messages"] / 1000.0, label, colour)
            spread = res["knows_3"] + res["knows_4"]
            _mean_band(row[2], res.iterations, spread, label, colour)
        title = "10R-10G-10Y-10B" if group == "10rgyb" else "39I-1M"
        row[0].set(ylabel=f"{title}, 25 a colour\ntargets collected (%)", ylim=(0, 105))
        row[1].set(ylabel="messages delivered (thousands)")
        row[2].set(ylabel="robots knowing 3 or 4 colours")
        for ax in row:
            ax.set_xlabel("iterations")
        row[0].legend(fontsize="x-small", loc="lower right")
    fig.suptitle(f"The release's hidden modes and our two variants ({SPREAD})")
    return fig


# -- entry point -----------------------------------------------------------------------------


def _drawers(base: float, exponent: float) -> list[tuple[str, Drawer]]:
    out: list[tuple[str, Drawer]] = [
        ("collection", draw_collection),
        ("t99", draw_t99),
        ("opportunities", draw_opportunities),
        ("range", draw_range),
        ("queries_lost", draw_queries_lost),
        ("teaching", draw_teaching),
        ("modes", draw_modes),
    ]
    for name in HETEROGENEITY:
        out.append((name, partial(_heterogeneity_of, name, base=base, exponent=exponent)))
    return out


def _heterogeneity_of(
    name: str, results: Mapping[str, Results], base: float, exponent: float
) -> Figure | None:
    return draw_heterogeneity(results.get(name), base, exponent)


def plot(
    directory: str | Path,
    results: Mapping[str, Results] | None = None,
    study: str | None = None,
    *,
    base: float = math.e,
    exponent: float = 1.0,
) -> list[Path]:
    """Draw every figure there are results for into ``directory``, plus ``summary.md``.

    ``results`` defaults to what ``results.load(directory)`` finds. ``study`` (a key of
    ``STUDIES``) draws only that study's figures and tables only its scenarios. ``base``
    and ``exponent`` are the heterogeneity parameters (see ``metrics``). Returns the files
    written, PNG then SVG for each figure, the table last.
    """
    folder = Path(directory)
    if study is not None and study not in STUDIES:
        raise ValueError(f"no study {study!r}; studies: {', '.join(STUDIES)}")
    runs = dict(load(folder) if results is None else results)
    drawers = _drawers(base, exponent)
    if study is not None:
        figures, scenarios = STUDIES[study]
        runs = {n: r for n, r in runs.items() if n in scenarios}
        drawers = [(stem, draw) for stem, draw in drawers if stem in figures]
    folder.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    for stem, draw in drawers:
        fig = draw(runs)
        if fig is not None:
            written += _save(fig, folder, stem)
    table = folder / "summary.md"
    table.write_text(summary_table(runs), encoding="utf-8")
    return [*written, table]
