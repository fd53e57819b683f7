"""The ``ktbt-cli`` directive: the command-line reference, generated at build time from the
``ktbt`` command itself (the typer app behind the ``ktbt`` console script, with the commands
its plugins add), so the page says what ``ktbt ... --help`` says and cannot drift from it.

Each command gets a section with its plain (uncoloured) help text; a group lists its commands
and is followed by theirs.
"""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points
from typing import Any

import typer
from docutils import nodes
from sphinx.application import Sphinx
from sphinx.util.docutils import SphinxDirective

WIDTH = 100


def ktbt_command() -> Any:
    """The click command the ``ktbt`` console script runs: the module its entry point names
    holds the typer app."""
    (script,) = entry_points(group="console_scripts", name="ktbt")
    module = importlib.import_module(script.module)
    apps = [value for value in vars(module).values() if isinstance(value, typer.Typer)]
    main = next(app for app in apps if app.info.name == "ktbt")
    return typer.main.get_command(main)


def plain_help(command: Any, path: list[str], parent: Any) -> str:
    ctx = context(command, path[-1], parent)
    ctx.terminal_width = WIDTH
    ctx.max_content_width = WIDTH
    command.rich_markup_mode = None  # click's plain help, without colours or boxes
    formatter = ctx.make_formatter()
    command.format_help(ctx, formatter)
    return formatter.getvalue().rstrip() + "\n"


def context(command: Any, name: str, parent: Any) -> Any:
    """A context of the command's own click (typer may carry its own copy of click)."""
    return command.context_class(command, info_name=name, parent=parent)


def walk(command: Any, path: list[str], parent: Any = None) -> list[tuple[list[str], str]]:
    """(command path, help text) for the command and every subcommand, in the help's order."""
    ctx = context(command, path[-1], parent)
    found = [(path, plain_help(command, path, parent))]
    if hasattr(command, "list_commands"):
        for name in command.list_commands(ctx):
            sub = command.get_command(ctx, name)
            if sub is not None and not sub.hidden:
                found += walk(sub, [*path, name], ctx)
    return found


class KtbtCli(SphinxDirective):
    """``{ktbt-cli}``: one section per command, with its help."""

    def run(self) -> list[nodes.Node]:
        out: list[nodes.Node] = []
        for path, text in walk(ktbt_command(), ["ktbt"]):
            title = " ".join(path)
            section = nodes.section(
                ids=[nodes.make_id(title)], names=[nodes.fully_normalize_name(title)]
            )
            section += nodes.title(text=title)
            block = nodes.literal_block(text, text)
            block["language"] = "text"
            section += block
            self.state.document.note_implicit_target(section)
            out.append(section)
        return out


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_directive("ktbt-cli", KtbtCli)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
