"""``ktbt sim …`` and ``ktbt demo``: the simulator's commands, added to the ``ktbt`` command
line through the ``ktbt.commands`` entry point so that ``ktbt_proto`` never imports the
simulator. Heavy modules are imported inside the commands: ``ktbt fmt`` stays quick."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    from .experiment import Job
    from .scenario import Scenario

sim = typer.Typer(
    help="The search-and-rescue simulator: run the paper's studies, plot them, watch a run.",
    no_args_is_help=True,
)


def _fail(message: str) -> typer.Exit:
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(2)


def _scenarios(
    target: str, trials: int | None, iterations: int | None, seed: int | None
) -> list[Scenario]:
    from .experiment import scenarios_for

    changes: dict[str, int] = {}
    if trials is not None:
        changes["trials"] = trials
    if iterations is not None:
        changes["iterations"] = iterations
    if seed is not None:
        changes["seed"] = seed
    try:
        found = scenarios_for(target)
        return [s.with_(**changes) if changes else s for s in found]
    except ValueError as exc:
        raise _fail(str(exc)) from None


def sweep(
    scenarios: list[Scenario],
    out: Path,
    workers: int,
    executor: str = "local",
    address: str | None = None,
) -> float:
    """Run with a progress bar (trials done, ETA); returns the wall time in seconds."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from .experiment import plan, run, twins

    try:
        todo = len(plan(scenarios, out))
    except (ValueError, OSError) as exc:
        raise _fail(str(exc)) from None
    original = twins(scenarios)
    total = sum(s.trials for s in scenarios if original[s.name] == s.name)
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("trials"),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
    )
    started = time.perf_counter()
    with Progress(*columns, transient=False) as bar:
        task = bar.add_task(f"{len(scenarios)} scenario(s)", total=total, completed=total - todo)

        def done(job: Job, seconds: float) -> None:
            bar.update(task, advance=1, description=f"{job.scenario.name} #{job.trial}")

        try:
            run(scenarios, out, workers=workers, executor=executor, address=address, progress=done)
        except (ValueError, OSError) as exc:
            raise _fail(str(exc)) from None
    return time.perf_counter() - started


Workers = Annotated[
    int, typer.Option("--workers", "-j", help="Parallel processes (default: all cores).")
]


@sim.command("run")
def run_command(
    target: Annotated[str, typer.Argument(help="A study, a preset or a scenario file.")],
    trials: Annotated[int | None, typer.Option(help="Trials per scenario.")] = None,
    iterations: Annotated[int | None, typer.Option(help="Iterations per trial.")] = None,
    seed: Annotated[int | None, typer.Option(help="Root seed of the trials.")] = None,
    workers: Workers = 0,
    out: Annotated[Path, typer.Option(help="Output folder (resumable).")] = Path("results"),
    executor: Annotated[str, typer.Option(help="local (process pool) or ray.")] = "local",
    address: Annotated[
        str | None, typer.Option(help="Ray cluster address (default: a local Ray).")
    ] = None,
    release_csv: Annotated[
        bool,
        typer.Option(help="Also write each trial in the release's 35-column CSV format."),
    ] = False,
) -> None:
    """Run a study; an interrupted run restarted with the same --out runs only what is
    missing."""
    scenarios = _scenarios(target, trials, iterations, seed)
    seconds = sweep(scenarios, out, workers or os.cpu_count() or 1, executor, address)
    if release_csv:
        from .records import export_release

        for scenario in scenarios:
            typer.echo(str(export_release(out / scenario.name)))
    typer.echo(f"{sum(s.trials for s in scenarios)} trials in {out} ({seconds:.1f} s)")


@sim.command("compare")
def compare_command(
    ours: Annotated[Path, typer.Argument(help="A scenario folder (ours or a release one).")],
    theirs: Annotated[Path, typer.Argument(help="Another, e.g. a release SimData folder.")],
    out: Annotated[
        Path | None, typer.Option(help="Write OUT.png and OUT.md beside the printed table.")
    ] = None,
) -> None:
    """Two runs of one configuration side by side: the numbers and one figure."""
    from .compare import compare

    try:
        typer.echo(compare(ours, theirs, out))
    except (ValueError, OSError) as exc:
        raise _fail(str(exc)) from None


