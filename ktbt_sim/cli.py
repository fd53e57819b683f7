"""``ktbt sim …`` and ``ktbt demo``: the simulator's commands, added to the ``ktbt`` command
line through the ``ktbt.commands`` entry point so that ``ktbt_proto`` never imports the
simulator. Heavy modules are imported inside the commands: ``ktbt fmt`` stays quick."""

from __future__ import annotations

import importlib.util
import os
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

import typer

from ktbt_proto.tools.cli.options import example

if TYPE_CHECKING:
    from ktbt_sim.experiment import Executor, Job
    from ktbt_sim.scenario import Scenario

sim = typer.Typer(
    help="The search-and-rescue simulator.",
    no_args_is_help=True,
)


def _fail(message: str) -> typer.Exit:
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(2)


SIM_MODULES = ("numpy", "pymunk", "pyarrow", "matplotlib", "pygame")
"""What the ``sim`` extra installs; the core distribution has none of them."""


def missing_extra() -> list[str]:
    """The simulator's dependencies that are not installed (none after ``ktbt[sim]``)."""
    return [name for name in SIM_MODULES if importlib.util.find_spec(name) is None]


@sim.callback()
def _need_sim() -> None:
    """Before any ``ktbt sim`` command: without the extra, say in one line how to get it."""
    missing = missing_extra()
    if missing:
        raise _fail(
            f"the simulator needs the sim extra ({', '.join(missing)} missing): "
            "pip install 'ktbt[sim]'"
        )


