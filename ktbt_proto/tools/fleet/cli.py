"""``ktbt fleet ...``: added to the ``ktbt`` command line through the ``ktbt.commands`` entry
point, so the core command line never imports it."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from ktbt_proto.items import show_sequence
from ktbt_proto.tools.cli.options import (
    ControlOption,
    DemoOption,
    VocabularyOption,
    address,
    example,
    knowledge_or_exit,
    refuse,
    robot_or_exit,
)
from ktbt_proto.tools.fleet.plan import PartitionKind, TeacherProgram, Topology

fleet = typer.Typer(
    help="A fleet of real peers on this machine, with faults on every link.",
    no_args_is_help=True,
)


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
    for item in summary.get("hops") or ():  # type: ignore[attr-defined]
        typer.echo(f"  hop by hop, {show_sequence(item['item'])}: {hop_line(item)}")
    idle: Any = summary.get("idle")
    if idle:
        typer.echo(f"  idle after convergence ({idle['window_s']:.1f} s): {idle_line(idle)}")


def idle_line(idle: dict[str, Any]) -> str:
    """What each role cost when nothing was left to learn (check.idle_cost), median / worst."""
    return "; ".join(
        f"{role} {cpu['median']:.1f} / {cpu['worst']:.1f} ms CPU a second,"
        f" {idle['rss_mb'][role]['median']:.0f} / {idle['rss_mb'][role]['worst']:.0f} MB RSS"
        for role, cpu in idle["cpu_ms_per_s"].items()
    )


def hop_line(item: dict[str, Any]) -> str:
    """One item's hops as the report prints them (check.hops)."""
    at, per = item["last_at_eccentricity_s"], item["per_hop_s"]
    far = (
        "not every peer that far learned it"
        if at is None
        else f"the last peer that far knew it {at:.2f} s after the reference, {per:.3f} s a hop"
    )
    depth = "-" if item["depth"] is None else item["depth"]
    return (
        f"tree depth {depth}, longest shortest path {item['eccentricity']} hops; {far}"
        f" ({item['detours']} learned on a longer path, {item['off_graph']} off the graph)"
    )


def _absolute(vocabulary: str | None) -> str:
    """``--vocabulary`` as every peer must be given it: a file by its absolute path (a
    module:callable as given: the peers run in this folder)."""
    if vocabulary is None:
        return ""
    path = Path(vocabulary)
    return str(path.resolve()) if path.is_file() else vocabulary


def _ms(value: object) -> str:
    return "-" if value is None else f"{float(value) * 1000:.1f} ms"  # type: ignore[arg-type]


def run_command(
    peers: Annotated[
        int, typer.Option("--peers", metavar="N", help="Peers, teachers included.")
    ] = 10,
    teachers: Annotated[
        int, typer.Option("--teachers", metavar="N", help="Peers that start with the knowledge.")
    ] = 1,
    topology: Annotated[
        Topology, typer.Option("--topology", help="How the peers are linked.")
    ] = "mesh",
    routers: Annotated[
        int, typer.Option("--routers", metavar="N", help="Routers (0: one per 20 peers).")
    ] = 0,
    radius: Annotated[
        float,
        typer.Option(
            "--radius",
            metavar="R",
            help="With --topology geometric: peers placed at random (by --seed) in a square of "
            "side 1 are linked within this range, e.g. 0.2.",
        ),
    ] = 0.0,
    edges: Annotated[
        Path | None,
        typer.Option(
            "--edges",
            metavar="FILE",
            help="With --topology edges: a networkx edge list of peer indices (0 1 a line).",
            readable=False,
        ),
    ] = None,
    loss: Annotated[
        float,
        typer.Option("--loss", metavar="FRACTION", help="Packets dropped on every link, 0 to 1."),
    ] = 0.0,
    delay: Annotated[
        str,
        typer.Option("--delay", metavar="TIME", help="One-way delay on every link, e.g. 200ms."),
    ] = "0",
    partition: Annotated[
        str,
        typer.Option(
            "--partition",
            metavar="TIME",
            help="A half/half partition this long, e.g. 30s (routers: between two groups).",
        ),
    ] = "0",
    partition_kind: Annotated[
        PartitionKind,
        typer.Option(
            "--partition-kind",
            help="silent (hold bytes, keep sockets), reset (RST), or none (the same halves, "
            "nothing cut: a baseline).",
        ),
    ] = "silent",
    churn: Annotated[
        float,
        typer.Option(
            "--churn", metavar="FRACTION", help="Learners killed -9 and restarted, 0 to 1."
        ),
    ] = 0.0,
    churn_rounds: Annotated[
        int, typer.Option("--churn-rounds", metavar="N", help="Churn rounds.")
    ] = 1,
    seed: Annotated[
        int, typer.Option("--seed", metavar="N", help="The seed of the fault schedule.")
    ] = 7,
    bound: Annotated[
        float,
        typer.Option("--bound", metavar="SECONDS", help="Seconds allowed for convergence."),
    ] = 30.0,
    knowledge: Annotated[
        Path | None,
        typer.Option(
            "--knowledge",
            metavar="FILE",
            help="The teachers' .sbt file; learners meet its sequences (default: the colours).",
            readable=False,
        ),
    ] = None,
    vocabulary: VocabularyOption = None,
    control: ControlOption = None,
    demo: DemoOption = False,
    teacher: Annotated[
        TeacherProgram,
        typer.Option(
            "--teacher", help="run (fleet members: peer run --knowledge) or serve (peer serve)."
        ),
    ] = "run",
    out: Annotated[
        Path, typer.Option("--out", metavar="FOLDER", help="Folder for the record and figure.")
    ] = Path("fleet-run"),
    live: Annotated[bool, typer.Option("--live/--no-live", help="Show the live table.")] = True,
    monitor: Annotated[
        str | None,
        typer.Option(
            "--monitor",
            metavar="HOST:PORT",
            help="Watch the fleet in the browser: `ktbt monitor` serves its page here for the "
            "whole run; needs the monitor extra.",
        ),
    ] = None,
    settle: Annotated[
        float,
        typer.Option(
            "--settle",
            metavar="SECONDS",
            help="Seconds the fleet keeps running once it has converged.",
        ),
    ] = 1.0,
) -> None:
    """Run a fleet scenario, check it and draw it.

    Exit 1 if a property failed. Every link goes through a fault layer. Partitions need
    peer links (not --topology router); times are like 200ms or 30s (0: none). Every peer is
    the robot --vocabulary and --control describe (as in peer run), or the demo robot. The
    geometric, grid and edges topologies need the fleet extra (networkx); one that is not
    connected is refused."""
    from ktbt_proto.tools.fleet.plan import FleetConfig, PlanError, seconds
    from ktbt_proto.tools.fleet.runner import run
    from ktbt_proto.tools.fleet.watch import MonitorFailed

    if monitor is not None:
        from ktbt_proto.tools.monitor.command import INSTALL

        address(monitor, "--monitor")  # a bad HOST:PORT is refused before anything starts
        try:
            import starlette  # noqa: F401
            import uvicorn  # noqa: F401
        except ImportError:
            raise refuse(INSTALL) from None
    # Refused here, in one line with its position, not inside the namespace.
    robot = robot_or_exit(vocabulary, control, demo)
    if knowledge is not None or robot.vocabulary is not None:
        from ktbt_proto.tools.fleet.runner import EXAMPLE_KNOWLEDGE

        knowledge_or_exit(knowledge or EXAMPLE_KNOWLEDGE, robot.registry)
    try:
        config = FleetConfig(
            peers=peers, teachers=teachers, topology=topology, routers=routers, radius=radius,
            edges=str(edges.resolve()) if edges else "",
            loss=loss, delay=seconds(delay), partition=seconds(partition),
            partition_kind=partition_kind, churn=churn, churn_rounds=churn_rounds,
            seed=seed, bound=bound, teacher=teacher, settle=settle,
            knowledge=str(knowledge.resolve()) if knowledge else "",
            vocabulary=_absolute(vocabulary), control=str(control.resolve()) if control else "",
            name=out.name,
        )  # fmt: skip
    except PlanError as exc:
        raise refuse(str(exc)) from None
    try:
        summary = run(config, out, typer.echo, live=live and sys.stdout.isatty(), monitor=monitor)
    except MonitorFailed as exc:
        raise refuse(str(exc)) from None
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


