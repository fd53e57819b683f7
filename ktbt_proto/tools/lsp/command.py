"""``ktbt lsp``: added to the ``ktbt`` command through the ``ktbt.commands`` entry point.

Nothing of pygls is imported until the command runs, so ``ktbt`` works without the ``lsp``
extra, and the command says in one line how to get it. The server speaks LSP on standard input
and output (its log goes to standard error), which is how editors start a language server.
"""

from __future__ import annotations

import logging
from typing import Annotated

import typer

from ktbt_proto.tools.cli.options import example

INSTALL = "ktbt lsp needs the lsp extra: pip install 'ktbt[lsp]'"


def lsp_command(
    vocabulary: Annotated[
        str | None,
        typer.Option(
            "--vocabulary",
            metavar="SPEC",
            help="The robot's vocabulary for every document, FILE.toml or module:callable "
            "(default: the one ktbt.toml or pyproject.toml [tool.ktbt] names, found upward "
            "from each file; without one, syntax and the language's rules alone).",
        ),
    ] = None,
    fleet: Annotated[
        str | None,
        typer.Option(
            "--fleet",
            metavar="ENDPOINT",
            help="Show what the fleet reached at ENDPOINT (tcp/127.0.0.1:7447) knows: which "
            "robots know each item's sequence (hover), and a warning where an item differs from "
            "what they teach. Read-only, in the background; off by default (no network).",
        ),
    ] = None,
    stdio: Annotated[
        bool,
        typer.Option("--stdio", hidden=True, help="Accepted, as some editors pass it."),
    ] = False,
    log_level: Annotated[
        str,
        typer.Option(
            "--log-level",
            metavar="LEVEL",
            help="What to log on stderr: DEBUG, INFO, WARNING or ERROR.",
        ),
    ] = "WARNING",
) -> None:
    """A language server for stringBT files (.sbt), over stdio.

    Diagnostics as you type, formatting, completion and hover from the robot's vocabulary,
    outline, folding, go to definition, quick fixes and semantic tokens, for any editor that
    speaks LSP (docs/howto/editors.md)."""
    del stdio
    try:
        from ktbt_proto.tools.lsp.server import build
    except ImportError:
        typer.echo(INSTALL, err=True)
        raise typer.Exit(2) from None
    level = getattr(logging, log_level.upper(), None)
    if not isinstance(level, int):
        typer.echo(
            f"error: --log-level: {log_level!r} is not DEBUG, INFO, WARNING or ERROR", err=True
        )
        raise typer.Exit(2)
    logging.basicConfig(level=level, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    if fleet is not None:  # a bad endpoint is one line and exit 2, before any editor waits
        from ktbt_proto.transport.zenoh import ZenohSettings

        try:
            ZenohSettings(connect=[fleet])
        except ValueError as exc:
            typer.echo(f"error: --fleet: {str(exc).removeprefix('connect: ')}", err=True)
            raise typer.Exit(2) from None
    build(vocabulary, fleet=fleet).start_io()


def register(app: typer.Typer) -> None:
    """Entry point of ``ktbt.commands``: add ``lsp`` to the ``ktbt`` app."""
    app.command("lsp", epilog=example("ktbt lsp --vocabulary examples/sar_vocabulary.toml"))(
        lsp_command
    )
