"""``ktbt peer``: a fleet's members on eclipse-zenoh (spec/protocol.md): ``serve``, ``ask``,
``run``, ``router``, ``list`` and ``keygen``.

Each command lists its options, the shared ones from :mod:`ktbt_proto.tools.cli.options`, and
hands the objects they describe to :mod:`ktbt_proto.tools.peer`, which does the work. A zenoh or
file problem while it runs is one line and exit 1, never a traceback.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.overhearing import Overhear
from ktbt_proto.exchange.trust import Policy
from ktbt_proto.tools.cli.options import (
    Connect,
    ControlOption,
    DemoOption,
    Duration,
    GrootPort,
    JoinMode,
    KeyFile,
    KnowledgeFile,
    LeasePeriod,
    Listen,
    LogFile,
    Multicast,
    OverhearOption,
    PeerId,
    PolicyOption,
    PublishAnswers,
    PublishEvents,
    ReadyFile,
    RetryPeriod,
    Timeout,
    TrustFile,
    VocabularyOption,
    ZenohConfig,
    acceptable_or_exit,
    example,
    knowledge_or_exit,
    refuse,
    robot_or_exit,
    say,
    security,
    sequence_or_exit,
    vocabulary_or_exit,
    zenoh_settings,
)
from ktbt_proto.transport.zenoh import LEASE_MS, RETRY_MS, SessionError

if TYPE_CHECKING:
    from ktbt_proto.interop.sidecar import LearnedExport

peer_app = typer.Typer(
    help="Exchange knowledge with other robots over eclipse-zenoh.", no_args_is_help=True
)


def _peer_call(action: Callable[[], int]) -> None:
    """Run a peer command; a zenoh or file problem is one line and exit 1, never a traceback."""
    try:
        code = action()
    except StringBTError as err:
        say(f"error: {err.code} {err.line}:{err.column}: {err.message}")
        code = 1
    except SessionError as exc:  # the network's settings: a usage error, like a bad --listen
        say(f"error: {exc}")
        code = 2
    except (OSError, ValueError, ImportError) as exc:  # ImportError: an extra not installed
        say(f"error: {exc}")
        code = 1
    except Exception as exc:  # what zenoh raises at run time is its own ZError: one line too
        say(f"error: {type(exc).__name__}: {exc}")
        code = 1
    raise typer.Exit(code)


@peer_app.command("serve", epilog=example("ktbt peer serve --knowledge skills.sbt --key r1.key"))
def peer_serve(
    knowledge: KnowledgeFile,
    vocabulary: VocabularyOption = None,
    name: PeerId = "server",
    key: KeyFile = None,
    policy: PolicyOption = Policy.ANY,
    trust: TrustFile = None,
    log: LogFile = None,
    publish_answers: PublishAnswers = False,
    overhear: OverhearOption = Overhear.OFF,
    publish_events: PublishEvents = False,
    groot: GrootPort = None,
    ready: ReadyFile = None,
    listen: Listen = None,
    connect: Connect = None,
    config: ZenohConfig = None,
    multicast: Multicast = False,
    retry: RetryPeriod = RETRY_MS,
    lease: LeasePeriod = LEASE_MS,
    mode: JoinMode = "peer",
) -> None:
    """Answer queries for the knowledge in a file until stopped.

    A .sbt file's <k>(...) items, or a .xml file's BehaviorTree.CPP skills (one
    <BehaviorTree> each). With --vocabulary, an item it names wrongly is refused at start.
    Answers are signed with --key; with --overhear, it also serves what it overhears, once
    that passes the checks a learner runs (--policy, --trust, --vocabulary, the receive
    limits)."""
    from ktbt_proto.tools import peer

    settings = zenoh_settings(listen, connect, config, multicast, mode, retry, lease)
    registry = vocabulary_or_exit(vocabulary) if vocabulary is not None else None
    served = knowledge_or_exit(knowledge, registry)
    secure = security(key, policy, trust, log)
    member = peer.PeerSettings(
        name, settings, secure, publish_answers, overhear, publish_events, groot, ready
    )
    _peer_call(lambda: peer.serve(member, served, typer.echo, registry))


@peer_app.command(
    "ask", epilog=example("ktbt peer ask --sequence 'TargetSeen(colour=2)' --timeout 5")
)
def peer_ask(
    sequence: Annotated[
        str,
        typer.Option(
            "--sequence",
            metavar="CONDITIONS",
            help="The conditions to ask about, as `peer list` prints them: "
            "'TargetSeen(colour=2), !_inZoneF'.",
        ),
    ],
    vocabulary: VocabularyOption = None,
    timeout: Timeout = 2.0,
    name: PeerId = "asker",
    policy: PolicyOption = Policy.ANY,
    trust: TrustFile = None,
    log: LogFile = None,
    listen: Listen = None,
    connect: Connect = None,
    config: ZenohConfig = None,
    multicast: Multicast = False,
    mode: JoinMode = "peer",
) -> None:
    """Ask the fleet; print each answer with its provenance as it arrives.

    With --vocabulary, an answer it could not execute is shown as refused. Exit 1 if no
    acceptable answer came in time, saying on stderr whether no peer was reachable or no peer
    knew."""
    from ktbt_proto.tools import peer

    settings = zenoh_settings(listen, connect, config, multicast, mode)
    registry = None
    if vocabulary is not None:
        registry = vocabulary_or_exit(vocabulary)
        acceptable_or_exit("--sequence", sequence, registry)
    conds = sequence_or_exit("--sequence", sequence)
    secure = security(None, policy, trust, log)
    _peer_call(
        lambda: peer.ask(
            name, conds, settings, timeout, typer.echo, note=say, security=secure,
            registry=registry,
        )[0]
    )  # fmt: skip


@peer_app.command(
    "run",
    epilog=example(
        "ktbt peer run --id door1 --vocabulary door.toml --control door.sbt \\",
        "    --connect tcp/127.0.0.1:7447 --exit-when-done",
    ),
)
def peer_run(
    name: PeerId = "robot",
    vocabulary: VocabularyOption = None,
    control: ControlOption = None,
    demo: DemoOption = False,
    sequence: Annotated[
        list[str] | None,
        typer.Option(
            "--sequence",
            metavar="CONDITIONS",
            help="A sequence to meet, e.g. 'TargetSeen(colour=2)' (repeatable).",
        ),
    ] = None,
    duration: Duration = 30.0,
    exit_when_done: Annotated[
        bool, typer.Option("--exit-when-done", help="Stop once every sequence is known.")
    ] = False,
    knowledge_file: Annotated[
        Path | None,
        typer.Option("--save", metavar="FILE", help="Persist learned knowledge here."),
    ] = None,
    knowledge: Annotated[
        Path | None,
        typer.Option(
            "--knowledge",
            metavar="FILE",
            help="A .sbt knowledge file to start with (and teach).",
            readable=False,
        ),
    ] = None,
    key: KeyFile = None,
    policy: PolicyOption = Policy.ANY,
    trust: TrustFile = None,
    log: LogFile = None,
    publish_answers: PublishAnswers = False,
    overhear: OverhearOption = Overhear.OFF,
    export_learned: Annotated[
        Path | None,
        typer.Option(
            "--export-learned",
            metavar="FOLDER",
            help="Write each learned item here as a BehaviorTree.CPP file.",
            file_okay=False,
        ),
    ] = None,
    tree_id: Annotated[
        list[str] | None,
        typer.Option(
            "--tree-id",
            metavar="ID=CONDITIONS",
            help="The <BehaviorTree> ID of that sequence's exported file, for a Nav2 goal to "
            "name, e.g. 'OpenLeftDoor=HandleSeen(side=left)' (repeatable; default "
            "ktbt-<placeholder>-<digest>).",
        ),
    ] = None,
    publish_events: PublishEvents = False,
    groot: GrootPort = None,
    ready: ReadyFile = None,
    listen: Listen = None,
    connect: Connect = None,
    config: ZenohConfig = None,
    multicast: Multicast = False,
    retry: RetryPeriod = RETRY_MS,
    lease: LeasePeriod = LEASE_MS,
    mode: JoinMode = "peer",
) -> None:
    """Run a robot: it learns what it meets and teaches what it knows.

    It meets each --sequence until it knows it; without one, each sequence its peers list
    that its vocabulary can execute. --control runs your tree (learning into its <k>(new),
    else its last placeholder); --vocabulary alone runs only what it knows. Without either
    (or with --demo), the search-and-rescue demo robot. With --knowledge it starts knowing
    that file's items."""
    from ktbt_proto.tools import peer

    settings = zenoh_settings(listen, connect, config, multicast, mode, retry, lease)
    robot = robot_or_exit(vocabulary, control, demo)
    registry = robot.registry
    for text in sequence or ():
        acceptable_or_exit("--sequence", text, registry)
    start = knowledge_or_exit(knowledge, registry) if knowledge is not None else None
    secure = security(key, policy, trust, log)
    export = _export_or_exit(export_learned, tree_id or [])
    member = peer.PeerSettings(
        name, settings, secure, publish_answers, overhear, publish_events, groot, ready
    )
    _peer_call(
        lambda: peer.run_agent(
            member,
            sequence or None,
            typer.echo,
            control=robot.control,
            registry=registry,
            slot=robot.slot,
            knowledge=start,
            duration=duration,
            exit_when_done=exit_when_done,
            knowledge_path=str(knowledge_file) if knowledge_file else None,
            export_learned=export,
        )
    )


