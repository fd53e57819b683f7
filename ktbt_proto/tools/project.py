"""A project's own settings for the tools: which vocabulary its stringBT files are written for.

Found upward from a file: the first folder holding a ``ktbt.toml``, or a ``pyproject.toml``
with a ``[tool.ktbt]`` table, is the project's. Both say the same, with the same keys::

    vocabulary = "robot.toml"           # a vocabulary file (spec/stringbt.md section 5.1), or
    vocabulary = "mypkg.robot:registry" # a Python registry, module:callable

A relative path is read from the settings' folder, and a Python registry is imported with that
folder on the path (``tools.vocabulary.load_vocabulary``), so the same setting means the same
vocabulary whichever folder an editor or a command was started in. ``ktbt lsp`` reads it for
every document it checks; a setting that is wrong is one line naming the file and the key
(:class:`ProjectError`), never a traceback.
"""

from __future__ import annotations

import os
import sys
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from ktbt_proto.files import TooLarge, read_bounded
from ktbt_proto.registry import Registry
from ktbt_proto.tools.vocabulary import load_vocabulary

__all__ = ["Project", "ProjectError", "candidates", "find_project", "read_settings"]

SETTINGS = "ktbt.toml"
PYPROJECT = "pyproject.toml"
KEYS = frozenset(("vocabulary",))
MAX_SETTINGS_FILE = 1_000_000
"""A settings file larger than this is refused, not read."""


class ProjectError(ValueError):
    """The project's settings cannot be read or name something that is not there (one line)."""


@dataclass(frozen=True)
class Project:
    """A project's settings: the file they were read from and the vocabulary they name."""

    settings: Path
    vocabulary: str | None

    @property
    def root(self) -> Path:
        return self.settings.parent

    @property
    def where(self) -> str:
        """How a message names the setting: ``ktbt.toml`` or ``pyproject.toml [tool.ktbt]``."""
        table = " [tool.ktbt]" if self.settings.name == PYPROJECT else ""
        return f"{self.settings}{table}"

    def vocabulary_file(self) -> Path | None:
        """The vocabulary file named (None for a Python registry or no vocabulary)."""
        spec = self.vocabulary
        if spec is None or not _is_file_spec(spec):
            return None
        return self.root / spec

    def load_vocabulary(self) -> Registry | None:
        """The registry the settings name (None: no vocabulary); raises :class:`ProjectError`."""
        spec = self.vocabulary
        if spec is None:
            return None
        path = self.vocabulary_file()
        try:
            if path is not None:
                return load_vocabulary(path)
            root = str(self.root)
            if root not in sys.path:
                sys.path.insert(0, root)
            return load_vocabulary(spec)
        except ValueError as exc:
            raise ProjectError(f"{self.where}: vocabulary: {exc}") from None


def _is_file_spec(spec: str) -> bool:
    return spec.endswith(".toml") or ":" not in spec or os.sep in spec.split(":", 1)[0]


def _read(path: Path) -> dict[str, object]:
    try:
        data = read_bounded(path, MAX_SETTINGS_FILE).decode("utf-8")
        return tomllib.loads(data)
    except TooLarge:
        raise ProjectError(f"{path}: larger than {MAX_SETTINGS_FILE} bytes") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ProjectError(f"{path}: cannot read: {exc}") from None


def read_settings(path: Path) -> Project | None:
    """The settings a ``ktbt.toml`` or a ``pyproject.toml`` holds (None: a ``pyproject.toml``
    without ``[tool.ktbt]``); raises :class:`ProjectError`."""
    data = _read(path)
    table: object = data
    if path.name == PYPROJECT:
        tool = data.get("tool")
        table = tool.get("ktbt") if isinstance(tool, dict) else None
        if table is None:
            return None
        where = f"{path} [tool.ktbt]"
    else:
        where = str(path)
    if not isinstance(table, dict):
        raise ProjectError(f"{where}: must be a table")
    unknown = set(table) - KEYS
    if unknown:
        raise ProjectError(f"{where}: unknown keys {sorted(unknown)} (known: vocabulary)")
    vocabulary = table.get("vocabulary")
    if vocabulary is not None and (not isinstance(vocabulary, str) or not vocabulary):
        raise ProjectError(f"{where}: vocabulary must be a FILE.toml or module:callable")
    return Project(path, vocabulary)


def candidates(start: str | os.PathLike[str]) -> Iterator[Path]:
    """The settings files that could hold the settings of ``start`` (a file or a folder),
    nearest first: each folder's ``ktbt.toml``, then its ``pyproject.toml``, that exist."""
    here = Path(start).resolve()
    folder = here if here.is_dir() else here.parent
    for candidate in (folder, *folder.parents):
        for name in (SETTINGS, PYPROJECT):
            path = candidate / name
            if path.is_file():
                yield path


def find_project(start: str | os.PathLike[str]) -> Project | None:
    """The settings of the project ``start`` (a file or a folder) belongs to, or None; raises
    :class:`ProjectError` for settings that cannot be read."""
    for path in candidates(start):
        project = read_settings(path)
        if project is not None:
            return project
    return None
