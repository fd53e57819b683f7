"""``ktbt kb`` and ``ktbt log``: what a fleet member leaves behind, its saved knowledge
(``--save``) and its transfer log (``--log``, spec/protocol.md section 8)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.transferlog import Event
from ktbt_proto.formatter import format_tree
from ktbt_proto.tools.cli.options import example, io_reason, refuse, say

kb_app = typer.Typer(help="Inspect knowledge files.", no_args_is_help=True)


@kb_app.command("show", epilog=example("ktbt kb show r2.json"))
def kb_show(
    path: Annotated[Path, typer.Argument(metavar="FILE", help="A knowledge file (--save).")],
) -> None:
    """Each item a learner saved, with who taught and who signed it.

    For each: its subtree, segment, teacher, when it was learned, its author and whether the
    author's signature holds."""
    from ktbt_proto.exchange.knowledge import KnowledgeBase
    from ktbt_proto.exchange.signing import item_bytes, verify

    try:
        kb = KnowledgeBase.load(path)
    except (OSError, ValueError, StringBTError) as exc:
        kind = _other_kind(path)
        if kind is not None:  # a mistake of the user's, not a damaged file
            raise refuse(
                f"FILE {path}: {kind}, not a saved knowledge base; kb show reads the JSON "
                "that peer run --save writes"
            ) from None
        say(f"error: {path}: {str(exc).splitlines()[0]}")
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


def _other_kind(path: Path) -> str | None:
    """What a file given to ``kb show`` is when it is a tree, not a saved knowledge base: a
    stringBT file (a knowledge file for ``--knowledge``, say) or a BehaviorTree.CPP
    document; None for anything else (a damaged save file is its own error)."""
    from ktbt_proto.files import read_at_most
    from ktbt_proto.limits import DEFAULT_LIMITS
    from ktbt_proto.syntax import parse

    try:
        data = read_at_most(path, DEFAULT_LIMITS.max_size)
    except OSError:
        return None
    if data.lstrip().startswith((b"<?xml", b"<root")):
        return "a BehaviorTree.CPP XML file"
    try:
        parse(data)
    except StringBTError:
        return None
    return "a stringBT file"


def log_command(
    path: Annotated[Path, typer.Argument(metavar="FILE", help="A transfer log (--log).")],
    event: Annotated[
        list[Event] | None,
        typer.Option(
            "--event",
            metavar="EVENT",
            help=f"Show only this event (repeatable): {', '.join(Event)}.",
        ),
    ] = None,
) -> None:
    """Read a transfer log: its events, then the count of each kind.

    One line an event, as recorded (spec/protocol.md section 8)."""
    from collections import Counter

    from ktbt_proto.exchange.transferlog import describe, read

    shown = {e.value for e in event or ()}
    counts: Counter[str] = Counter()
    try:
        for entry in read(path):
            if isinstance(entry, str):
                say(f"warning: {path}: {entry}")
                continue
            counts[entry["event"]] += 1
            if not shown or entry["event"] in shown:
                typer.echo(describe(entry))
    except OSError as exc:
        say(f"error: {path}: {io_reason(exc)}")
        raise typer.Exit(1) from None
    typer.echo(", ".join(f"{k} {v}" for k, v in sorted(counts.items())) or "no events")


def register(app: typer.Typer) -> None:
    """Add ``ktbt kb`` and ``ktbt log`` to the ``ktbt`` app."""
    app.add_typer(kb_app, name="kb")
    app.command("log", epilog=example("ktbt log r2.log --event refused"))(log_command)
