"""Every ``ktbt`` command's help reads well at 80 columns and every usage error is one line
(the root app's style, ``ktbt_proto.tools.cli.root``): the commands other packages add
(``sim``, ``monitor``, ``fleet``) included, found by walking the app, not listed by hand."""

from __future__ import annotations

import re
import subprocess
import sys
from collections.abc import Iterator

import pytest
import typer
from typer.testing import CliRunner

from ktbt_proto.tools.cli import app, load_plugins

TYPE_NOISE = re.compile(r"<(bool|str|text|int|integer|float|path|list)>", re.IGNORECASE)


def _commands() -> list[tuple[str, ...]]:
    """Every command and group of the ``ktbt`` app, as the words that name it."""
    assert {"sim", "monitor", "fleet"} <= set(load_plugins())

    def walk(command: object, path: tuple[str, ...]) -> Iterator[tuple[str, ...]]:
        yield path
        for name, sub in sorted(getattr(command, "commands", {}).items()):
            yield from walk(sub, (*path, name))

    return list(walk(typer.main.get_command(app), ()))


COMMANDS = _commands()


def _is_group(path: tuple[str, ...]) -> bool:
    command: object = typer.main.get_command(app)
    for word in path:
        command = command.commands[word]  # type: ignore[attr-defined]
    return hasattr(command, "commands")


def _help(path: tuple[str, ...]) -> str:
    result = CliRunner().invoke(app, [*path, "--help"], env={"COLUMNS": "80"})
    assert result.exit_code == 0, result.output
    return result.output


def test_the_walk_finds_every_command() -> None:
    names = {" ".join(p) for p in COMMANDS}
    assert {"fmt", "tour", "peer run", "kb show", "log", "monitor", "fleet run", "sim run"} <= names


@pytest.mark.parametrize("path", COMMANDS, ids=lambda p: " ".join(p) or "ktbt")
def test_help_fits_80_columns_without_noise_or_cuts(path: tuple[str, ...]) -> None:
    shown = _help(path)
    too_long = [line for line in shown.splitlines() if len(line) > 80]
    assert not too_long, too_long
    assert "…" not in shown
    cut = [
        line
        for line in shown.splitlines()
        if line.rstrip().endswith("...") and not line.startswith("Usage:")
    ]
    assert not cut, cut
    options = [line for line in shown.splitlines() if line.lstrip().startswith("-")]
    noisy = [line for line in options if TYPE_NOISE.search(line)]
    assert not noisy and "<bool>" not in shown, noisy
    assert "╭" not in shown  # plain text, no boxed panels
    if not _is_group(path):
        assert re.search(r"Example:\n +ktbt ", shown), shown


@pytest.mark.parametrize(
    ("path", "choices"),
    [
        (("fleet", "run"), ["--topology <mesh|line|router|geometric|grid|edges>",
                            "--teacher <run|serve>", "--partition-kind <silent|reset|none>"]),
        (("peer", "run"), ["--policy <any|signed|trusted>", "--overhear <off|update|buffer>",
                           "--mode <peer|client>"]),
        (("show",), ["<outline|dot|mermaid>"]),
    ],
)  # fmt: skip
def test_fixed_choices_are_listed(path: tuple[str, ...], choices: list[str]) -> None:
    shown = " ".join(_help(path).split())
    for choice in choices:
        assert choice in shown


@pytest.mark.parametrize("path", [p for p in COMMANDS if p], ids=" ".join)
def test_an_unknown_option_is_one_line_naming_it(path: tuple[str, ...]) -> None:
    result = CliRunner().invoke(app, [*path, "--no-such-option"])
    assert result.exit_code == 2
    assert result.stderr == "error: --no-such-option: no such option\n"
    assert result.stdout == ""


@pytest.mark.parametrize(
    ("args", "line"),
    [
        (["peer", "ask", "--sequence", "A", "--timeout", "-1"],
         "error: --timeout: -1 is not a number of seconds in (0, 3600]"),
        (["peer", "run", "--duration", "nan"], "error: --duration: nan is not a number of seconds"),
        (["peer", "list", "--id", "a b"], "error: --id: 'a b': use 1 to 64 letters"),
        (["peer", "serve", "--knowledge", "k.sbt", "--overhear", "loud"],
         "error: --overhear: 'loud' is not one of 'off', 'update', 'buffer'"),
        (["peer", "ask", "--sequence", "A", "--policy", "x"],
         "error: --policy: 'x' is not one of 'any', 'signed', 'trusted'"),
        (["peer", "ask"], "error: --sequence: required"),
        (["merge", "a.sbt"], "error: SUBTREE: required"),
        (["fleet", "run", "--topology", "star"], "error: --topology: 'star' is not one of"),
        (["nosuch"], "error: ktbt: no such command 'nosuch'"),
    ],
)  # fmt: skip
def test_a_usage_error_is_one_line_naming_the_option_exit_2(args: list[str], line: str) -> None:
    """As a user runs it: a real process, stderr exactly one line, no traceback or panel."""
    done = subprocess.run(
        [sys.executable, "-m", "ktbt_proto", *args], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith(line) and done.stderr.count("\n") == 1, done.stderr
    assert "Value error" not in done.stderr and "Usage:" not in done.stderr
