"""``ktbt fmt``, ``check``, ``show``, ``merge``, ``convert`` and ``tour``: the language's
tools (spec/stringbt.md).

Every failure a user can cause (a bad path, an unreadable or non-UTF-8 file, invalid stringBT)
is one clear line on stderr and an exit code, never a traceback. ``fmt`` follows black: exit 0
when nothing changed or files were rewritten, 1 when ``--check`` finds work, 123 on an error.
"""

from __future__ import annotations

import difflib
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import typer

from ktbt_proto.errors import StringBTError
from ktbt_proto.files import read_at_most, write_atomic
from ktbt_proto.formatter import Style, format_tree
from ktbt_proto.limits import DEFAULT_LIMITS
from ktbt_proto.merge import merge
from ktbt_proto.registry import Registry
from ktbt_proto.render import Format, render
from ktbt_proto.syntax import parse
from ktbt_proto.tools.cli.options import (
    STDIN,
    example,
    io_reason,
    refuse,
    say,
    sequence_or_exit,
)
from ktbt_proto.tree import Tree
from ktbt_proto.validate import find_problems

EXIT_ERROR = 123
"""``fmt``: a file could not be formatted (black's code)."""

Files = Annotated[
    list[str], typer.Argument(metavar="FILES", help="Files or directories; '-' for stdin.")
]


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
    if path == STDIN:
        if sys.stdin is None:
            raise OSError("standard input is closed")
        return sys.stdin.buffer.read(DEFAULT_LIMITS.max_size + 1)
    return read_at_most(path, DEFAULT_LIMITS.max_size)


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


def fmt_command(
    files: Files,
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
            say(f"error: cannot format {name}: {io_reason(exc)}")
            failed += 1
            continue
        try:
            tree = parse(data)
            new = format_tree(tree, style) + ("\n" if compact else "")
        except StringBTError as err:
            say(f"error: cannot format {name}:{err.line}:{err.column}: {err.code} {err.message}")
            failed += 1
            continue
        if compact and path != STDIN and not (check_only or diff) and _has_comments(tree):
            # The compact form has no comments: rewriting the file would lose them.
            say(
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
                    _diff_lines(old),
                    _diff_lines(new),
                    fromfile=f"{name}\t(original)",
                    tofile=f"{name}\t(formatted)",
                )
            )
        if check_only or diff:
            say(f"would reformat {name}")
            continue
        try:
            _write(path, new)
        except OSError as exc:
            say(f"error: cannot write {name}: {io_reason(exc)}")
            failed += 1
            changed -= 1
            continue
        say(f"reformatted {name}")
    verb = "would be reformatted" if (check_only or diff) else "reformatted"
    parts = [f"{changed} file{'s' * (changed != 1)} {verb}"]
    if unchanged:
        parts.append(f"{unchanged} file{'s' * (unchanged != 1)} left unchanged")
    if failed:
        parts.append(f"{failed} file{'s' * (failed != 1)} failed")
    say(", ".join(parts) + ".")
    if failed:
        raise typer.Exit(EXIT_ERROR)
    if check_only and changed:
        raise typer.Exit(1)


def _diff_lines(text: str) -> list[str]:
    """Lines for a unified diff, each ending in a newline: a last line without one is marked
    as ``diff`` and ``patch`` mark it (``\\ No newline at end of file``)."""
    lines = text.splitlines(keepends=True)
    if lines and not lines[-1].endswith("\n"):
        lines[-1] += "\n\\ No newline at end of file\n"
    return lines


def check_command(
    files: Files,
    vocabulary: Annotated[
        str | None,
        typer.Option(
            "--vocabulary",
            metavar="SPEC",
            help="The robot's vocabulary, FILE.toml or module:callable: names it lacks and "
            "arguments it does not take are problems.",
        ),
    ] = None,
) -> None:
    """Report every problem in stringBT files; exit 1 if there is any.

    Each is file:line:col: CODE message. Warnings (SBT5xx) are reported too, but do not
    change the exit status. Without --vocabulary, a file is checked against the vocabulary its
    project names (ktbt.toml, or [tool.ktbt] in pyproject.toml, found upward from the file),
    as the language server checks it."""
    from ktbt_proto.items import find_warnings
    from ktbt_proto.tools.cli.options import vocabulary_or_exit

    given = vocabulary_or_exit(vocabulary) if vocabulary is not None else None
    projects = _ProjectVocabularies()
    problems = checked = 0
    for path in _expand(files):
        name = _location(path)
        checked += 1
        registry = given if vocabulary is not None else projects.of(path)
        try:
            data = _read(path)
        except OSError as exc:
            typer.echo(f"{name}: error: cannot read: {io_reason(exc)}")
            problems += 1
            continue
        warnings: list[StringBTError] = []
        try:
            tree = parse(data)
            found: list[StringBTError] = find_problems(tree, registry)
            warnings = find_warnings(tree)
        except StringBTError as exc:
            found = [exc]
        for problem in sorted([*found, *warnings], key=lambda p: (p.line, p.column)):
            kind = " warning:" if problem in warnings else ""
            typer.echo(
                f"{name}:{problem.line}:{problem.column}: {problem.code}{kind} {problem.message}"
            )
        problems += len(found)
    if not checked:
        say(f"error: no .sbt file in {' '.join(files)}")
        raise typer.Exit(2)
    if problems:
        raise typer.Exit(1)


