"""``ktbt fleet ...``: added to the ``ktbt`` command line through the ``ktbt.commands`` entry
point, so the core command line never imports it."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer

fleet = typer.Typer(
    help="A fleet of real peers on this machine, every link through a fault layer.",
    no_args_is_help=True,
)


def _fail(message: str) -> typer.Exit:
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(2)


def _show(summary: dict[str, object]) -> None:
    for v in summary["verdicts"]:  # type: ignore[attr-defined]
        typer.echo(f"  {v['status']:7} {v['name']}: {v['detail']}")
    conv = summary.get("convergence_s")
    floor, linked = summary.get("floor_s"), summary.get("floor_proxied_s")
    typer.echo(
        f"  convergence {'-' if conv is None else f'{conv:.2f} s'}, "
        f"{summary.get('messages_per_item')} messages per learned item, "
        f"query round trip {_ms(floor)} direct, {_ms(linked)} through a link, "
        f"{summary.get('honest_answers_refused')} honest answers refused"
    )


def _ms(value: object) -> str:
    return "-" if value is None else f"{float(value) * 1000:.1f} ms"  # type: ignore[arg-type]


@fleet.command("run")
def run_command(
    peers: Annotated[int, typer.Option(help="Peers, teachers included.")] = 10,
    teachers: Annotated[int, typer.Option(help="Peers that start with the knowledge.")] = 1,
    topology: Annotated[str, typer.Option(help="mesh, line, or router.")] = "mesh",
    routers: Annotated[int, typer.Option(help="Routers (0: one per 20 peers).")] = 0,
    loss: Annotated[float, typer.Option(help="Packets dropped on every link, 0 to 1.")] = 0.0,
    delay: Annotated[str, typer.Option(help="One-way delay on every link, e.g. 200ms.")] = "0",
    partition: Annotated[
        str, typer.Option(help="A half/half partition this long, e.g. 30s (0: none).")
    ] = "0",
    partition_kind: Annotated[
        str,
        typer.Option(
            help="silent (hold bytes, keep sockets), reset (RST), or none (the same halves, "
            "nothing cut: a baseline)."
        ),
    ] = "silent",
    churn: Annotated[float, typer.Option(help="Learners killed -9 and restarted, 0 to 1.")] = 0.0,
    churn_rounds: Annotated[int, typer.Option(help="Churn rounds.")] = 1,
    seed: Annotated[int, typer.Option(help="The seed of the fault schedule.")] = 7,
    bound: Annotated[float, typer.Option(help="Seconds allowed for convergence.")] = 30.0,
    knowledge: Annotated[
        Path | None, typer.Option(help="The teachers' .sbt file (default: the colours).")
    ] = None,
    teacher: Annotated[
        str, typer.Option(help="run (fleet members: peer run --knowledge) or serve (peer serve).")
    ] = "run",
    out: Annotated[Path, typer.Option(help="Folder for the record and the figure.")] = Path(
        "fleet-run"
    ),
    live: Annotated[bool, typer.Option(help="Show the live table.")] = True,
    monitor: Annotated[
        str | None,
        typer.Option(
            help="Watch the fleet in the browser: `ktbt monitor` serves its page on HOST:PORT "
            "(e.g. 127.0.0.1:8470) for the whole run; needs the monitor extra."
        ),
    ] = None,
    settle: Annotated[
        float, typer.Option(help="Seconds the fleet keeps running once it has converged.")
    ] = 1.0,
) -> None:
    """Run a fleet scenario, check it and draw it; exit 1 if a property failed."""
    from ktbt_proto.tools.cli import _knowledge_or_exit
    from ktbt_proto.tools.fleet.plan import FleetConfig, PlanError, seconds
    from ktbt_proto.tools.fleet.runner import run
    from ktbt_proto.tools.fleet.watch import MonitorFailed

    if monitor is not None:
        from ktbt_proto.tools.monitor.command import INSTALL, _address

        _address(monitor, "--monitor")  # a bad HOST:PORT is refused before anything starts
        try:
            import starlette  # noqa: F401
            import uvicorn  # noqa: F401
        except ImportError:
            raise _fail(INSTALL) from None
    if knowledge is not None:  # refused here, with its position, not inside the namespace
        _knowledge_or_exit(knowledge)
    try:
        config = FleetConfig(
            peers=peers, teachers=teachers, topology=topology, routers=routers,  # type: ignore[arg-type]
            loss=loss, delay=seconds(delay), partition=seconds(partition),
            partition_kind=partition_kind, churn=churn, churn_rounds=churn_rounds,  # type: ignore[arg-type]
            seed=seed, bound=bound, teacher=teacher, settle=settle,  # type: ignore[arg-type]
            knowledge=str(knowledge.resolve()) if knowledge else "",
            name=out.name,
        )  # fmt: skip
    except PlanError as exc:
        raise _fail(str(exc)) from None
    try:
        summary = run(config, out, typer.echo, live=live and sys.stdout.isatty(), monitor=monitor)
    except MonitorFailed as exc:
        raise _fail(str(exc)) from None
    except KeyboardInterrupt:  # before the schedule began, or after it ended
        typer.echo(f"{out}: interrupted; every process it started is stopped", err=True)
        raise typer.Exit(130) from None
    typer.echo(f"{out}: {'passed' if summary['passed'] else 'FAILED'}")
    _show(summary)
    _figure(out)
    raise typer.Exit(0 if summary["passed"] else 1)


def _figure(out: Path) -> None:
    from ktbt_proto.tools.fleet.figure import FigureUnavailable, plot_run

    try:
        typer.echo(f"figure: {plot_run(out)}")
    except FigureUnavailable as exc:
        typer.echo(str(exc))


@fleet.command("check")
def check_command(
    folder: Annotated[Path, typer.Argument(help="A run's folder (with events.jsonl).")],
) -> None:
    """Check a run's record again; exit 1 if a property failed."""
    from ktbt_proto.tools.fleet.check import check_record

    if not (folder / "events.jsonl").exists():
        raise _fail(f"{folder}: no events.jsonl")
    try:
        summary = check_record(folder)
    except (ValueError, KeyError, TypeError) as exc:
        raise _fail(f"{folder}/events.jsonl: not a fleet record ({exc})") from None
    typer.echo(f"{folder}: {'passed' if summary['passed'] else 'FAILED'}")
    _show(summary)
    raise typer.Exit(0 if summary["passed"] else 1)


@fleet.command("study")
def study_command(
    out: Annotated[Path, typer.Option(help="Folder for every run's record.")] = Path(
        "results/fleet"
    ),
    docs: Annotated[Path, typer.Option(help="Where the table and the figure go.")] = Path(
        "docs/results"
    ),
    only: Annotated[
        list[str] | None, typer.Option(help="Run only this scenario (repeatable).")
    ] = None,
) -> None:
    """The whole study: convergence against size, loss, delay, partition and churn."""
    from ktbt_proto.tools.fleet.study import SCENARIOS, study

    unknown = set(only or ()) - {name for name, _, _ in SCENARIOS}
    if unknown:
        raise _fail(f"no such scenario: {', '.join(sorted(unknown))}")
    summaries = study(out, docs, typer.echo, only)
    failed = [s["name"] for s in summaries if not s["passed"]]
    typer.echo(json.dumps({"runs": len(summaries), "failed": failed}))
    raise typer.Exit(1 if failed else 0)


def register(app: typer.Typer) -> None:
    app.add_typer(fleet, name="fleet")