@sim.command("plot")
def plot_command(
    directory: Annotated[Path, typer.Argument(help="An output folder of `ktbt sim run`.")],
) -> None:
    """Draw every figure the folder has data for (PNG and SVG) and a summary table."""
    from .plots import plot
    from .results import load

    if not directory.is_dir():
        raise _fail(f"{directory} is not a folder")
    try:
        results = load(directory)
        if not results:
            raise _fail(f"{directory} holds no finished trial")
        written = plot(directory, results)
    except (ValueError, OSError) as exc:
        raise _fail(str(exc)) from None
    for path in written:
        typer.echo(str(path))


@sim.command("list")
def list_command() -> None:
    """Studies and presets."""
    from .experiment import STUDIES
    from .scenario import PRESETS

    typer.echo("studies:")
    for name, presets in STUDIES.items():
        typer.echo(f"  {name:<14} {', '.join(presets)}")
    typer.echo("presets:")
    for name, s in PRESETS.items():
        typer.echo(
            f"  {name:<22} {s.mode.value:<12} {s.robots.label():<16} "
            f"{s.targets.total} targets, range {s.comm_range:g}"
            f"{', obstacles' if s.arena.obstacles else ''}"
        )


@sim.command("scenario")
def scenario_command(
    target: Annotated[str, typer.Argument(help="A preset or a scenario file.")],
) -> None:
    """Print a scenario as JSON (a starting point for a file of your own) and, on standard
    error, the physical values its numbers stand for in the release (radius in units, seconds
    per iteration), so that the output stays a file one can save."""
    for scenario in _scenarios(target, None, None, None):
        typer.echo(scenario.dump())
        for key, value in scenario.derived().items():
            typer.echo(f"# {key}: {value:g}", err=True)


@sim.command("view")
def view_command(
    target: Annotated[str, typer.Argument(help="A preset or a scenario file.")] = "ktbt",
    seed: Annotated[int, typer.Option(min=0, help="Seed of the run.")] = 0,
    record: Annotated[
        Path | None, typer.Option(help="Write frames headless: out.gif or a folder of PNGs.")
    ] = None,
    frames: Annotated[int, typer.Option(min=1, help="Frames to record.")] = 100,
    every: Annotated[int, typer.Option(min=1, help="Iterations between recorded frames.")] = 50,
) -> None:
    """Watch a run: space pauses, right arrow steps, +/- change speed, q quits."""
    scenarios = _scenarios(target, None, None, None)
    if len(scenarios) != 1:
        raise _fail("view takes one scenario, not a study")
    from . import viewer
    from .world import World

    world = World(scenarios[0], seed=seed)
    try:
        if record is not None:
            viewer.record(world, record, frames=frames, every=every)
            typer.echo(str(record))
        else:
            viewer.run(world)
    except (ValueError, OSError, RuntimeError) as exc:  # pygame.error is a RuntimeError
        raise _fail(str(exc)) from None


def demo_command(
    out: Annotated[Path, typer.Option(help="Output folder.")] = Path("ktbt-demo"),
    trials: Annotated[int, typer.Option(help="Trials per group.")] = 4,
    iterations: Annotated[int, typer.Option(help="Iterations per trial.")] = 30_000,
    workers: Workers = 0,
) -> None:
    """The paper's main result in about a minute: KT-BT against both no-transfer baselines."""
    from .experiment import STUDIES
    from .plots import plot
    from .scenario import PRESETS

    try:
        scenarios = [
            PRESETS[n].with_(trials=trials, iterations=iterations) for n in STUDIES["demo"]
        ]
    except ValueError as exc:
        raise _fail(str(exc)) from None
    typer.echo(
        f"BL1 (40 robots that know every colour), BL2 (10 per colour, no transfer) and KT-BT "
        f"(10 per colour, sharing knowledge): {trials} trials of {iterations:,} iterations each."
    )
    seconds = sweep(scenarios, out, workers or os.cpu_count() or 1)
    try:
        plot(out)
    except (ValueError, OSError) as exc:
        raise _fail(str(exc)) from None
    typer.echo((out / "summary.md").read_text(encoding="utf-8"))
    typer.echo(f"figures in {out}/ ({seconds:.0f} s); the full studies: ktbt sim run all")


def register(app: typer.Typer) -> None:
    """Entry point of ``ktbt.commands``: add ``sim`` and ``demo`` to the ``ktbt`` app."""
    app.add_typer(sim, name="sim")
    app.command("demo")(demo_command)
