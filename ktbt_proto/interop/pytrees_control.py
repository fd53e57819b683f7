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

import logging
import re
import threading
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

try:
    from py_trees import behaviour, common, composites, decorators, trees
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError(
        "ktbt_proto.interop.pytrees_control needs py_trees: pip install 'ktbt[py-trees]'"
    ) from exc

from ktbt_proto.blackboard import Blackboard
from ktbt_proto.control import ControlFactory, TickClock
from ktbt_proto.errors import ErrorCode, ValidationError
from ktbt_proto.interop.pytrees import (
    ORIGIN,
    Behaviours,
    Clock,
    build,
    from_py_trees_status,
    origin,
)
from ktbt_proto.items import read_sequence, show_sequence, split_item
from ktbt_proto.limits import DEFAULT_LIMITS, Limits
from ktbt_proto.merge import MergeError, admits, building, check_item, knowledge
from ktbt_proto.registry import Registry
from ktbt_proto.status import Status
from ktbt_proto.syntax import NAME_RE, parse
from ktbt_proto.tree import (
    Action,
    Condition,
    Container,
    Inverter,
    Node,
    Parallel,
    Placeholder,
    Selector,
    SequenceNode,
    Tree,
    as_node,
    walk,
    with_children,
)

__all__ = ["PREFIX", "PyTreesControl", "known_behaviours", "py_trees_control", "tick_tree"]

log = logging.getLogger("ktbt.pytrees")

PREFIX = "k:"
"""A ``Selector(memory=False)`` named ``k:NAME`` is the placeholder ``<k>(NAME)``."""
Key = tuple[Condition, ...]
_RUNNING = common.Status.RUNNING
_FAILURE = common.Status.FAILURE
_NOT_A_NAME = re.compile(r"[^A-Za-z0-9_]")
_NO_SETUP = behaviour.Behaviour.setup


def _placeholder(made: behaviour.Behaviour) -> str | None:
    """The placeholder name of a behaviour, None if it is not one."""
    if type(made) is composites.Selector and not made.memory and made.name.startswith(PREFIX):
        return made.name[len(PREFIX) :]
    return None


def _is_name(name: str) -> bool:
    return NAME_RE.fullmatch(name) is not None and name not in ("true", "false")


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
class _Held:
    """An item a placeholder holds."""

    made: behaviour.Behaviour
    nodes: int
    """Its stringBT nodes, those in the placeholders it holds excluded (they count there)."""
    inner: list[str]
    """The placeholders it holds (not those inside their items: they count there)."""


@dataclass(eq=False)
class _Slot:
    name: str
    selector: composites.Selector
    depth: int
    """Nodes from the root to the placeholder, itself included (as stringBT reads the tree)."""
    items: dict[Key, _Held] = field(default_factory=dict)
    """The items it holds, pending merges included and pending forgets excluded."""
    fixed: int = 0
    """Nodes of its other children (the user's own, never taught nor forgotten)."""
    inner: list[str] = field(default_factory=list)
    """The placeholders those other children hold."""


def _own(node: Node) -> tuple[int, list[str]]:
    """The nodes of ``node`` outside the placeholders it holds (the placeholders themselves
    counted), and those placeholders' names."""
    count, inner, stack = 0, [], [node]
    while stack:
        top = stack.pop()
        count += 1
        if isinstance(top, Placeholder) and top is not node:
            inner.append(top.name)
        elif isinstance(top, Container):
            stack.extend(top.children)
    return count, inner


