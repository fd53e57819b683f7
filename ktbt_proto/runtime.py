"""The live runtime: compile a tree into closures once, tick it fast, merge knowledge while it runs.

Each node compiles to a pair of closures, ``tick() -> Status`` and ``halt()``, whose state
(running child, counters, memory) lives in closure cells: no attribute lookups, no dispatch, no
per-tick allocation (the compile dispatches on the kinds once, through the tree's visitor).
Every ``halt`` is a no-op unless its node is running, so a parent may call it freely.
Knowledge merged into a placeholder is validated and compiled outside the tick, then appended
to that placeholder's child list at the next tick boundary, so a tick never sees a half-merged
tree and every node outside the placeholder keeps its state, running actions included.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

from ktbt_proto.blackboard import Blackboard
from ktbt_proto.errors import ErrorCode, StringBTError
from ktbt_proto.items import read_sequence, split_item
from ktbt_proto.limits import DEFAULT_LIMITS, Limits
from ktbt_proto.merge import (
    MergeError,
    building,
    check_item,
    descend,
    find_placeholder,
    knowledge,
    merge_at,
    remove_at,
)
from ktbt_proto.registry import Registry
from ktbt_proto.status import FAILURE, RUNNING, SUCCESS, Status
from ktbt_proto.syntax import parse
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
    walk,
    with_children,
)
from ktbt_proto.validate import validate

Tick = Callable[[], Status]
Halt = Callable[[], None]
Compiled = tuple[Tick, Halt]
Calls = tuple[tuple[list[Any], bool], ...]
"""The lists a compiled container calls its children through, in child order; True marks a list
of predicates (the conditions leading a sequence, called for their truth, not a status)."""
Clock = Callable[[], float]
TickClock = Callable[[], int]
"""The tick number TT1, TT2 and ``<w>N`` measure against (a tree's own count by default)."""


def _noop() -> None:
    return None


def _coerce(value: object, name: str) -> Status:
    if value is True or value is None:
        return SUCCESS
    if value is False:
        return FAILURE
    raise TypeError(f"action {name!r} returned {value!r}; return a Status (or a bool)")


# -- composites --------------------------------------------------------------------------------


def _split(kids: list[Compiled]) -> tuple[list[Tick], list[Halt]]:
    return [k[0] for k in kids], [k[1] for k in kids]


def _reactive(kids: list[Compiled], go_on: Status) -> tuple[Compiled, Calls, list[Halt]]:
    """Sequence (go on while SUCCESS) or selector (go on while FAILURE), re-evaluated from the
    left every tick; a running child to the right of where this tick stopped is halted.

    The conditions that lead a sequence (the usual shape of knowledge, ``Sequence(s_q, T_ka)``)
    are called as plain predicates: no status to build for them."""
    ticks, halts = _split(kids)
    guards: list[Callable[[], object]] = []
    if go_on is SUCCESS:
        for child in ticks:
            holds = getattr(child, "holds", None)
            if holds is None:
                break
            guards.append(holds)
    rest = ticks[len(guards) :]
    first = len(guards)
    index = rest.index
    running = -1

    def tick() -> Status:
        nonlocal running
        for holds in guards:
            if not holds():
                if running >= 0:
                    i, running = running, -1
                    halts[i]()
                return FAILURE
        for child in rest:
            status = child()
            if status is not go_on:
                i = first + index(child)
                if running > i:
                    halts[running]()
                running = i if status is RUNNING else -1
                return status
        running = -1
        return go_on

    def halt() -> None:
        nonlocal running
        if running >= 0:
            i, running = running, -1
            halts[i]()

    return (tick, halt), ((guards, True), (rest, False)), halts


def _memory(kids: list[Compiled], go_on: Status) -> tuple[Compiled, Calls, list[Halt]]:
    """Sequence or selector with memory: resume at the child that was running."""
    ticks, halts = _split(kids)
    n = len(ticks)
    running = -1

    def tick() -> Status:
        nonlocal running
        for i in range(running if running >= 0 else 0, n):
            status = ticks[i]()
            if status is not go_on:
                running = i if status is RUNNING else -1
                return status
        running = -1
        return go_on

    def halt() -> None:
        nonlocal running
        if running >= 0:
            index, running = running, -1
            halts[index]()

    return (tick, halt), ((ticks, False),), halts


def _parallel(kids: list[Compiled], threshold: int | None) -> tuple[Compiled, Calls, list[Halt]]:
    ticks, halts = _split(kids)
    n = len(ticks)
    need = n if threshold is None else threshold
    running = [False] * n

    def halt() -> None:
        for i in range(n):
            if running[i]:
                running[i] = False
                halts[i]()

    def tick() -> Status:
        succeeded = failed = 0
        for i, child in enumerate(ticks):
            status = child()
            if status is SUCCESS:
                succeeded += 1
                running[i] = False
            elif status is FAILURE:
                failed += 1
                running[i] = False
            else:
                running[i] = True
        if succeeded >= need:
            halt()
            return SUCCESS
        if failed > n - need:
            halt()
            return FAILURE
        return RUNNING

    return (tick, halt), ((ticks, False),), halts


def _inverter(kid: Compiled) -> tuple[Compiled, Calls, list[Halt]]:
    child, halts = [kid[0]], [kid[1]]

    def tick() -> Status:
        status = child[0]()
        if status is SUCCESS:
            return FAILURE
        if status is FAILURE:
            return SUCCESS
        return status

    def halt() -> None:
        halts[0]()

    return (tick, halt), ((child, False),), halts


def _wait_timer(kid: Compiled, ticks: int, now: TickClock) -> tuple[Compiled, Calls, list[Halt]]:
    """TT1: RUNNING on ticks 1..N of an activation, then the child's status.

    Ticks are read off the tick clock, not counted here, so an owner that ticks the tree only
    when something can happen (at the deadline) keeps exact time."""
    calls, halts = [kid[0]], [kid[1]]
    start: int | None = None
    child_running = False

    def tick() -> Status:
        nonlocal start, child_running
        t = now()
        if start is None:
            start = t
        if t - start < ticks:
            return RUNNING
        status = calls[0]()
        if status is RUNNING:
            child_running = True
            return RUNNING
        start = None
        child_running = False
        return status

    def halt() -> None:
        nonlocal start, child_running
        start = None
        if child_running:
            child_running = False
            halts[0]()

    return (tick, halt), ((calls, False),), halts


def _run_timer(kid: Compiled, ticks: int, now: TickClock) -> tuple[Compiled, Calls, list[Halt]]:
    """TT2: the child's status for up to N ticks; still running after its N-th tick: FAILURE.
    (Ticks read off the tick clock, as for TT1.)"""
    calls, halts = [kid[0]], [kid[1]]
    start: int | None = None

    def tick() -> Status:
        nonlocal start
        if ticks == 0:
            return FAILURE
        t = now()
        if start is None:
            start = t
        status = calls[0]()
        if status is not RUNNING:
            start = None
            return status
        if t - start >= ticks - 1:
            start = None
            halts[0]()
            return FAILURE
        return RUNNING

    def halt() -> None:
        nonlocal start
        if start is not None:
            start = None
            halts[0]()

    return (tick, halt), ((calls, False),), halts


def _index_of(items: list[Node], key: tuple[Condition, ...]) -> int | None:
    """Where the knowledge item answering ``key`` sits among a placeholder's items."""
    for index, item in enumerate(items):
        split = split_item(item)
        if split is not None and split[0] == key:
            return index
    return None


@dataclass(eq=False, slots=True)
class Wire:
    """One compiled node and how its parent calls it: what a :class:`Probe` wraps.

    ``tick``, ``holds`` (a condition's predicate) and ``halt`` are the node's own closures;
    ``calls`` and ``halts`` are the lists through which the node, if it is a container, calls its
    children (``kids``, in order). A probe goes in by writing wrappers into those lists at a tick
    boundary and comes out by writing the originals back, so a tree without one runs exactly the
    closures it compiled (spec/groot2.md, section 3)."""

    node: Node
    tick: Tick
    halt: Halt
    holds: Callable[[], object] | None = None
    kids: list[Wire] = field(default_factory=list)
    calls: Calls = ()
    halts: list[Halt] | None = None


class Probe(Protocol):
    """What :meth:`LiveTree.probe` puts around every node of a running tree: a monitor that
    records statuses, or hooks that replace a node's result (spec/groot2.md)."""

    def rewired(self, tree: Tree) -> None:
        """The tree as it runs from now on; index ``i`` below is its ``i``-th node in pre-order
        (``tree.walk()``). Called before the wrappers are asked for: in the ticking thread at a
        tick boundary, or in the thread that calls :meth:`LiveTree.probe`."""

    def tick(self, index: int, tick: Tick) -> Tick:
        """What to call in place of node ``index``'s tick."""

    def holds(self, index: int, holds: Callable[[], object]) -> Callable[[], object]:
        """What to call in place of condition ``index``'s predicate (leading a sequence)."""

    def halt(self, index: int, halt: Halt) -> Halt:
        """What to call in place of node ``index``'s halt."""


def _rebuild(wire: Wire) -> Node:
    """The node as it runs: merges and forgets reach the compiled children before the node."""
    if not isinstance(wire.node, Container):
        return wire.node
    return with_children(wire.node, tuple(_rebuild(kid) for kid in wire.kids))


@dataclass(eq=False)
class _Slot:
    """A compiled placeholder: a reactive selector over a child list that merges extend."""

    name: str
    ticks: list[Tick] = field(default_factory=list)
    halts: list[Halt] = field(default_factory=list)
    running: int = -1
    items: list[Node] = field(default_factory=list)
    """The placeholder's children, in the order of ``ticks`` (what ``forget`` looks up)."""
    used: list[int] = field(default_factory=list)
    """The tick each child last did not fail (its conditions held: it was used), -1 never."""
    now: TickClock = lambda: 0
    wires: list[Wire] = field(default_factory=list)
    """The children's wires, in the order of ``ticks``."""

    def compiled(self) -> Compiled:
        ticks, halts, used, now = self.ticks, self.halts, self.used, self.now
        slot = self

        def tick() -> Status:
            for i, child in enumerate(ticks):
                status = child()
                if status is not FAILURE:
                    used[i] = now()
                    if slot.running > i:
                        halts[slot.running]()
                    slot.running = i if status is RUNNING else -1
                    return status
            slot.running = -1
            return FAILURE

        def halt() -> None:
            if slot.running >= 0:
                index, slot.running = slot.running, -1
                halts[index]()

        return tick, halt


# -- leaves ------------------------------------------------------------------------------------


def _condition(node: Condition, registry: Registry, blackboard: Any) -> Compiled:
    holds = registry.bind_condition(node.name, blackboard, node.args)
    if node.negated:
        positive = holds

        def holds() -> bool:
            return not positive()

    def tick() -> Status:
        return SUCCESS if holds() else FAILURE

    tick.holds = holds  # type: ignore[attr-defined]  # read by _reactive
    return tick, _noop


def _action(node: Action, registry: Registry, blackboard: Any) -> Compiled:
    # Every halt() in a compiled tree is called only on a node that returned RUNNING on its
    # last tick, so an action needs no running flag of its own: the parent keeps it.
    run, stop, trusted = registry.bind_action(node.name, blackboard, node.args)
    if trusted:
        return run, stop or _noop
    name = node.name

    def tick() -> Status:
        status = run()
        return status if status.__class__ is Status else _coerce(status, name)

    return tick, stop or _noop


def _wait(node: Wait, clock: Clock, now: TickClock) -> Compiled:
    if node.unit == "ticks":
        limit = int(node.duration)
        start: int | None = None

        def tick() -> Status:
            nonlocal start
            t = now()
            if start is None:
                start = t
            if t - start < limit:
                return RUNNING
            start = None
            return SUCCESS

        def halt() -> None:
            nonlocal start
            start = None

        return tick, halt
    seconds = float(node.duration)
    deadline: float | None = None

    def tick_seconds() -> Status:
        nonlocal deadline
        now = clock()
        if deadline is None:
            deadline = now + seconds
        if now >= deadline:
            deadline = None
            return SUCCESS
        return RUNNING

    def halt_seconds() -> None:
        nonlocal deadline
        deadline = None

    return tick_seconds, halt_seconds


# -- compiling a tree ---------------------------------------------------------------------------


class _Leaves(Visitor[Compiled | None]):
    """The first pass of :func:`compile_node`, in pre-order: a leaf is bound to its behaviour
    as it is listed (so constructors run in document order); a container waits for its
    children (``None``)."""

    def __init__(self, registry: Registry, blackboard: Any, clock: Clock, ticks: TickClock):
        self.registry, self.blackboard, self.clock, self.ticks = registry, blackboard, clock, ticks

    def condition(self, node: Condition) -> Compiled:
        return _condition(node, self.registry, self.blackboard)

    def action(self, node: Action) -> Compiled:
        return _action(node, self.registry, self.blackboard)

    def wait(self, node: Wait) -> Compiled:
        return _wait(node, self.clock, self.ticks)

    def _container(self, node: Container) -> None:
        return None

    sequence = selector = parallel = inverter = wait_timer = run_timer = placeholder = _container


class _Containers(Visitor[tuple[Compiled, Calls, list[Halt]]]):
    """The second pass of :func:`compile_node`, in reverse pre-order: a container is compiled
    over its children's closures (``kids``) and wires, which the pass sets before each visit."""

    def __init__(self, ticks: TickClock) -> None:
        self.ticks = ticks
        self.slots: dict[str, _Slot] = {}
        self.kids: list[Compiled] = []
        self.wires: list[Wire] = []

    def sequence(self, node: SequenceNode) -> tuple[Compiled, Calls, list[Halt]]:
        return (_memory if node.memory else _reactive)(self.kids, SUCCESS)

    def selector(self, node: Selector) -> tuple[Compiled, Calls, list[Halt]]:
        return (_memory if node.memory else _reactive)(self.kids, FAILURE)

    def parallel(self, node: Parallel) -> tuple[Compiled, Calls, list[Halt]]:
        return _parallel(self.kids, node.threshold)

    def inverter(self, node: Inverter) -> tuple[Compiled, Calls, list[Halt]]:
        return _inverter(self.kids[0])

    def wait_timer(self, node: WaitTimer) -> tuple[Compiled, Calls, list[Halt]]:
        return _wait_timer(self.kids[0], node.ticks, self.ticks)

    def run_timer(self, node: RunTimer) -> tuple[Compiled, Calls, list[Halt]]:
        return _run_timer(self.kids[0], node.ticks, self.ticks)

    def placeholder(self, node: Placeholder) -> tuple[Compiled, Calls, list[Halt]]:
        kids = self.kids
        slot = _Slot(
            node.name,
            [k[0] for k in kids],
            [k[1] for k in kids],
            items=[*node.children],
            used=[-1] * len(kids),
            now=self.ticks,
            wires=self.wires,
        )
        self.slots[node.name] = slot
        return slot.compiled(), ((slot.ticks, False),), slot.halts


def compile_node(
    root: Node,
    registry: Registry,
    blackboard: Any,
    clock: Clock,
    ticks: TickClock,
) -> tuple[Compiled, dict[str, _Slot], int, Wire]:
    """Compile a (validated) tree without recursion; returns the root's closures, the
    placeholders by name, the number of nodes and the root's wire.

    Nodes are listed in pre-order and compiled in reverse, so every child is compiled before
    its parent and a parent finds its children, first child on top, on the result stack. What
    each kind of node compiles to is said once a kind, by the two passes' visitors
    (:class:`~ktbt_proto.tree.Visitor`, looked up by the node's class)."""
    leaf_of = _Leaves(registry, blackboard, clock, ticks).methods()
    containers = _Containers(ticks)
    container_of = containers.methods()
    order: list[Node] = []
    leaves: list[Compiled | None] = []  # bound in document order: constructors run in order
    pending: list[Node] = [root]
    while pending:
        node = pending.pop()
        visit = leaf_of.get(type(node))
        if visit is None:
            raise TypeError(f"not a stringBT node: {node!r}")
        order.append(node)
        leaf = visit(node)
        leaves.append(leaf)
        if leaf is None:
            pending.extend(reversed(node.children))  # type: ignore[attr-defined]
    done: list[Compiled] = []
    wires: list[Wire] = []
    for i in range(len(order) - 1, -1, -1):
        leaf = leaves[i]
        node = order[i]
        if leaf is not None:
            done.append(leaf)
            wires.append(Wire(node, *leaf, getattr(leaf[0], "holds", None)))
            continue
        n = len(node.children)  # type: ignore[attr-defined]
        containers.kids = done[: -n - 1 : -1] if n else []
        containers.wires = kid_wires = wires[: -n - 1 : -1] if n else []
        del done[len(done) - n :], wires[len(wires) - n :]
        compiled, calls, halts = container_of[type(node)](node)
        done.append(compiled)
        wires.append(Wire(node, *compiled, None, kid_wires, calls, halts))
    return done[0], containers.slots, len(order), wires[0]


# -- the live tree ------------------------------------------------------------------------------


class LiveTree:
    """A compiled tree bound to a registry and a blackboard, ticked by its owner.

    ``merge`` may be called from any thread: the knowledge is checked and compiled in the
    caller's thread and takes effect at the next tick boundary. Knowledge that does not fit
    (no such placeholder, a conflicting answer, a behaviour the registry lacks, a limit) raises a
    :class:`StringBTError` and changes nothing.
    """

    def __init__(
        self,
        tree: Tree | Node | str | bytes,
        registry: Registry,
        blackboard: Any = None,
        *,
        clock: Clock = time.monotonic,
        limits: Limits = DEFAULT_LIMITS,
        ticks: TickClock | None = None,
    ) -> None:
        """``clock`` (seconds) times ``<wt>``; ``ticks`` is the tick number TT1, TT2 and
        ``<w>N`` measure against: by default this tree's own count of ticks. An owner whose
        clock runs on while it skips ticks that could change nothing (a simulator) passes its
        own, and ticks the tree again by the deadline."""
        source = tree.decode("utf-8", "replace") if isinstance(tree, bytes) else tree
        parsed = parse(tree, limits=limits) if isinstance(tree, str | bytes) else tree
        try:
            validate(parsed, registry, limits=limits)
        except StringBTError as err:
            if isinstance(source, str) and not err.excerpt and err.line:
                err.excerpt = StringBTError(
                    err.code, "", err.line, err.column, source=source
                ).excerpt
            raise
        self.registry = registry
        self.blackboard = Blackboard() if blackboard is None else blackboard
        self.clock = clock
        self.limits = limits
        self.ticks = 0
        self._tick_clock: TickClock = ticks if ticks is not None else self._own_ticks
        self._tree = parsed if isinstance(parsed, Tree) else Tree(parsed)
        (self._tick, self._halt), self._slots, self._nodes, self._wire = compile_node(
            self._tree.root, registry, self.blackboard, clock, self._tick_clock
        )
        self._lock = threading.Lock()
        self._pending: list[tuple[_Slot, Compiled, Node, Wire]] = []
        # Forgotten items are named by their condition sequence, not by node identity: a merge
        # into a placeholder nested in an item rebuilds that item's node in the tree.
        self._forgotten: list[tuple[_Slot, tuple[Condition, ...]]] = []
        self._paths: dict[str, tuple[int, ...]] = {}
        self._running = False
        self._dirty = False
        """Something waits for the next tick boundary: a merge, a forget or a probe."""
        self._probe: Probe | None = None
        self._rewire = False

    def _own_ticks(self) -> int:
        return self.ticks

    @property
    def tree(self) -> Tree:
        """The tree as of the last merge (merges still pending included)."""
        return self._tree

    def tick(self) -> Status:
        """Tick the root once; merges and forgetting since the last tick take effect first."""
        if self._dirty:
            self._apply()
        self.ticks += 1
        status = self._tick()
        if status.__class__ is not Status:  # one check a tick, for the whole tree
            raise TypeError(
                f"the tree's tick returned {status!r}, not a Status: a behaviour annotated "
                "'-> Status' is trusted and must return SUCCESS, FAILURE or RUNNING"
            )
        self._running = status is RUNNING
        return status

    def halt(self) -> None:
        """Halt every running node (the robot stops, or the tree is being replaced)."""
        # Halts are only ever sent to running nodes: the compiled nodes rely on it.
        if self._running:
            self._running = False
            self._halt()

    def probe(self, probe: Probe) -> None:
        """Put ``probe``'s wrappers around every node from the next tick boundary on, and again
        after every merge or forget that takes effect, until :meth:`unprobe` takes them out (at
        the next boundary too). Calling it again with the same probe asks for new wrappers; a
        tree has one probe at a time, so another is refused with ``RuntimeError``.
        ``probe.rewired`` is told the running tree at once, in the caller's thread, if no merge
        or forget is pending (spec/groot2.md, section 3)."""
        with self._lock:
            if self._probe is not None and self._probe is not probe:
                raise RuntimeError(
                    f"the tree is probed already (by {self._probe!r}): one probe at a time"
                )
            self._probe, self._rewire, self._dirty = probe, True, True
            if probe is not None and not self._pending and not self._forgotten:
                probe.rewired(Tree(_rebuild(self._wire)))

    def unprobe(self, probe: Probe) -> None:
        """Take ``probe``'s wrappers out at the next tick boundary; another probe is left alone."""
        with self._lock:
            if self._probe is probe:
                self._probe, self._rewire, self._dirty = None, True, True

    def _wires(self, probe: Probe | None) -> None:
        """Write the probe's wrappers (or, without one, the compiled closures) into every list
        the tree calls its nodes through. Only between ticks, in the ticking thread."""
        order: list[Wire] = []
        todo = [self._wire]
        while todo:
            wire = todo.pop()
            order.append(wire)
            todo.extend(reversed(wire.kids))
        at = {id(wire): i for i, wire in enumerate(order)}
        if probe is not None:
            probe.rewired(Tree(_rebuild(self._wire)))
        for wire in order:
            kids = iter(wire.kids)
            for calls, predicate in wire.calls:
                for pos in range(len(calls)):
                    kid = next(kids)
                    holds = kid.holds
                    if predicate and holds is not None:  # a predicate call is a condition's
                        calls[pos] = holds if probe is None else probe.holds(at[id(kid)], holds)
                    else:
                        calls[pos] = (
                            kid.tick if probe is None else probe.tick(at[id(kid)], kid.tick)
                        )
            if wire.halts is not None:
                for pos, kid in enumerate(wire.kids):
                    halt = kid.halt
                    wire.halts[pos] = halt if probe is None else probe.halt(at[id(kid)], halt)
        root = self._wire
        self._tick = root.tick if probe is None else probe.tick(0, root.tick)
        self._halt = root.halt if probe is None else probe.halt(0, root.halt)

    def _apply(self) -> None:
        with self._lock:
            self._dirty = False
            pending, self._pending = self._pending, []
            forgotten, self._forgotten = self._forgotten, []
            changed, self._rewire = self._rewire, False
            for slot, (tick, halt), item, wire in pending:
                slot.ticks.append(tick)
                slot.halts.append(halt)
                slot.items.append(item)
                slot.used.append(-1)
                slot.wires.append(wire)
                changed = True
            later = self._forget_now(forgotten)
            changed = changed or len(later) < len(forgotten)
            if later:
                self._forgotten[:0] = later
                self._dirty = True
            if changed and (self._probe is not None or self._tick is not self._wire.tick):
                self._wires(self._probe)

    def _forget_now(
        self, forgotten: list[tuple[_Slot, tuple[Condition, ...]]]
    ) -> list[tuple[_Slot, tuple[Condition, ...]]]:
        """Remove the forgotten items that are not running; returns those left for later."""
        later = []
        for slot, key in forgotten:
            index = _index_of(slot.items, key)
            if index is None:  # its parent item was forgotten too, and went first
                continue
            if slot.running == index:  # it is running: leave it alone until it stops
                later.append((slot, key))
                continue
            del slot.ticks[index], slot.halts[index], slot.items[index], slot.used[index]
            del slot.wires[index]
            if slot.running > index:
                slot.running -= 1
        return later

    def last_used(self, slot: str = "new", when: Iterable[Condition | str] = ()) -> int | None:
        """The tick at which the item answering ``when`` in placeholder ``slot`` last did not
        fail (its conditions held and its subtree ran), -1 if never since it took effect;
        None if the placeholder holds no such item in force."""
        compiled = self._slots.get(slot)
        if compiled is None:
            return None
        index = _index_of(compiled.items, read_sequence(when))
        return None if index is None else compiled.used[index]

    def knows(self, slot: str = "new", when: Iterable[Condition | str] = ()) -> bool:
        """Whether placeholder ``slot`` holds an item answering ``when`` (pending included)."""
        with self._lock:
            tree = self._tree
            path = self._paths.get(slot)
            if path is None:
                path = find_placeholder(tree, slot)
                if path is None:
                    return False
                self._paths[slot] = path
        return _index_of(list(descend(tree, path)[1].children), read_sequence(when)) is not None

    def forget(self, slot: str = "new", when: Iterable[Condition | str] = ()) -> bool:
        """Remove the knowledge item answering the condition sequence ``when`` from placeholder
        ``slot``; True if the tree held one. It leaves the running tree at the first tick
        boundary at which it is not running: a running action is never cut short by forgetting
        (spec/stringbt.md section 4)."""
        key = read_sequence(when)
        with self._lock:
            path = self._paths.get(slot) or find_placeholder(self._tree, slot)
            if path is None:
                raise MergeError(ErrorCode.UNKNOWN_SLOT, f"the tree has no placeholder <k>({slot})")
            self._paths[slot] = path
            found = remove_at(self._tree, key, path)
            if found is None:
                return False
            self._tree, item = found
            # Removing a child shifts its later siblings: every cached path that runs through
            # this placeholder's children is stale now (only the placeholder's own stays).
            depth = len(path)
            self._paths = {
                name: known
                for name, known in self._paths.items()
                if len(known) <= depth or known[:depth] != path
            }
            compiled = self._slots[slot]
            pending = [
                entry
                for entry in self._pending
                if entry[0] is compiled and _index_of([entry[2]], key) is not None
            ]
            if pending:  # merged and forgotten before any tick: never compiled in
                self._pending.remove(pending[0])
            else:
                self._forgotten.append((compiled, key))
                self._dirty = True
            inner = [n for n, _ in walk(item) if isinstance(n, Placeholder)]
            for placeholder in inner:
                self._slots.pop(placeholder.name, None)
            self._nodes -= sum(1 for _ in walk(item))
        return True

    def merge(
        self,
        subtree: Tree | Node | str | bytes,
        slot: str = "new",
        when: Iterable[Condition | str] | None = None,
    ) -> bool:
        """Merge knowledge into placeholder ``slot``; True if the tree changed, False if it
        already held exactly this knowledge."""
        item_tree = (
            parse(subtree, limits=self.limits) if isinstance(subtree, str | bytes) else subtree
        )
        item = knowledge(when, item_tree) if when is not None else as_node(item_tree)
        with self._lock:
            path = self._paths.get(slot)
            if path is None:
                path = find_placeholder(self._tree, slot)
                if path is None:
                    message = f"the tree has no placeholder <k>({slot})"
                    raise MergeError(ErrorCode.UNKNOWN_SLOT, message)
                self._paths[slot] = path
            merged = merge_at(self._tree, item, path)
            if merged is None:
                return False
            # The item must fit the registry and, where it lands, the limits of the whole tree.
            item_nodes, _ = check_item(
                item,
                self.registry,
                self.limits,
                depth=len(path) + 1,
                nodes=self._nodes,
                taken=self._slots,
            )
            with building():
                compiled, slots, _, wire = compile_node(
                    item, self.registry, self.blackboard, self.clock, self._tick_clock
                )
            self._slots.update(slots)
            self._dirty = True
            self._pending.append((self._slots[slot], compiled, item, wire))
            self._tree = merged
            self._nodes += item_nodes
        return True
