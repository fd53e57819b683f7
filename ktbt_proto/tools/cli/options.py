"""The options the ``ktbt`` commands share, and the builders that turn them into the objects a
command runs with: defined once, here, for the core commands and for the packages that add
commands through the ``ktbt.commands`` entry point (``monitor``, ``fleet``).

Each option is a typed ``Annotated`` alias that a command lists explicitly among its
parameters, its default given there. Fixed choices are the protocol's own types (the trust
policy :class:`~ktbt_proto.exchange.trust.Policy`, the overhearing mode
:class:`~ktbt_proto.exchange.overhearing.Overhear`, the zenoh mode
:data:`~ktbt_proto.transport.zenoh.MemberMode`), so the help lists them and a value outside
them is refused. A value that cannot be right (a peer name, a number of seconds) is refused by
the option itself (``typer.BadParameter``, one line naming the option, exit 2: the root app's
style, :mod:`ktbt_proto.tools.cli.root`); a file that cannot be used is refused by its builder
in one line, exit 2. Nothing here opens a session or reads a file until a command runs.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.overhearing import Overhear
from ktbt_proto.exchange.trust import Policy
from ktbt_proto.transport.zenoh import MemberMode, Mode
from ktbt_proto.tree import Condition

if TYPE_CHECKING:
    from ktbt_proto.exchange.knowledge import KnowledgeBase
    from ktbt_proto.exchange.security import Security
    from ktbt_proto.registry import Registry
    from ktbt_proto.tools.robot import Robot
    from ktbt_proto.transport.zenoh import ZenohSettings

EXIT_USAGE = 2
"""A command used wrongly: a bad option, a file it cannot use."""
STDIN = "-"
"""The file name that means standard input."""
PEER_NAME = re.compile(r"[A-Za-z0-9_.-]{1,64}")
"""A peer's name (spec/protocol.md section 2): what ``--id`` takes."""
MOST_WAIT = 3600.0
"""The longest a command waits (``--timeout``), in seconds."""
MOST_RUN = 365 * 86400.0
"""The longest an agent runs (``--duration``), in seconds: an agent may run for days."""


def say(message: str) -> None:
    """One line for the user, on stderr."""
    typer.echo(message, err=True)


def refuse(message: str) -> typer.Exit:
    """``error: MESSAGE`` on stderr; the exit (code 2) for the caller to raise."""
    say(f"error: {message}")
    return typer.Exit(EXIT_USAGE)


def io_reason(exc: OSError) -> str:
    """Why a file operation failed, as the system says it (``No such file or directory``)."""
    return exc.strerror or str(exc)


def example(*lines: str) -> str:
    """A command's epilog: its example, kept as written (click's ``\\b`` stops re-wrapping)."""
    return "\b\nExample:\n" + "\n".join(f"  {line}" for line in lines)


def _peer_name(value: str) -> str:
    if not PEER_NAME.fullmatch(value):
        raise typer.BadParameter(f"{value!r}: use 1 to 64 letters, digits, '_', '.' or '-'")
    return value


def _seconds(most: float) -> Callable[[float], float]:
    def check(value: float) -> float:
        if not (math.isfinite(value) and 0 < value <= most):
            raise typer.BadParameter(f"{value:g} is not a number of seconds in (0, {most:g}]")
        return value

    return check


def _port(value: int | None) -> int | None:
    if value is not None and not 1 <= value <= 65534:
        raise typer.BadParameter(f"{value} is not a port in [1, 65534] (it takes the next too)")
    return value


