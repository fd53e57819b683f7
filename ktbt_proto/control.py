"""What an agent needs from the control tree it learns into and teaches from.

An :class:`~ktbt_proto.exchange.agent.Agent` merges answers into a placeholder of its control tree,
forgets them again, asks when each item last ran (its memory policy, ``spec/protocol.md``
section 4.2), ticks the tree, and reads the knowledge its placeholders already hold from the
tree's stringBT form (section 4). :class:`ControlTree` is that contract, and nothing more: the
compiled :class:`~ktbt_proto.runtime.LiveTree` is one backend, a py_trees ``BehaviourTree``
(:class:`ktbt_proto.interop.pytrees_control.PyTreesControl`, ``spec/protocol.md`` section 4.4)
another. Every backend keeps the same rules: a merge or a forget takes effect at a tick
boundary, never inside a tick; a forget leaves a running item alone until it stops
(``spec/stringbt.md`` section 4); whatever does not fit raises a ``StringBTError`` and changes
nothing, a behaviour the application's code fails to build included (``SBT403``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any, Protocol, runtime_checkable

from ktbt_proto.registry import Registry
from ktbt_proto.runtime import TickClock
from ktbt_proto.status import Status
from ktbt_proto.tree import Condition, Node, Tree

__all__ = ["ControlFactory", "ControlTree", "TickClock"]


@runtime_checkable
class ControlTree(Protocol):
    """A robot's running control tree, as the agent learns into it (``spec/protocol.md`` §4).
    ``registry`` is the vocabulary it runs, which received items are checked against (a
    py_trees backend's includes the tree's own behaviours)."""

    registry: Registry

    @property
    def tree(self) -> Tree:
        """The tree in stringBT, merges and forgets still pending included: the knowledge
        base reads the items its placeholders hold from it."""
        ...

    def tick(self) -> Status:
        """Tick the root once; merges and forgets since the last tick take effect first."""
        ...

    def halt(self) -> None:
        """Halt every running node."""
        ...

    def merge(
        self,
        subtree: Tree | Node | str | bytes,
        slot: str = "new",
        when: Iterable[Condition | str] | None = None,
    ) -> bool:
        """Merge ``Sequence(when, subtree)`` into placeholder ``slot`` at the next tick
        boundary; True if the tree changed, False if it already held exactly this item. An
        item that does not fit ``registry`` raises a ``StringBTError``: an agent leaves that
        check to the merge (``spec/protocol.md`` section 2, rule 5)."""
        ...

    def forget(self, slot: str = "new", when: Iterable[Condition | str] = ()) -> bool:
        """Remove the item answering ``when`` from ``slot`` at the first tick boundary at which
        it is not running; True if the tree held one."""
        ...

    def knows(self, slot: str = "new", when: Iterable[Condition | str] = ()) -> bool:
        """Whether placeholder ``slot`` holds an item answering ``when`` (pending included)."""
        ...

    def last_used(self, slot: str = "new", when: Iterable[Condition | str] = ()) -> int | None:
        """The tick the item answering ``when`` in ``slot`` last did not fail, -1 if never since
        it took effect; None if the placeholder holds no such item in force."""
        ...


ControlFactory = Callable[[Registry, Any, TickClock], ControlTree]
"""How an agent builds a backend around its own registry, blackboard and clock: an agent
given one calls it with those three instead of compiling a :class:`LiveTree`."""