def _export_or_exit(folder: Path | None, given: list[str]) -> LearnedExport | None:
    """The export --export-learned asks for, with the tree IDs --tree-id gives (ID=CONDITIONS,
    spec/stringbt.md section 12.2): a folder it cannot write into, an ID it cannot use or that
    another file of the folder holds, is one line naming the option and exit 2."""
    if folder is None:
        if given:
            raise refuse("--tree-id: names the tree of an exported file; give --export-learned")
        return None
    from ktbt_proto.interop.sidecar import LearnedExport, tree_ids

    try:
        ids = tree_ids(given, lambda conditions: sequence_or_exit("--tree-id", conditions))
    except ValueError as exc:
        raise refuse(f"--tree-id: {exc}") from None
    try:
        return LearnedExport(folder, ids)
    except OSError as exc:
        raise refuse(f"--export-learned: {exc.strerror or exc}") from None
    except ValueError as exc:
        raise refuse(f"--tree-id: {exc}") from None


@peer_app.command("router", epilog=example("ktbt peer router --listen tcp/0.0.0.0:7447"))
def peer_router(
    ready: ReadyFile = None,
    listen: Listen = None,
    connect: Connect = None,
    config: ZenohConfig = None,
    multicast: Multicast = False,
    retry: RetryPeriod = RETRY_MS,
    lease: LeasePeriod = LEASE_MS,
) -> None:
    """Run a zenoh router, for fleets that span subnets."""
    from ktbt_proto.tools import peer

    settings = zenoh_settings(listen, connect, config, multicast, retry_ms=retry, lease_ms=lease)
    _peer_call(lambda: peer.router(settings, typer.echo, ready))


