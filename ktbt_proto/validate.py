"""Rules a parsed tree must follow before it is formatted for the wire, compiled or merged.

The parser accepts any number of children anywhere so that one pass over the text can report a
clear, positioned problem for each rule here instead of a generic syntax error. With a registry,
validation is also what a robot uses to refuse knowledge it cannot execute.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import lru_cache
from typing import Protocol

from ktbt_proto.errors import ErrorCode, LimitError, StringBTError, ValidationError
from ktbt_proto.limits import DEFAULT_LIMITS, Limits
from ktbt_proto.syntax import NAME_RE
from ktbt_proto.tree import (
    Action,
    Args,
    Condition,
    Container,
    Inverter,
    Node,
    Parallel,
    Placeholder,
    RunTimer,
    Selector,
    SequenceNode,
    Tree,
    Wait,
    WaitTimer,
    as_node,
)

_RESERVED = frozenset(("true", "false"))


class SupportsNames(Protocol):
    """What validation needs to know of a registry: which names it can execute."""

    def has_condition(self, name: str) -> bool: ...

    def has_action(self, name: str) -> bool: ...


@dataclass(frozen=True, slots=True)
class Vocabulary:
    """The condition and action names a robot knows, without their arguments: the two questions
    validation asks of any registry. A vocabulary file, with its arguments' types and ranges
    checked too, is read by :func:`~ktbt_proto.tools.vocabulary.load_vocabulary` into a
    ``Registry``.
    """

    conditions: frozenset[str]
    actions: frozenset[str]

    def has_condition(self, name: str) -> bool:
        return name in self.conditions

    def has_action(self, name: str) -> bool:
        return name in self.actions

    @classmethod
    def of(cls, conditions: Iterable[str] = (), actions: Iterable[str] = ()) -> Vocabulary:
        return cls(frozenset(conditions), frozenset(actions))


def _problem(code: ErrorCode, message: str, node: Node) -> ValidationError:
    line, column = node.pos if node.pos else (0, 0)
    return ValidationError(code, message, line, column)


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _name_ok(name: object, max_literal: int) -> bool:
    return isinstance(name, str) and _well_formed(name, max_literal)


@lru_cache(maxsize=4096)
def _well_formed(name: str, max_literal: int) -> bool:
    # Cached: a robot validates the same few dozen names over and over.
    return (
        len(name) <= max_literal and NAME_RE.fullmatch(name) is not None and (name not in _RESERVED)
    )


def _too_big(value: object, limits: Limits) -> bool:
    """Whether a number is beyond ``limits.max_number`` (never for a bool or a string)."""
    bound = limits.max_number
    return (
        bound is not None
        and isinstance(value, int | float)
        and not isinstance(value, bool)
        and abs(value) > bound
    )


def _check_args(args: Args, node: Node, limits: Limits, out: list[StringBTError]) -> None:
    seen: set[str] = set()
    for key, value in args:
        if not _name_ok(key, limits.max_literal):
            out.append(_problem(ErrorCode.INVALID_NAME, f"invalid argument name {key!r}", node))
        elif key in seen:
            out.append(
                _problem(ErrorCode.DUPLICATE_ARGUMENT, f"argument {key!r} given twice", node)
            )
        seen.add(key)
        bad = None
        if isinstance(value, float) and not math.isfinite(value):
            bad = f"argument {key!r} is {value}; numbers must be finite"
        elif isinstance(value, str):
            try:
                value.encode("utf-8")
            except UnicodeEncodeError:
                bad = f"argument {key!r} holds a lone surrogate, which UTF-8 cannot carry"
        elif not isinstance(value, bool | int | float):
            bad = f"argument {key!r} is a {type(value).__name__}; use a number, string or bool"
        elif _too_big(value, limits):
            bad = f"argument {key!r} is beyond the limit of {limits.max_number:g} in magnitude"
        if bad:
            out.append(_problem(ErrorCode.INVALID_VALUE, bad, node))


_TAG = {
    SequenceNode: "<sq>",
    Selector: "<sl>",
    Parallel: "<pl>",
    Inverter: "<neg>",
    WaitTimer: "<tt1>",
    RunTimer: "<tt2>",
    Placeholder: "<k>",
}


def _check_container(
    node: Container, limits: Limits, placeholders: set[str], add: Callable[[StringBTError], None]
) -> None:
    n = len(node.children)
    tag = _TAG.get(type(node), type(node).__name__)
    if node.is_decorator:
        if n != 1:
            add(
                _problem(ErrorCode.DECORATOR_ARITY, f"{tag} needs exactly one child, not {n}", node)
            )
        if isinstance(node, WaitTimer | RunTimer) and not (_is_int(node.ticks) and node.ticks >= 0):
            add(
                _problem(
                    ErrorCode.INVALID_DURATION,
                    f"{tag} ticks must be a non-negative integer, not {node.ticks!r}",
                    node,
                )
            )
        elif isinstance(node, WaitTimer | RunTimer) and _too_big(node.ticks, limits):
            message = f"{tag} ticks beyond the limit of {limits.max_number:g}"
            add(_problem(ErrorCode.INVALID_DURATION, message, node))
    elif isinstance(node, Placeholder):
        if not _name_ok(node.name, limits.max_literal):
            add(_problem(ErrorCode.INVALID_NAME, f"invalid placeholder name {node.name!r}", node))
        elif node.name in placeholders:
            add(
                _problem(
                    ErrorCode.DUPLICATE_PLACEHOLDER,
                    f"placeholder {node.name!r} appears twice",
                    node,
                )
            )
        else:
            placeholders.add(node.name)
    else:
        if n == 0:
            add(_problem(ErrorCode.EMPTY_COMPOSITE, f"{tag} needs at least one child", node))
        if isinstance(node, Parallel) and node.threshold is not None:
            t = node.threshold
            if not (_is_int(t) and 1 <= t <= max(n, 1)):
                add(
                    _problem(
                        ErrorCode.INVALID_THRESHOLD,
                        f"parallel threshold {t!r} is not in 1..{max(n, 1)}",
                        node,
                    )
                )


def _check_wait(node: Wait, limits: Limits, add: Callable[[StringBTError], None]) -> None:
    d = node.duration
    if node.unit == "ticks":
        ok = _is_int(d) and d >= 0
        want = "a non-negative integer number of ticks"
    else:
        ok = node.unit == "seconds" and isinstance(d, int | float) and not isinstance(d, bool)
        # isinstance first: math.isfinite cannot take an integer too large for a float.
        ok = ok and (isinstance(d, int) or math.isfinite(d)) and d >= 0
        want = "a non-negative, finite number of seconds"
    if ok and _too_big(d, limits):
        ok, want = False, f"at most {limits.max_number:g}"
    if not ok:
        shown = repr(d) if len(repr(d)) <= 40 else f"{repr(d)[:20]}...({len(repr(d))} digits)"
        add(_problem(ErrorCode.INVALID_DURATION, f"wait must be {want}, not {shown}", node))


def find_problems(
    tree: Tree | Node,
    registry: SupportsNames | None = None,
    *,
    limits: Limits = DEFAULT_LIMITS,
) -> list[StringBTError]:
    """Every problem in the tree, in document order (empty when the tree is valid).

    A limit problem ends the walk at once: past it, the tree is not worth reading.
    """
    problems: list[StringBTError] = []
    add = problems.append
    placeholders: set[str] = set()
    max_depth, max_nodes, max_lit = limits.max_depth, limits.max_nodes, limits.max_literal
    # A runtime registry also knows the arguments each behaviour takes.
    fits = getattr(registry, "arguments_problem", None)
    values = getattr(registry, "values_problem", None)
    count = 0
    stack: list[tuple[Node, int]] = [(as_node(tree), 1)]
    pop, push = stack.pop, stack.append
    while stack:
        node, depth = pop()
        count += 1
        if depth > max_depth or count > max_nodes:
            line, column = node.pos if node.pos else (0, 0)
            if depth > max_depth:
                message = f"node nested deeper than the depth limit of {max_depth}"
                add(LimitError(ErrorCode.TOO_DEEP, message, line, column))
            else:
                message = f"more than {max_nodes} nodes"
                add(LimitError(ErrorCode.TOO_MANY_NODES, message, line, column))
            break
        kind = type(node)
        if kind is Condition or kind is Action:
            leaf: Condition | Action = node  # type: ignore[assignment]
            if not _name_ok(leaf.name, max_lit):
                what = "condition" if kind is Condition else "action"
                add(_problem(ErrorCode.INVALID_NAME, f"invalid {what} name {leaf.name!r}", node))
            elif registry is not None:
                if kind is Condition and not registry.has_condition(leaf.name):
                    add(
                        _problem(
                            ErrorCode.UNKNOWN_CONDITION, f"unknown condition {leaf.name!r}", node
                        )
                    )
                elif kind is Action and not registry.has_action(leaf.name):
                    add(_problem(ErrorCode.UNKNOWN_ACTION, f"unknown action {leaf.name!r}", node))
            if leaf.args:
                _check_args(leaf.args, node, limits, problems)
            if fits is not None:
                why = fits("condition" if kind is Condition else "action", leaf.name, leaf.args)
                if why is not None:
                    add(_problem(ErrorCode.INVALID_ARGUMENTS, why, node))
                elif values is not None and leaf.args:
                    why = values(
                        "condition" if kind is Condition else "action", leaf.name, leaf.args
                    )
                    if why is not None:
                        add(_problem(ErrorCode.INVALID_VALUE, why, node))
        elif isinstance(node, Container):
            _check_container(node, limits, placeholders, add)
            children = node.children
            for i in range(len(children) - 1, -1, -1):
                push((children[i], depth + 1))
        elif kind is Wait:
            _check_wait(node, limits, add)  # type: ignore[arg-type]
        else:
            add(_problem(ErrorCode.INVALID_VALUE, f"not a stringBT node: {node!r}", node))
            break
    return problems


def validate(
    tree: Tree | Node,
    registry: SupportsNames | None = None,
    *,
    limits: Limits = DEFAULT_LIMITS,
) -> None:
    """Raise a ``LimitError`` if the tree breaks a limit, else the first problem
    :func:`find_problems` finds (a ``ValidationError`` carrying all of them in ``problems``);
    ``None`` if valid."""
    problems = find_problems(tree, registry, limits=limits)
    if not problems:
        return
    # A limit problem wins: it says the rest of the tree was not even read.
    first = next((p for p in problems if isinstance(p, LimitError)), problems[0])
    if isinstance(first, ValidationError):
        first.problems = tuple(problems)
    raise first
