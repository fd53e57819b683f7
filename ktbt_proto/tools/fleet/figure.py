"""A run's figure: what each peer knows over time, fault windows shaded, the reference time
and convergence marked. matplotlib comes with the ``fleet`` (or ``sim``) extra and is imported
only here."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

from ktbt_proto.exchange.transferlog import Event
from ktbt_proto.tools.fleet.check import History, convergence_time, read_record, reference_time

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


def plot_run(folder: Path) -> Path:
    plt = pyplot()
    h = History(read_record(folder / "events.jsonl"))
    fig, ax = plt.subplots(figsize=(7, 3.5))
    draw(ax, h, f"{folder.name}: {len(h.peers)} peers, {h.config['topology']}")
    fig.tight_layout()
    path = folder / "knowledge.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
