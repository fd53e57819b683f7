"""What a robot can execute: conditions and actions by name, with the arguments they take.

The registry is also what the robot checks received knowledge against: a subtree naming a
behaviour it does not have, or passing arguments a behaviour does not take, is refused before it
touches the running tree.

A robot's vocabulary can also be a file (spec/stringbt.md, section 5.1): the conditions and
actions with their arguments' names, types and ranges, what a Python registry learns from its
behaviours' annotations. :meth:`Registry.load` reads one and :meth:`Registry.to_toml` writes
one, so that a robot written in another language (a BehaviorTree.CPP program) is checked
exactly as a Python one is; the tools also take a Python registry named ``module:callable``
(:func:`ktbt_proto.tools.robot.load_vocabulary`, which imports the user's module).
"""

from __future__ import annotations

import inspect
import logging
import math
import os
import re
import tomllib
import typing
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from functools import lru_cache, partial
from typing import TYPE_CHECKING, Annotated, Any, Literal, Protocol, TypeVar, runtime_checkable

from ktbt_proto.files import TooLarge, read_bounded
from ktbt_proto.status import FAILURE, Status
from ktbt_proto.syntax import NAME_RE
from ktbt_proto.tree import Args

if TYPE_CHECKING:
    from pydantic import TypeAdapter

F = TypeVar("F", bound=Callable[..., Any])
Kind = Literal["condition", "action"]
_Params = tuple[frozenset[str], frozenset[str], bool]

log = logging.getLogger("ktbt.registry")

PLUMBING = frozenset(("name", "blackboard", "bb"))
"""Parameters of a behaviour factory that are not stringBT arguments
(:meth:`Registry.declare_from`): py_trees behaviours take their ``name``, some their blackboard."""


@runtime_checkable
class StatefulAction(Protocol):
    """An action registered as a class: one instance per node, ``halt`` when preempted."""

    def tick(self) -> Status | bool | None: ...

    def halt(self) -> None: ...


@dataclass(frozen=True, slots=True)
class _Entry:
    target: Any
    params: frozenset[str]
    required: frozenset[str]
    var_kw: bool
    is_class: bool = False
    halt: Callable[..., None] | None = None
    flag: str | None = None
    trusted: bool = False
    doc: str = field(default="", compare=False)
    types: Mapping[str, Any] = field(default_factory=dict, compare=False)
    """Parameter name -> its annotation, for the parameters that have one."""
    reserved: frozenset[str] = frozenset()
    """Names no argument may take: the blackboard parameter's, which a behaviour taking
    ``**kw`` would otherwise be given twice (``holds(bb, **kw)`` called with ``bb=1``)."""


def _parameters(fn: Any) -> inspect.Signature:
    """The signature with string annotations resolved where they can be (a name that does
    not resolve leaves every annotation as written, and string ones are then not checked)."""
    try:
        return inspect.signature(fn, eval_str=True)
    except (NameError, SyntaxError, TypeError, AttributeError):
        return inspect.signature(fn)


_KINDS = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)


def _describe(
    params: Iterable[inspect.Parameter],
) -> tuple[frozenset[str], frozenset[str], bool, dict[str, Any]]:
    """What the arguments of a behaviour are, from its parameters after the blackboard (or the
    plumbing a factory takes): all keyword names, the required ones, whether ``**kw`` is
    taken, and the annotations that can check a value (parameter name -> annotation)."""
    params = list(params)
    names = frozenset(p.name for p in params if p.kind in _KINDS)
    required = frozenset(
        p.name for p in params if p.kind in _KINDS and p.default is inspect.Parameter.empty
    )
    var_kw = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params)
    types = {
        p.name: p.annotation
        for p in params
        if p.kind in _KINDS
        and p.annotation is not inspect.Parameter.empty
        and not isinstance(p.annotation, str)
        and p.annotation is not Any
    }
    return names, required, var_kw, types


def _own_parameters(target: Any, is_class: bool) -> list[inspect.Parameter] | None:
    """The parameters of a function, or of a class's ``__init__`` without ``self``; None for
    a builtin without a signature (it takes anything)."""
    try:
        sig = _parameters(target.__init__ if is_class else target)
    except (TypeError, ValueError):
        return None
    params = list(sig.parameters.values())
    return params[1:] if is_class else params


