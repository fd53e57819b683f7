"""What the editor knows of a robot's vocabulary: each condition's and action's arguments with
their types and ranges, its doc, and where it is defined.

The description is the vocabulary file's (spec/stringbt.md section 5.1): a registry writes it
(``write_vocabulary``), and this module reads it back, so an argument is shown to the writer of
a tree exactly as the file declares it (``degrees: int, 1 <= degrees <= 90``) whether the robot's
vocabulary is a file or a Python registry. A Python registry whose annotations have no form in
the file (a class of the application's own) is still known by its names.
"""

from __future__ import annotations

import contextlib
import inspect
import os
import re
import stat
import tomllib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from ktbt_proto.registry import Registry
from ktbt_proto.tools.project import PYPROJECT, SETTINGS, Project, ProjectError, read_settings
from ktbt_proto.tools.vocabulary import load_vocabulary, write_vocabulary

Kind = Literal["condition", "action"]

_DEFINES = ("def ", "async def ", "class ")
_BOUND_SIGN = {"ge": ">=", "gt": ">", "le": "<=", "lt": "<"}


@dataclass(frozen=True)
class Argument:
    """One argument a behaviour takes, as the vocabulary file declares it."""

    name: str
    spec: Mapping[str, Any]

    @property
    def required(self) -> bool:
        return bool(self.spec.get("required", True))

    @property
    def type(self) -> str:
        return str(self.spec.get("type", "any"))

    @property
    def choices(self) -> list[Any]:
        choices = self.spec.get("choices", [])
        return list(choices) if isinstance(choices, list) else []

    def shown(self) -> str:
        """``degrees: int, 1 <= degrees <= 90``, ``side: str, one of "left", "right"``,
        ``speed: float (optional)``."""
        parts = [f"{self.name}: {self.type}"]
        low = next((k for k in ("ge", "gt") if k in self.spec), None)
        high = next((k for k in ("le", "lt") if k in self.spec), None)
        if low and high:
            low_sign = "<=" if low == "ge" else "<"
            parts.append(
                f"{self.spec[low]} {low_sign} {self.name} {_BOUND_SIGN[high]} {self.spec[high]}"
            )
        else:
            parts += [f"{self.name} {_BOUND_SIGN[k]} {self.spec[k]}" for k in (low, high) if k]
        if self.choices:
            parts.append("one of " + ", ".join(_literal(c) for c in self.choices))
        for key, word in (("min_length", "at least"), ("max_length", "at most")):
            if key in self.spec:
                parts.append(f"{word} {self.spec[key]} characters")
        text = ", ".join(parts)
        return text if self.required else f"{text} (optional)"


def _literal(value: Any) -> str:
    """A value as stringBT writes it."""
    from ktbt_proto.formatter import format_value

    return format_value(value)


@dataclass(frozen=True)
class Entry:
    """A condition or action: its arguments, doc and kind of entry."""

    kind: Kind
    name: str
    doc: str = ""
    arguments: tuple[Argument, ...] = ()
    more_arguments: bool = False
    flag: bool = False
    described: bool = True
    """False when only the name is known (an annotation without a vocabulary form)."""

    def signature(self) -> str:
        """``action TurnHandle(degrees: int, 1 <= degrees <= 90, speed: float (optional))``."""
        args = [a.shown() for a in self.arguments]
        if self.more_arguments:
            args.append("...")
        what = "condition (a blackboard flag)" if self.flag else self.kind
        inside = "; ".join(args) if args else ""
        return f"{what} {self.name}({inside})" if self.described else f"{what} {self.name}"

    def argument(self, name: str) -> Argument | None:
        return next((a for a in self.arguments if a.name == name), None)


