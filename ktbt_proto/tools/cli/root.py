"""The ``ktbt`` app: its commands, ``--version``, the commands other packages add, and one style
for every usage error.

Commands are grouped by concern, one module each: the language's (:mod:`.language`), a
fleet's peers (:mod:`.peer`), what they leave behind (:mod:`.knowledge`). Other packages add
theirs through the ``ktbt.commands`` entry point (the simulator's ``sim``, ``monitor``,
``fleet``), loaded by :func:`load_plugins` when ``ktbt`` runs: this package never imports them.

Help is plain text that reads at 80 columns; a usage error (an unknown option, a value outside
its choices or range, a missing argument) is one line, ``error: OPTION: what is wrong``, on
stderr with exit 2, for every command, the added ones too.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Annotated, Any

import typer
from typer.core import TyperGroup

from ktbt_proto import __version__
from ktbt_proto.tools.cli import knowledge, language, peer
from ktbt_proto.tools.cli.options import EXIT_USAGE, example, say

try:  # typer carries its own copy of click from 0.20 on
    from typer._click.exceptions import (
        ClickException,
        MissingParameter,
        NoArgsIsHelpError,
        NoSuchOption,
        UsageError,
    )
except ImportError:  # pragma: no cover - an older typer, on click
    from click.exceptions import (  # type: ignore[assignment]
        ClickException,
        MissingParameter,
        NoArgsIsHelpError,
        NoSuchOption,
        UsageError,
    )

PLUGINS = "ktbt.commands"
"""The entry-point group through which other packages add commands."""


def problem(exc: ClickException) -> str:
    """A usage error as ``OPTION: what is wrong``: the option by its long name (an argument by
    its name), and click's message without its framing (nor pydantic's ``Value error, ``)."""
    message = exc.message.removeprefix("Value error, ").rstrip(".")
    if isinstance(exc, NoSuchOption):
        guess = ", ".join(sorted(exc.possibilities or ()))
        return f"{exc.option_name}: no such option" + (f" (did you mean {guess}?)" if guess else "")
    param = getattr(exc, "param", None)
    given = getattr(exc, "param_hint", None)
    if isinstance(given, str):
        subject = given
    elif param is not None:
        longest = sorted(param.opts, key=len)[-1] if param.opts else ""
        named = (param.metavar or param.name or "argument").upper().rstrip(".")
        subject = longest if longest.startswith("-") else named
    else:
        ctx = getattr(exc, "ctx", None)
        subject = ctx.command_path if ctx is not None else "ktbt"
    if isinstance(exc, MissingParameter):
        return f"{subject}: required, and not given"
    return f"{subject}: {message[:1].lower()}{message[1:]}"


class Group(TyperGroup):
    """The root group: every usage error below it is one line (:func:`problem`), exit 2, not
    click's usage block nor typer's boxed panel."""

    def main(  # type: ignore[override]
        self,
        args: Sequence[str] | None = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        **extra: Any,
    ) -> Any:
        try:
            result = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except NoArgsIsHelpError as exc:  # `ktbt` or `ktbt peer` alone: the help
            if not standalone_mode:
                raise
            typer.echo(exc.ctx.get_help() if exc.ctx is not None else exc.message)
            sys.exit(EXIT_USAGE)
        except UsageError as exc:
            if not standalone_mode:
                raise
            say(f"error: {problem(exc)}")
            sys.exit(EXIT_USAGE)
        except ClickException as exc:
            if not standalone_mode:
                raise
            say(f"error: {exc.format_message()}")
            sys.exit(exc.exit_code)
        except typer.Abort:
            if not standalone_mode:
                raise
            say("error: aborted")
            sys.exit(1)
        if not standalone_mode:
            return result
        sys.exit(result if isinstance(result, int) else 0)


app = typer.Typer(
    name="ktbt",
    cls=Group,
    help="KT-BT: behaviour trees that robots share while they run.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # plain help, wrapped to the terminal: no boxes
)
for module in (language, peer, knowledge):
    module.register(app)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"ktbt {__version__}")
        raise typer.Exit()


@app.callback(epilog=example("ktbt tour", "ktbt fmt --help"))
def main_options(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version, is_eager=True, help="Print the version."),
    ] = False,
) -> None:
    """KT-BT: behaviour trees that robots share while they run."""


_loaded: list[str] | None = None


def load_plugins() -> list[str]:
    """Add the commands other packages declare in the ``ktbt.commands`` entry point (once);
    a plugin that fails to load is a warning, and the core commands still work. Returns the
    names of the plugins loaded."""
    from importlib.metadata import entry_points

    global _loaded
    if _loaded is not None:
        return _loaded
    _loaded = []
    for entry in entry_points(group=PLUGINS):
        try:
            entry.load()(app)
        except Exception as exc:  # a broken plugin must not take the core commands down
            say(f"warning: cannot load ktbt command plugin {entry.name}: {exc}")
        else:
            _loaded.append(entry.name)
    return _loaded


def main() -> None:
    """The ``ktbt`` script and ``python -m ktbt_proto``."""
    load_plugins()
    app(prog_name="ktbt")
