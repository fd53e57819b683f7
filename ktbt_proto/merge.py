"""Merging learned knowledge into a named placeholder: the paper's Merge(T_Control, T_k).

A merge builds a new tree that shares every untouched subtree with the old one, so the old tree
stays valid for whoever still holds it (a running agent swaps trees between ticks), and the cost
is proportional to the depth of the placeholder, not to the size of the tree.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Iterator
from collections.abc import Sequence as Items
from contextlib import contextmanager
from dataclasses import replace

from ktbt_proto.errors import ErrorCode, LimitError, StringBTError, ValidationError
from ktbt_proto.items import read_sequence, split_item
from ktbt_proto.limits import Limits
from ktbt_proto.tree import (
    Condition,
    Container,
    Node,
    Placeholder,
    SequenceNode,
    Tree,
    as_node,
    walk,
    with_children,
)
from ktbt_proto.validate import SupportsNames, validate


class MergeError(StringBTError):
    """The knowledge cannot go where it was asked to go; the tree is unchanged."""


@contextmanager
def building() -> Iterator[None]:
    """Build an item's behaviours: whatever the application's own code raises on the way (a
    registry factory, a py_trees behaviour's constructor or ``setup``) is a refusal like any
    other, a :class:`MergeError` (``SBT403``), and the caller changes nothing."""
    try:
        yield
    except StringBTError:
        raise
    except Exception as exc:
        raise MergeError(
            ErrorCode.BEHAVIOUR_FAILED, f"a behaviour failed to build: {exc!r}"[:300]
        ) from exc


def knowledge(when: Iterable[Condition | str], subtree: Tree | Node) -> Node:
    """The knowledge item ``Sequence(s_q, T_ka)``: the condition sequence, then the subtree."""
    return SequenceNode((*read_sequence(when), as_node(subtree)))


def find_placeholder(tree: Tree | Node, slot: str) -> tuple[int, ...] | None:
    """Child-index path from the root to the placeholder named ``slot`` (iterative search;
    only containers are visited, since only they can be or hold a placeholder)."""
    root = as_node(tree)
    if not isinstance(root, Container):
        return None
    stack: list[tuple[Container, tuple[int, ...]]] = [(root, ())]
    while stack:
        node, path = stack.pop()
        if isinstance(node, Placeholder) and node.name == slot:
            return path
        children = node.children
        for i in range(len(children) - 1, -1, -1):
            child = children[i]
            if isinstance(child, Container):
                stack.append((child, (*path, i)))
    return None


def merge(
    control: Tree | Node,
    subtree: Tree | Node,
    slot: str = "new",
    when: Iterable[Condition | str] | None = None,
) -> Tree:
    """Append knowledge to placeholder ``slot`` and return the new tree.

    This is the structural merge only: validate the result (``kp.validate``) before using it,
    as ``LiveTree.merge`` and ``ktbt merge`` do.

    With ``when``, the knowledge item is ``Sequence(when..., subtree)``; without, ``subtree`` is
    the item itself. Merging an item the placeholder already holds returns the tree unchanged;
    an item answering the same condition sequence differently raises :class:`MergeError`
    (``SBT402``), as does a missing placeholder (``SBT401``).
    """
    item = knowledge(when, subtree) if when is not None else as_node(subtree)
    path = find_placeholder(control, slot)
    if path is None:
        raise MergeError(ErrorCode.UNKNOWN_SLOT, f"the tree has no placeholder <k>({slot})")
    merged = merge_at(control, item, path)
    return (
        merged if merged is not None else (control if isinstance(control, Tree) else Tree(control))
    )


def descend(control: Tree | Node, path: tuple[int, ...]) -> tuple[list[Container], Placeholder]:
    """The containers from the root down to the placeholder at ``path``, and the placeholder."""
    chain: list[Container] = []
    node = as_node(control)
    for index in path:
        if not isinstance(node, Container):
            raise MergeError(ErrorCode.UNKNOWN_SLOT, f"no placeholder at {path}")
        chain.append(node)
        node = node.children[index]
    if not isinstance(node, Placeholder):
        raise MergeError(ErrorCode.UNKNOWN_SLOT, f"no placeholder at {path}")
    return chain, node


def _rebuild(
    control: Tree | Node, chain: list[Container], path: tuple[int, ...], new: Node
) -> Tree:
    """The tree with the placeholder at ``path`` replaced by ``new`` (nodes are values: every
    container on the way is rebuilt, everything else is shared)."""
    for parent, index in zip(reversed(chain), reversed(path), strict=True):
        children = parent.children
        new = with_children(parent, (*children[:index], new, *children[index + 1 :]))
    return Tree(new, footer=control.footer if isinstance(control, Tree) else ())


def admits(slot: str, held: Items[Node], item: Node) -> bool:
    """Whether placeholder ``slot``, holding ``held``, takes ``item`` (spec/stringbt.md section
    4): False if it holds it already (written flat or nested); a knowledge item answering the
    same condition sequence with another subtree raises :class:`MergeError` (``SBT402``)."""
    split = split_item(item)
    for existing in held:
        if existing == item:
            return False
        known = None if split is None else split_item(existing)
        if known is not None and split is not None and known[0] == split[0]:
            if known[1] == split[1]:  # the same item, written flat or nested (spec section 4)
                return False
            line, column = existing.pos if existing.pos else (0, 0)
            raise MergeError(
                ErrorCode.KNOWLEDGE_CONFLICT,
                f"<k>({slot}) already answers this condition sequence with another subtree",
                line,
                column,
            )
    return True


def check_item(
    item: Node,
    registry: SupportsNames,
    limits: Limits,
    *,
    depth: int,
    nodes: int,
    taken: Collection[str],
) -> tuple[int, list[str]]:
    """Check ``item`` for a placeholder at ``depth`` (the root is 1) of a tree of ``nodes``
    nodes whose placeholders are named ``taken``: room left there, then the item against the
    registry and the limits of what is left, then no placeholder it holds named as one the tree
    has (``SBT304``). Raises a :class:`StringBTError`; returns the item's number of nodes and
    the names of the placeholders it holds. Every backend of a live tree checks a merge here."""
    depth_left = limits.max_depth - depth
    nodes_left = limits.max_nodes - nodes
    if depth_left < 1 or nodes_left < 1:
        code = ErrorCode.TOO_DEEP if depth_left < 1 else ErrorCode.TOO_MANY_NODES
        raise LimitError(code, "the tree has no room for more knowledge there")
    validate(item, registry, limits=replace(limits, max_depth=depth_left, max_nodes=nodes_left))
    count, inner = 0, []
    for node, _ in walk(item):
        count += 1
        if isinstance(node, Placeholder):
            if node.name in taken:
                raise ValidationError(
                    ErrorCode.DUPLICATE_PLACEHOLDER, f"placeholder {node.name!r} appears twice"
                )
            inner.append(node.name)
    return count, inner


def merge_at(control: Tree | Node, item: Node, path: tuple[int, ...]) -> Tree | None:
    """Append ``item`` to the placeholder at ``path`` (from :func:`find_placeholder`); None if
    the placeholder already holds it. A merge never moves a placeholder, since it only appends
    inside one; :func:`remove_at` does move those nested in later siblings of the removed item,
    so a caller that keeps paths must drop those below the placeholder after a removal."""
    chain, node = descend(control, path)
    if not admits(node.name, node.children, item):
        return None
    return _rebuild(control, chain, path, with_children(node, (*node.children, item)))


def remove(control: Tree | Node, slot: str = "new", when: Iterable[Condition | str] = ()) -> Tree:
    """Remove the knowledge item answering the condition sequence ``when`` from placeholder
    ``slot`` and return the new tree (the same tree if the placeholder holds no such item);
    a missing placeholder raises :class:`MergeError` (``SBT401``). Forgetting, the inverse of
    :func:`merge`."""
    path = find_placeholder(control, slot)
    if path is None:
        raise MergeError(ErrorCode.UNKNOWN_SLOT, f"the tree has no placeholder <k>({slot})")
    found = remove_at(control, read_sequence(when), path)
    if found is None:
        return control if isinstance(control, Tree) else Tree(control)
    return found[0]


def remove_at(
    control: Tree | Node, key: tuple[Condition, ...], path: tuple[int, ...]
) -> tuple[Tree, Node] | None:
    """Remove the item keyed ``key`` from the placeholder at ``path``: the new tree and the
    removed item, or None if the placeholder holds no item with that condition sequence."""
    chain, node = descend(control, path)
    for k, existing in enumerate(node.children):
        split = split_item(existing)
        if split is not None and split[0] == key:
            kept = with_children(node, (*node.children[:k], *node.children[k + 1 :]))
            return _rebuild(control, chain, path, kept), existing
    return None
