"""A py_trees ``BehaviourTree`` its user built in py_trees, as an agent's control tree.

The :class:`~ktbt_proto.control.ControlTree` backend for robots whose tree is py_trees
(``spec/protocol.md`` section 4.4). A knowledge placeholder is a ``Selector`` with
``memory=False`` named ``k:NAME`` (what :func:`~ktbt_proto.interop.to_py_trees` makes of
``<k>(NAME)``). A merge checks the item as :class:`~ktbt_proto.LiveTree` does (the registry,
the limits, a conflicting answer, a placeholder named twice), builds ``Sequence(conditions,
subtree)`` as py_trees behaviours (the user's own per leaf name, or the registry's bound
callables) and inserts it at the end of the placeholder from a pre-tick handler, so it takes
effect between two ticks whoever ticks the tree. A forget prunes the item from a pre-tick handler
too, and not while it runs (``spec/stringbt.md`` section 4). Nothing outside the placeholder is
touched: a behaviour running elsewhere keeps running. Whatever does not fit raises a
``StringBTError`` before anything changes.
"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from typing import Any

try:
    from py_trees import behaviour, common, composites, decorators, trees
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError(
        "ktbt_proto.interop.pytrees_control needs py_trees: pip install 'ktbt[py-trees]'"
    ) from exc

from ..blackboard import Blackboard
from ..control import ControlFactory, TickClock
from ..errors import ErrorCode, LimitError, ValidationError
from ..items import show_sequence, split_item
from ..limits import DEFAULT_LIMITS, Limits
from ..merge import MergeError, conditions, knowledge
from ..registry import Registry
from ..status import Status
from ..syntax import parse
from ..tree import (
    Action,
    Condition,
    Container,
    Inverter,
    Node,
    Parallel,
    Placeholder,
    Selector,
    Sequence,
    Tree,
    as_node,
    walk,
    with_children,
)
from ..validate import validate
from .pytrees import Behaviours, Clock, build, from_py_trees_status, origin

__all__ = ["PREFIX", "PyTreesControl", "py_trees_control"]

PREFIX = "k:"
"""A ``Selector(memory=False)`` named ``k:NAME`` is the placeholder ``<k>(NAME)``."""
Key = tuple[Condition, ...]
_RUNNING = common.Status.RUNNING
_FAILURE = common.Status.FAILURE
_NOT_A_NAME = re.compile(r"[^A-Za-z0-9_.]")


def _placeholder(made: behaviour.Behaviour) -> str | None:
    """The placeholder name of a behaviour, None if it is not one."""
    if type(made) is composites.Selector and not made.memory and made.name.startswith(PREFIX):
        return made.name[len(PREFIX) :]
    return None


class _Item(composites.Sequence):
    """A merged knowledge item, ``Sequence(conditions, subtree)``: stamps the tick at which it
    last did not fail (its conditions held and its subtree ran), as LiveTree does."""

    def __init__(self, children: list[behaviour.Behaviour], key: Key, now: TickClock) -> None:
        super().__init__(show_sequence(key), False, children)
        self.key = key
        self.used = -1
        self._now = now

    def tick(self) -> Iterator[behaviour.Behaviour]:
        # The parent stops reading once it sees this node with its final status: stamp then.
        for made in super().tick():
            if made is self and self.status is not _FAILURE:
                self.used = self._now()
            yield made


@dataclass(eq=False)
class _Slot:
    name: str
    selector: composites.Selector
    depth: int
    """Nodes from the root to the placeholder, itself included."""
    items: dict[Key, behaviour.Behaviour] = field(default_factory=dict)
    """The items it holds, pending merges included and pending forgets excluded."""


class PyTreesControl:
    """A py_trees ``BehaviourTree`` an agent learns into and teaches from.

    ``registry`` is what received knowledge is checked against and what its leaves call unless
    ``behaviours`` names the leaf (then the leaf is the user's own behaviour); ``ticks`` is the
    clock ``last_used`` reads (by default this tree's own count of ticks). Items the user put in
    a placeholder with :func:`~ktbt_proto.interop.to_py_trees` are known, taught and may be
    forgotten; only merged items are stamped when used (the others report -1).
    """

    def __init__(
        self,
        tree: trees.BehaviourTree,
        registry: Registry,
        blackboard: Any = None,
        *,
        ticks: TickClock | None = None,
        clock: Clock = time.monotonic,
        behaviours: Behaviours | None = None,
        limits: Limits = DEFAULT_LIMITS,
    ) -> None:
        self.bt = tree
        self.registry = registry
        self.blackboard = Blackboard() if blackboard is None else blackboard
        self.limits = limits
        self.behaviours: Behaviours = behaviours or {}
        self.clock = clock
        self.ticks = 0
        self._now: TickClock = ticks if ticks is not None else self._own_ticks
        self._lock = threading.Lock()
        self._adds: list[tuple[_Slot, behaviour.Behaviour]] = []
        self._drops: list[tuple[_Slot, behaviour.Behaviour]] = []
        self._slots: dict[str, _Slot] = {}
        self._nodes = 0
        for made, depth in _iterate(tree.root):
            self._nodes += 1
            name = _placeholder(made)
            if name is None:
                continue
            slot = self._add_slot(name, made, depth)
            for child in made.children:
                split = split_item(_view(child, {}, set()))
                if split is not None and split[0] not in slot.items:
                    slot.items[split[0]] = child
        tree.add_pre_tick_handler(self._apply)

    def _own_ticks(self) -> int:
        return self.ticks

    def _add_slot(self, name: str, selector: behaviour.Behaviour, depth: int) -> _Slot:
        if name in self._slots:
            raise ValidationError(
                ErrorCode.DUPLICATE_PLACEHOLDER, f"placeholder {name!r} appears twice"
            )
        assert isinstance(selector, composites.Selector)
        slot = _Slot(name, selector, depth)
        self._slots[name] = slot
        return slot

    def _slot(self, name: str) -> _Slot:
        slot = self._slots.get(name)
        if slot is None:
            raise MergeError(
                ErrorCode.UNKNOWN_SLOT,
                f"the tree has no placeholder {PREFIX}{name} (a py_trees Selector, memory=False)",
            )
        return slot

    # -- the ControlTree contract ---------------------------------------------------------------

    @property
    def tree(self) -> Tree:
        """The py_trees tree read as stringBT, pending merges and forgets included: what was
        built from stringBT reads back as it was; a placeholder as ``<k>``; the user's other
        composites as their stringBT kind; any other behaviour as an action named after it
        (a decorator other than ``Inverter`` as its child)."""
        with self._lock:
            adds: dict[int, list[behaviour.Behaviour]] = {}
            for slot, made in self._adds:
                adds.setdefault(id(slot.selector), []).append(made)
            drops = {id(made) for _, made in self._drops}
            return Tree(_view(self.bt.root, adds, drops))

    def tick(self) -> Status:
        bt = self.bt
        if bt.visitors or type(bt).tick is not trees.BehaviourTree.tick:
            bt.tick()
        else:  # ``BehaviourTree.tick`` without visitors: the same calls, minus a walk of the tree
            for handler in bt.pre_tick_handlers:
                handler(bt)
            for _ in bt.root.tick():
                pass
            for handler in bt.post_tick_handlers:
                handler(bt)
            bt.count += 1
        return from_py_trees_status(bt.root.status)

    def halt(self) -> None:
        root = self.bt.root
        if root.status == _RUNNING:
            root.stop(common.Status.INVALID)

    def merge(
        self,
        subtree: Tree | Node | str | bytes,
        slot: str = "new",
        when: Iterable[Condition | str] | None = None,
    ) -> bool:
        item_tree = (
            parse(subtree, limits=self.limits) if isinstance(subtree, str | bytes) else subtree
        )
        item = knowledge(when, item_tree) if when is not None else as_node(item_tree)
        split = split_item(item)
        if split is None:
            raise MergeError(
                ErrorCode.NOT_KNOWLEDGE,
                "a py_trees placeholder takes knowledge items: Sequence(conditions, subtree)",
            )
        key, _ = split
        with self._lock:
            target = self._slot(slot)
            known = target.items.get(key)
            if known is not None:
                held = split_item(_view(known, {}, set()))
                if held is not None and held[1] == split[1]:
                    return False
                raise MergeError(
                    ErrorCode.KNOWLEDGE_CONFLICT,
                    f"<k>({slot}) already answers this condition sequence with another subtree",
                )
            depth_left = self.limits.max_depth - target.depth
            nodes_left = self.limits.max_nodes - self._nodes
            if depth_left < 1 or nodes_left < 1:
                code = ErrorCode.TOO_DEEP if depth_left < 1 else ErrorCode.TOO_MANY_NODES
                raise LimitError(code, "the tree has no room for more knowledge there")
            room = replace(self.limits, max_depth=depth_left, max_nodes=nodes_left)
            validate(item, self.registry, limits=room)
            inner = [n.name for n, _ in walk(item) if isinstance(n, Placeholder)]
            for name in inner:
                if name in self._slots:
                    raise ValidationError(
                        ErrorCode.DUPLICATE_PLACEHOLDER, f"placeholder {name!r} appears twice"
                    )
            assert isinstance(item, Sequence)
            kids = [
                build(child, self.registry, self.blackboard, self.clock, self.behaviours)
                for child in item.children
            ]
            made = _Item(kids, key, self._now)
            setattr(made, "ktbt_node", item)  # noqa: B010 - read back by ``origin``
            count = 0
            for node, depth in _iterate(made):
                count += 1
                nested = _placeholder(node) if inner else None
                if nested is not None:
                    self._add_slot(nested, node, target.depth + depth)
            target.items[key] = made
            self._adds.append((target, made))
            self._nodes += count
        return True

    def forget(self, slot: str = "new", when: Iterable[Condition | str] = ()) -> bool:
        key = conditions(when)
        with self._lock:
            target = self._slot(slot)
            made = target.items.pop(key, None)
            if made is None:
                return False
            pending = [entry for entry in self._adds if entry[1] is made]
            if pending:  # merged and forgotten before any tick: never inserted
                self._adds.remove(pending[0])
            else:
                self._drops.append((target, made))
            gone = set()
            for node, _ in _iterate(made):
                self._nodes -= 1
                inner = _placeholder(node)
                if inner is not None and inner in self._slots:
                    gone.add(id(self._slots.pop(inner)))
            if gone:  # merges into a placeholder inside the forgotten item go with it
                self._adds = [entry for entry in self._adds if id(entry[0]) not in gone]
        return True

    def knows(self, slot: str = "new", when: Iterable[Condition | str] = ()) -> bool:
        target = self._slots.get(slot)
        return target is not None and conditions(when) in target.items

    def last_used(self, slot: str = "new", when: Iterable[Condition | str] = ()) -> int | None:
        target = self._slots.get(slot)
        if target is None:
            return None
        made = target.items.get(conditions(when))
        if made is None or made.parent is None:  # not in force yet
            return None
        return made.used if isinstance(made, _Item) else -1

    # -- between two ticks ------------------------------------------------------------------------

    def _apply(self, tree: trees.BehaviourTree) -> None:
        """The pre-tick handler: count the tick, insert what was merged, prune what was
        forgotten and is not running (the rest waits for a later tick)."""
        self.ticks += 1
        if not (self._adds or self._drops):
            return
        with self._lock:
            adds, self._adds = self._adds, []
            drops, self._drops = self._drops, []
            later, changed = [], bool(adds)
            # What ``insert_subtree`` and ``prune_subtree`` do, without their search of the
            # whole tree for a parent this backend already holds.
            for slot, made in adds:
                slot.selector.add_child(made)
            for slot, made in drops:
                if made.status == _RUNNING:  # never cut short by forgetting
                    later.append((slot, made))
                elif made.parent is slot.selector:
                    slot.selector.remove_child(made)
                    changed = True
            self._drops = later
        if changed and tree.tree_update_handler is not None:
            tree.tree_update_handler()


def py_trees_control(
    tree: trees.BehaviourTree,
    *,
    behaviours: Behaviours | None = None,
    clock: Clock = time.monotonic,
    limits: Limits = DEFAULT_LIMITS,
) -> ControlFactory:
    """What :class:`~ktbt_proto.agent.Agent` takes as its control tree to learn into ``tree``:
    the agent builds the backend around its own registry, blackboard and clock."""

    def make(registry: Registry, blackboard: Any, ticks: TickClock) -> PyTreesControl:
        return PyTreesControl(
            tree,
            registry,
            blackboard,
            ticks=ticks,
            clock=clock,
            behaviours=behaviours,
            limits=limits,
        )

    return make


# -- reading a py_trees tree as stringBT -------------------------------------------------------


def _iterate(root: behaviour.Behaviour) -> Iterator[tuple[behaviour.Behaviour, int]]:
    """Every behaviour under ``root`` with its depth (root: 1), pre-order, without recursion."""
    stack = [(root, 1)]
    while stack:
        made, depth = stack.pop()
        yield made, depth
        stack.extend((child, depth + 1) for child in reversed(made.children))


def _view(
    made: behaviour.Behaviour, adds: dict[int, list[behaviour.Behaviour]], drops: set[int]
) -> Node:
    name = _placeholder(made)
    if name is not None:
        kids = [c for c in made.children if id(c) not in drops] + adds.get(id(made), [])
        return Placeholder(tuple(_view(c, adds, drops) for c in kids), name=name)
    node = origin(made)
    children = tuple(_view(c, adds, drops) for c in made.children)
    if node is not None:
        return with_children(node, children) if isinstance(node, Container) else node
    if isinstance(made, composites.Sequence):
        return Sequence(children, memory=made.memory)
    if isinstance(made, composites.Selector):
        return Selector(children, memory=made.memory)
    if isinstance(made, composites.Parallel):
        return Parallel(children)
    if isinstance(made, decorators.Inverter):
        return Inverter(children)
    if isinstance(made, decorators.Decorator):
        return children[0]
    return Action(_NOT_A_NAME.sub("_", made.name) or "_")