class Known:
    """A loaded vocabulary, described for the editor: ``registry`` validates, ``entries``
    describes, ``definition`` finds where a name is defined."""

    def __init__(self, registry: Registry, spec: str, file: Path | None = None) -> None:
        self.registry = registry
        self.spec = spec
        self.file = file
        self.entries: dict[tuple[Kind, str], Entry] = {}
        try:
            described = tomllib.loads(write_vocabulary(registry))
        except (ValueError, tomllib.TOMLDecodeError):  # an annotation with no file form
            described = {}
        kinds: tuple[tuple[Kind, frozenset[str], Any], ...] = (
            ("condition", registry.conditions, described.get("conditions", {})),
            ("action", registry.actions, described.get("actions", {})),
        )
        for kind, names, table in kinds:
            for name in names:
                self.entries[(kind, name)] = _entry(kind, name, table.get(name))

    def entry(self, kind: Kind, name: str) -> Entry | None:
        return self.entries.get((kind, name))

    def names(self, kind: Kind) -> list[Entry]:
        return sorted((e for (k, _), e in self.entries.items() if k == kind), key=lambda e: e.name)

    def definition(self, kind: Kind, name: str) -> tuple[Path, int] | None:
        """Where ``name`` is defined: the line (0-based) of its table in the vocabulary file,
        or of the Python function or class behind it; None when neither can be found."""
        if self.entry(kind, name) is None:
            return None
        if self.file is not None:
            return _in_file(self.file, kind, name)
        return _in_python(self.registry, kind, name)


def _entry(kind: Kind, name: str, table: Any) -> Entry:
    if not isinstance(table, dict):
        return Entry(kind, name, described=False)
    arguments = table.get("arguments", {})
    return Entry(
        kind,
        name,
        doc=str(table.get("doc", "")),
        arguments=tuple(
            Argument(arg, spec) for arg, spec in sorted(arguments.items()) if isinstance(spec, dict)
        ),
        more_arguments=bool(table.get("more_arguments", False)),
        flag=bool(table.get("flag", False)),
    )


def _in_file(path: Path, kind: Kind, name: str) -> tuple[Path, int] | None:
    """The line of ``[conditions.NAME]`` (or ``"NAME"`` in a list of names) in a vocabulary file."""
    plural = "conditions" if kind == "condition" else "actions"
    header = re.compile(rf'^\s*\[\s*{plural}\s*\.\s*(?:{re.escape(name)}|"{re.escape(name)}")\s*\]')
    listed = re.compile(rf'"{re.escape(name)}"')
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError):
        return None
    for number, line in enumerate(lines):
        if header.match(line):
            return path, number
    in_list = False
    for number, line in enumerate(lines):
        if re.match(rf"^\s*{plural}\s*=", line):
            in_list = True
        elif re.match(r"^\s*(\[|\w+\s*=)", line):
            in_list = False
        if in_list and listed.search(line):
            return path, number
    return None


def _in_python(registry: Registry, kind: Kind, name: str) -> tuple[Path, int] | None:
    """The source line of the function or class a Python registry runs for ``name``.

    A behaviour without Python source (a builtin, a declared name, a blackboard flag) has no
    definition to go to."""
    entry = registry.behaviours(kind).get(name)
    target = None if entry is None else entry.target
    if target is None:
        return None
    with contextlib.suppress(TypeError, OSError):
        source = inspect.getsourcefile(inspect.unwrap(target))
        if source is not None:
            lines, first = inspect.getsourcelines(inspect.unwrap(target))
            # Past its decorators (``@registry.action(...)``), to its ``def`` or ``class``.
            skip = next(
                (i for i, line in enumerate(lines) if line.lstrip().startswith(_DEFINES)), 0
            )
            return Path(source), max(first - 1 + skip, 0)
    return None


