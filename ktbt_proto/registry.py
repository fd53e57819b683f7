"""What a robot can execute: conditions and actions by name, with the arguments they take.

The registry is also what the robot checks received knowledge against: a subtree naming a
behaviour it does not have, or passing arguments a behaviour does not take, is refused before it
touches the running tree.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import lru_cache, partial
from typing import Any, Literal, Protocol, TypeVar, runtime_checkable

from pydantic import TypeAdapter
from pydantic import ValidationError as PydanticError

from ktbt_proto.status import Status
from ktbt_proto.tree import Args

F = TypeVar("F", bound=Callable[..., Any])
Kind = Literal["condition", "action"]


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


def _parameters(fn: Any) -> inspect.Signature:
    """The signature with string annotations resolved where they can be (a name that does
    not resolve leaves every annotation as written, and string ones are then not checked)."""
    try:
        return inspect.signature(fn, eval_str=True)
    except (NameError, SyntaxError, TypeError, AttributeError):
        return inspect.signature(fn)


def _types(target: Any, is_class: bool) -> dict[str, Any]:
    """The annotations of the keyword parameters, for checking argument values."""
    try:
        sig = _parameters(target.__init__ if is_class else target)
    except (TypeError, ValueError):
        return {}
    return {
        p.name: p.annotation
        for p in sig.parameters.values()
        if p.annotation is not inspect.Parameter.empty
        and not isinstance(p.annotation, str)
        and p.annotation is not Any
    }


@lru_cache(maxsize=1024)
def _adapter(annotation: Any) -> TypeAdapter[Any]:
    return TypeAdapter(annotation)


def _value_problem(annotation: Any, value: Any) -> str | None:
    """Why ``value`` does not fit ``annotation`` in pydantic's strict mode (an ``int`` takes no
    bool or float; ``Annotated[int, Field(ge=1, le=4)]`` takes 1 to 4), or None if it does."""
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


def _signature(target: Any, is_class: bool) -> tuple[frozenset[str], frozenset[str], bool]:
    """Keyword parameters after the blackboard: all, required, and whether ``**kw`` is taken."""
    try:
        sig = inspect.signature(target.__init__ if is_class else target)
    except (TypeError, ValueError):  # builtins without a signature: take anything
        return frozenset(), frozenset(), True
    params = list(sig.parameters.values())
    if is_class:
        params = params[1:]  # self
    if not params or params[0].kind not in (
        inspect.Parameter.POSITIONAL_ONLY,
        inspect.Parameter.POSITIONAL_OR_KEYWORD,
    ):
        raise TypeError(f"{target!r} must take the blackboard as its first parameter")
    rest = params[1:]
    kinds = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    names = frozenset(p.name for p in rest if p.kind in kinds)
    required = frozenset(
        p.name for p in rest if p.kind in kinds and p.default is inspect.Parameter.empty
    )
    var_kw = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in rest)
    return names, required, var_kw


_STATUS_NAMES = frozenset(("Status", "kp.Status", "ktbt_proto.Status", "ktbt_proto.status.Status"))


def _returns_status(fn: Any) -> bool:
    """Whether ``fn`` is annotated to return exactly ``Status`` (then its result is trusted)."""
    try:
        annotation = inspect.signature(fn).return_annotation
    except (TypeError, ValueError):
        return False
    return annotation is Status or (isinstance(annotation, str) and annotation in _STATUS_NAMES)


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
        params, required, var_kw = _signature(fn, False)
        self._conditions[name] = _Entry(
            fn, params, required, var_kw, doc=fn.__doc__ or "", types=_types(fn, False)
        )

    def add_action(
        self, name: str, target: Any, *, halt: Callable[..., None] | None = None
    ) -> None:
        is_class = isinstance(target, type)
        if is_class and not callable(getattr(target, "tick", None)):
            raise TypeError(f"action class {target.__name__} needs a tick() method")
        params, required, var_kw = _signature(target, is_class)
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
            types=_types(target, is_class),
        )

    def flags(self, *names: str) -> None:
        """Register conditions that read blackboard flags of the same name (missing = false)."""
        for name in names:
            self._conditions[name] = _Entry(None, frozenset(), frozenset(), False, flag=name)

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
        unknown = sorted(given - entry.params) if not entry.var_kw else []
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
        fn = entry.target
        return partial(fn, blackboard, **dict(args)) if args else partial(fn, blackboard)

    def bind_action(
        self, name: str, blackboard: Any, args: Args
    ) -> tuple[Callable[[], Any], Callable[[], None] | None, bool]:
        """``(tick, halt, trusted)`` for one node; a class gets a fresh instance per node.
        ``trusted``: the behaviour is annotated to return a Status, so its result is used as
        it is (anything else is checked and converted on every call)."""
        entry = self._actions[name]
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
