"""The ``ktbt`` command line: the language's tools (``fmt``, ``check``, ``show``, ``merge``,
``convert``, ``tour``), a fleet's peers (``peer``) and what they leave behind (``kb``, ``log``);
other packages add commands through the ``ktbt.commands`` entry point (the simulator's ``sim``
and ``demo``).

Every failure a user can cause (a bad path, an unreadable or non-UTF-8 file, invalid stringBT)
is one clear line on stderr and an exit code, never a traceback. ``fmt`` follows black: exit 0
when nothing changed or files were rewritten, 1 when ``--check`` finds work, 123 on an error.
"""

from __future__ import annotations

import difflib
import functools
import inspect
import os
import sys
from collections.abc import Callable, Iterator
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, cast

import typer

from ktbt_proto import __version__
from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.transferlog import Event
from ktbt_proto.files import write_atomic
from ktbt_proto.formatter import Style, format_tree
from ktbt_proto.limits import DEFAULT_LIMITS
from ktbt_proto.merge import merge
from ktbt_proto.render import render
from ktbt_proto.syntax import parse
from ktbt_proto.tree import Condition, Tree
from ktbt_proto.validate import Vocabulary, find_problems

if TYPE_CHECKING:
    from ktbt_proto.exchange.knowledge import KnowledgeBase
    from ktbt_proto.exchange.security import Security
    from ktbt_proto.registry import Registry
    from ktbt_proto.transport.zenoh import ZenohSettings

