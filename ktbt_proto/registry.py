"""What a robot can execute: conditions and actions by name, with the arguments they take.

The registry is also what the robot checks received knowledge against: a subtree naming a
behaviour it does not have, or passing arguments a behaviour does not take, is refused before it
touches the running tree.

A registry learns its arguments' names, types and ranges from its behaviours' annotations, or
from :meth:`Registry.declare` for a robot written in another language. Reading and writing the
vocabulary file that declares them (spec/stringbt.md, section 5.1), and importing a Python
registry named ``module:callable``, are the tools' work (:mod:`ktbt_proto.tools.vocabulary`):
the language holds no file format and imports no user code."""

from __future__ import annotations

import inspect
import logging
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from functools import lru_cache, partial
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Literal, Protocol, TypeVar, runtime_checkable

from ktbt_proto.status import FAILURE, Status
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
class Behaviour:
    """One registered condition or action, as :meth:`Registry.behaviours` hands it out: what it
    runs (``None`` when only declared), the arguments it takes, their annotations and its doc."""

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
    pure: bool = False
    """It reads and writes nothing but the blackboard and its arguments, keeps no state and
    acts on nothing outside (a flag, a declared behaviour, a stand-in registered ``pure=True``):
    ticked again on the same blackboard, it does the same. A tree of such leaves and no timers
    that ticks without changing its blackboard or its status may be ticked less often until
    something arrives (``ktbt peer run``'s rest rate, spec/protocol.md section 4.5)."""
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


def _returns_status(fn: Any) -> bool:
    """Whether ``fn`` is annotated to return exactly ``Status`` (then its result is trusted).
    The annotation is resolved as Python resolves it (``from __future__ import annotations``
    leaves a string); one that does not resolve to the class is not trusted, and the result is
    checked at every tick."""
    try:
        return _parameters(fn).return_annotation is Status
    except (TypeError, ValueError):
        return False


class Registry:
    """Conditions and actions by name.

    A condition is ``predicate(blackboard, **args) -> bool``. An action is
    ``action(blackboard, **args) -> Status`` (``True``/``None`` count as SUCCESS and ``False``
    as FAILURE), optionally with a ``halt(blackboard, **args)`` hook; or a class whose
    ``__init__(self, blackboard, **args)`` makes one instance per node and whose ``tick()`` and
    ``halt()`` keep state across ticks.
    """

    def __init__(self) -> None:
        self._conditions: dict[str, Behaviour] = {}
        self._actions: dict[str, Behaviour] = {}
        self._warned: set[tuple[str, str]] = set()

    # -- registering -----------------------------------------------------------------------

    def condition(self, name: str | None = None, *, pure: bool = False) -> Callable[[F], F]:
        """Decorator: register a predicate under ``name`` (default: the function's name);
        ``pure``: it reads nothing but the blackboard and its arguments (:attr:`Behaviour.pure`)."""

        def register(fn: F) -> F:
            self.add_condition(name or fn.__name__, fn, pure=pure)
            return fn

        return register

    def action(
        self,
        name: str | None = None,
        *,
        halt: Callable[..., None] | None = None,
        pure: bool = False,
    ) -> Callable[[F], F]:
        """Decorator: register an action function or class under ``name``; ``pure``: it
        reads and writes nothing but the blackboard, acts on nothing outside and keeps no state
        (:attr:`Behaviour.pure`)."""

        def register(target: F) -> F:
            self.add_action(name or target.__name__, target, halt=halt, pure=pure)
            return target

        return register

    def add_condition(self, name: str, fn: Callable[..., Any], *, pure: bool = False) -> None:
        (params, required, var_kw), types, reserved = _behaviour(fn, False)
        self._conditions[name] = Behaviour(
            fn,
            params,
            required,
            var_kw,
            doc=fn.__doc__ or "",
            types=types,
            reserved=reserved,
            pure=pure,
        )

    def add_action(
        self,
        name: str,
        target: Any,
        *,
        halt: Callable[..., None] | None = None,
        pure: bool = False,
    ) -> None:
        is_class = isinstance(target, type)
        if is_class and not callable(getattr(target, "tick", None)):
            raise TypeError(f"action class {target.__name__} needs a tick() method")
        if is_class and pure:  # an instance keeps state between ticks: never pure
            raise TypeError(f"action class {target.__name__} cannot be pure (it keeps state)")
        (params, required, var_kw), types, reserved = _behaviour(target, is_class)
        trusted = _returns_status(target.tick if is_class else target)
        self._actions[name] = Behaviour(
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
            pure=pure,
        )

    def flags(self, *names: str) -> None:
        """Register conditions that read blackboard flags of the same name (missing = false)."""
        for name in names:
            self._conditions[name] = Behaviour(
                None, frozenset(), frozenset(), False, flag=name, pure=True
            )

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
        entry = Behaviour(
            None, names, needed, var_kw or more_arguments, doc=doc, types=types, pure=True
        )
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
        entry = Behaviour(None, names, required, var_kw, doc=made.__doc__ or "", types=types)
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

    def pure(self, kind: Kind, name: str) -> bool:
        """Whether the ``kind`` named ``name`` is known here and pure (:attr:`Behaviour.pure`)."""
        entry = (self._conditions if kind == "condition" else self._actions).get(name)
        return entry is not None and entry.pure

    def behaviours(self, kind: Kind) -> Mapping[str, Behaviour]:
        """The registered conditions or actions by name, read-only: what a vocabulary file is
        written from and what an editor goes to the definition of."""
        return MappingProxyType(self._conditions if kind == "condition" else self._actions)

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
