"""Records in the release's format: reading its CSVs, writing ours like them, comparing."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ktbt_sim import compare, records
from ktbt_sim import results as on_disk
from ktbt_sim.records import set_name
from ktbt_sim.scenario import Mode, Scenario
from ktbt_sim.world import World

RELEASE = Path(__file__).resolve().parents[1] / "data" / "release"
RL = RELEASE / "RL_0_0_10_10_10_10_N_100_100_100_100_200_-1"
"""The first 40 rows of two trials of the release's own KT-BT calibration run, unchanged."""


def test_a_release_csv_reads_as_our_columns() -> None:
    data = records.read_release_csv(next(RL.glob("*_Tr_1.csv")))
    assert data["iteration"][:3].tolist() == [10, 20, 30]  # blank lines between rows skipped
    assert data["queries"][0] == 13 and data["responses"][0] == 3
    assert data["lost"][0] == 10
    assert data["knows_1"][0] == 37 and data["knows_2"][0] == 3
    sets = np.stack([data[set_name(b)] for b in range(16)], axis=1)
    assert np.all(sets >= 0), "read in the order the values are really in, no set is negative"
    assert np.all(sets.sum(axis=1) == 40)
    # The three robots that know two colours at iteration 10 (columns 25 to 30 read
    # 1,0,1,0,0,1): in the release's real order RY, RB, RG, GY, GB, YB they are RY, RG, YB.
    pairs = {set_name(b): int(sets[0, b]) for b in range(16) if bin(b).count("1") == 2}
    assert {k for k, v in pairs.items() if v} == {"set_RY", "set_RG", "set_YB"}


def test_a_release_folder_reads_as_results_with_its_scenario() -> None:
    results = on_disk.read_release_folder(RL)
    assert results.trials == (1, 2)
    assert results.scenario.mode is Mode.KT_BT
    assert results.scenario.robots.label() == "10R-10G-10Y-10B"
    assert results.scenario.targets.total == 400 and results.scenario.comm_range == 200
    assert results["collected"].shape == (2, len(results.iterations))


def test_our_rows_written_as_the_release_writes_them_read_back_the_same(tmp_path: Path) -> None:
    world = World(Scenario(mode=Mode.KT_BT, iterations=1), seed=2)
    rows: dict[str, list[int]] = {name: [] for name in records.COLUMNS}
    for _ in range(300):
        world.run(10)
        for name, value in world.record().items():
            rows[name].append(value)
    path = tmp_path / "x_Tr_1.csv"
    records.write_release_csv(path, rows)
    lines = path.read_text(encoding="utf-8").splitlines()
    assert lines[0] == records.RELEASE_HEADER
    assert lines[0].split(",")[24:27] == [" Known St. RG", " Known St. RY", " Known St. RB"]
    assert all(line.endswith(",") and line.count(",") == 35 for line in lines[1:])
    back = records.read_release_csv(path)
    for name in (*records.RELEASE_FIELDS, *(set_name(b) for b in range(16))):
        assert back[name].tolist() == rows[name], name


def test_the_two_colour_columns_hold_ry_rb_rg_under_the_header_rg_ry_rb() -> None:
    sets = np.zeros(16, dtype=np.int64)
    sets[0b0101] = 7  # exactly red and yellow
    combos = records.at_least(sets)
    assert combos[:3].tolist() == [7, 0, 0]  # column 25 (labelled "RG") holds RY