app = typer.Typer(
    name="ktbt",
    help="KT-BT: behaviour trees that robots share while they run.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

EXIT_ERROR = 123
STDIN = "-"


def _say(message: str) -> None:
    typer.echo(message, err=True)


def _expand(paths: list[str]) -> Iterator[str]:
    """Files as given; directories become the ``*.sbt`` files below them, sorted."""
    for p in paths:
        if p != STDIN and os.path.isdir(p):
            yield from sorted(str(f) for f in Path(p).rglob("*.sbt") if f.is_file())
        else:
            yield p


def _read(path: str) -> bytes:
    """At most one byte more than the size limit: enough for the parser to refuse a file that
    is too large without ever holding all of it (``/dev/zero`` included)."""
    limit = DEFAULT_LIMITS.max_size + 1
    if path == STDIN:
        if sys.stdin is None:
            raise OSError("standard input is closed")
        return sys.stdin.buffer.read(limit)
    with open(path, "rb") as f:
        return f.read(limit)


def _io_reason(exc: OSError) -> str:
    return exc.strerror or str(exc)


def _write(path: str, text: str) -> None:
    """Replace a file durably, keeping its permissions (:func:`files.write_atomic`: a symlink is
    written through). A file in a folder we cannot create files in is rewritten in place: a
    user may format a file they own in a folder they do not."""
    if not os.access(os.path.dirname(os.path.realpath(path)), os.W_OK):
        with open(path, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)
        return
    write_atomic(path, text, keep_mode=True)


def _has_comments(tree: Tree) -> bool:
    if tree.footer:
        return True
    return any(
        node.comments is not None
        and (
            node.comments.leading
            or node.comments.trailing is not None
            or node.comments.end
            or node.comments.end_trailing is not None
        )
        for node, _ in tree.walk()
    )


def _location(path: str) -> str:
    return "<stdin>" if path == STDIN else path


@app.command("fmt")
def fmt_command(
    files: Annotated[list[str], typer.Argument(help="Files or directories; '-' for stdin.")],
    check_only: Annotated[
        bool, typer.Option("--check", help="Write nothing; exit 1 if a file would change.")
    ] = False,
    diff: Annotated[
        bool, typer.Option("--diff", help="Write nothing; print a unified diff instead.")
    ] = False,
    compact: Annotated[
        bool, typer.Option("--compact", help="Canonical one-line form (drops comments).")
    ] = False,
) -> None:
    """Reformat stringBT files in place (pretty by default)."""
    style: Style = "compact" if compact else "pretty"
    changed = unchanged = failed = 0
    for path in _expand(files):
        name = _location(path)
        try:
            data = _read(path)
        except OSError as exc:
            _say(f"error: cannot format {name}: {_io_reason(exc)}")
            failed += 1
            continue
        try:
            tree = parse(data)
            new = format_tree(tree, style) + ("\n" if compact else "")
        except StringBTError as err:
            _say(f"error: cannot format {name}:{err.line}:{err.column}: {err.code} {err.message}")
            failed += 1
            continue
        if compact and path != STDIN and not (check_only or diff) and _has_comments(tree):
            # The compact form has no comments: rewriting the file would lose them.
            _say(
                f"error: cannot format {name} compact in place: it has comments, which the "
                f"compact form drops (print it instead: ktbt fmt --compact - < {name})"
            )
            failed += 1
            continue
        old = data.decode("utf-8")
        if path == STDIN and not (check_only or diff):
            sys.stdout.write(new)
            changed += new != old
            continue
        if new == old:
            unchanged += 1
            continue
        changed += 1
        if diff:
            sys.stdout.writelines(
                difflib.unified_diff(
                    old.splitlines(keepends=True),
                    new.splitlines(keepends=True),
                    fromfile=f"{name}\t(original)",
                    tofile=f"{name}\t(formatted)",
                )
            )
        if check_only or diff:
            _say(f"would reformat {name}")
            continue
        try:
            _write(path, new)
        except OSError as exc:
            _say(f"error: cannot write {name}: {_io_reason(exc)}")
            failed += 1
            changed -= 1
            continue
        _say(f"reformatted {name}")
    verb = "would be reformatted" if (check_only or diff) else "reformatted"
    parts = [f"{changed} file{'s' * (changed != 1)} {verb}"]
    if unchanged:
        parts.append(f"{unchanged} file{'s' * (unchanged != 1)} left unchanged")
    if failed:
        parts.append(f"{failed} file{'s' * (failed != 1)} failed")
    _say(", ".join(parts) + ".")
    if failed:
        raise typer.Exit(EXIT_ERROR)
    if check_only and changed:
        raise typer.Exit(1)


@app.command("check")
def check_command(
    files: Annotated[list[str], typer.Argument(help="Files or directories; '-' for stdin.")],
    registry: Annotated[
        Path | None,
        typer.Option(
            "--registry",
            help="TOML file: conditions = [...], actions = [...]; unknown names are problems.",
            readable=False,  # checked when read, with one clear line
        ),
    ] = None,
) -> None:
    """Report every problem as file:line:col: CODE message; exit 1 if there are any.

    Warnings (SBT5xx) are reported too, but do not change the exit status."""
    from ktbt_proto.items import stray_nodes

    vocabulary = None
    if registry is not None:
        try:
            vocabulary = Vocabulary.load(registry)
        except ValueError as exc:
            _say(f"error: {exc}")
            raise typer.Exit(2) from None
    problems = checked = 0
    for path in _expand(files):
        name = _location(path)
        checked += 1
        try:
            data = _read(path)
        except OSError as exc:
            typer.echo(f"{name}: error: cannot read: {_io_reason(exc)}")
            problems += 1
            continue
        warnings: list[StringBTError] = []
        try:
            tree = parse(data)
            found: list[StringBTError] = find_problems(tree, vocabulary)
            warnings = stray_nodes(tree)
        except StringBTError as exc:
            found = [exc]
        for problem in sorted([*found, *warnings], key=lambda p: (p.line, p.column)):
            kind = " warning:" if problem in warnings else ""
            typer.echo(
                f"{name}:{problem.line}:{problem.column}: {problem.code}{kind} {problem.message}"
            )
        problems += len(found)
    if not checked:
        _say(f"error: no .sbt file in {' '.join(files)}")
        raise typer.Exit(2)
    if problems:
        raise typer.Exit(1)


@app.command("merge")
def merge_command(
    control: Annotated[str, typer.Argument(help="The control tree; '-' for stdin.")],
    subtree: Annotated[str, typer.Argument(help="The knowledge subtree; '-' for stdin.")],
    slot: Annotated[str, typer.Option("--slot", help="The placeholder <k>(NAME).")] = "new",
    when: Annotated[
        str | None,
        typer.Option(
            "--when",
            help="Conditions the knowledge answers: COND[,COND...], each NAME, !NAME or "
            "NAME(key=value, ...). Without it the subtree is merged as it is.",
        ),
    ] = None,
    compact: Annotated[bool, typer.Option("--compact", help="Write the one-line form.")] = False,
    output: Annotated[
        str | None, typer.Option("--output", "-o", help="Write here instead of stdout.")
    ] = None,
) -> None:
    """Merge Sequence(conditions, subtree) into a placeholder; write the merged tree."""
    if control == STDIN and subtree == STDIN:
        _say("error: only one of CONTROL and SUBTREE can be '-'")
        raise typer.Exit(2)
    conds = None if when is None else _sequence_or_exit("--when", when)
    base = _load_or_exit(control)
    knowledge = _load_or_exit(subtree)
    try:
        merged = merge(base, knowledge, slot, conds)
        problems = find_problems(merged)
        if problems:  # never write a tree the toolkit itself would refuse
            raise problems[0]
        text = format_tree(merged, "compact" if compact else "pretty")
    except StringBTError as err:
        where = f" {err.line}:{err.column}" if err.line else ""
        _say(f"error: cannot merge{where}: {err.code} {err.message}")
        raise typer.Exit(1) from None
    text += "\n" if compact else ""
    if output is None:
        sys.stdout.write(text)
        return
    try:
        _write(output, text)
    except OSError as exc:
        _say(f"error: cannot write {output}: {_io_reason(exc)}")
        raise typer.Exit(1) from None


@app.command("convert")
def convert_command(
    source: Annotated[str, typer.Argument(help="The file to read (.sbt or .xml).")],
    target: Annotated[str, typer.Argument(help="The file to write (.xml or .sbt).")],
) -> None:
    """Convert between stringBT (.sbt) and BehaviorTree.CPP v4 XML (.xml), by extension."""
    from ktbt_proto.interop import convert

    try:
        convert(source, target)
    except StringBTError as err:
        _say(f"error: cannot convert {source}:{err.line}:{err.column}: {err.code} {err.message}")
        raise typer.Exit(1) from None
    except OSError as exc:  # name the file that failed: the target is often the culprit
        failed = os.fsdecode(exc.filename) if exc.filename is not None else source
        verb = "write" if os.path.abspath(failed) == os.path.abspath(target) else "read"
        _say(f"error: cannot convert {source}: cannot {verb} {failed}: {_io_reason(exc)}")
        raise typer.Exit(1) from None
    except ValueError as exc:
        _say(f"error: cannot convert {source}: {exc}")
        raise typer.Exit(1) from None


class RenderFormat(StrEnum):
    outline = "outline"
    dot = "dot"
    mermaid = "mermaid"


@app.command("show")
def show_command(
    file: Annotated[str, typer.Argument(help="A stringBT file; '-' for stdin.")],
    fmt: Annotated[
        RenderFormat, typer.Option("--format", "-f", help="outline, dot or mermaid.")
    ] = RenderFormat.outline,
) -> None:
    """Draw a tree: a unicode outline, Graphviz DOT or a Mermaid flowchart."""
    tree = _load_or_exit(file)
    sys.stdout.write(render(tree, fmt.value))


def _sequence_or_exit(option: str, text: str) -> tuple[Condition, ...]:
    """A condition sequence as typed (``TargetSeen(colour=2), !_inZoneF``); a mistake is one
    line naming the option, and a caret under the character in what the user typed."""
    from ktbt_proto.items import read_sequence

    try:
        return read_sequence(text)
    except StringBTError as err:
        _say(f"error: {option} {text!r}: {err.code} {err.message}")
        if err.excerpt:
            _say(err.excerpt)
        raise typer.Exit(2) from None


def _load_or_exit(path: str) -> Tree:
    name = _location(path)
    try:
        return parse(_read(path))
    except OSError as exc:
        _say(f"error: cannot read {name}: {_io_reason(exc)}")
    except StringBTError as err:
        _say(f"{name}:{err}")
    raise typer.Exit(1)


@app.command("tour")
def tour_command(
    examples: Annotated[
        Path | None,
        typer.Option(
            help="Folder of .sbt files to show (default: the examples shipped here).",
            readable=False,
        ),
    ] = None,
) -> None:
    """A short tour of stringBT on the example trees: format, check, render."""
    from ktbt_proto.tools.demo import examples_folder, run_demo

    raise typer.Exit(run_demo(examples or examples_folder()))


peer_app = typer.Typer(
    help="Exchange knowledge with other robots over eclipse-zenoh.", no_args_is_help=True
)
app.add_typer(peer_app, name="peer")


class ZenohMode(StrEnum):
    """How a peer command joins the fleet (a router is ``ktbt peer router``)."""

    peer = "peer"
    client = "client"


class OverhearMode(StrEnum):
    """What a fleet member does with the answers others publish (spec/protocol.md 4.3)."""

    off = "off"
    update = "update"
    buffer = "buffer"


class PolicyName(StrEnum):
    """Which answers are accepted (spec/protocol.md section 7)."""

    any = "any"
    signed = "signed"
    trusted = "trusted"


Listen = Annotated[
    list[str] | None, typer.Option("--listen", help="Endpoint to listen on, e.g. tcp/0.0.0.0:7447.")
]
Connect = Annotated[
    list[str] | None,
    typer.Option("--connect", help="Endpoint of a peer or router (retried for ever)."),
]
Config = Annotated[
    Path | None,
    typer.Option("--config", help="A zenoh JSON5 config file (TLS, auth...).", readable=False),
]
Multicast = Annotated[
    bool, typer.Option("--multicast/--no-multicast", help="Multicast scouting on the LAN.")
]
Mode = Annotated[ZenohMode, typer.Option("--mode", help="peer, or client (through a router).")]
KeyFile = Annotated[
    Path | None, typer.Option("--key", help="This peer's private key (ktbt peer keygen).")
]
Policy = Annotated[
    PolicyName, typer.Option("--policy", help="Accept answers: any, signed, or trusted (--trust).")
]
TrustFile = Annotated[
    Path | None, typer.Option("--trust", help="Trusted keys: 'KEY' or 'NAME KEY' a line.")
]
LogFile = Annotated[
    Path | None, typer.Option("--log", help="Append every exchange event here (JSON lines).")
]
PublishAnswers = Annotated[
    bool,
    typer.Option(
        "--publish-answers",
        help="Also publish every answer sent on ktbt/v1/answers/<id>, for peers that overhear.",
    ),
]
PublishEvents = Annotated[
    bool, typer.Option("--publish-events", help="Publish every exchange event (ktbt monitor).")
]
Overhearing = Annotated[
    OverhearMode,
    typer.Option(
        "--overhear",
        help="Answers others publish: off (ignore), update (check and learn at once), or buffer "
        "(keep, check and learn when needed).",
    ),
]
GrootPort = Annotated[
    int | None,
    typer.Option(
        "--groot",
        min=1,
        max=65534,
        help="Serve Groot2 (btview) on this port and the next, loopback.",
    ),
]


def _network_parameters(mode: bool) -> list[inspect.Parameter]:
    """The network options every peer command takes, defined once (``router`` has no mode)."""
    keyword = inspect.Parameter.KEYWORD_ONLY
    options = [
        inspect.Parameter("listen", keyword, default=None, annotation=Listen),
        inspect.Parameter("connect", keyword, default=None, annotation=Connect),
        inspect.Parameter("config", keyword, default=None, annotation=Config),
        inspect.Parameter("multicast", keyword, default=False, annotation=Multicast),
    ]
    if mode:
        options.append(inspect.Parameter("mode", keyword, default=ZenohMode.peer, annotation=Mode))
    return options


def _networked(*, mode: bool = True) -> Callable[[Callable[..., None]], Callable[..., None]]:
    """A peer command that takes the network options: the command itself names a ``settings``
    parameter and receives the ``ZenohSettings`` they describe (checked, one line and exit 2 if
    not); every other parameter is the command's own."""

    def decorate(command: Callable[..., None]) -> Callable[..., None]:
        own = [
            p
            for p in inspect.signature(
                command,
                eval_str=True,
                locals={"ZenohSettings": object},  # loaded only to run
            ).parameters.values()
            if p.name != "settings"
        ]
        network = _network_parameters(mode)
        names = [p.name for p in network]

        @functools.wraps(command)
        def run(**options: object) -> None:
            given = {name: options.pop(name) for name in names}
            settings = _settings(
                cast("list[str] | None", given["listen"]),
                cast("list[str] | None", given["connect"]),
                cast("Path | None", given["config"]),
                bool(given["multicast"]),
                str(given.get("mode", ZenohMode.peer)),
            )
            command(settings=settings, **options)

        parameters = [*own, *network]
        run.__signature__ = inspect.Signature(parameters)  # type: ignore[attr-defined]
        run.__annotations__ = {p.name: p.annotation for p in parameters}
        return run

    return decorate


def _security(key: Path | None, policy: str, trust: Path | None, log: Path | None) -> Security:
    """Key pair, trust policy and transfer log from the options; a bad one is one line, exit 2."""
    from ktbt_proto.exchange.security import Security
    from ktbt_proto.exchange.signing import Identity, KeyFileError
    from ktbt_proto.exchange.transferlog import TransferLog
    from ktbt_proto.exchange.trust import Policy, TrustStore
    from ktbt_proto.tools.peer import configure_logging

    configure_logging()
    if policy == Policy.TRUSTED and trust is None:
        _say("error: --policy trusted needs --trust FILE")
        raise typer.Exit(2)
    try:
        identity = Identity.load(key) if key is not None else None
        store = TrustStore.load(trust) if trust is not None else None
        transfer_log = TransferLog(log) if log is not None else None
    except (KeyFileError, OSError) as exc:
        _say(f"error: {exc}")
        raise typer.Exit(2) from None
    return Security(identity, Policy(policy), store, transfer_log)


def _settings(
    listen: list[str] | None,
    connect: list[str] | None,
    config: Path | None,
    multicast: bool,
    mode: str = "peer",
) -> ZenohSettings:
    from ktbt_proto.transport.zenoh import ZenohSettings  # zenoh and pydantic load only for peers

    if config is not None and not config.is_file():
        _say(f"error: config file {config} not found")
        raise typer.Exit(2)
    if config is not None:
        try:
            config.open("rb").close()
        except OSError as exc:
            _say(f"error: cannot read --config {config}: {_io_reason(exc)}")
            raise typer.Exit(2) from None
    return ZenohSettings(listen or (), connect or (), config, mode, multicast)


def _check_peer(name: str, seconds: float = 1.0, most: float = 3600) -> None:
    import math
    import re

    if not re.fullmatch(r"[A-Za-z0-9_.-]{1,64}", name):
        _say(f"error: --id {name!r}: use 1 to 64 letters, digits, '_', '.' or '-'")
        raise typer.Exit(2)
    if not (math.isfinite(seconds) and 0 < seconds <= most):
        _say(f"error: {seconds} seconds: use a number in (0, {most:g}]")
        raise typer.Exit(2)


def _peer_call(action: Callable[[], int]) -> None:
    """Run a peer command; a zenoh or file problem is one line and exit 1, never a traceback."""
    try:
        code = action()
    except StringBTError as err:
        _say(f"error: {err.code} {err.line}:{err.column}: {err.message}")
        code = 1
    except (OSError, ValueError) as exc:
        _say(f"error: {exc}")
        code = 1
    except Exception as exc:  # zenoh raises its own ZError for bad endpoints or configs
        _say(f"error: {type(exc).__name__}: {exc}")
        code = 1
    raise typer.Exit(code)


def _knowledge_or_exit(path: Path) -> KnowledgeBase:
    """A knowledge file to serve or start with; a problem with it is one line and exit 2."""
    from ktbt_proto.tools import peer

    try:
        return peer.load_knowledge(path)
    except OSError as exc:
        _say(f"error: cannot read --knowledge {path}: {_io_reason(exc)}")
    except StringBTError as err:
        _say(f"{path}:{err}")
    except ValueError as exc:
        _say(f"error: {exc}")
    raise typer.Exit(2)


def _acceptable_or_exit(option: str, text: str, registry: Registry) -> None:
    """A sequence the learner's own registry refuses (an unknown condition, an argument of the
    wrong type or out of range) could never be learned: one line, a caret under the part of
    ``text`` at fault, exit 2."""
    import re

    from ktbt_proto.tree import SequenceNode
    from ktbt_proto.validate import validate

    conds = _sequence_or_exit(option, text)
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
            _say(f"error: {option} {text!r}: {err.code} {err.message}")
            _say(f"    {text}\n    {' ' * at}^")
            raise typer.Exit(2) from None


@peer_app.command("serve")
@_networked()
def peer_serve(
    settings: ZenohSettings,
    knowledge: Annotated[
        Path, typer.Option("--knowledge", help="A .sbt knowledge file.", readable=False)
    ],
    name: Annotated[str, typer.Option("--id", help="This peer's name.")] = "server",
    key: KeyFile = None,
    log: LogFile = None,
    publish_answers: PublishAnswers = False,
    overhear: Overhearing = OverhearMode.off,
    publish_events: PublishEvents = False,
    groot: GrootPort = None,
) -> None:
    """Answer queries for the knowledge in a file until stopped (signed, with --key); with
    --overhear, also serve what it overhears."""
    from ktbt_proto.tools import peer

    _check_peer(name)
    served = _knowledge_or_exit(knowledge)
    security = _security(key, "any", None, log)
    member = peer.Member(
        name, settings, security, publish_answers, overhear.value, publish_events, groot
    )
    _peer_call(lambda: peer.serve(member, served, typer.echo))


@peer_app.command("ask")
@_networked()
def peer_ask(
    settings: ZenohSettings,
    sequence: Annotated[
        str,
        typer.Option(
            "--sequence",
            help="The conditions to ask about, as `peer list` prints them: "
            "'TargetSeen(colour=2), !_inZoneF'.",
        ),
    ],
    timeout: Annotated[float, typer.Option(help="Seconds to wait for answers.")] = 2.0,
    name: Annotated[str, typer.Option("--id", help="This peer's name.")] = "asker",
    policy: Policy = PolicyName.any,
    trust: TrustFile = None,
    log: LogFile = None,
) -> None:
    """Ask the fleet; print each answer (pretty stringBT) with its provenance as it arrives;
    exit 1 if no acceptable one came in time, saying on stderr whether no peer was reachable or
    no peer knew."""
    from ktbt_proto.tools import peer

    _check_peer(name, timeout)
    conds = _sequence_or_exit("--sequence", sequence)
    security = _security(None, policy.value, trust, log)
    _peer_call(
        lambda: peer.ask(name, conds, settings, timeout, typer.echo, note=_say, security=security)[
            0
        ]
    )


@peer_app.command("run")
@_networked()
def peer_run(
    settings: ZenohSettings,
    name: Annotated[str, typer.Option("--id", help="This agent's name.")] = "robot",
    sequence: Annotated[
        list[str] | None,
        typer.Option(
            "--sequence",
            help="A sequence to meet, e.g. 'TargetSeen(colour=2)' (repeatable).",
        ),
    ] = None,
    duration: Annotated[float, typer.Option(help="Seconds to run.")] = 30.0,
    exit_when_done: Annotated[
        bool, typer.Option(help="Stop once every sequence is known.")
    ] = False,
    knowledge_file: Annotated[
        Path | None,
        typer.Option("--save", help="Persist learned knowledge here.", readable=False),
    ] = None,
    knowledge: Annotated[
        Path | None,
        typer.Option(
            "--knowledge", help="A .sbt knowledge file to start with (and teach).", readable=False
        ),
    ] = None,
    key: KeyFile = None,
    policy: Policy = PolicyName.any,
    trust: TrustFile = None,
    log: LogFile = None,
    publish_answers: PublishAnswers = False,
    overhear: Overhearing = OverhearMode.off,
    export_learned: Annotated[
        Path | None,
        typer.Option(
            help="Write each learned item here as a BehaviorTree.CPP file.", file_okay=False
        ),
    ] = None,
    publish_events: PublishEvents = False,
    groot: GrootPort = None,
) -> None:
    """Run an agent that meets each sequence (default: the four colours), learns it and
    teaches what it knows; with --knowledge it starts knowing that file's items."""
    from ktbt_proto.tools import peer

    _check_peer(name, duration, most=365 * 86400)  # an agent may run for days
    registry = peer.demo_registry()
    for text in sequence or ():
        _acceptable_or_exit("--sequence", text, registry)
    start = _knowledge_or_exit(knowledge) if knowledge is not None else None
    security = _security(key, policy.value, trust, log)
    member = peer.Member(
        name, settings, security, publish_answers, overhear.value, publish_events, groot
    )
    sequences = sequence or peer.COLOURS
    _peer_call(
        lambda: peer.run_agent(
            member,
            sequences,
            typer.echo,
            knowledge=start,
            duration=duration,
            exit_when_done=exit_when_done,
            knowledge_path=str(knowledge_file) if knowledge_file else None,
            export_learned=str(export_learned) if export_learned else None,
        )
    )


@peer_app.command("router")
@_networked(mode=False)
def peer_router(settings: ZenohSettings) -> None:
    """Run a zenoh router, for fleets that span subnets."""
    from ktbt_proto.tools import peer

    _peer_call(lambda: peer.router(settings, typer.echo))


@peer_app.command("list")
@_networked()
def peer_list(
    settings: ZenohSettings,
    timeout: Annotated[float, typer.Option(help="Seconds to look.")] = 2.0,
    name: Annotated[str, typer.Option("--id", help="This peer's name.")] = "observer",
) -> None:
    """Show who is present and what each knows."""
    from ktbt_proto.tools import peer

    _check_peer(name, timeout)
    _peer_call(lambda: peer.list_peers(name, settings, timeout, typer.echo))


@peer_app.command("keygen")
def peer_keygen(
    path: Annotated[Path, typer.Argument(help="Where to write the private key.")],
    name: Annotated[
        str, typer.Option("--id", help="The peer's name, for the trust line.")
    ] = "peer",
) -> None:
    """Make an Ed25519 key pair: PATH (private) and PATH.pub; print its trust-store line."""
    from ktbt_proto.tools import peer

    _check_peer(name)
    if path.exists():
        _say(f"error: {path} exists; a key is never overwritten")
        raise typer.Exit(2)
    _peer_call(lambda: peer.keygen(path, name, typer.echo))


kb_app = typer.Typer(help="Inspect knowledge files.", no_args_is_help=True)
app.add_typer(kb_app, name="kb")


@kb_app.command("show")
def kb_show(path: Annotated[Path, typer.Argument(help="A knowledge file (--save).")]) -> None:
    """Each item a learner saved, with its teacher, time, author and signature check."""
    from ktbt_proto.exchange.knowledge import KnowledgeBase
    from ktbt_proto.exchange.signing import item_bytes, verify

    try:
        kb = KnowledgeBase.load(path)
    except (OSError, ValueError, StringBTError) as exc:
        _say(f"error: {path}: {str(exc).splitlines()[0]}")
        raise typer.Exit(1) from None
    for item in kb:
        typer.echo(item.key)
        typer.echo(f"  subtree   {format_tree(item.subtree, 'compact')}")
        typer.echo(f"  segment   {item.segment}")
        typer.echo(f"  teacher   {item.source or '-'}")
        typer.echo(f"  learned   tick {item.learned_at}, {item.received_at or 'time unknown'}")
        if item.author is None or item.signature is None:
            typer.echo("  author    - (unsigned)")
            continue
        ok = verify(
            item.author, item.signature, item_bytes(item.key, format_tree(item.subtree, "compact"))
        )
        typer.echo(f"  author    {item.author}")
        typer.echo(f"  signature {item.signature} ({'valid' if ok else 'INVALID'})")
    typer.echo(f"{len(kb)} items")


"""The kinds of transfer-log event, as ``--event`` takes them (spec/protocol.md section 8)."""


@app.command("log")
def log_command(
    path: Annotated[Path, typer.Argument(help="A transfer log (--log).")],
    event: Annotated[
        list[Event] | None,
        typer.Option("--event", help="Show only this event (repeatable)."),
    ] = None,
) -> None:
    """Read a transfer log: one line an event, then the count of each kind."""
    from collections import Counter

    from ktbt_proto.exchange.transferlog import describe, read

    shown = {e.value for e in event or ()}
    counts: Counter[str] = Counter()
    try:
        for entry in read(path):
            if isinstance(entry, str):
                _say(f"warning: {path}: {entry}")
                continue
            counts[entry["event"]] += 1
            if not shown or entry["event"] in shown:
                typer.echo(describe(entry))
    except OSError as exc:
        _say(f"error: {path}: {_io_reason(exc)}")
        raise typer.Exit(1) from None
    typer.echo(", ".join(f"{k} {v}" for k, v in sorted(counts.items())) or "no events")


def _version(value: bool) -> None:
    if value:
        typer.echo(f"ktbt {__version__}")
        raise typer.Exit()


@app.callback()
def main_options(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version, is_eager=True, help="Print the version."),
    ] = False,
) -> None:
    """KT-BT: behaviour trees that robots share while they run."""


def _plugins() -> None:
    """Commands other packages add (the simulator adds ``sim`` and ``demo``) through the
    ``ktbt.commands`` entry point: this package never imports them itself."""
    from importlib.metadata import entry_points

    for entry in entry_points(group="ktbt.commands"):
        try:
            entry.load()(app)
        except Exception as exc:  # a broken plugin must not take the core commands down
            _say(f"warning: cannot load ktbt command plugin {entry.name}: {exc}")


_plugins()


def main() -> None:
    app()