@lru_cache(maxsize=1024)
def _adapter(annotation: Any) -> TypeAdapter[Any]:
    from pydantic import TypeAdapter

    return TypeAdapter(annotation)


def _value_problem(annotation: Any, value: Any) -> str | None:
    """Why ``value`` does not fit ``annotation`` in pydantic's strict mode (an ``int`` takes no
    bool or float; ``Annotated[int, Field(ge=1, le=4)]`` takes 1 to 4), or None if it does.

    pydantic is imported here, where an argument is first checked, so that parsing and
    formatting a tree never load it."""
    from pydantic import TypeAdapter
    from pydantic import ValidationError as PydanticError

    try:
        adapter = _adapter(annotation)
    except TypeError:  # an unhashable annotation: build it afresh
        adapter = TypeAdapter(annotation)
    try:
        adapter.validate_python(value, strict=True)
    except PydanticError as exc:
        first = exc.errors()[0]
        return str(first.get("msg", "invalid value"))
    return None


def _behaviour(target: Any, is_class: bool) -> tuple[_Params, dict[str, Any], frozenset[str]]:
    """A behaviour's keyword parameters after the blackboard, their annotations, and the
    names no argument may take (the blackboard parameter's, when it can be named)."""
    params = _own_parameters(target, is_class)
    if params is None:  # builtins without a signature: take anything
        return (frozenset(), frozenset(), True), {}, frozenset()
    if not params or params[0].kind not in (
        inspect.Parameter.POSITIONAL_ONLY,
        inspect.Parameter.POSITIONAL_OR_KEYWORD,
    ):
        raise TypeError(f"{target!r} must take the blackboard as its first parameter")
    names, required, var_kw, types = _describe(params[1:])
    named = params[0].kind is inspect.Parameter.POSITIONAL_OR_KEYWORD
    return (names, required, var_kw), types, frozenset({params[0].name} if named else ())


_STATUS_NAMES = frozenset(("Status", "kp.Status", "ktbt_proto.Status", "ktbt_proto.status.Status"))


def _returns_status(fn: Any) -> bool:
    """Whether ``fn`` is annotated to return exactly ``Status`` (then its result is trusted)."""
    try:
        annotation = inspect.signature(fn).return_annotation
    except (TypeError, ValueError):
        return False
    return annotation is Status or (isinstance(annotation, str) and annotation in _STATUS_NAMES)


MAX_VOCABULARY_FILE = 1_000_000
"""A vocabulary file larger than this is refused, not read (a path may be /dev/zero)."""