PeerId = Annotated[
    str,
    typer.Option(
        "--id",
        metavar="NAME",
        callback=_peer_name,
        help="The peer's name: 1 to 64 letters, digits, '_', '.' or '-'.",
    ),
]
Timeout = Annotated[
    float,
    typer.Option(
        "--timeout",
        metavar="SECONDS",
        callback=_seconds(MOST_WAIT),
        help=f"Seconds to wait, at most {MOST_WAIT:g}.",
    ),
]
Duration = Annotated[
    float,
    typer.Option(
        "--duration",
        metavar="SECONDS",
        callback=_seconds(MOST_RUN),
        help="Seconds to run, at most a year.",
    ),
]
Listen = Annotated[
    list[str] | None,
    typer.Option(
        "--listen", metavar="ENDPOINT", help="Endpoint to listen on, e.g. tcp/0.0.0.0:7447."
    ),
]
Connect = Annotated[
    list[str] | None,
    typer.Option(
        "--connect", metavar="ENDPOINT", help="Endpoint of a peer or router (retried for ever)."
    ),
]
ZenohConfig = Annotated[
    Path | None,
    typer.Option(
        "--config",
        metavar="FILE",
        help="A zenoh JSON5 config file (TLS, auth...).",
        readable=False,  # checked by zenoh_settings, in one line
    ),
]
Multicast = Annotated[
    bool, typer.Option("--multicast/--no-multicast", help="Multicast scouting on the LAN.")
]
RetryPeriod = Annotated[
    int,
    typer.Option(
        "--retry",
        metavar="MS",
        min=10,
        max=600_000,
        help="Dial an endpoint that does not answer again every MS ms (about 1000/MS "
        "attempts a second to each dead one).",
    ),
]
LeasePeriod = Annotated[
    int,
    typer.Option(
        "--lease",
        metavar="MS",
        min=500,
        max=600_000,
        help="Close a link silent for MS ms, and dial it again (4 keep-alives a lease on an "
        "idle link).",
    ),
]
JoinMode = Annotated[MemberMode, typer.Option("--mode", help="peer, or client (through a router).")]
KeyFile = Annotated[
    Path | None,
    typer.Option("--key", metavar="FILE", help="This peer's private key (ktbt peer keygen)."),
]
PolicyOption = Annotated[
    Policy,
    typer.Option("--policy", help="Answers accepted: any, signed, or trusted (keys in --trust)."),
]
TrustFile = Annotated[
    Path | None,
    typer.Option("--trust", metavar="FILE", help="Trusted keys: 'KEY' or 'NAME KEY' a line."),
]
LogFile = Annotated[
    Path | None,
    typer.Option("--log", metavar="FILE", help="Append every exchange event here (JSON lines)."),
]
PublishAnswers = Annotated[
    bool,
    typer.Option(
        "--publish-answers",
        help="Also publish every answer sent, for peers that overhear.",
    ),
]
PublishEvents = Annotated[
    bool,
    typer.Option("--publish-events", help="Publish every exchange event (for ktbt monitor)."),
]
OverhearOption = Annotated[
    Overhear,
    typer.Option(
        "--overhear",
        help="Answers others publish: off (ignore), update (check and learn at once), or "
        "buffer (keep; check and learn when needed).",
    ),
]
GrootPort = Annotated[
    int | None,
    typer.Option(
        "--groot",
        metavar="PORT",
        callback=_port,
        help="Serve Groot2 (btview) on this port and the next, loopback.",
    ),
]
ReadyFile = Annotated[
    Path | None,
    typer.Option(
        "--ready",
        metavar="FILE",
        help='Once up, write {"peer": NAME, "knows": N} here (for a supervisor).',
    ),
]
KnowledgeFile = Annotated[
    Path,
    typer.Option(
        "--knowledge",
        metavar="FILE",
        help="A .sbt knowledge file, or BT.CPP .xml skills.",
        readable=False,
    ),
]
VocabularyOption = Annotated[
    str | None,
    typer.Option(
        "--vocabulary",
        metavar="SPEC",
        help="The robot's conditions and actions: FILE.toml or module:callable.",
    ),
]
ControlOption = Annotated[
    Path | None,
    typer.Option(
        "--control",
        metavar="FILE",
        help="The robot's control tree (.sbt), with a <k>(...) placeholder.",
        readable=False,  # checked by robot_or_exit, in one line
    ),
]
DemoOption = Annotated[bool, typer.Option("--demo", help="Be the search-and-rescue demo robot.")]
DEMO_NOTE = "using the search-and-rescue demo robot (give --vocabulary and --control for your own)"
"""What a robot command says when it runs the demo robot without being asked to."""


def zenoh_settings(
    listen: list[str] | None,
    connect: list[str] | None,
    config: Path | None,
    multicast: bool,
    mode: Mode = "peer",
    retry_ms: int | None = None,
    lease_ms: int | None = None,
) -> ZenohSettings:
    """The zenoh settings the network options describe; a config file that cannot be read is
    one line, exit 2 (spec/protocol.md section 3)."""
    from ktbt_proto.transport.zenoh import ZenohSettings  # zenoh loads only for peers

    if config is not None and not config.is_file():
        raise refuse(f"--config: {config} not found")
    if config is not None:
        try:
            config.open("rb").close()
        except OSError as exc:
            raise refuse(f"cannot read --config {config}: {io_reason(exc)}") from None
    try:
        settings = ZenohSettings(listen or (), connect or (), config, mode, multicast)
        if retry_ms is not None:
            settings = replace(settings, retry_ms=retry_ms)
        return settings if lease_ms is None else replace(settings, lease_ms=lease_ms)
    except ValueError as exc:  # an EndpointError: "connect: 127.0.0.1:7447 names no protocol..."
        raise refuse(f"--{exc}") from None