class Vocabularies:
    """Which vocabulary each document is checked against, loaded once and kept: the one
    ``ktbt lsp --vocabulary`` names for every document, else the one its project's settings name
    (``tools.project``: ``ktbt.toml`` or ``pyproject.toml [tool.ktbt]``, found upward from the
    file), else none (syntax and the language's own rules alone).

    A keystroke costs a few ``stat`` calls, never a read: settings and vocabulary files are
    read again only when their modification time changes, and a Python registry is imported
    once per server (restart the server to see a change in its code). A vocabulary that fails
    to load is a one-line reason naming the setting, which the server shows on the document's
    first line while it checks the syntax alone."""

    def __init__(self, override: str | None = None) -> None:
        self.override = override
        self._settings: dict[Path, tuple[int, Project | None, str | None]] = {}
        self._loaded: dict[tuple[str, str], tuple[int, Known | None, str | None]] = {}
        self._places: dict[Path, list[tuple[str, Path]]] = {}
        self._named: dict[int, tuple[Project, tuple[str, str], Path | None]] = {}

    def for_path(self, path: Path | None) -> tuple[Known | None, str | None]:
        """``(vocabulary, None)``, ``(None, None)`` with no vocabulary, or ``(None, reason)``."""
        if self.override is not None:
            spec = self.override
            file = Path(spec) if _looks_like_file(spec) else None
            return self._load(("--vocabulary", spec), file, lambda: load_vocabulary(spec))
        if path is None:
            return None, None
        try:
            found = self._project(path)
        except ProjectError as exc:
            return None, str(exc)
        if found is None or found.vocabulary is None:
            return None, None
        named = self._named.get(id(found))
        if named is None or named[0] is not found:  # once per settings read
            named = (found, (str(found.settings), found.vocabulary), found.vocabulary_file())
            self._named[id(found)] = named
        return self._load(named[1], named[2], found.load_vocabulary, where=found.where)

    def _project(self, path: Path) -> Project | None:
        for settings, stamp in self._candidates(path):
            cached = self._settings.get(settings)
            if cached is None or cached[0] != stamp:
                try:
                    cached = (stamp, read_settings(settings), None)
                except ProjectError as exc:
                    cached = (stamp, None, str(exc))
                self._settings[settings] = cached
            _, project, error = cached
            if error is not None:
                raise ProjectError(error)
            if project is not None:
                return project
        return None

    def _candidates(self, path: Path) -> Iterator[tuple[Path, int]]:
        """``tools.project.candidates``, each with its modification time: the settings files
        that exist from the document's folder upward, nearest first. The folders above a
        document are found once per document (a path resolved once), the files looked at again
        on every check (one ``stat`` each)."""
        places = self._places.get(path)
        if places is None:
            here = path.resolve()
            folder = here if here.is_dir() else here.parent
            places = [
                (str(folder / name), folder / name)
                for folder in (folder, *folder.parents)
                for name in (SETTINGS, PYPROJECT)
            ]
            self._places[path] = places
        for name, settings in places:
            try:
                found = os.stat(name)
            except OSError:
                continue
            if stat.S_ISREG(found.st_mode):
                yield settings, found.st_mtime_ns

    def _load(
        self,
        key: tuple[str, str],
        file: Path | None,
        load: Callable[[], Registry | None],
        where: str = "--vocabulary",
    ) -> tuple[Known | None, str | None]:
        stamp = _stamp(file) if file is not None else 0
        cached = self._loaded.get(key)
        if cached is not None and cached[0] == stamp:
            return cached[1], cached[2]
        try:
            registry = load()
            known = Known(registry, key[1], file) if registry is not None else None
            result: tuple[int, Known | None, str | None] = (stamp, known, None)
        except ValueError as exc:
            reason = str(exc)
            if not reason.startswith(where):
                reason = f"{where}: {reason}"
            result = (stamp, None, reason)
        self._loaded[key] = result
        return result[1], result[2]


def _looks_like_file(spec: str) -> bool:
    return spec.endswith(".toml") or ":" not in spec


def _stamp(path: Path) -> int:
    try:
        return os.stat(path).st_mtime_ns
    except OSError:
        return -1
