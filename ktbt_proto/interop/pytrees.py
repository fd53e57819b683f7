"""A stringBT tree as a py_trees tree, for its tooling (visitors, ASCII and dot rendering, ROS).

The result ticks exactly like :class:`ktbt_proto.LiveTree`: same statuses, same action calls and
halts, in the same order (the tests tick both side by side). py_trees' own nodes serve where
their semantics are stringBT's:

- ``<sq>``/``<sl>``/``<k>`` are ``Sequence``/``Selector`` with ``memory=False``, ``<msq>``/``<msl>``
  with ``memory=True``; an empty placeholder is a selector with no children, which fails.
- ``<pl>`` and ``<pl>(N)`` are ``Parallel`` with ``SuccessOnAll(synchronise=False)``: every child
  is ticked every tick and one failure fails it, as in stringBT. py_trees has no "M of N" policy
  (``SuccessOnOne`` fails on any failure; ``SuccessOnSelected`` names children), so ``<pl>(M)``
  with M < N is a ``Parallel`` subclass that counts, as the spec says.
- ``<neg>`` is ``Inverter``. TT1, TT2 and both waits are small custom nodes: py_trees' ``Timer``
  counts seconds, and its decorators tick their child on every tick, which TT1 must not.

Leaves call the registry's bound callables. An action's halt hook runs from ``terminate`` when
the action is stopped (``INVALID``) while RUNNING, which is exactly when stringBT halts it.
Every custom node keeps its state per activation: py_trees calls ``initialise`` on the first tick
after any stop, which is where stringBT resets timers.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Mapping
from typing import Any

try:
    from py_trees import behaviour, common, composites, decorators
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError(
        "ktbt_proto.interop.pytrees needs py_trees: pip install 'ktbt[py-trees]'"
    ) from exc

from ktbt_proto.blackboard import Blackboard
from ktbt_proto.formatter import format_value
from ktbt_proto.registry import Registry
from ktbt_proto.status import FAILURE, RUNNING, SUCCESS, Status
from ktbt_proto.tree import (
    Action,
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
    Visitor,
    Wait,
    WaitTimer,
    as_node,
)
from ktbt_proto.validate import validate

__all__ = ["Behaviours", "from_py_trees_status", "origin", "to_py_trees", "to_py_trees_status"]

Clock = Callable[[], float]
Behaviours = Mapping[str, Callable[..., behaviour.Behaviour]]
"""The user's own py_trees behaviour per leaf name, made with the leaf's arguments as keywords
(a negated condition is its factory's behaviour under an ``Inverter``); leaves not named here
call the registry's bound callables. Keyed by name only: a name the registry has both as a
condition and as an action gets one factory for both."""
ORIGIN = "ktbt_node"
"""The attribute on every behaviour built here that holds the stringBT node it was built from."""


def origin(made: behaviour.Behaviour) -> Node | None:
    """The stringBT node ``made`` was built from by :func:`to_py_trees`, None if not built there."""
    node = getattr(made, ORIGIN, None)
    return node if isinstance(node, Node) else None


PyStatus = common.Status
_TO_PY = {SUCCESS: PyStatus.SUCCESS, FAILURE: PyStatus.FAILURE, RUNNING: PyStatus.RUNNING}
_FROM_PY = {v: k for k, v in _TO_PY.items()}


def to_py_trees_status(status: Status) -> common.Status:
    return _TO_PY[status]


def from_py_trees_status(status: common.Status) -> Status:
    """py_trees' INVALID (never ticked, or stopped) has no stringBT status: KeyError."""
    return _FROM_PY[status]


class _Condition(behaviour.Behaviour):
    def __init__(self, name: str, holds: Callable[[], Any], negated: bool) -> None:
        super().__init__(("!" if negated else "") + name)
        self._holds, self._negated = holds, negated

    def update(self) -> common.Status:
        return PyStatus.SUCCESS if bool(self._holds()) != self._negated else PyStatus.FAILURE


class _Action(behaviour.Behaviour):
    def __init__(self, name: str, run: Callable[[], Any], stop: Callable[[], None] | None) -> None:
        super().__init__(name)
        self._run, self._stop = run, stop

    def update(self) -> common.Status:
        value = self._run()
        if value.__class__ is Status:
            return _TO_PY[value]
        if value is True or value is None:
            return PyStatus.SUCCESS
        if value is False:
            return PyStatus.FAILURE
        raise TypeError(f"action {self.name!r} returned {value!r}; return a Status (or a bool)")

    def terminate(self, new_status: common.Status) -> None:
        # self.status is still the old one: halt only an action that was running.
        if new_status == PyStatus.INVALID and self.status == PyStatus.RUNNING and self._stop:
            self._stop()


class _WaitTicks(behaviour.Behaviour):
    def __init__(self, ticks: int) -> None:
        super().__init__(f"Wait({ticks})")
        self._ticks = ticks
        self._waited = 0

    def initialise(self) -> None:
        self._waited = 0

    def update(self) -> common.Status:
        if self._waited < self._ticks:
            self._waited += 1
            return PyStatus.RUNNING
        return PyStatus.SUCCESS


class _WaitSeconds(behaviour.Behaviour):
    def __init__(self, seconds: float, clock: Clock) -> None:
        super().__init__(f"Wait({format_value(seconds)}s)")
        self._seconds, self._clock = seconds, clock
        self._deadline: float | None = None

    def initialise(self) -> None:
        self._deadline = None

    def update(self) -> common.Status:
        now = self._clock()
        if self._deadline is None:
            self._deadline = now + self._seconds
        return PyStatus.SUCCESS if now >= self._deadline else PyStatus.RUNNING


class _Timer(decorators.Decorator):
    """TT1 and TT2 decide whether to tick the child at all, so they own ``tick``."""

    def __init__(self, name: str, child: behaviour.Behaviour, ticks: int) -> None:
        super().__init__(name=name, child=child)
        self._ticks = ticks
        self._count = 0

    def initialise(self) -> None:
        self._count = 0

    def update(self) -> common.Status:
        return self.decorated.status  # unused: tick() decides

    def _finish(self, status: common.Status) -> None:
        if status != PyStatus.RUNNING:
            self.stop(status)  # Decorator.stop halts a child still running
        self.status = status


class _WaitTimer(_Timer):
    """TT1: RUNNING on ticks 1..N of an activation without ticking the child, then the child."""

    def tick(self) -> Iterator[behaviour.Behaviour]:
        if self.status != PyStatus.RUNNING:
            self.initialise()
        if self._count < self._ticks:
            self._count += 1
            self.status = PyStatus.RUNNING
        else:
            yield from self.decorated.tick()
            self._finish(self.decorated.status)
        yield self


class _RunTimer(_Timer):
    """TT2: the child's status for up to N ticks; still running after its N-th: FAILURE."""

    def tick(self) -> Iterator[behaviour.Behaviour]:
        if self.status != PyStatus.RUNNING:
            self.initialise()
        if self._ticks == 0:
            self._finish(PyStatus.FAILURE)
            yield self
            return
        self._count += 1
        yield from self.decorated.tick()
        status = self.decorated.status
        if status == PyStatus.RUNNING and self._count >= self._ticks:
            status = PyStatus.FAILURE
        self._finish(status)
        yield self


class _ThresholdParallel(composites.Parallel):
    """SUCCESS once M children succeed on a tick, FAILURE once more than N - M fail."""

    def __init__(self, name: str, children: list[behaviour.Behaviour], threshold: int) -> None:
        super().__init__(name, common.ParallelPolicy.SuccessOnAll(synchronise=False), children)
        self.threshold = threshold

    def tick(self) -> Iterator[behaviour.Behaviour]:
        if self.status != PyStatus.RUNNING:
            for child in self.children:
                if child.status != PyStatus.INVALID:
                    child.stop(PyStatus.INVALID)
            self.initialise()
        for child in self.children:
            yield from child.tick()
        statuses = [child.status for child in self.children]
        if statuses.count(PyStatus.SUCCESS) >= self.threshold:
            status = PyStatus.SUCCESS
        elif statuses.count(PyStatus.FAILURE) > len(statuses) - self.threshold:
            status = PyStatus.FAILURE
        else:
            status = PyStatus.RUNNING
        if status != PyStatus.RUNNING:
            self.stop(status)  # Parallel.stop halts the children still running
        self.status = status
        yield self


def to_py_trees(
    tree: Tree | Node | str,
    registry: Registry,
    blackboard: Any = None,
    *,
    clock: Clock = time.monotonic,
    behaviours: Behaviours | None = None,
) -> behaviour.Behaviour:
    """The tree as a py_trees behaviour bound to ``registry`` and ``blackboard`` (a new
    :class:`Blackboard` if None); tick it with ``py_trees.trees.BehaviourTree(root).tick()``.
    ``behaviours`` makes the named leaves the user's own py_trees behaviours.

    The tree is validated against the registry first, as :class:`LiveTree` does.
    """
    if isinstance(tree, str):
        from ktbt_proto.syntax import parse

        tree = parse(tree)
    validate(tree, registry)
    bb = Blackboard() if blackboard is None else blackboard
    return build(as_node(tree), registry, bb, clock, behaviours or {})


def build(
    node: Node, registry: Registry, bb: Any, clock: Clock, behaviours: Behaviours
) -> behaviour.Behaviour:
    """A validated node as py_trees behaviours, each tagged with its stringBT node
    (:func:`origin`)."""
    made = _build(node, registry, bb, clock, behaviours)
    setattr(made, ORIGIN, node)
    return made


def _leaf(node: Condition | Action, behaviours: Behaviours) -> behaviour.Behaviour | None:
    factory = behaviours.get(node.name)
    if factory is None:
        return None
    made = factory(**dict(node.args))
    if not isinstance(made, behaviour.Behaviour):
        raise TypeError(f"the factory of {node.name!r} made {made!r}, not a py_trees Behaviour")
    if isinstance(node, Condition) and node.negated:
        return decorators.Inverter(f"!{node.name}", made)
    return made


class _Builder(Visitor[behaviour.Behaviour]):
    """Each node as its py_trees behaviour; a leaf the user gave a behaviour of their own
    (``behaviours``) is theirs. Validation bounds the depth, so building children through
    :func:`build` (recursion) is safe; py_trees ticks recursively anyway."""

    def __init__(self, registry: Registry, bb: Any, clock: Clock, behaviours: Behaviours):
        self.registry, self.bb, self.clock, self.behaviours = registry, bb, clock, behaviours

    def _kids(self, node: Container) -> list[behaviour.Behaviour]:
        return [
            build(child, self.registry, self.bb, self.clock, self.behaviours)
            for child in node.children
        ]

    def condition(self, node: Condition) -> behaviour.Behaviour:
        own = _leaf(node, self.behaviours) if self.behaviours else None
        if own is not None:
            return own
        holds = self.registry.bind_condition(node.name, self.bb, node.args)
        return _Condition(node.name, holds, node.negated)

    def action(self, node: Action) -> behaviour.Behaviour:
        own = _leaf(node, self.behaviours) if self.behaviours else None
        if own is not None:
            return own
        bound = self.registry.bind_action(node.name, self.bb, node.args)  # (tick, halt, ...)
        return _Action(node.name, bound[0], bound[1])

    def wait(self, node: Wait) -> behaviour.Behaviour:
        if node.unit == "ticks":
            return _WaitTicks(int(node.duration))
        return _WaitSeconds(float(node.duration), self.clock)

    def sequence(self, node: SequenceNode) -> behaviour.Behaviour:
        name = "Sequence*" if node.memory else "Sequence"
        return composites.Sequence(name, node.memory, self._kids(node))

    def selector(self, node: Selector) -> behaviour.Behaviour:
        name = "Selector*" if node.memory else "Selector"
        return composites.Selector(name, node.memory, self._kids(node))

    def placeholder(self, node: Placeholder) -> behaviour.Behaviour:
        return composites.Selector(f"k:{node.name}", False, self._kids(node))

    def parallel(self, node: Parallel) -> behaviour.Behaviour:
        kids = self._kids(node)
        if node.threshold is None or node.threshold == len(kids):
            policy = common.ParallelPolicy.SuccessOnAll(synchronise=False)
            return composites.Parallel("Parallel", policy, kids)
        return _ThresholdParallel(f"Parallel({node.threshold})", kids, node.threshold)

    def inverter(self, node: Inverter) -> behaviour.Behaviour:
        return decorators.Inverter("Inverter", self._kids(node)[0])

    def wait_timer(self, node: WaitTimer) -> behaviour.Behaviour:
        return _WaitTimer(f"TT1({node.ticks})", self._kids(node)[0], node.ticks)

    def run_timer(self, node: RunTimer) -> behaviour.Behaviour:
        return _RunTimer(f"TT2({node.ticks})", self._kids(node)[0], node.ticks)


def _build(
    node: Node, registry: Registry, bb: Any, clock: Clock, behaviours: Behaviours
) -> behaviour.Behaviour:
    return _Builder(registry, bb, clock, behaviours).visit(node)
    kids = [build(child, registry, bb, clock, behaviours) for child in node.children]
    if isinstance(node, SequenceNode):
        return composites.Sequence("Sequence*" if node.memory else "Sequence", node.memory, kids)
    if isinstance(node, Selector):
        return composites.Selector("Selector*" if node.memory else "Selector", node.memory, kids)
    if isinstance(node, Placeholder):
        return composites.Selector(f"k:{node.name}", False, kids)
    if isinstance(node, Parallel):
        if node.threshold is None or node.threshold == len(kids):
            policy = common.ParallelPolicy.SuccessOnAll(synchronise=False)
            return composites.Parallel("Parallel", policy, kids)
        return _ThresholdParallel(f"Parallel({node.threshold})", kids, node.threshold)
    if isinstance(node, Inverter):
        return decorators.Inverter("Inverter", kids[0])
    if isinstance(node, WaitTimer):
        return _WaitTimer(f"TT1({node.ticks})", kids[0], node.ticks)
    if isinstance(node, RunTimer):
        return _RunTimer(f"TT2({node.ticks})", kids[0], node.ticks)
    raise TypeError(f"not a stringBT node: {node!r}")