class PyTreesControl:
    """A py_trees ``BehaviourTree`` an agent learns into and teaches from.

    ``registry`` is what received knowledge is checked against and what its leaves call unless
    ``behaviours`` names the leaf (then the leaf is the user's own behaviour; one the registry does
    not know is an action with its factory's arguments, :func:`known_behaviours`); ``ticks`` is the
    clock ``last_used`` reads (by default this tree's own count of ticks); ``setup_kwargs`` is
    what each behaviour a merge inserts gets as ``setup(**setup_kwargs)`` (a py_trees_ros
    node, a timeout), as ``BehaviourTree.setup`` gives the tree's own. Items the user put in a
    placeholder with :func:`~ktbt_proto.interop.to_py_trees` are known, taught and may be
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
        setup_kwargs: Mapping[str, Any] | None = None,
    ) -> None:
        _is_tree(tree)
        if any(isinstance(getattr(h, "__self__", None), PyTreesControl) for h in
               tree.pre_tick_handlers):  # fmt: skip
            raise ValueError("this BehaviourTree has a PyTreesControl already: wrap a tree once")
        self.bt = tree
        self.behaviours: Behaviours = behaviours or {}
        self.registry = known_behaviours(registry, self.behaviours)
        """What received knowledge is checked against: ``registry`` and the behaviours."""
        self.blackboard = Blackboard() if blackboard is None else blackboard
        self.limits = limits
        self.setup_kwargs: dict[str, Any] = dict(setup_kwargs or {})
        self.clock = clock
        self.ticks = 0
        self._now: TickClock = ticks if ticks is not None else self._own_ticks
        self._lock = threading.Lock()
        self._adds: list[tuple[_Slot, behaviour.Behaviour]] = []
        self._drops: list[tuple[_Slot, behaviour.Behaviour]] = []
        self._slots: dict[str, _Slot] = {}
        view = _view(tree.root, {}, set())
        self._nodes = sum(1 for _ in walk(view))
        self._register(view, _selectors(tree.root), 0)
        tree.add_pre_tick_handler(self._apply)

    def _own_ticks(self) -> int:
        return self.ticks

    def _register(self, node: Node, selectors: dict[str, behaviour.Behaviour], depth: int) -> None:
        """Hold every placeholder in ``node`` (at ``depth`` + its depth there) with its items;
        ``selectors`` are the py_trees placeholders by name."""
        for found, at in walk(node):
            if not isinstance(found, Placeholder):
                continue
            selector = selectors[found.name]
            if not isinstance(selector, composites.Selector):
                raise TypeError(f"placeholder {found.name} is not held by a py_trees Selector")
            slot = _Slot(found.name, selector, depth + at)
            for child, made in zip(found.children, selector.children, strict=True):
                split = split_item(child)
                count, inner = _own(child)
                if split is not None and split[0] not in slot.items:
                    slot.items[split[0]] = _Held(made, count, inner)
                else:
                    slot.fixed += count
                    slot.inner.extend(inner)
            self._slots[found.name] = slot

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
            return Tree(self._read(self.bt.root))

    def _read(self, made: behaviour.Behaviour) -> Node:
        """``made`` as stringBT, pending merges and forgets included (under the lock)."""
        adds: dict[int, list[behaviour.Behaviour]] = {}
        for slot, added in self._adds:
            adds.setdefault(id(slot.selector), []).append(added)
        return _view(made, adds, {id(dropped) for _, dropped in self._drops})

    def tick(self) -> Status:
        tick_tree(self.bt)
        return from_py_trees_status(self.bt.root.status)

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
        key = split[0]
        with self._lock:
            target = self._slot(slot)
            known = target.items.get(key)
            held = [] if known is None else [self._read(known.made)]
            if not admits(slot, held, item):
                return False
            count, nested = check_item(
                item,
                self.registry,
                self.limits,
                depth=target.depth,
                nodes=self._nodes,
                taken=self._slots,
            )
            if not isinstance(item, SequenceNode):  # check_item refuses anything else first
                return False
            with building():
                kids = [
                    build(child, self.registry, self.blackboard, self.clock, self.behaviours)
                    for child in item.children
                ]
            made = _Item(kids, key, self._now)
            setattr(made, ORIGIN, item)
            self._set_up(made)
            if nested:
                self._register(item, _selectors(made), target.depth)
                own, inner = _own(item)
            else:
                own, inner = count, []
            target.items[key] = _Held(made, own, inner)
            self._adds.append((target, made))
            self._nodes += count
        return True

    def _set_up(self, made: behaviour.Behaviour) -> None:
        """``setup(**setup_kwargs)`` on every behaviour of a new item, outside the tick; one
        that fails is a refusal, and those already set up are shut down again."""
        done: list[behaviour.Behaviour] = []
        try:
            with building():
                for node in made.iterate():
                    if type(node).setup is not _NO_SETUP:  # py_trees' own does nothing
                        node.setup(**self.setup_kwargs)
                    done.append(node)
        except MergeError:
            _shut_down(done)
            raise

    def forget(self, slot: str = "new", when: Iterable[Condition | str] = ()) -> bool:
        key = read_sequence(when)
        with self._lock:
            target = self._slot(slot)
            held = target.items.pop(key, None)
            if held is None:
                return False
            made = held.made
            pending = [entry for entry in self._adds if entry[1] is made]
            if pending:  # merged and forgotten before any tick: never inserted
                self._adds.remove(pending[0])
                _shut_down(made.iterate())
            else:
                self._drops.append((target, made))
            self._nodes -= held.nodes
            gone: set[int] = set()
            names = list(held.inner)
            while names:  # placeholders inside the item go with it, and what they hold
                inner = self._slots.pop(names.pop(), None)
                if inner is None:
                    continue
                gone.add(id(inner))
                self._nodes -= inner.fixed + sum(h.nodes for h in inner.items.values())
                names.extend(inner.inner)
                for each in inner.items.values():
                    names.extend(each.inner)
            if gone:  # merges and forgets inside the forgotten item go with it
                for entry in self._adds:
                    if id(entry[0]) in gone:
                        _shut_down(entry[1].iterate())  # set up, never inserted
                self._adds = [entry for entry in self._adds if id(entry[0]) not in gone]
                self._drops = [entry for entry in self._drops if id(entry[0]) not in gone]
        return True

    def knows(self, slot: str = "new", when: Iterable[Condition | str] = ()) -> bool:
        target = self._slots.get(slot)
        return target is not None and read_sequence(when) in target.items

    def last_used(self, slot: str = "new", when: Iterable[Condition | str] = ()) -> int | None:
        target = self._slots.get(slot)
        if target is None:
            return None
        held = target.items.get(read_sequence(when))
        if held is None or held.made.parent is None:  # not in force yet
            return None
        return held.made.used if isinstance(held.made, _Item) else -1

    # -- between two ticks ------------------------------------------------------------------------

    def _apply(self, tree: trees.BehaviourTree) -> None:
        """The pre-tick handler: count the tick, insert what was merged, prune what was
        forgotten and is not running (the rest waits for a later tick) and shut it down."""
        self.ticks += 1
        if not (self._adds or self._drops):
            return
        pruned: list[behaviour.Behaviour] = []
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
                    pruned.append(made)
                    changed = True
            self._drops = later
        for made in pruned:
            _shut_down(made.iterate())
        if changed and tree.tree_update_handler is not None:
            tree.tree_update_handler()


def tick_tree(bt: trees.BehaviourTree) -> None:
    """Tick ``bt`` once as ``BehaviourTree.tick`` does (py_trees 2.6): its pre-tick handlers,
    the root, its post-tick handlers, the count. Without visitors it skips the walk of the
    whole tree that ``BehaviourTree.tick`` makes for them after the tick (nothing else differs,
    ``tests/interop/test_pytrees_control_rules.py`` checks it); a tree with visitors, or of a
    class with its own ``tick``, is ticked by its ``tick``."""
    if bt.visitors or type(bt).tick is not trees.BehaviourTree.tick:
        bt.tick()
        return
    for handler in bt.pre_tick_handlers:
        handler(bt)
    for _ in bt.root.tick():
        pass
    for handler in bt.post_tick_handlers:
        handler(bt)
    bt.count += 1


def _selectors(root: behaviour.Behaviour) -> dict[str, behaviour.Behaviour]:
    """The placeholders under ``root`` by name; a name twice, or one that is not a stringBT
    name, is refused (``SBT304``, ``SBT303``)."""
    found: dict[str, behaviour.Behaviour] = {}
    for made, _ in _iterate(root):
        name = _placeholder(made)
        if name is None:
            continue
        if not _is_name(name):
            raise ValidationError(
                ErrorCode.INVALID_NAME,
                f"placeholder {made.name!r}: after {PREFIX!r} comes a stringBT name "
                "(letters, digits, '_', dotted parts, not starting with a digit)",
            )
        if name in found:
            raise ValidationError(
                ErrorCode.DUPLICATE_PLACEHOLDER, f"placeholder {name!r} appears twice"
            )
        found[name] = made
    return found


def _shut_down(made: Iterable[behaviour.Behaviour]) -> None:
    """``shutdown()`` on behaviours leaving the tree (``BehaviourTree.shutdown`` does it for
    the whole tree); the item is gone either way, so a failure is logged, not raised."""
    for node in made:
        try:
            node.shutdown()
        except Exception as exc:
            log.warning("shutdown of %s failed: %r", node.name, exc)


def py_trees_control(
    tree: trees.BehaviourTree,
    *,
    behaviours: Behaviours | None = None,
    clock: Clock = time.monotonic,
    limits: Limits = DEFAULT_LIMITS,
    setup_kwargs: Mapping[str, Any] | None = None,
) -> ControlFactory:
    """What :class:`~ktbt_proto.exchange.agent.Agent` takes as its control tree to learn into
    ``tree``: the agent builds the backend around its own registry, blackboard and clock.
    ``behaviours`` are the robot's own py_trees behaviours by leaf name, known to the agent as
    actions with their factories' arguments (:func:`known_behaviours`): no registry entry is
    needed for them. Raises at once, in one line, for what an agent could not learn into: not
    a ``BehaviourTree`` (``TypeError``), or a tree without a knowledge placeholder
    (``ValueError``, saying how to add one; spec/protocol.md section 4.4)."""
    _is_tree(tree)
    if not _selectors(tree.root):
        raise ValueError(
            "the py_trees tree has no knowledge placeholder, so an agent could learn nothing "
            f"into it: add py_trees.composites.Selector(name='{PREFIX}new', memory=False, "
            "children=[]) where learned knowledge should run, before the fallback"
        )

    def make(registry: Registry, blackboard: Any, ticks: TickClock) -> PyTreesControl:
        return PyTreesControl(
            tree,
            registry,
            blackboard,
            ticks=ticks,
            clock=clock,
            behaviours=behaviours,
            limits=limits,
            setup_kwargs=setup_kwargs,
        )

    return make


def _is_tree(tree: object) -> None:
    """A one-line ``TypeError`` for anything but a ``BehaviourTree`` (a root behaviour, say)."""
    if isinstance(tree, trees.BehaviourTree):
        return
    what = (
        f"the behaviour {tree.name!r}"
        if isinstance(tree, behaviour.Behaviour)
        else f"a {type(tree).__name__}"
    )
    raise TypeError(
        f"a py_trees control tree is a py_trees.trees.BehaviourTree, not {what}: pass "
        "py_trees.trees.BehaviourTree(root)"
    )


def known_behaviours(registry: Registry, behaviours: Behaviours) -> Registry:
    """``registry`` with the user's own behaviours known (a new registry; ``registry`` itself
    when it knows them all already). A behaviour whose name ``registry`` does not know is an
    action, and the arguments a leaf may pass are its factory's parameters (a class's
    ``__init__``'s) without the plumbing (``name``, ``blackboard``, ``bb``), typed and ranged
    by their annotations; a name ``registry`` knows keeps its entry there. So received
    knowledge naming them is checked as it would be against registered behaviours, and a robot
    needs no stand-in registration for them."""
    new = [
        (name, factory)
        for name, factory in behaviours.items()
        if not (registry.has_action(name) or registry.has_condition(name))
    ]
    if not new:
        return registry
    known = registry.copy()
    for name, factory in new:
        known.declare_from("action", name, factory)
    return known


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
        return SequenceNode(children, memory=made.memory)
    if isinstance(made, composites.Selector):
        return Selector(children, memory=made.memory)
    if isinstance(made, composites.Parallel):
        one = isinstance(made.policy, common.ParallelPolicy.SuccessOnOne)
        return Parallel(children, threshold=1 if one else None)
    if isinstance(made, decorators.Inverter):
        return Inverter(children)
    if isinstance(made, decorators.Decorator):
        return children[0]
    return Action(_leaf_name(made.name))


def _leaf_name(name: str) -> str:
    """A behaviour's name as a stringBT name: itself if it is one, else with every character
    outside ``[A-Za-z0-9_]`` as ``_`` and a ``_`` before a leading digit."""
    if _is_name(name):
        return name
    clean = _NOT_A_NAME.sub("_", name)
    return clean if _is_name(clean) else f"_{clean}"
