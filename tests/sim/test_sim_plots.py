"""Simulator figures: every figure is written for synthetic results of its scenarios."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure

from ktbt_sim import plots
from ktbt_sim.results import Results, write_trial
from ktbt_sim.scenario import PRESETS, preset
from ktbt_sim.world import RECORD_COLUMNS

PNG = b"\x89PNG\r\n\x1a\n"
ROWS, TRIALS = 30, 3
FIGURES = (
    "collection",
    "t99",
    "opportunities",
    "range",
    "queries_lost",
    "teaching",
    "modes",
    "heterogeneity-39i1m",
    "heterogeneity-10rgyb",
)


def _levels(name: str, progress: np.ndarray) -> dict[str, np.ndarray]:
    """Robots by level moving from the scenario's start towards everyone at g4."""
    robots = preset(name).robots
    start = np.zeros(5, dtype=np.int64)
    start[0], start[1], start[4] = robots.ignorant, robots.red + robots.green, robots.multi
    start[1] += robots.yellow + robots.blue
    moved = np.minimum((progress * (start[:4].sum())).astype(np.int64), start[:4].sum())
    counts = np.zeros((*progress.shape, 5), dtype=np.int64)
    counts[..., 2] = moved // 2  # some robots half way, the rest at g4
    counts[..., 4] = start[4] + moved - moved // 2
    left = start[:4].sum() - moved
    lowest = 0 if robots.ignorant else 1
    counts[..., lowest] = left
    return {f"knows_{k}": counts[..., k] for k in range(5)}


def fake(name: str, reached: int = TRIALS, trials: int = TRIALS) -> Results:
    """Synthetic trials: linear collection, the first ``reached`` trials getting to 100 %."""
    scenario = preset(name)
    total = scenario.targets.total
    rng = np.random.default_rng(len(name))
    iterations = np.arange(1, ROWS + 1) * 10
    ramp = np.linspace(0.0, 1.0, ROWS)[None, :] * rng.uniform(1.2, 1.6, (trials, 1))
    cap = np.where(np.arange(trials) < reached, 1.0, 0.9)[:, None]
    progress = np.minimum(ramp, cap)
    data = {c: np.zeros((trials, ROWS), dtype=np.int64) for c in RECORD_COLUMNS[1:]}
    data["collected"] = np.floor(progress * total).astype(np.int64)
    data["queries"] = np.cumsum(rng.integers(0, 5, (trials, ROWS)), axis=1)
    data["responses"] = data["queries"] // 2
    data["lost"] = np.cumsum(rng.integers(0, 3, (trials, ROWS)), axis=1)
    data.update(_levels(name, np.minimum(ramp, 1.0)))
    return Results(scenario, tuple(range(trials)), iterations, data)


@pytest.fixture(scope="module")
def every_study() -> dict[str, Results]:
    out = {name: fake(name) for name in PRESETS}
    out["bl2-obstacles"] = fake("bl2-obstacles", reached=1)  # some trials never get to 99 %
    out["bl1-obstacles"] = fake("bl1-obstacles", reached=0)  # none do
    return out