def test_compare_against_the_release_excerpt(tmp_path: Path) -> None:
    lines = compare.lines(on_disk.read_release_folder(RL), on_disk.read_release_folder(RL))
    assert all(line.holds for line in lines if line.ours[2])
    assert [line.name.split(" at ")[0] for line in lines][3:] == [
        "queries",
        "answers",
        "queries lost",
        "robots knowing 4",
        "robots knowing 3",
        "robots knowing 2",
    ]
    out = tmp_path / "cmp"
    result = subprocess.run(
        [sys.executable, "-m", "ktbt_proto", "sim", "compare", str(RL), str(RL), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert "| queries at 400 |" in result.stdout and "**no**" not in result.stdout
    assert out.with_suffix(".png").stat().st_size > 0
    bad = subprocess.run(
        [sys.executable, "-m", "ktbt_proto", "sim", "compare", str(tmp_path), str(RL)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert bad.returncode == 2 and "neither" in bad.stderr


def test_sim_plot_reads_a_release_folder(tmp_path: Path) -> None:
    import shutil

    from ktbt_sim.results import load

    loaded = load(RL)
    assert list(loaded) == [f"release {RL.name}"]
    shutil.copytree(RL, tmp_path / RL.name)
    result = subprocess.run(
        [sys.executable, "-m", "ktbt_proto", "sim", "plot", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    assert f"release {RL.name}" in (tmp_path / "summary.md").read_text(encoding="utf-8")


def ktbt(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """The command line, run in ``cwd`` as a user runs it."""
    return subprocess.run(
        [sys.executable, "-m", "ktbt_proto", *args],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=cwd,
    )


def test_sim_run_writes_a_release_simdata_folder_that_compare_reads(tmp_path: Path) -> None:
    run = ktbt(tmp_path, "sim", "run", "calibration-rl", "--trials", "2", "--iterations", "300",
               "--release-csv", "-j", "1")  # fmt: skip
    assert run.returncode == 0, run.stderr
    name = "RL_0_0_10_10_10_10_N_100_100_100_100_200_-1"
    theirs = tmp_path / "results" / "calibration-rl" / "release" / name
    assert sorted(p.name for p in theirs.glob("*.csv")) == [f"{name}_Tr_{k}.csv" for k in (1, 2)]
    assert "RY" in (theirs / "README.txt").read_text(encoding="utf-8")
    shown = ktbt(tmp_path, "sim", "compare", "results/calibration-rl", str(theirs))
    assert shown.returncode == 0, shown.stderr
    assert "**no**" not in shown.stdout  # our rows, read back through the release's format


def test_every_preset_is_named_as_the_release_names_it_and_reads_back() -> None:
    """Each of the release's modes keeps its own name and memory duration through the folder
    name; our variants, which the release has not, get no release name at all."""
    from ktbt_sim.scenario import PRESETS, TeachingRule

    named = set()
    for scenario in PRESETS.values():
        variant = (
            scenario.teaching is not TeachingRule.RELEASE
            or scenario.memory_when_full != "refuse"
            or scenario.overhear_window != "wait"
        )
        if variant:
            with pytest.raises(ValueError, match="no such variant"):
                records.release_name(scenario)
            continue
        name = records.release_name(scenario)
        back = records.release_scenario(Path(name), scenario.iterations)
        assert name.split("_")[0] == records.RELEASE_MODES[scenario.mode]
        assert (back.mode, back.memory_duration) == (scenario.mode, scenario.memory_duration)
        assert (back.robots, back.targets) == (scenario.robots, scenario.targets)
        assert (back.comm_range, back.arena.obstacles) == (
            scenario.comm_range,
            scenario.arena.obstacles,
        )
        named.add(scenario.mode)
    assert named == set(Mode)


def test_sim_run_modes_exports_each_mode_under_its_own_name_and_compare_reads_it(
    tmp_path: Path,
) -> None:
    run = ktbt(tmp_path, "sim", "run", "modes", "--trials", "1", "--iterations", "100",
               "--release-csv", "-j", "2")  # fmt: skip
    assert run.returncode == 0, run.stderr
    exported = sorted(p for p in (tmp_path / "results").glob("*/release/*") if p.is_dir())
    prefixes = {p.name.split("_")[0] for p in exported}
    assert prefixes == {"NL", "RL", "EL", "PLB", "PL"}
    assert "EL_0_0_10_10_10_10_N_25_25_25_25_200_5000" in {p.name for p in exported}
    assert run.stderr.count("no such variant") == 4  # el-evict and pl-answer, in both groups
    for folder in exported:
        ours = folder.parent.parent
        shown = ktbt(tmp_path, "sim", "compare", str(ours.relative_to(tmp_path)), str(folder))
        assert shown.returncode == 0, shown.stderr
        assert "**no**" not in shown.stdout