class _ProjectVocabularies:
    """The vocabulary each file's project names (spec/stringbt.md section 5.1), each project's
    read once; one that cannot be read is one line naming its settings, exit 2."""

    def __init__(self) -> None:
        self._loaded: dict[Path, Registry | None] = {}

    def of(self, path: str) -> Registry | None:
        from ktbt_proto.tools.project import ProjectError, find_project

        if path == STDIN:
            return None
        try:
            project = find_project(path)
            if project is None:
                return None
            if project.settings not in self._loaded:
                self._loaded[project.settings] = project.load_vocabulary()
            return self._loaded[project.settings]
        except ProjectError as exc:
            raise refuse(str(exc)) from None


def merge_command(
    control: Annotated[
        str, typer.Argument(metavar="CONTROL", help="The control tree; '-' for stdin.")
    ],
    subtree: Annotated[
        str, typer.Argument(metavar="SUBTREE", help="The knowledge subtree; '-' for stdin.")
    ],
    slot: Annotated[
        str, typer.Option("--slot", metavar="NAME", help="The placeholder <k>(NAME).")
    ] = "new",
    when: Annotated[
        str | None,
        typer.Option(
            "--when",
            metavar="CONDITIONS",
            help="Conditions the knowledge answers: COND[,COND...], each NAME, !NAME or "
            "NAME(key=value, ...). Without it the subtree is merged as it is.",
        ),
    ] = None,
    compact: Annotated[bool, typer.Option("--compact", help="Write the one-line form.")] = False,
    output: Annotated[
        str | None,
        typer.Option("--output", "-o", metavar="FILE", help="Write here instead of stdout."),
    ] = None,
) -> None:
    """Merge a knowledge subtree into a placeholder of a control tree.

    The subtree goes in as Sequence(conditions, subtree) when --when names the conditions;
    the merged tree is checked before it is written."""
    if control == STDIN and subtree == STDIN:
        say("error: only one of CONTROL and SUBTREE can be '-'")
        raise typer.Exit(2)
    conds = None if when is None else sequence_or_exit("--when", when)
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
        say(f"error: cannot merge{where}: {err.code} {err.message}")
        raise typer.Exit(1) from None
    text += "\n" if compact else ""
    if output is None:
        sys.stdout.write(text)
        return
    try:
        _write(output, text)
    except OSError as exc:
        say(f"error: cannot write {output}: {io_reason(exc)}")
        raise typer.Exit(1) from None


def convert_command(
    source: Annotated[
        str, typer.Argument(metavar="SOURCE", help="The file to read (.sbt or .xml).")
    ],
    target: Annotated[
        str, typer.Argument(metavar="TARGET", help="The file to write (.xml or .sbt).")
    ],
) -> None:
    """Convert between stringBT (.sbt) and BehaviorTree.CPP v4 XML (.xml).

    The direction follows the files' extensions."""
    from ktbt_proto.interop import convert

    try:
        convert(source, target)
    except StringBTError as err:
        say(f"error: cannot convert {source}:{err.line}:{err.column}: {err.code} {err.message}")
        raise typer.Exit(1) from None
    except OSError as exc:  # name the file that failed: the target is often the culprit
        failed = os.fsdecode(exc.filename) if exc.filename is not None else source
        verb = "write" if os.path.abspath(failed) == os.path.abspath(target) else "read"
        say(f"error: cannot convert {source}: cannot {verb} {failed}: {io_reason(exc)}")
        raise typer.Exit(1) from None
    except ValueError as exc:
        say(f"error: cannot convert {source}: {exc}")
        raise typer.Exit(1) from None


def show_command(
    file: Annotated[str, typer.Argument(metavar="FILE", help="A stringBT file; '-' for stdin.")],
    fmt: Annotated[
        Format, typer.Option("--format", "-f", help="A unicode outline, DOT or Mermaid.")
    ] = "outline",
) -> None:
    """Draw a tree as an outline, Graphviz DOT or Mermaid.

    The outline is unicode text; DOT and Mermaid are for drawing tools."""
    tree = _load_or_exit(file)
    sys.stdout.write(render(tree, fmt))


def _load_or_exit(path: str) -> Tree:
    name = _location(path)
    try:
        return parse(_read(path))
    except OSError as exc:
        say(f"error: cannot read {name}: {io_reason(exc)}")
    except StringBTError as err:
        say(f"{name}:{err}")
    raise typer.Exit(1)


def tour_command(
    examples: Annotated[
        Path | None,
        typer.Option(
            "--examples",
            metavar="FOLDER",
            help="Folder of the example files (default: those shipped here).",
            readable=False,
        ),
    ] = None,
) -> None:
    """A one-screen tour of the language and of a robot learning.

    It formats, checks and shows the example trees, then lets one robot teach another."""
    from ktbt_proto.tools.demo import examples_folder, run_demo

    raise typer.Exit(run_demo(examples or examples_folder()))


def register(app: typer.Typer) -> None:
    """Add the language's commands to the ``ktbt`` app."""
    app.command("fmt", epilog=example("ktbt fmt --check trees/"))(fmt_command)
    app.command("check", epilog=example("ktbt check --vocabulary robot.toml trees/"))(check_command)
    app.command("show", epilog=example("ktbt show --format mermaid control.sbt"))(show_command)
    app.command(
        "merge", epilog=example("ktbt merge control.sbt skill.sbt --when 'TargetSeen(colour=2)'")
    )(merge_command)
    app.command("convert", epilog=example("ktbt convert control.sbt control.xml"))(convert_command)
    app.command("tour", epilog=example("ktbt tour"))(tour_command)