@pytest.fixture(scope="module")
def drawn(every_study: dict[str, Results], tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("plots")
    written = plots.plot(folder, every_study)
    expected = [folder / f"{f}.{ext}" for f in FIGURES for ext in ("png", "svg")]
    assert written == [*expected, folder / "summary.md"]
    return folder


@pytest.mark.parametrize("figure", FIGURES)
def test_every_figure_is_written_as_png_and_svg(drawn: Path, figure: str) -> None:
    png, svg = drawn / f"{figure}.png", drawn / f"{figure}.svg"
    assert png.read_bytes().startswith(PNG)
    assert svg.stat().st_size > 0 and b"<svg" in svg.read_bytes()[:2000]


def test_summary_has_a_row_per_scenario(drawn: Path, every_study: dict[str, Results]) -> None:
    text = (drawn / "summary.md").read_text(encoding="utf-8").split("\n## ")[0]
    rows = [line for line in text.splitlines() if line.startswith("| ") and "---" not in line]
    assert len(rows) == len(every_study) + 1  # the header, then one per scenario
    names = [row.split("|")[1].strip() for row in rows[1:]]
    assert names == list(PRESETS)  # the paper's order
    bl1_obstacles = next(r for r in rows if r.startswith("| bl1-obstacles |"))
    assert "— (0/3)" in bl1_obstacles and "40M" in bl1_obstacles and "no-transfer" in bl1_obstacles
    assert "(1/3)" in next(r for r in rows if r.startswith("| bl2-obstacles |"))


def test_a_study_keeps_only_its_figures_and_scenarios(
    tmp_path: Path, every_study: dict[str, Results], monkeypatch: pytest.MonkeyPatch
) -> None:
    # Which figures are drawn is the question here, not rendering: skip the slow saving.
    def stems(fig: Figure, directory: Path, stem: str) -> list[Path]:
        return [directory / f"{stem}.png"]

    monkeypatch.setattr(plots, "_save", stems)
    subset = {n: every_study[n] for n in ("bl1", "ktbt", "range-100", "opportunities-10")}
    written = plots.plot(tmp_path, subset, study="range")
    assert [p.stem for p in written] == ["range", "queries_lost", "summary"]
    text = (tmp_path / "summary.md").read_text(encoding="utf-8")
    assert "| range-100 |" in text and "| bl1 |" in text and "| ktbt |" not in text
    written = plots.plot(tmp_path, subset)
    assert [p.stem for p in written] == [
        "collection",
        "t99",
        "opportunities",
        "range",
        "queries_lost",
        "summary",
    ]
    with pytest.raises(ValueError, match="no study 'nope'"):
        plots.plot(tmp_path, subset, study="nope")


def test_results_are_loaded_from_the_directory_and_only_present_figures_drawn(
    tmp_path: Path,
) -> None:
    res = fake("bl1", trials=1)  # one trial: no spread band or error bar, still figures
    folder = tmp_path / res.scenario.name
    folder.mkdir()
    (folder / "scenario.json").write_text(res.scenario.dump(), encoding="utf-8")
    rows = {"iteration": res.iterations.tolist()}
    rows.update({c: res[c][0].tolist() for c in RECORD_COLUMNS[1:]})
    write_trial(folder, res.scenario, 0, seed=0, rows=rows)
    written = plots.plot(tmp_path)
    assert [p.name for p in written] == [
        "collection.png",
        "collection.svg",
        "t99.png",
        "t99.svg",
        "summary.md",
    ]
    assert written[0].read_bytes().startswith(PNG)
    row = f"| bl1 | 40M | no-transfer | 100 | {rows['iteration'][-1]:,} | 1 | 100.0 |"
    assert row in (tmp_path / "summary.md").read_text(encoding="utf-8")


def test_the_modes_table_reads_how_robots_learned_and_forgot() -> None:
    res = fake("modes-39i1m-pl")
    res.data["learned_passive"][:, -1] = [3, 5, 7]  # TRIALS of them
    res.data["forgotten"][:, -1] = 2
    res.data["messages"][:, -1] = 1500
    res.data["knows_3"][:, -1] = 4
    text = plots.summary_table({"modes-39i1m-pl": res, "bl1": fake("bl1")})
    modes = text.split("## Modes")[1]
    row = next(line for line in modes.splitlines() if line.startswith("| modes-39i1m-pl |"))
    cells = [c.strip() for c in row.split("|")[1:-1]]
    passive = float(np.mean(res.data["learned_passive"][:, -1]))
    assert cells[8].endswith(f"/ {passive:.0f}") and cells[9] == "2" and cells[10] == "1.5"
    knows = float(np.mean(res.data["knows_3"][:, -1] + res.data["knows_4"][:, -1]))
    assert cells[11] == f"{knows:.1f}"
    assert "| bl1 |" not in modes  # only the modes study's scenarios
    assert "## Modes" not in plots.summary_table({"bl1": fake("bl1")})