def check_command(
    folder: Annotated[
        Path, typer.Argument(metavar="FOLDER", help="A run's folder (with events.jsonl).")
    ],
) -> None:
    """Check a run's record again; exit 1 if a property failed."""
    from ktbt_proto.tools.fleet.check import check_record

    if not (folder / "events.jsonl").exists():
        raise refuse(f"{folder}: no events.jsonl")
    try:
        summary = check_record(folder)
    except (ValueError, KeyError, TypeError) as exc:
        raise refuse(f"{folder}/events.jsonl: not a fleet record ({exc})") from None
    typer.echo(f"{folder}: {'passed' if summary['passed'] else 'FAILED'}")
    _show(summary)
    raise typer.Exit(0 if summary["passed"] else 1)


def study_command(
    out: Annotated[
        Path, typer.Option("--out", metavar="FOLDER", help="Folder for every run's record.")
    ] = Path("results/fleet"),
    docs: Annotated[
        Path, typer.Option("--docs", metavar="FOLDER", help="Where the table and figure go.")
    ] = Path("docs/results"),
    only: Annotated[
        list[str] | None,
        typer.Option(
            "--only",
            metavar="NAME[,NAME]",
            help="Run only these scenarios (repeatable); the others' rows are kept.",
        ),
    ] = None,
) -> None:
    """Run the whole fleet study and write its table and figure.

    Convergence against size, loss, delay, partition, churn and the lease. With --only, the
    rows of the scenarios not run are kept from the previous fleet.json."""
    from ktbt_proto.tools.fleet.study import SCENARIOS, study

    names = [name for given in only or () for name in given.split(",") if name]
    unknown = set(names) - {name for name, _, _ in SCENARIOS}
    if unknown:
        raise refuse(f"--only: no such scenario: {', '.join(sorted(unknown))}")
    summaries = study(out, docs, typer.echo, names or None)
    failed = [s["name"] for s in summaries if not s["passed"]]
    typer.echo(json.dumps({"runs": len(summaries), "failed": failed}))
    raise typer.Exit(1 if failed else 0)


fleet.command(
    "run",
    epilog=example(
        "ktbt fleet run --peers 6 --loss 0.05 --out run1",
        "ktbt fleet run --peers 4 --knowledge door.sbt --vocabulary door.toml",
        "ktbt fleet run --peers 40 --topology geometric --radius 0.2 --seed 7",
    ),
)(run_command)
fleet.command("check", epilog=example("ktbt fleet check run1"))(check_command)
fleet.command("study", epilog=example("ktbt fleet study --only size-5,partition-30s-lease-1s"))(
    study_command
)


def register(app: typer.Typer) -> None:
    """Entry point of ``ktbt.commands``: add ``fleet`` to the ``ktbt`` app."""
    app.add_typer(fleet, name="fleet")