class Registry:
    """Conditions and actions by name.

    A condition is ``predicate(blackboard, **args) -> bool``. An action is
    ``action(blackboard, **args) -> Status`` (``True``/``None`` count as SUCCESS and ``False``
    as FAILURE), optionally with a ``halt(blackboard, **args)`` hook; or a class whose
    ``__init__(self, blackboard, **args)`` makes one instance per node and whose ``tick()`` and
    ``halt()`` keep state across ticks.
    """

    def __init__(self) -> None:
        self._conditions: dict[str, _Entry] = {}
        self._actions: dict[str, _Entry] = {}
        self._warned: set[tuple[str, str]] = set()

    # -- registering -----------------------------------------------------------------------

    def condition(self, name: str | None = None) -> Callable[[F], F]:
        """Decorator: register a predicate under ``name`` (default: the function's name)."""

        def register(fn: F) -> F:
            self.add_condition(name or fn.__name__, fn)
            return fn

        return register

    def action(
        self, name: str | None = None, *, halt: Callable[..., None] | None = None
    ) -> Callable[[F], F]:
        """Decorator: register an action function or class under ``name``."""

        def register(target: F) -> F:
            self.add_action(name or target.__name__, target, halt=halt)
            return target

        return register

    def add_condition(self, name: str, fn: Callable[..., Any]) -> None:
        (params, required, var_kw), types, reserved = _behaviour(fn, False)
        self._conditions[name] = _Entry(
            fn, params, required, var_kw, doc=fn.__doc__ or "", types=types, reserved=reserved
        )

    def add_action(
        self, name: str, target: Any, *, halt: Callable[..., None] | None = None
    ) -> None:
        is_class = isinstance(target, type)
        if is_class and not callable(getattr(target, "tick", None)):
            raise TypeError(f"action class {target.__name__} needs a tick() method")
        (params, required, var_kw), types, reserved = _behaviour(target, is_class)
        trusted = _returns_status(target.tick if is_class else target)
        self._actions[name] = _Entry(
            target,
            params,
            required,
            var_kw,
            is_class,
            halt,
            trusted=trusted,
            doc=target.__doc__ or "",
            types=types,
            reserved=reserved,
        )

    def flags(self, *names: str) -> None:
        """Register conditions that read blackboard flags of the same name (missing = false)."""
        for name in names:
            self._conditions[name] = _Entry(None, frozenset(), frozenset(), False, flag=name)

    def declare(
        self,
        kind: Kind,
        name: str,
        arguments: Mapping[str, Any] | None = None,
        *,
        required: Iterable[str] | None = None,
        more_arguments: bool = False,
        doc: str = "",
    ) -> None:
        """Know a condition or action by its arguments only, without an implementation: what a
        vocabulary file declares for a robot that runs its behaviours elsewhere (a C++ program,
        a py_trees robot's own behaviours). ``arguments`` maps each argument to its annotation
        (``Any``: any value); all are required unless ``required`` names some;
        ``more_arguments`` takes any other argument too. Received knowledge is checked against
        it as against a Python behaviour's signature. Ticked here, a declared condition does
        not hold and a declared action fails (logged once at WARNING)."""
        arguments = dict(arguments or {})
        params = inspect.Parameter
        names, needed, var_kw, types = _describe(
            [params(arg, params.KEYWORD_ONLY, annotation=a) for arg, a in arguments.items()]
        )
        if required is not None:
            needed = frozenset(required) & names
        entry = _Entry(None, names, needed, var_kw or more_arguments, doc=doc, types=types)
        (self._conditions if kind == "condition" else self._actions)[name] = entry

    def declare_from(
        self, kind: Kind, name: str, factory: Callable[..., Any], *, skip: Iterable[str] = PLUMBING
    ) -> None:
        """Declare ``name`` with the arguments ``factory`` takes (a class: its ``__init__``),
        the parameters in ``skip`` aside: a py_trees behaviour class is made with a leaf's
        arguments as keywords, so its signature is what the leaf may pass, typed and ranged by
        its annotations as a registered behaviour's are."""
        is_class = isinstance(factory, type)
        params = _own_parameters(factory, is_class)
        skipped = frozenset(skip)
        names: frozenset[str] = frozenset()
        required: frozenset[str] = frozenset()
        var_kw, types = True, dict[str, Any]()  # a builtin without a signature: takes anything
        if params is not None:
            names, required, var_kw, types = _describe(p for p in params if p.name not in skipped)
        made = factory.func if isinstance(factory, partial) else factory  # its own doc
        entry = _Entry(None, names, required, var_kw, doc=made.__doc__ or "", types=types)
        (self._conditions if kind == "condition" else self._actions)[name] = entry

    def copy(self) -> Registry:
        """Another registry with the same entries (adding to one leaves the other as it was)."""
        other = Registry()
        other._conditions = dict(self._conditions)
        other._actions = dict(self._actions)
        return other

    # -- what validation asks --------------------------------------------------------------

    def has_condition(self, name: str) -> bool:
        return name in self._conditions

    def has_action(self, name: str) -> bool:
        return name in self._actions

    @property
    def conditions(self) -> frozenset[str]:
        return frozenset(self._conditions)

    @property
    def actions(self) -> frozenset[str]:
        return frozenset(self._actions)

    def arguments_problem(self, kind: Kind, name: str, args: Args) -> str | None:
        """Why these arguments do not fit the registered behaviour, or None if they do."""
        table = self._conditions if kind == "condition" else self._actions
        entry = table.get(name)
        if entry is None or (not args and not entry.required):
            return None
        given = {k for k, _ in args}
        unknown = (
            sorted(given - entry.params) if not entry.var_kw else sorted(given & entry.reserved)
        )
        missing = sorted(entry.required - given)
        if unknown:
            return f"{kind} {name!r} takes no argument {', '.join(map(repr, unknown))}"
        if missing:
            return f"{kind} {name!r} needs argument {', '.join(map(repr, missing))}"
        return None

    def values_problem(self, kind: Kind, name: str, args: Args) -> str | None:
        """Why an argument's value does not fit its parameter's annotation (type and range,
        checked by pydantic in strict mode), or None. Checked at validation, so that a
        wrong-typed or out-of-range argument is refused before a merge, never met at a tick."""
        table = self._conditions if kind == "condition" else self._actions
        entry = table.get(name)
        if entry is None or not entry.types:
            return None
        for key, value in args:
            annotation = entry.types.get(key)
            if annotation is None:
                continue
            why = _value_problem(annotation, value)
            if why is not None:
                shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
                return f"{kind} {name!r}: argument {key}={shown}: {why}"
        return None

    # -- what compilation asks -------------------------------------------------------------

    def bind_condition(self, name: str, blackboard: Any, args: Args) -> Callable[[], Any]:
        """A zero-argument predicate for one node: bound once, called every tick."""
        entry = self._conditions[name]
        if entry.flag is not None:
            return partial(blackboard.get, entry.flag, False)
        if entry.target is None:
            return partial(self._declared, "condition", name, False)
        fn = entry.target
        return partial(fn, blackboard, **dict(args)) if args else partial(fn, blackboard)

    def bind_action(
        self, name: str, blackboard: Any, args: Args
    ) -> tuple[Callable[[], Any], Callable[[], None] | None, bool]:
        """``(tick, halt, trusted)`` for one node; a class gets a fresh instance per node.
        ``trusted``: the behaviour is annotated to return a Status, so its result is used as
        it is (anything else is checked and converted on every call)."""
        entry = self._actions[name]
        if entry.target is None:
            return partial(self._declared, "action", name, FAILURE), None, True
        kwargs = dict(args)
        if entry.is_class:
            instance = entry.target(blackboard, **kwargs)
            return instance.tick, getattr(instance, "halt", None), entry.trusted
        tick = (
            partial(entry.target, blackboard, **kwargs)
            if kwargs
            else partial(entry.target, blackboard)
        )
        halt = partial(entry.halt, blackboard, **kwargs) if entry.halt is not None else None
        return tick, halt, entry.trusted

    def _declared(self, kind: Kind, name: str, result: Any) -> Any:
        """A declared behaviour ticked here: it has no implementation to run (logged once)."""
        if (kind, name) not in self._warned:
            self._warned.add((kind, name))
            log.warning(
                "%s %r is declared without an implementation here: it %s",
                kind,
                name,
                "does not hold" if kind == "condition" else "fails",
            )
        return result

    # -- the vocabulary file (spec/stringbt.md, section 5.1) ---------------------------------

    def to_toml(self) -> str:
        """This registry as a vocabulary file, which :meth:`load` reads back into a
        registry that checks knowledge exactly as this one does. Raises ``ValueError`` (one
        line) for an argument whose annotation has no form there (int, float, str, bool, a
        ``Literal`` of one of them, with ``ge``/``gt``/``le``/``lt`` or length bounds)."""
        lines = [
            "# The conditions and actions a robot can execute, with their arguments",
            "# (spec/stringbt.md, section 5.1).",
        ]
        for kind, table in (("conditions", self._conditions), ("actions", self._actions)):
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

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Registry:
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
        return cls.from_toml(text, os.fspath(path))

    @classmethod
    def from_toml(cls, text: str, source: str = "<vocabulary>") -> Registry:
        """A registry from a vocabulary file's text; raises ``ValueError`` with a one-line
        reason naming ``source`` and the key at fault."""
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"cannot read registry {source}: {exc}") from None
        unknown = set(data) - {"conditions", "actions"}
        if unknown:
            raise ValueError(f"registry {source}: unknown keys {sorted(unknown)}")
        reg = cls()
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


# -- the vocabulary file -----------------------------------------------------------------------

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
