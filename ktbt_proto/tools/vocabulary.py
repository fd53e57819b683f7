"""The vocabulary a robot is checked against, as the tools load it (spec/stringbt.md, section
5.1): a vocabulary file (``robot.toml``: the conditions and actions with their arguments' names,
types and ranges) read into a :class:`~ktbt_proto.registry.Registry` and written from one, or
a Python registry named ``module:callable``, imported with the current folder on the path as
``python -m`` would.

This is the tools' work, not the language's: the language keeps the registry and what checking
against it means; reading files in a format of its own and importing the user's modules are
what a command, a host or an editor does on the way to one (:func:`load_vocabulary` is what
``--vocabulary`` and the ``vocabulary`` parameter name).
"""

from __future__ import annotations

import importlib
import inspect
import math
import os
import re
import sys
import tomllib
import typing
from collections.abc import Iterable
from pathlib import Path
from typing import Annotated, Any, Literal

from ktbt_proto.files import TooLarge, read_bounded
from ktbt_proto.registry import Kind, Registry
from ktbt_proto.syntax import NAME_RE

__all__ = [
    "MAX_VOCABULARY_FILE",
    "load_vocabulary",
    "parse_vocabulary",
    "read_vocabulary",
    "write_vocabulary",
]

MAX_VOCABULARY_FILE = 1_000_000
"""A vocabulary file larger than this is refused, not read (a path may be /dev/zero)."""


def load_vocabulary(spec: str | os.PathLike[str]) -> Registry:
    """The registry a robot's vocabulary names: a vocabulary file (``robot.toml``), or a Python
    registry as ``module:callable`` (``mypkg.robot:make_registry``, called with no argument,
    or a ``Registry`` object itself), imported with the current folder on the path. Raises
    ``ValueError`` with one line: a file that cannot be read or declares something wrong, a
    module that is missing or fails to import, a name it lacks, a callable that fails or
    returns something other than a ``Registry``."""
    text = os.fspath(spec)
    path = Path(text)
    if path.is_file() or text.endswith(".toml") or _MODULE.fullmatch(text) is None:
        if not path.is_file() and not text.endswith(".toml"):
            raise ValueError(
                f"registry {text}: neither a vocabulary file (.toml) nor a Python registry "
                "named module:callable"
            )
        return read_vocabulary(path)
    module_name, _, attribute = text.partition(":")
    if os.getcwd() not in sys.path and "" not in sys.path:
        sys.path.insert(0, os.getcwd())  # as `python -m` would: the robot's own package
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name is not None and module_name.startswith(exc.name):
            raise ValueError(f"registry {text}: no module named {exc.name!r}") from None
        raise ValueError(
            f"registry {text}: cannot import {module_name}: {_one_line(exc)}"
        ) from None
    except Exception as exc:
        raise ValueError(
            f"registry {text}: cannot import {module_name}: {_one_line(exc)}"
        ) from None
    target: Any = module
    for part in attribute.split("."):
        if not hasattr(target, part):
            raise ValueError(f"registry {text}: {module_name} has no {attribute!r}")
        target = getattr(target, part)
    if not isinstance(target, Registry):
        if not callable(target):
            raise ValueError(f"registry {text}: {attribute} is neither a Registry nor callable")
        try:
            target = target()
        except Exception as exc:
            raise ValueError(f"registry {text}: {attribute}() failed: {_one_line(exc)}") from None
        if not isinstance(target, Registry):
            raise ValueError(
                f"registry {text}: {attribute}() returned {type(target).__name__}, not a Registry"
            )
    return target


_MODULE = re.compile(r"[A-Za-z_][\w.]*:[A-Za-z_][\w.]*")


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


# -- the vocabulary file (spec/stringbt.md, section 5.1) ------------------------------------


def write_vocabulary(registry: Registry) -> str:
    """``registry`` as a vocabulary file, which :func:`read_vocabulary` reads back into a
    registry that checks knowledge exactly as this one does. Raises ``ValueError`` (one
    line) for an argument whose annotation has no form there (int, float, str, bool, a
    ``Literal`` of one of them, with ``ge``/``gt``/``le``/``lt`` or length bounds)."""
    lines = [
        "# The conditions and actions a robot can execute, with their arguments",
        "# (spec/stringbt.md, section 5.1).",
    ]
    for kind, table in (
        ("conditions", registry.behaviours("condition")),
        ("actions", registry.behaviours("action")),
    ):
        for name in sorted(table):
            entry = table[name]
            lines += ["", f"[{kind}.{_toml_key(name)}]"]
            if entry.doc:
                lines.append(f"doc = {_toml_value(inspect.cleandoc(entry.doc))}")
            if entry.flag is not None:
                lines.append("flag = true")
            if entry.var_kw:
                lines.append("more_arguments = true")
            for arg in sorted(entry.params):
                try:
                    spec = _spec_of(entry.types.get(arg, Any))
                except ValueError as exc:
                    raise ValueError(f"{kind[:-1]} {name!r}, argument {arg!r}: {exc}") from None
                if arg not in entry.required:
                    spec["required"] = False
                lines.append(f"arguments.{_toml_key(arg)} = {_toml_value(spec)}")
    return "\n".join(lines) + "\n"