def _scenarios(
    target: str, trials: int | None, iterations: int | None, seed: int | None
) -> list[Scenario]:
    from ktbt_sim.experiment import scenarios_for

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
    executor: Executor = "local",
    address: str | None = None,
) -> tuple[int, int, float]:
    """Run with a progress bar (trials done, ETA); returns the trials run now, the trials that
    were already there, and the wall time in seconds. Ctrl-C stops at once, says how many
    trials are saved and how to resume, and exits 130."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from ktbt_sim.experiment import plan, run, twins

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
    ran = 0
    with Progress(*columns, transient=False) as bar:
        task = bar.add_task(f"{len(scenarios)} scenario(s)", total=total, completed=total - todo)

        def done(job: Job, seconds: float) -> None:
            nonlocal ran
            ran += 1
            bar.update(task, advance=1, description=f"{job.scenario.name} #{job.trial}")

        try:
            run(scenarios, out, workers=workers, executor=executor, address=address, progress=done)
        except (ValueError, OSError) as exc:
            raise _fail(str(exc)) from None
        except KeyboardInterrupt:
            bar.stop()
            # What is on disk, not what the workers reported: a trial whose file was renamed
            # into place just before the interrupt is saved, though its report never came.
            try:
                saved = total - len(plan(scenarios, out))
            except (ValueError, OSError):
                saved = total - todo + ran
            typer.echo(
                f"interrupted: {saved} of {total} trials are saved in {out}; "
                f"run the same command again to resume with the {total - saved} missing",
                err=True,
            )
            raise typer.Exit(130) from None
    return ran, total - todo, time.perf_counter() - started


Workers = Annotated[
    int,
    typer.Option("--workers", "-j", metavar="N", help="Parallel processes (default 0: all cores)."),
]


def _workers(workers: int) -> int:
    if workers < 0:
        raise _fail(f"--workers {workers}: use a number of processes, or 0 for all cores")
    return workers or os.cpu_count() or 1


@sim.command("run", epilog=example("ktbt sim run ktbt --trials 4 --out results"))
def run_command(
    target: Annotated[str, typer.Argument(help="A study, a preset or a scenario file.")],
    trials: Annotated[int | None, typer.Option(metavar="N", help="Trials per scenario.")] = None,
    iterations: Annotated[
        int | None, typer.Option(metavar="N", help="Iterations per trial.")
    ] = None,
    seed: Annotated[int | None, typer.Option(metavar="N", help="Root seed of the trials.")] = None,
    workers: Workers = 0,
    out: Annotated[
        Path, typer.Option(metavar="FOLDER", help="Output folder (resumable).", readable=False)
    ] = Path("results"),
    executor: Annotated[
        Literal["local", "ray"], typer.Option(help="local (process pool) or ray.")
    ] = "local",
    address: Annotated[
        str | None,
        typer.Option(metavar="ADDRESS", help="Ray cluster address (default: a local Ray)."),
    ] = None,
    release_csv: Annotated[
        bool,
        typer.Option(help="Also write each trial in the release's 35-column CSV format."),
    ] = False,
) -> None:
    """Run a study, a preset or a scenario file.

    An interrupted run restarted with the same --out runs only what is missing."""
    scenarios = _scenarios(target, trials, iterations, seed)
    ran, before, seconds = sweep(scenarios, out, _workers(workers), executor, address)
    if release_csv:
        from ktbt_sim.results import export_release

        for scenario in scenarios:
            try:
                typer.echo(str(export_release(out / scenario.name)))
            except ValueError as exc:  # one of our variants: the release has no name for it
                typer.echo(f"not exported in the release's format: {exc}", err=True)
    kept = f" ({before} {'was' if before == 1 else 'were'} already there)" if before else ""
    typer.echo(f"ran {ran} trial{'s' * (ran != 1)} in {seconds:.1f} s{kept}; results in {out}")


@sim.command("compare", epilog=example("ktbt sim compare results/ktbt release/ktbt"))
def compare_command(
    ours: Annotated[Path, typer.Argument(help="A scenario folder (ours or a release one).")],
    theirs: Annotated[Path, typer.Argument(help="Another, e.g. a release SimData folder.")],
    out: Annotated[
        Path | None,
        typer.Option(metavar="FOLDER", help="Write OUT.png and OUT.md beside the printed table."),
    ] = None,
) -> None:
    """Two runs of one configuration side by side.

    The numbers, and one figure."""
    from ktbt_sim.compare import compare

    try:
        typer.echo(compare(ours, theirs, out))
    except (ValueError, OSError) as exc:
        raise _fail(str(exc)) from None


@sim.command("plot", epilog=example("ktbt sim plot results"))
def plot_command(
    directory: Annotated[
        Path, typer.Argument(help="An output folder of `ktbt sim run`.", readable=False)
    ],
) -> None:
    """Draw every figure a run's folder has data for.

    PNG and SVG, and a summary table."""
    from ktbt_sim.plots import plot
    from ktbt_sim.results import load

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


@sim.command("list", epilog=example("ktbt sim list"))
def list_command() -> None:
    """Studies and presets."""
    from ktbt_sim.scenario import PRESETS, STUDIES

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


@sim.command("scenario", epilog=example("ktbt sim scenario ktbt > mine.json"))
def scenario_command(
    target: Annotated[str, typer.Argument(help="A preset or a scenario file.")],
) -> None:
    """Print a scenario as JSON.

    It is a starting point for a file of your own; on standard
    error, the physical values its numbers stand for in the release (radius in units, seconds
    per iteration), so that the output stays a file one can save."""
    for scenario in _scenarios(target, None, None, None):
        typer.echo(scenario.dump())
        for key, value in scenario.derived().items():
            typer.echo(f"# {key}: {value:g}", err=True)


@sim.command("view", epilog=example("ktbt sim view ktbt --record run.gif"))
def view_command(
    target: Annotated[str, typer.Argument(help="A preset or a scenario file.")] = "ktbt",
    seed: Annotated[int, typer.Option(metavar="N", help="Seed of the run.")] = 0,
    record: Annotated[
        Path | None,
        typer.Option(
            metavar="PATH",
            help="Write frames headless: out.gif, or a folder (no suffix) of PNGs.",
            readable=False,
        ),
    ] = None,
    frames: Annotated[int, typer.Option(metavar="N", help="Frames to record.")] = 150,
    every: Annotated[
        int,
        typer.Option(
            metavar="N", help="Iterations between recorded frames (default: 30,000 in all)."
        ),
    ] = 200,
    iterations: Annotated[
        int,
        typer.Option(
            metavar="N", help="Watching: close the window after this many (0: when you quit)."
        ),
    ] = 0,
    publish_events: Annotated[
        str | None,
        typer.Option(
            metavar="ENDPOINT", help="Stream the robots' events (ktbt monitor) from this endpoint."
        ),
    ] = None,
    wait_monitor: Annotated[
        float,
        typer.Option(
            metavar="SECONDS",
            help="With --publish-events: seconds to wait for a monitor before the first step, "
            "watching or recording headless alike, so it sees the run from its start "
            "(0: start at once; inf: wait for ever).",
        ),
    ] = 30.0,
) -> None:
    """Watch a run in a window, or record it headless.

    Space pauses, right arrow steps, +/- change speed, q quits."""
    for option, value, least in (
        ("--seed", seed, 0),
        ("--frames", frames, 1),
        ("--every", every, 1),
        ("--iterations", iterations, 0),
    ):
        if value < least:
            raise _fail(f"{option} {value}: use a whole number of at least {least}")
    if not wait_monitor >= 0:  # negative or nan
        raise _fail(f"--wait-monitor {wait_monitor}: use a number of seconds of at least 0")
    if wait_monitor >= threading.TIMEOUT_MAX:  # longer than a thread can wait: for ever
        wait_monitor = float("inf")
    if record is not None and record.suffix and record.suffix.lower() != ".gif":
        raise _fail(
            f"--record {record}: write an animated .gif, or a folder of PNG frames "
            f"(a name without a suffix), not {record.suffix}"
        )
    scenarios = _scenarios(target, None, None, None)
    if len(scenarios) != 1:
        raise _fail("view takes one scenario, not a study")
    from ktbt_sim import viewer

    if record is None:
        reason = viewer.no_display()
        if reason:
            raise _fail(f"{reason}; record the run instead: --record run.gif")
    from ktbt_proto.transport.stream import AgentStream
    from ktbt_proto.transport.zenoh import ZenohSettings
    from ktbt_sim.world import World

    world = World(scenarios[0], seed=seed)
    stream = None
    try:
        if publish_events:
            stream = AgentStream(world.agents, ZenohSettings(listen=[publish_events]))
            if wait_monitor:
                within = f" up to {wait_monitor:g} s" if wait_monitor < float("inf") else ""
                typer.echo(
                    f"waiting{within} for a monitor: "
                    f"ktbt monitor --connect {_connectable(publish_events)}"
                )
                if not stream.wait_watched(wait_monitor):
                    typer.echo("no monitor yet: running; a monitor started now misses the start")
        if record is not None:
            viewer.record(world, record, frames=frames, every=every)
            typer.echo(f"{record}: {frames} frames, iterations 0 to {(frames - 1) * every:,}")
        else:
            viewer.run(world, max_iterations=iterations or None)
    except (ValueError, OSError, RuntimeError) as exc:  # pygame.error is a RuntimeError
        raise _fail(str(exc)) from None
    finally:
        if stream is not None:
            stream.close()
            sent = sum(p.sent for p in stream.publishers)
            dropped = sum(p.dropped for p in stream.publishers)
            typer.echo(
                f"streamed {sent:,} events of {len(stream.publishers)} robots, {dropped:,} dropped"
            )


def _connectable(endpoint: str) -> str:
    """An endpoint a monitor on this machine connects to: one listening on any address
    (``tcp/0.0.0.0:7450``, ``tcp/[::]:7450``) is reached on loopback."""
    for any_address, loopback in (("0.0.0.0", "127.0.0.1"), ("[::]", "[::1]")):
        protocol, _, rest = endpoint.partition("/")
        if rest.startswith(any_address + ":"):
            return f"{protocol}/{loopback}{rest[len(any_address) :]}"
    return endpoint


def demo_command(
    out: Annotated[
        Path, typer.Option(metavar="FOLDER", help="Output folder.", readable=False)
    ] = Path("ktbt-demo"),
    trials: Annotated[int, typer.Option(metavar="N", help="Trials per group.")] = 4,
    iterations: Annotated[int, typer.Option(metavar="N", help="Iterations per trial.")] = 30_000,
    workers: Workers = 0,
) -> None:
    """The paper's main result in about a minute.

    KT-BT against both no-transfer baselines."""
    _need_sim()
    from ktbt_sim.plots import plot
    from ktbt_sim.scenario import PRESETS, STUDIES

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
    *_, seconds = sweep(scenarios, out, _workers(workers))
    try:
        plot(out)
    except (ValueError, OSError) as exc:
        raise _fail(str(exc)) from None
    typer.echo((out / "summary.md").read_text(encoding="utf-8"))
    typer.echo(f"figures in {out}/ ({seconds:.0f} s); the full studies: ktbt sim run all")


def register(app: typer.Typer) -> None:
    """Entry point of ``ktbt.commands``: add ``sim`` and ``demo`` to the ``ktbt`` app."""
    app.add_typer(sim, name="sim")
    app.command("demo", epilog=example("ktbt demo --out ktbt-demo"))(demo_command)
