"""Immutable, typed behaviour-tree nodes: what the parser returns and every other stage consumes.

Equality is structural: source positions and comments never take part, so a tree equals its own
reformatted, re-parsed self. Argument and duration values compare by type as well as value
(``1``, ``1.0`` and ``true`` are three different literals with three different canonical forms).
Trees are immutable so that a running agent can hand one to another thread, and a merge can
share every untouched subtree with the tree it came from. Node classes keep their defaults on the
class (no ``__slots__``) so the parser can build a node by filling only the fields it read.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, ClassVar, Generic, Literal, TypeAlias, TypeVar

Value: TypeAlias = bool | int | float | str
"""A literal argument value."""
Args: TypeAlias = tuple[tuple[str, Value], ...]
"""Keyword arguments of a condition or action, in source order."""
Pos: TypeAlias = tuple[int, int]
"""(line, column), both 1-based."""


@dataclass(frozen=True, slots=True)
class Comments:
    """Comments attached to a node, so that ``fmt`` keeps them where they were written.

    ``leading``: full-line comments above the node. ``trailing``: a comment at the end of the
    node's first line. For containers, ``end`` holds full-line comments just before the closing
    ``<e>`` and ``end_trailing`` a comment after it. Texts exclude the ``#``.
    """

    leading: tuple[str, ...] = ()
    trailing: str | None = None
    end: tuple[str, ...] = ()
    end_trailing: str | None = None


@dataclass(frozen=True)
class Node:
    """Base of every node: a source position and comments, neither of which affects equality."""

    pos: Pos | None = field(default=None, compare=False, kw_only=True, repr=False)
    comments: Comments | None = field(default=None, compare=False, kw_only=True, repr=False)

    @property
    def line(self) -> int:
        return self.pos[0] if self.pos else 0

    @property
    def column(self) -> int:
        return self.pos[1] if self.pos else 0


@dataclass(frozen=True)
class Container(Node):
    """A node with children, closed by ``<e>`` in stringBT."""

    children: tuple[Node, ...]

    is_decorator: ClassVar[bool] = False

    @property
    def child(self) -> Node:
        """The only child of a decorator (validated trees have exactly one)."""
        return self.children[0]


@dataclass(frozen=True)
class SequenceNode(Container):
    """A Sequence (``<sq>``, ``<msq>``): ticks children left to right while they succeed.
    Reactive unless ``memory``. Named apart from ``collections.abc.Sequence``, which the same
    modules often need."""

    memory: bool = False


@dataclass(frozen=True)
class Selector(Container):
    """Ticks children left to right until one does not fail. Reactive unless ``memory``."""

    memory: bool = False


@dataclass(frozen=True)
class Parallel(Container):
    """Ticks every child each tick; succeeds once ``threshold`` children succeed (all if None)."""

    threshold: int | None = None


@dataclass(frozen=True)
class Inverter(Container):
    """Swaps SUCCESS and FAILURE of its child; RUNNING passes through."""

    is_decorator: ClassVar[bool] = True


@dataclass(frozen=True)
class WaitTimer(Container):
    """TT1, the paper's wait (pulse) timer: RUNNING for ``ticks`` ticks, then the child."""

    ticks: int = 0
    is_decorator: ClassVar[bool] = True


@dataclass(frozen=True)
class RunTimer(Container):
    """TT2, the paper's run timer: the child's status for ``ticks`` ticks, then FAILURE."""

    ticks: int = 0
    is_decorator: ClassVar[bool] = True


@dataclass(frozen=True)
class Placeholder(Container):
    """A named knowledge segment (``common``, ``prior``, ``new``...) where learned subtrees are
    merged. Behaves as a reactive selector over its children; empty, it fails."""

    name: str = ""


def _value_key(value: object) -> tuple[str, str]:
    # repr distinguishes 1 / 1.0 / True and -0.0 / 0.0, which == does not.
    return (type(value).__name__, repr(value))


def _args_key(args: Args) -> tuple[tuple[str, tuple[str, str]], ...]:
    return tuple((k, _value_key(v)) for k, v in args)


@dataclass(frozen=True, eq=False)
class Condition(Node):
    """A named check on the blackboard: SUCCESS when true (false if ``negated``), else FAILURE."""

    name: str
    negated: bool = False
    args: Args = ()

    def __eq__(self, other: object) -> bool:
        if type(other) is not Condition:
            return NotImplemented
        return (
            self.name == other.name
            and self.negated == other.negated
            and (self.args is other.args or _args_key(self.args) == _args_key(other.args))
        )

    def __hash__(self) -> int:
        return hash((Condition, self.name, self.negated, _args_key(self.args)))


