"""A run's figure: what each peer knows over time, fault windows shaded, the reference time
and convergence marked; below it, every learned item's timeline, stage by stage
(``check.STAGES``: where each transfer's time went). matplotlib comes with the ``fleet`` (or
``sim``) extra and is imported only here."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

from ktbt_proto.exchange.transferlog import Event
from ktbt_proto.tools.fleet.check import (
    STAGES,
    History,
    convergence_time,
    read_record,
    reference_time,
    timelines,
)

INSTALL = "the figure needs matplotlib: pip install 'ktbt[fleet]'"
COLOURS = {"partition-silent": "tab:red", "partition-reset": "tab:purple", "churn": "tab:orange"}


class FigureUnavailable(RuntimeError):
    pass


def pyplot() -> Any:
    if importlib.util.find_spec("matplotlib") is None:
        raise FigureUnavailable(INSTALL)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def knowledge_steps(h: History) -> dict[str, list[tuple[float, int]]]:
    """Per peer, (time, items known) at each change, over all its lives (0 while down)."""
    steps: dict[str, list[tuple[float, int]]] = {p: [(0.0, 0)] for p in h.peers}
    known: dict[str, set[str]] = {}
    timeline: list[tuple[float, str, str, Any]] = []
    for e in h.events:
        if e["kind"] == "launch" and e["peer"] in steps:  # a life starts with its save file
            timeline.append((e["t"], e["peer"], "up", e["life"]))
        elif e["kind"] == Event.MERGED and e["peer"] in steps:
            timeline.append((e["t"], e["peer"], "merged", e["sequence"]))
        elif e["kind"] == "kill":
            timeline.append((e["t"], e["peer"], "kill", None))
    lives = h.lives()
    for t, peer, what, value in sorted(timeline, key=lambda x: x[0]):
        if what == "up":
            known[peer] = set(lives[(peer, value)].get("known", []))
        elif what == Event.MERGED:
            known.setdefault(peer, set()).add(value)
        else:
            known[peer] = set()
        steps[peer].append((t, len(known.get(peer, set()) & set(h.items))))
    return steps


def draw(ax: Any, h: History, title: str) -> None:
    end = h.one("end")
    t_end = end["t"] if end else max(e["t"] for e in h.events)
    opened: dict[str, float] = {}
    for e in h.of("fault"):
        if e["fault"] not in COLOURS:
            continue
        if e["phase"] == "start":
            opened[e["fault"]] = e["t"]
        elif e["fault"] in opened:
            ax.axvspan(opened.pop(e["fault"]), e["t"], color=COLOURS[e["fault"]], alpha=0.15,
                       label=e["fault"])  # fmt: skip
    for steps in knowledge_steps(h).values():
        xs = [t for t, _ in steps] + [t_end]
        ys = [n for _, n in steps] + [steps[-1][1]]
        ax.step(xs, ys, where="post", lw=0.8, alpha=0.7)
    ref, done = reference_time(h), convergence_time(h)
    ax.axvline(ref, color="grey", ls="--", lw=0.8, label="reference")
    if done is not None:
        ax.axvline(done, color="black", lw=0.8, label="converged")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("seconds since launch")
    ax.set_ylabel("items known")
    ax.set_ylim(-0.2, len(h.items) + 0.2)
    ax.set_yticks(range(len(h.items) + 1))
    handles, labels = ax.get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))
    ax.legend(unique.values(), unique.keys(), fontsize=7, loc="lower right")


def draw_timelines(ax: Any, h: History) -> None:
    """One row per learned item (in merge order), a bar per stage of its timeline, coloured by
    stage; a stage whose marks the record lacks, or that ran backwards, is not drawn."""
    lines = sorted(timelines(h), key=lambda line: line["merge"])
    colours = plt_colours(len(STAGES))
    for row, line in enumerate(lines):
        for (a, b), colour in zip(STAGES, colours, strict=True):
            if line.get(a) is not None and line.get(b) is not None and line[b] >= line[a]:
                ax.barh(row, line[b] - line[a], left=line[a], height=0.8, color=colour,
                        label=f"{a} → {b}")  # fmt: skip
    ax.set_xlabel("seconds since launch")
    ax.set_ylabel("items learned")
    ax.set_yticks([])
    ax.set_title("each learned item's timeline", fontsize=9)
    handles, labels = ax.get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))
    if unique:
        ax.legend(unique.values(), unique.keys(), fontsize=6, loc="lower right", ncol=2)


def plt_colours(n: int) -> list[Any]:
    """``n`` distinct colours of matplotlib's qualitative map."""
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    return [cmap(i) for i in range(n)]


def plot_run(folder: Path) -> Path:
    plt = pyplot()
    h = History(read_record(folder / "events.jsonl"))
    fig, (ax, below) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    draw(ax, h, f"{folder.name}: {len(h.peers)} peers, {h.config['topology']}")
    draw_timelines(below, h)
    fig.tight_layout()
    path = folder / "knowledge.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
