"""Running studies: many trials of some scenarios, in parallel processes or on a Ray cluster.

Every trial has its own seed, derived from the scenario's root seed and the trial number
(``SeedSequence(root, spawn_key=(trial,))``, the same stream as ``SeedSequence(root).spawn``),
so a trial gives the same rows wherever and in whatever order it runs. Workers return rows; the
driver alone writes files, one per finished trial, atomically: an interrupted sweep restarted
with the same output folder runs only the trials that are missing.
"""

from __future__ import annotations

import json
import multiprocessing
import signal
import time
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ktbt_proto.files import write_atomic
from ktbt_sim.results import (
    Results,
    combine,
    finished,
    load_folder,
    read_trial,
    trial_path,
    write_trial,
)
from ktbt_sim.scenario import PRESETS, STUDIES, Scenario

Rows = dict[str, list[int]]


def trial_seed(scenario: Scenario, trial: int) -> np.random.SeedSequence:
    return np.random.SeedSequence(scenario.seed, spawn_key=(trial,))


def run_trial(scenario_json: str, trial: int) -> Rows:
    """One trial from scratch: the rows recorded every ``record_every`` iterations (and at 0).

    Takes the scenario as JSON so that it crosses process and machine boundaries as data."""
    from ktbt_sim.world import RECORD_COLUMNS, World

    scenario = Scenario.model_validate_json(scenario_json)
    world = World(scenario, seed=trial_seed(scenario, trial))
    rows: Rows = {name: [] for name in RECORD_COLUMNS}

    def keep() -> None:
        for name, value in world.record().items():
            rows[name].append(value)

    keep()
    every = scenario.record_every
    for _ in range(scenario.iterations // every):
        world.run(every)
        keep()
    if scenario.iterations % every:
        world.run(scenario.iterations % every)
        keep()
    return rows


def scenarios_for(target: str) -> list[Scenario]:
    """A study name, a preset name, or a scenario file (TOML or JSON)."""
    if target in STUDIES:
        return [PRESETS[name] for name in STUDIES[target]]
    if target in PRESETS:
        return [PRESETS[target]]
    path = Path(target)
    if path.exists():
        return [Scenario.load(path)]
    known = ", ".join([*STUDIES, *sorted(PRESETS)])
    raise ValueError(f"{target!r} is neither a study, a preset nor a file; known: {known}")


Executor = Literal["local", "ray"]
"""Where a study's trials run: a pool of local processes, or a Ray cluster (the ray extra)."""


@dataclass(frozen=True)
class Job:
    scenario: Scenario
    folder: Path
    trial: int


def twins(scenarios: Iterable[Scenario]) -> dict[str, str]:
    """Each scenario's name -> the name of the first one with the same configuration (the
    paper's studies share some: ``range-200`` is ``opportunities-25``). A twin's trials are
    the same trials, so they run once and are copied."""
    first: dict[str, str] = {}
    out = {}
    for scenario in scenarios:
        key = json.dumps(scenario.model_dump(mode="json", exclude={"name"}), sort_keys=True)
        out[scenario.name] = first.setdefault(key, scenario.name)
    return out


def plan(scenarios: Iterable[Scenario], out: Path) -> list[Job]:
    """The trials still to run (a twin's only once); each scenario's folder is claimed with
    its ``scenario.json``. A folder that already holds a different scenario is refused rather
    than mixed."""
    scenarios = list(scenarios)
    original = twins(scenarios)
    jobs = []
    for scenario in scenarios:
        folder = out / scenario.name
        spec = folder / "scenario.json"
        text = scenario.dump()
        if spec.exists():
            try:
                held = json.loads(spec.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError, ValueError) as exc:
                raise ValueError(f"{spec}: not a scenario ({exc})") from None
            if not isinstance(held, dict):
                raise ValueError(f"{spec}: not a scenario")
            held.pop("trials", None)  # more or fewer trials of the same scenario mix well
            wanted = json.loads(text)
            wanted.pop("trials")
            if held != wanted:
                raise ValueError(
                    f"{folder} holds results of a different {scenario.name!r} scenario; "
                    "choose another --out or remove it"
                )
        else:
            write_atomic(spec, text)
        if original[scenario.name] != scenario.name:
            continue
        for torn in folder.glob(".trial-*.tmp"):  # left by a run that was killed mid-write
            torn.unlink(missing_ok=True)
        done = finished(folder)
        jobs += [Job(scenario, folder, t) for t in range(scenario.trials) if t not in done]
    return jobs


def _mirror(source: Path, twin: Scenario, target: Path) -> None:
    """Copy a twin's finished trials, each under its own scenario's name, written whole."""
    for trial in sorted(finished(source) - finished(target)):
        rows = read_trial(trial_path(source, trial))
        seed = int(trial_seed(twin, trial).generate_state(1)[0])
        write_trial(target, twin, trial, seed, rows)


Progress = Callable[[Job, float], None]
"""Told of each finished trial and how long it took."""


def run(
    scenarios: list[Scenario],
    out: Path,
    *,
    workers: int = 1,
    executor: Executor = "local",
    address: str | None = None,
    progress: Progress | None = None,
) -> dict[str, Results]:
    """Run every missing trial of ``scenarios`` into ``out`` and return all results."""
    jobs = plan(scenarios, out)
    if jobs:
        if executor == "ray":
            _run_ray(jobs, workers, address, progress)
        else:
            _run_local(jobs, workers, progress)
    original = twins(scenarios)
    results = {}
    for scenario in scenarios:
        folder = out / scenario.name
        if original[scenario.name] != scenario.name:
            _mirror(out / original[scenario.name], scenario, folder)
        combine(folder)
        loaded = load_folder(folder)
        if loaded is not None:
            results[scenario.name] = loaded
    return results


def _finish(job: Job, rows: Rows, started: float, progress: Progress | None) -> None:
    seed = int(trial_seed(job.scenario, job.trial).generate_state(1)[0])
    write_trial(job.folder, job.scenario, job.trial, seed, rows)
    if progress is not None:
        progress(job, time.perf_counter() - started)


def _run_local(jobs: list[Job], workers: int, progress: Progress | None) -> None:
    if workers <= 1:
        for job in jobs:
            started = time.perf_counter()
            _finish(job, run_trial(job.scenario.dump(), job.trial), started, progress)
        return
    context = multiprocessing.get_context("spawn")  # never fork near pymunk or zenoh
    pool = ProcessPoolExecutor(
        max_workers=workers, mp_context=context, initializer=_ignore_interrupts
    )
    try:
        pending: dict[Future[Rows], tuple[Job, float]] = {}
        queue = list(reversed(jobs))
        while queue or pending:
            while queue and len(pending) < workers * 2:
                job = queue.pop()
                future = pool.submit(run_trial, job.scenario.dump(), job.trial)
                pending[future] = (job, time.perf_counter())
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                job, started = pending.pop(future)
                _finish(job, future.result(), started, progress)
    except BaseException:
        # Ctrl-C (or an error): finished trials are already on disk; the running ones are
        # abandoned at once rather than waited for, and resume with the next run.
        _stop_now(pool)
        raise
    pool.shutdown()


def _ignore_interrupts() -> None:
    """Workers leave Ctrl-C to the driver, which stops them: a trial is never half-written."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _stop_now(pool: ProcessPoolExecutor) -> None:
    """Shut the pool down without waiting for the trials still running: terminate its workers
    (the executor keeps them in ``_processes``; it has no public way to stop them)."""
    workers = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for worker in workers:
        worker.terminate()
    for worker in workers:
        worker.join(timeout=5)


def _run_ray(jobs: list[Job], workers: int, address: str | None, progress: Progress | None) -> None:
    try:
        import ray
    except ImportError:
        raise ValueError("the Ray executor needs the ray extra: pip install 'ktbt[ray]'") from None
    started_here = not ray.is_initialized()
    if started_here:
        options: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
        if address:
            ray.init(address=address, **options)
        else:
            ray.init(num_cpus=max(1, workers), **options)
    try:
        remote = ray.remote(run_trial)
        pending = {
            remote.remote(job.scenario.dump(), job.trial): (job, time.perf_counter())
            for job in jobs
        }
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                job, started = pending.pop(ref)
                _finish(job, ray.get(ref), started, progress)
    finally:
        if started_here:
            ray.shutdown()