@dataclass(frozen=True, eq=False)
class Action(Node):
    """A named behaviour: returns SUCCESS, FAILURE or RUNNING, and is halted when preempted."""

    name: str
    args: Args = ()

    def __eq__(self, other: object) -> bool:
        if type(other) is not Action:
            return NotImplemented
        return self.name == other.name and (
            self.args is other.args or _args_key(self.args) == _args_key(other.args)
        )

    def __hash__(self) -> int:
        return hash((Action, self.name, _args_key(self.args)))


@dataclass(frozen=True, eq=False)
class Wait(Node):
    """RUNNING until ``duration`` has passed, then SUCCESS: ``<w>`` ticks, ``<wt>`` seconds."""

    duration: int | float
    unit: Literal["ticks", "seconds"] = "ticks"

    def __eq__(self, other: object) -> bool:
        if type(other) is not Wait:
            return NotImplemented
        return self.unit == other.unit and _value_key(self.duration) == _value_key(other.duration)

    def __hash__(self) -> int:
        return hash((Wait, self.unit, _value_key(self.duration)))


Leaf: TypeAlias = Condition | Action | Wait


@dataclass(frozen=True, slots=True)
class Tree:
    """A parsed document: the root node and the comments written after it."""

    root: Node
    footer: tuple[str, ...] = field(default=(), compare=False, repr=False)

    def walk(self) -> Iterator[tuple[Node, int]]:
        """Every node with its depth (root = 1), in document order; iterative, so any depth."""
        return walk(self.root)


def walk(root: Node) -> Iterator[tuple[Node, int]]:
    """Pre-order traversal with depths, without recursion."""
    stack: list[tuple[Node, int]] = [(root, 1)]
    pop, push = stack.pop, stack.extend
    while stack:
        node, depth = pop()
        yield node, depth
        if isinstance(node, Container) and node.children:
            push([(c, depth + 1) for c in reversed(node.children)])


def with_children(node: Container, children: tuple[Node, ...]) -> Container:
    """A copy of ``node`` with other children: what a merge does on the path to a placeholder.

    Faster than ``dataclasses.replace`` (no field introspection), which matters on the hot
    path of learning; the copy is as immutable as the original."""
    copy = object.__new__(type(node))
    fields = copy.__dict__
    fields.update(node.__dict__)
    fields["children"] = children
    return copy


def as_node(tree: Tree | Node) -> Node:
    return tree.root if isinstance(tree, Tree) else tree


T = TypeVar("T")


class Visitor(Generic[T]):
    """What to make of each kind of node, one method a kind (``spec/stringbt.md`` section 3),
    as lark's and py_trees' visitors do: :meth:`visit` calls the method of the node's class, so
    a walker (the formatter, the renderer, the BehaviorTree.CPP exporter...) says what it does
    with a sequence, a condition or a wait, never how to tell them apart. A kind a subclass
    does not handle goes to :meth:`other`, which refuses it."""

    _bound: dict[type, Callable[[Any], T]]

    def methods(self) -> dict[type, Callable[[Any], T]]:
        """Each node class's method, bound: what a walker on a hot path looks up itself
        (``methods()[type(node)](node)``) to save a call per node."""
        try:
            return self._bound
        except AttributeError:  # the first time: each kind's method, bound once
            self._bound = {cls: getattr(self, m) for cls, m in _METHOD_OF.items()}
            return self._bound

    def visit(self, node: Node) -> T:
        method = self.methods().get(type(node))
        return self.other(node) if method is None else method(node)

    def sequence(self, node: SequenceNode) -> T:
        return self.other(node)

    def selector(self, node: Selector) -> T:
        return self.other(node)

    def parallel(self, node: Parallel) -> T:
        return self.other(node)

    def inverter(self, node: Inverter) -> T:
        return self.other(node)

    def wait_timer(self, node: WaitTimer) -> T:
        return self.other(node)

    def run_timer(self, node: RunTimer) -> T:
        return self.other(node)

    def placeholder(self, node: Placeholder) -> T:
        return self.other(node)

    def condition(self, node: Condition) -> T:
        return self.other(node)

    def action(self, node: Action) -> T:
        return self.other(node)

    def wait(self, node: Wait) -> T:
        return self.other(node)

    def other(self, node: Node) -> T:
        raise TypeError(f"not a stringBT node: {node!r}")


_METHOD_OF: dict[type, str] = {
    SequenceNode: "sequence",
    Selector: "selector",
    Parallel: "parallel",
    Inverter: "inverter",
    WaitTimer: "wait_timer",
    RunTimer: "run_timer",
    Placeholder: "placeholder",
    Condition: "condition",
    Action: "action",
    Wait: "wait",
}