def knowledge_or_exit(path: Path, registry: Registry | None = None) -> KnowledgeBase:
    """A knowledge file to serve or start with; a problem with it is one line and exit 2.
    With the robot's ``registry``, an item it could not execute is refused too, with the code
    a peer's receive check gives (spec/protocol.md section 2): a robot never teaches, nor
    starts with, what it would refuse to learn."""
    from ktbt_proto.interop.knowledge_file import load_knowledge
    from ktbt_proto.validate import find_problems

    try:
        kb = load_knowledge(path)
    except OSError as exc:
        say(f"error: cannot read --knowledge {path}: {io_reason(exc)}")
    except StringBTError as err:
        say(f"{path}:{err}")
    except ValueError as exc:
        say(f"error: {exc}")
    else:
        for item in kb if registry is not None else ():
            for problem in find_problems(item.item(), registry):
                where = f":{problem.line}:{problem.column}" if problem.line else ""
                say(f"error: --knowledge {path}{where}: {problem.code} {problem.message}")
                raise typer.Exit(EXIT_USAGE)
        return kb
    raise typer.Exit(EXIT_USAGE)


def vocabulary_or_exit(spec: str) -> Registry:
    """The registry ``--vocabulary`` names (a vocabulary file, or a Python registry as
    ``module:callable``); a missing file, a module that does not import, a name it lacks: one
    line naming the option, exit 2."""
    return robot_or_exit(spec, None, False).registry


def robot_or_exit(
    vocabulary: str | None, control: Path | None, demo: bool, *, quiet: bool = False
) -> Robot:
    """The robot the options describe (:func:`ktbt_proto.tools.robot.build_robot`); the demo
    robot, unless asked for (``--demo``) or ``quiet``, is said in one line on stderr. Anything
    wrong is one line naming the option, exit 2 (spec/protocol.md section 4.5)."""
    from ktbt_proto.tools.robot import RobotError, build_robot

    try:
        robot = build_robot(vocabulary, control, demo, named=lambda name: f"--{name}")
    except RobotError as exc:
        raise refuse(str(exc)) from None
    if robot.vocabulary is None and not (demo or quiet):
        say(DEMO_NOTE)
    return robot


def address(text: str, option: str) -> tuple[str, int]:
    """``HOST:PORT`` as given to ``option`` (``[::1]:8470`` too): the host without brackets
    and the port; anything else is refused naming the option."""
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or int(port) > 65535 or not host:
        raise typer.BadParameter(f"{text!r} is not HOST:PORT (127.0.0.1:8470)", param_hint=option)
    return host.strip("[]"), int(port)


def security(key: Path | None, policy: Policy, trust: Path | None, log: Path | None) -> Security:
    """Key pair, trust policy and transfer log from the options (spec/protocol.md section 7);
    a bad one is one line, exit 2."""
    from ktbt_proto.exchange.security import Security
    from ktbt_proto.exchange.signing import Identity, KeyFileError
    from ktbt_proto.exchange.transferlog import TransferLog
    from ktbt_proto.exchange.trust import TrustStore
    from ktbt_proto.tools.peer import configure_logging

    configure_logging()
    if policy == Policy.TRUSTED and trust is None:
        raise refuse("--policy: trusted needs --trust FILE")
    try:
        identity = Identity.load(key) if key is not None else None
        store = TrustStore.load(trust) if trust is not None else None
        transfer_log = TransferLog(log) if log is not None else None
    except (KeyFileError, OSError) as exc:
        raise refuse(str(exc)) from None
    return Security(identity, policy, store, transfer_log)


def sequence_or_exit(option: str, text: str) -> tuple[Condition, ...]:
    """A condition sequence as typed (``TargetSeen(colour=2), !_inZoneF``); a mistake is one
    line naming the option, and a caret under the character in what the user typed."""
    from ktbt_proto.items import read_sequence

    try:
        return read_sequence(text)
    except StringBTError as err:
        say(f"error: {option} {text!r}: {err.code} {err.message}")
        if err.excerpt:
            say(err.excerpt)
        raise typer.Exit(EXIT_USAGE) from None


def acceptable_or_exit(option: str, text: str, registry: Registry) -> None:
    """A sequence the learner's own registry refuses (an unknown condition, an argument of the
    wrong type or out of range) could never be learned (spec/protocol.md section 4.5): one
    line, a caret under the part of ``text`` at fault, exit 2."""
    from ktbt_proto.tree import SequenceNode
    from ktbt_proto.validate import validate

    conds = sequence_or_exit(option, text)
    seen: dict[str, int] = {}
    for cond in conds:
        nth = seen.get(cond.name, 0)
        seen[cond.name] = nth + 1
        try:
            validate(SequenceNode((cond,)), registry)
        except StringBTError as err:
            starts = [m.start(1) for m in re.finditer(rf"({re.escape(cond.name)})\b", text)]
            at = starts[nth] if nth < len(starts) else 0
            arg = re.search(r"argument '?(\w+)'?=?", err.message)
            if arg is not None:
                found = re.compile(rf"\b{re.escape(arg.group(1))}\s*(=\s*)?").search(text, at)
                if found is not None:
                    at = found.end() if err.code == "SBT310" else found.start()
            say(f"error: {option} {text!r}: {err.code} {err.message}")
            say(f"    {text}\n    {' ' * at}^")
            raise typer.Exit(EXIT_USAGE) from None