@peer_app.command("list", epilog=example("ktbt peer list --connect tcp/192.0.2.7:7447"))
def peer_list(
    timeout: Timeout = 2.0,
    name: PeerId = "observer",
    listen: Listen = None,
    connect: Connect = None,
    config: ZenohConfig = None,
    multicast: Multicast = False,
    mode: JoinMode = "peer",
) -> None:
    """Show who is present and what each knows."""
    from ktbt_proto.tools import peer

    settings = zenoh_settings(listen, connect, config, multicast, mode)
    _peer_call(lambda: peer.list_peers(name, settings, timeout, typer.echo))


@peer_app.command("keygen", epilog=example("ktbt peer keygen r1.key --id r1 >> trusted.txt"))
def peer_keygen(
    path: Annotated[Path, typer.Argument(metavar="PATH", help="Where to write the private key.")],
    name: PeerId = "peer",
) -> None:
    """Make an Ed25519 key pair and print its trust-store line.

    The private key goes to PATH, the public one to PATH.pub."""
    from ktbt_proto.tools import peer

    if path.exists():
        raise refuse(f"{path} exists; a key is never overwritten")
    _peer_call(lambda: peer.keygen(path, name, typer.echo))


@peer_app.command(
    "keys", epilog=example("ktbt peer keys keys/ teacher robot1 robot2   # then --policy trusted")
)
def peer_keys(
    folder: Annotated[Path, typer.Argument(metavar="FOLDER", help="Where the keys go.")],
    names: Annotated[list[str], typer.Argument(metavar="NAME...", help="The robots' names.")],
) -> None:
    """Make a fleet's key pairs and its trust store in one go.

    FOLDER/NAME.key for each robot (its key), and FOLDER/trust.txt naming every robot's public
    key (the store each robot is given, with the trusted policy)."""
    import re

    from ktbt_proto.tools import peer

    bad = [n for n in names if re.fullmatch(r"[A-Za-z0-9_.-]{1,64}", n) is None]
    if bad or len(set(names)) != len(names):
        raise refuse(f"NAME: {', '.join(map(repr, bad)) or 'a name twice'}: one robot name each")
    _peer_call(lambda: peer.fleet_keys(folder, names, typer.echo))


def register(app: typer.Typer) -> None:
    """Add ``ktbt peer`` to the ``ktbt`` app."""
    app.add_typer(peer_app, name="peer")