def read_vocabulary(path: str | os.PathLike[str]) -> Registry:
    """The registry a vocabulary file declares (spec/stringbt.md, section 5.1), read
    bounded (at most ``MAX_VOCABULARY_FILE`` bytes); raises ``ValueError`` with one line."""
    try:
        text = read_bounded(path, MAX_VOCABULARY_FILE).decode("utf-8")
    except TooLarge:
        raise ValueError(
            f"cannot read registry {os.fspath(path)}: larger than {MAX_VOCABULARY_FILE} bytes"
        ) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read registry {os.fspath(path)}: {exc}") from None
    return parse_vocabulary(text, os.fspath(path))


def parse_vocabulary(text: str, source: str = "<vocabulary>") -> Registry:
    """A registry from a vocabulary file's text; raises ``ValueError`` with a one-line
    reason naming ``source`` and the key at fault."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"cannot read registry {source}: {exc}") from None
    unknown = set(data) - {"conditions", "actions"}
    if unknown:
        raise ValueError(f"registry {source}: unknown keys {sorted(unknown)}")
    reg = Registry()
    for key, kind in (("conditions", "condition"), ("actions", "action")):
        value = data.get(key, [])
        if isinstance(value, list):  # names only: any arguments
            if not all(isinstance(v, str) for v in value):
                raise ValueError(f"registry {source}: '{key}' must be a list of names")
            for name in value:
                _check_name(name, f"registry {source}: '{key}'")
                reg.declare(kind, name, more_arguments=True)  # type: ignore[arg-type]
        elif isinstance(value, dict):
            for name, entry in value.items():
                where = f"registry {source}: {key}.{name}"
                _check_name(name, where)
                _read_entry(reg, kind, name, entry, where)  # type: ignore[arg-type]
        else:
            raise ValueError(
                f"registry {source}: '{key}' must be a list of names or a table of declarations"
            )
    return reg


_PLAIN: dict[str, type] = {"int": int, "float": float, "str": str, "bool": bool}
_BOUNDS = ("ge", "gt", "le", "lt")
_LENGTHS = ("min_length", "max_length")
_ENTRY_KEYS = frozenset(("doc", "flag", "more_arguments", "arguments"))
_ARGUMENT_KEYS = frozenset(("type", "choices", "required", *_BOUNDS, *_LENGTHS))
_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _check_name(name: str, where: str) -> None:
    if NAME_RE.fullmatch(name) is None or name in ("true", "false"):
        raise ValueError(f"{where}: {name!r} is not a stringBT name")


def _read_entry(reg: Registry, kind: Kind, name: str, entry: Any, where: str) -> None:
    """Declare one ``[conditions.NAME]`` or ``[actions.NAME]`` table."""
    if not isinstance(entry, dict):
        raise ValueError(f"{where} must be a table")
    unknown = set(entry) - _ENTRY_KEYS
    if unknown:
        raise ValueError(f"{where}: unknown keys {sorted(unknown)}")
    for key, want in (("doc", str), ("flag", bool), ("more_arguments", bool)):
        if key in entry and not isinstance(entry[key], want):
            raise ValueError(f"{where}.{key} must be a {want.__name__}")
    arguments = entry.get("arguments", {})
    if not isinstance(arguments, dict):
        raise ValueError(f"{where}.arguments must be a table of argument names")
    if entry.get("flag", False):
        if kind != "condition" or arguments or entry.get("more_arguments", False):
            raise ValueError(f"{where}: a flag is a condition without arguments")
        reg.flags(name)
        return
    annotations: dict[str, Any] = {}
    required = []
    for arg, spec in arguments.items():
        _check_name(arg, f"{where}.arguments")
        annotations[arg] = _annotation_of(spec, f"{where}.arguments.{arg}")
        if spec.get("required", True):
            required.append(arg)
    reg.declare(
        kind,
        name,
        annotations,
        required=required,
        more_arguments=entry.get("more_arguments", False),
        doc=entry.get("doc", ""),
    )


def _number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _annotation_of(spec: Any, where: str) -> Any:
    """The annotation an argument's declaration stands for: ``{type = "int", ge = 1, le = 4}``
    is ``Annotated[int, Field(ge=1, le=4)]``, ``{type = "str", choices = ["l", "r"]}`` is
    ``Literal["l", "r"]``, ``{}`` is ``Any``."""
    from pydantic import Field

    if not isinstance(spec, dict):
        raise ValueError(f'{where} must be a table such as {{ type = "int", ge = 0 }}')
    unknown = set(spec) - _ARGUMENT_KEYS
    if unknown:
        raise ValueError(f"{where}: unknown keys {sorted(unknown)}")
    if not isinstance(spec.get("required", True), bool):
        raise ValueError(f"{where}.required must be true or false")
    name = spec.get("type")
    if name is None:
        if set(spec) - {"required"}:
            raise ValueError(f"{where}: a range or choices needs a type (int, float, str, bool)")
        return Any
    base = _PLAIN.get(name) if isinstance(name, str) else None
    if base is None:
        raise ValueError(f"{where}.type is {name!r}, not one of int, float, str, bool")
    annotation: Any = base
    if "choices" in spec:
        choices = spec["choices"]
        if (
            not isinstance(choices, list)
            or not choices
            or not all(type(c) is base and (base is not float or _number(c)) for c in choices)
        ):
            raise ValueError(f"{where}.choices must be a non-empty list of {name} values")
        annotation = Literal[tuple(choices)]
    constraints: dict[str, Any] = {}
    for key in _BOUNDS:
        if key in spec:
            if base not in (int, float) or not _number(spec[key]):
                raise ValueError(f"{where}.{key} must be a finite number, for an int or a float")
            constraints[key] = spec[key]
    for key in _LENGTHS:
        if key in spec:
            value = spec[key]
            if base is not str or not isinstance(value, int) or isinstance(value, bool):
                raise ValueError(f"{where}.{key} must be an integer, for a str")
            constraints[key] = value
    return Annotated[annotation, Field(**constraints)] if constraints else annotation


def _spec_of(annotation: Any) -> dict[str, Any]:
    """An argument's declaration in the vocabulary file (the inverse of :func:`_annotation_of`);
    raises ``ValueError`` for an annotation that has no form there."""
    import annotated_types as at
    from pydantic.fields import FieldInfo

    if annotation is Any:
        return {}
    base: Any = annotation
    meta: tuple[Any, ...] = ()
    if typing.get_origin(annotation) is Annotated:
        base, *rest = typing.get_args(annotation)
        meta = tuple(rest)
    spec: dict[str, Any] = {}
    names = {t: n for n, t in _PLAIN.items()}
    if typing.get_origin(base) is Literal:
        choices = list(typing.get_args(base))
        kinds = {type(c) for c in choices}
        kind = kinds.pop() if len(kinds) == 1 else None
        if kind not in names:
            raise ValueError(f"{_shown(annotation)}: choices must all be int, float, str or bool")
        spec["type"], spec["choices"] = names[kind], choices
    elif base in names:
        spec["type"] = names[base]
    else:
        raise ValueError(
            f"{_shown(annotation)} has no vocabulary form (int, float, str, bool, a Literal of "
            "one of them, with ge/gt/le/lt or min_length/max_length)"
        )
    for item in meta:
        bounds: Iterable[Any] = item.metadata if isinstance(item, FieldInfo) else (item,)
        for bound in bounds:
            if isinstance(bound, at.Interval):
                spec.update(
                    (k, getattr(bound, k)) for k in _BOUNDS if getattr(bound, k) is not None
                )
            elif isinstance(bound, at.Ge | at.Gt | at.Le | at.Lt):
                key = type(bound).__name__.lower()
                spec[key] = getattr(bound, key)
            elif isinstance(bound, at.MinLen | at.MaxLen):
                key = "min_length" if isinstance(bound, at.MinLen) else "max_length"
                spec[key] = getattr(bound, key)
            elif type(bound).__name__ != "Strict":  # values are checked strictly anyway
                raise ValueError(f"{_shown(annotation)}: {bound!r} has no vocabulary form")
    return spec


def _shown(annotation: Any) -> str:
    return getattr(annotation, "__name__", None) or repr(annotation).replace("typing.", "")


def _toml_key(key: str) -> str:
    return key if _BARE_KEY.fullmatch(key) else _toml_value(key)


_ESCAPES = {'"': '\\"', "\\": "\\\\", "\n": "\\n", "\t": "\\t"}


def _toml_value(value: Any) -> str:
    """A TOML value: a string, a number, a bool, a list or an inline table of them."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        escaped = "".join(
            _ESCAPES.get(c) or (f"\\u{ord(c):04X}" if ord(c) < 0x20 or ord(c) == 0x7F else c)
            for c in value
        )
        return f'"{escaped}"'
    if isinstance(value, list):
        return "[" + ", ".join(map(_toml_value, value)) + "]"
    items = ", ".join(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items())
    return "{ " + items + " }" if items else "{}"
