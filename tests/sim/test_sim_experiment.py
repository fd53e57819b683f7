"""Sweeps: seeds per trial, 1 vs 2 workers, resumption after a kill, Ray, plots, the CLI."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ktbt_sim.experiment import run, scenarios_for
from ktbt_sim.results import finished, load
from ktbt_sim.scenario import Scenario, preset

ROOT = Path(__file__).resolve().parents[2]


def small(name: str = "small", trials: int = 3, iterations: int = 400) -> Scenario:
    return preset("ktbt").with_(name=name, trials=trials, iterations=iterations, record_every=50)


def same(a: dict, b: dict) -> bool:  # type: ignore[type-arg]
    return a.keys() == b.keys() and all(
        a[k].trials == b[k].trials
        and all(np.array_equal(a[k].data[c], b[k].data[c]) for c in a[k].data)
        for k in a
    )


def ktbt(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ktbt_proto", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=timeout,
    )


def test_one_and_two_workers_give_identical_results(tmp_path: Path) -> None:
    one = run([small()], tmp_path / "one", workers=1)
    two = run([small()], tmp_path / "two", workers=2)
    assert same(one, two)
    results = one["small"]
    assert results.trials == (0, 1, 2)
    assert results.iterations.tolist() == list(range(0, 401, 50))
    # Each trial has its own seed: the trials differ from one another.
    assert not np.array_equal(results["walking"][0], results["walking"][1])
    header = (tmp_path / "one" / "small.csv").read_text().splitlines()[0]
    assert header.replace('"', "").startswith("trial,iteration,")
    assert (tmp_path / "one" / "small.parquet").stat().st_size > 0


def test_a_killed_sweep_resumes_with_only_the_missing_trials(tmp_path: Path) -> None:
    scenario = small(trials=6, iterations=3000)
    spec = tmp_path / "small.json"
    spec.write_text(scenario.dump())
    out = tmp_path / "out"
    args = [sys.executable, "-m", "ktbt_proto", "sim", "run", str(spec), "--out", str(out)]
    proc = subprocess.Popen([*args, "-j", "1"], cwd=ROOT, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while len(finished(out / "small")) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    done = finished(out / "small")
    assert 2 <= len(done) < 6
    stamps = {t: (out / "small" / f"trial-{t:04d}.parquet").stat().st_mtime_ns for t in done}
    resumed = ktbt("sim", "run", str(spec), "--out", str(out), "-j", "2")
    assert resumed.returncode == 0, resumed.stderr
    for t, stamp in stamps.items():  # finished trials were not run again
        assert (out / "small" / f"trial-{t:04d}.parquet").stat().st_mtime_ns == stamp
    assert finished(out / "small") == set(range(6))
    assert not list((out / "small").glob("*.tmp*"))
    assert same(load(out), run([scenario], tmp_path / "straight", workers=2))


def test_a_folder_of_another_scenario_is_refused(tmp_path: Path) -> None:
    run([small(iterations=100, trials=1)], tmp_path, workers=1)
    with pytest.raises(ValueError, match="different 'small' scenario"):
        run([small(iterations=200, trials=1)], tmp_path, workers=1)
    result = ktbt("sim", "run", "no-such-study", "--out", str(tmp_path))
    assert result.returncode == 2 and "neither a study, a preset nor a file" in result.stderr


def test_ray_executor_matches_the_local_pool(tmp_path: Path) -> None:
    import ray  # a dev dependency: missing, this test fails rather than skips

    assert ray.__version__
    scenario = small(trials=2, iterations=300)
    local = run([scenario], tmp_path / "local", workers=2)
    remote = run([scenario], tmp_path / "ray", workers=2, executor="ray")
    assert same(local, remote)


def test_sim_plot_draws_files_from_a_real_sweep(tmp_path: Path) -> None:
    scenarios = [p.with_(trials=2, iterations=600, record_every=50) for p in scenarios_for("demo")]
    run(scenarios, tmp_path, workers=2)
    result = ktbt("sim", "plot", str(tmp_path))
    assert result.returncode == 0, result.stderr
    for name in ("collection.png", "collection.svg", "t99.png", "summary.md"):
        assert (tmp_path / name).stat().st_size > 0
    summary = (tmp_path / "summary.md").read_text()
    assert all(f"| {name} " in summary for name in ("bl1", "bl2", "ktbt"))


def test_demo_prints_the_summary_and_writes_the_figure(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    result = ktbt("demo", "--trials", "1", "--iterations", "300", "--out", str(out), "-j", "2")
    assert result.returncode == 0, result.stderr
    assert "| bl1 " in result.stdout and "| ktbt " in result.stdout
    assert (out / "collection.png").stat().st_size > 0


def test_sim_list_and_scenario_print_what_a_user_can_run(tmp_path: Path) -> None:
    listed = ktbt("sim", "list")
    assert listed.returncode == 0 and "opportunities-100" in listed.stdout
    shown = ktbt("sim", "scenario", "range-500")
    assert shown.returncode == 0
    path = tmp_path / "mine.json"
    path.write_text(shown.stdout)
    assert Scenario.load(path).comm_range == 500.0
    assert "# comm_radius_units: 1536" in shown.stderr  # 3 x 500 + the body, in units


def test_sim_view_records_frames_headless(tmp_path: Path) -> None:
    gif = tmp_path / "run.gif"
    env = {**os.environ, "SDL_VIDEODRIVER": "dummy", "SDL_AUDIODRIVER": "dummy"}
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "ktbt_proto",
            "sim",
            "view",
            "bl1",
            "--record",
            str(gif),
            "--frames",
            "3",
            "--every",
            "20",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
        env=env,
    )
    assert result.returncode == 0, result.stderr
    from PIL import Image

    with Image.open(gif) as image:
        assert getattr(image, "n_frames", 1) == 3
    folder = tmp_path / "frames"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "ktbt_proto",
            "sim",
            "view",
            "ktbt",
            "--record",
            str(folder),
            "--frames",
            "2",
            "--every",
            "5",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
        env=env,
    )
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in folder.iterdir()) == ["frame-0000.png", "frame-0001.png"]


def test_twin_scenarios_run_once_and_both_get_the_trials(tmp_path: Path) -> None:
    a, b = small("a", trials=2, iterations=200), small("b", trials=2, iterations=200)
    results = run([a, b], tmp_path, workers=1)
    assert same({"x": results["a"]}, {"x": results["b"]})
    # Identical configuration, one run: the twin's files hold the same rows, under its name.
    import pyarrow.parquet as pq

    for t in (0, 1):
        meta = pq.read_table(tmp_path / "b" / f"trial-{t:04d}.parquet").schema.metadata
        assert Scenario.model_validate_json(meta[b"ktbt.scenario"]).name == "b"
    assert results["b"].scenario.name == "b"


def test_user_errors_are_one_line_and_exit_2(tmp_path: Path) -> None:
    afile = tmp_path / "afile"
    afile.write_text("x")
    empty = tmp_path / "empty"
    empty.mkdir()
    broken = tmp_path / "broken" / "s"
    broken.mkdir(parents=True)
    (broken / "scenario.json").write_text("[1, 2]")
    cases = [
        (("sim", "plot", str(empty)), "holds no finished trial"),
        (("sim", "run", "bl1", "--out", str(afile), "--iterations", "10"), "afile"),
        (("sim", "run", "bl1", "--trials", "0"), "trials"),
        (("demo", "--trials", "0", "--out", str(tmp_path / "d")), "trials"),
        (("sim", "plot", str(tmp_path / "broken")), "not a scenario"),
        (("sim", "view", "bl1", "--record", str(tmp_path / "x.gif"), "--frames", "0"), "frames"),
    ]
    for args, words in cases:
        result = ktbt(*args)
        assert result.returncode == 2, (args, result.stderr)
        assert "Traceback" not in result.stderr and words in result.stderr, (args, result.stderr)
    assert not (empty / "summary.md").exists()
