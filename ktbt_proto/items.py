"""Knowledge items and condition sequences: the shape the language gives knowledge.

A knowledge item is ``Sequence(s_q, T_ka)``, a reactive sequence whose leading conditions are its
key and whose remaining children are its action subtree (spec/stringbt.md, section 4). Its key is
the canonical compact form of the condition sequence, the string a query carries and a knowledge
base is looked up by (spec/protocol.md, section 1); people type and read the same sequence as
``TargetSeen(colour=2), !_inZoneF``. The merge, the live runtime, the checker and the knowledge
base all read items and sequences here, so that the language never depends on the protocol.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterable
from dataclasses import replace
from functools import lru_cache

from ktbt_proto.errors import ErrorCode, ParseError, StringBTError
from ktbt_proto.formatter import format_tree, format_value
from ktbt_proto.limits import DEFAULT_LIMITS, Limits
from ktbt_proto.syntax import parse
from ktbt_proto.tree import (
    Action,
    Condition,
    Container,
    Node,
    Placeholder,
    SequenceNode,
    Tree,
    Wait,
    WaitTimer,
    as_node,
    walk,
)

__all__ = [
    "actions_rerun",
    "find_warnings",
    "item_digest",
    "parse_sequence",
    "read_sequence",
    "sequence_digest",
    "sequence_key",
    "show_key",
    "show_sequence",
    "split_item",
    "stray_nodes",
]


def sequence_key(sequence: str | Iterable[Condition | str]) -> str:
    """The canonical form of a condition sequence: how knowledge is looked up and asked for
    (``spec/protocol.md`` section 1). The one way to get a key: a ``str`` is a key already
    (``<c>(A)<c>(!B)``) and is returned as it is; otherwise each element is a ``Condition`` or
    the text people type for one or more (``"TargetSeen(colour=2)"``, read by
    :func:`read_sequence`). Raises ``StringBTError`` for text that is not a condition."""
    if isinstance(sequence, str):
        return sequence
    return "".join(format_tree(c, "compact") for c in read_sequence(sequence))


def sequence_digest(key: str) -> str:
    """The digest of a condition sequence: SHA-256 of its key (UTF-8), hexadecimal. A fleet
    event names the item it is about by it (``spec/protocol.md`` section 10)."""
    return hashlib.sha256(key.encode("utf-8")).hexdigest()


def item_digest(key: str, subtree: Tree | Node | str) -> str:
    """The digest of a knowledge item, its sequence and its subtree: the first 16 hexadecimal
    digits of SHA-256 over ``key``, a newline and the compact subtree (UTF-8; a ``str`` is taken
    as the compact form already, as an answer or a save file carries it). Two items with the
    same digest teach the same thing; the fleet checks a saved item against its author's by it,
    and the BehaviorTree.CPP sidecar names its files by it (``spec/stringbt.md`` 12.1)."""
    compact = subtree if isinstance(subtree, str) else format_tree(subtree, "compact")
    text = f"{key}\n{compact}"
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


@lru_cache(maxsize=1024)
def parse_sequence(key: str, limits: Limits = DEFAULT_LIMITS) -> tuple[Condition, ...]:
    """The conditions of a sequence key (``<c>(A)<c>(!B)``); raises StringBTError. Cached:
    a robot asks and is asked about the same few sequences again and again."""
    root = parse(f"<sq>{key}<e>", limits=limits).root
    conds = root.children if isinstance(root, SequenceNode) else ()
    if not conds or not all(isinstance(c, Condition) for c in conds):
        raise ParseError(ErrorCode.UNEXPECTED_TOKEN, "a sequence holds conditions only")
    return tuple(c for c in conds if isinstance(c, Condition))


# -- the sequence as people type and read it (spec/protocol.md, section 1) ----------------------

_NAME = re.compile(r"\s*(!?\s*[A-Za-z0-9_.]+)\s*")


def show_sequence(sequence: str | Iterable[Condition]) -> str:
    """A condition sequence as the command line prints it and reads it back:
    ``TargetSeen(colour=2), !_inZoneF``. Takes conditions or a wire key (``<c>(...)...``)."""
    conds = parse_sequence(sequence) if isinstance(sequence, str) else tuple(sequence)
    parts = []
    for c in conds:
        head = ("!" if c.negated else "") + c.name
        if c.args:
            head += "(" + ", ".join(f"{k}={format_value(v)}" for k, v in c.args) + ")"
        parts.append(head)
    return ", ".join(parts)


def show_key(key: str) -> str:
    """A sequence key as people read and type it (``TargetSeen(colour=2)``); a key that does
    not parse (a hostile peer's catalog) is shown quoted, as it came."""
    try:
        return show_sequence(key)
    except StringBTError:
        return repr(key)


def read_sequence(sequence: str | Iterable[Condition | str]) -> tuple[Condition, ...]:
    """Conditions from what a user types: ``TargetSeen(colour=2), !_inZoneF`` (what
    :func:`show_sequence` prints), the wire form ``<c>(TargetSeen,colour=2)<c>(!_inZoneF)``,
    or an iterable of ``Condition`` nodes and such texts. The one reader of a sequence a person
    or a program gives (a peer's key is read by :func:`parse_sequence`, under the receiving
    limits, and in the wire form only).

    Raises :class:`ParseError` (or another StringBTError) positioned in the text itself, with
    a caret under the offending character, never in an internal rewrite of it."""
    if isinstance(sequence, str):
        return _read_sequence(sequence)  # cached: robots meet the same few sequences
    out: list[Condition] = []
    for element in sequence:
        if isinstance(element, Condition):
            out.append(element)
        elif isinstance(element, str):
            out.extend(_read_sequence(element))
        else:
            raise ParseError(
                ErrorCode.UNEXPECTED_TOKEN, f"a condition is a Condition or a str, not {element!r}"
            )
    return tuple(out)


@lru_cache(maxsize=1024)
def _read_sequence(text: str) -> tuple[Condition, ...]:
    if not text.strip():
        raise ParseError(ErrorCode.EMPTY, "the sequence names no condition", source=text)
    if text.lstrip().startswith("<"):
        try:
            return parse_sequence(text)
        except StringBTError as err:  # columns of "<sq>" + text + "<e>"
            column = max(1, err.column - 4) if err.line == 1 else err.column
            if err.line == 1 and column > len(text):  # at the "<e>" this function added
                raise ParseError(
                    ErrorCode.UNEXPECTED_END,
                    "the sequence ends inside a condition",
                    1,
                    column,
                    source=text,
                ) from None
            raise type(err)(err.code, err.message, err.line, column, source=text) from None
    conds = []
    for start, end in _top_level_spans(text):
        conds.append(_read_condition(text, start, end))
    return tuple(conds)


def _top_level_spans(text: str) -> list[tuple[int, int]]:
    """(start, end) of each comma-separated part, commas inside parentheses or strings kept."""
    spans: list[tuple[int, int]] = []
    depth, quoted, escaped, start = 0, False, False, 0
    for i, char in enumerate(text):
        if quoted:
            if escaped:
                escaped = False
            elif char == "\\":
                escaped = True
            elif char == '"':
                quoted = False
        elif char == '"':
            quoted = True
        elif char == "(":
            depth += 1
        elif char == ")":
            depth -= 1
        elif char == "," and depth == 0:
            spans.append((start, i))
            start = i + 1
    spans.append((start, len(text)))
    return spans


def _read_condition(text: str, start: int, end: int) -> Condition:
    def fail(code: ErrorCode, message: str, at: int) -> ParseError:
        return ParseError(code, message, 1, at + 1, source=text)

    part = text[start:end]
    if not part.strip():
        raise fail(
            ErrorCode.UNEXPECTED_TOKEN, "expected a condition before ','", min(end, len(text) - 1)
        )
    name = _NAME.match(text, start, end)
    if name is None:
        at = start + len(part) - len(part.lstrip())
        raise fail(ErrorCode.UNEXPECTED_CHARACTER, "expected a condition name", at)
    head = name.group(1)
    rest = name.end()
    if rest == end:
        args, open_at, close_at = "", -1, -1
    elif text[rest] == "(":
        open_at = rest
        close_at = len(text[:end].rstrip()) - 1
        if text[close_at] != ")" or close_at == open_at:
            raise fail(ErrorCode.UNEXPECTED_END, "missing ) to close the arguments", close_at + 1)
        args = text[open_at + 1 : close_at]
    else:
        raise fail(ErrorCode.UNEXPECTED_TOKEN, "expected '(' or ',' after the condition name", rest)
    rewrite = f"<c>({head}, {args})" if args.strip() else f"<c>({head})"
    try:
        node = parse(rewrite).root
    except StringBTError as err:
        raise type(err)(
            err.code,
            err.message,
            1,
            _user_column(err, head, name, args, open_at, close_at) + 1,
            source=text,
        ) from None
    if not isinstance(node, Condition):  # pragma: no cover - the grammar guarantees it
        raise fail(ErrorCode.UNEXPECTED_TOKEN, "not a condition", start)
    return replace(node, pos=None)


def _user_column(
    err: StringBTError, head: str, name: re.Match[str], args: str, open_at: int, close_at: int
) -> int:
    """Where in the user's text column ``err.column`` of ``<c>(HEAD, ARGS)`` came from."""
    r = err.column - 1 if err.line == 1 else len(head) + len(args) + 6
    if r < 4:
        return name.start(1)
    if r < 4 + len(head):
        return name.start(1) + r - 4
    if r < 6 + len(head):
        return open_at if open_at >= 0 else name.end(1)
    if r < 6 + len(head) + len(args):
        return open_at + 1 + r - 6 - len(head)
    return close_at if close_at >= 0 else name.end(1)


def split_item(node: Node) -> tuple[tuple[Condition, ...], Node] | None:
    """A knowledge item's condition sequence and action subtree; None if ``node`` is not an item
    (spec/stringbt.md, section 4). An item is a reactive ``<sq>`` whose leading conditions are
    the key and whose remaining children (at least one) are the actions: one child is the
    subtree itself, several are ``Sequence(children)``. So the paper's flat form
    ``<sq><c>(A)<a>(X)<a>(Y)<e>`` and the nested ``<sq><c>(A)<sq><a>(X)<a>(Y)<e><e>`` are the
    same item, and tick the same way."""
    if not isinstance(node, SequenceNode) or node.memory:
        return None
    children = node.children
    n = 0
    while n < len(children) and isinstance(children[n], Condition):
        n += 1
    if n == 0 or n == len(children):
        return None
    conds = tuple(c for c in children[:n] if isinstance(c, Condition))
    rest = children[n:]
    return conds, rest[0] if len(rest) == 1 else SequenceNode(rest)


def stray_nodes(tree: Tree | Node) -> list[StringBTError]:
    """Warnings (``SBT501``) for every child of a placeholder that is not a knowledge item: it is
    ticked like any node, but never taught, looked up or counted as knowledge."""
    found = []
    for node, _ in walk(as_node(tree)):
        if isinstance(node, Placeholder):
            for child in node.children:
                if split_item(child) is None:
                    found.append(
                        StringBTError(
                            ErrorCode.NOT_KNOWLEDGE,
                            f"<k>({node.name}) holds a node that is not a knowledge item "
                            "(<sq>, its conditions, then its actions): it is never taught",
                            child.line,
                            child.column,
                        )
                    )
    return found


def actions_rerun(tree: Tree | Node) -> list[StringBTError]:
    """Warnings (``SBT502``) for the re-run trap of the flat item form (spec/stringbt.md,
    section 4.1): in a reactive ``<sq>`` every tick starts again at the first child, so an
    action that succeeded runs again on every tick while a later one is RUNNING (``grasp, turn
    30/60, grasp, turn 60/60, push``). Looked for in knowledge items, the children of
    placeholders and a root that is an item, at any depth inside them: a reactive sequence
    with an action in one child and, in a later child, an action, a wait or a TT1 timer (which
    may return RUNNING). The memory form, the actions in one ``<msq>``, runs each once.
    Which actions finish in the tick they start is the robot's to know, not the text's, so
    this is a warning: the tree stays valid."""
    root = as_node(tree)
    items = [root] if split_item(root) is not None else []
    for node, _ in walk(root):
        if isinstance(node, Placeholder):
            items.extend(child for child in node.children if split_item(child) is not None)
    found = []
    for item in items:
        stack = [item]
        while stack:  # placeholders inside an item: their items are looked at on their own
            node = stack.pop()
            if isinstance(node, SequenceNode) and not node.memory:
                trap = _rerun(node.children)
                if trap is not None:
                    found.append(trap)
            if isinstance(node, Container) and not isinstance(node, Placeholder):
                stack.extend(reversed(node.children))
    return sorted(found, key=lambda w: (w.line, w.column))


def _rerun(children: tuple[Node, ...]) -> StringBTError | None:
    """The warning for one reactive sequence's children, None if no action there is re-run."""
    first: Action | None = None
    for child in children:
        if first is not None:
            later = _first(child, (Action, Wait, WaitTimer))
            if later is not None:
                return StringBTError(
                    ErrorCode.ACTIONS_RERUN,
                    f"{format_tree(first, 'compact')} runs again on every tick while "
                    f"{_shown(later)} is RUNNING: if it must run once, put the actions in "
                    "one <msq>...<e> (the memory form)",
                    first.line,
                    first.column,
                )
        if first is None:
            found = _first(child, (Action,))
            first = found if isinstance(found, Action) else None
    return None


def _first(node: Node, kinds: tuple[type[Node], ...]) -> Node | None:
    """The first node of one of ``kinds`` in ``node``, in document order."""
    return next((n for n, _ in walk(node) if isinstance(n, kinds)), None)


def _shown(node: Node) -> str:
    if isinstance(node, Action | Wait):
        return format_tree(node, "compact")
    return "a <tt1> timer"


def find_warnings(tree: Tree | Node) -> list[StringBTError]:
    """Every warning about a valid tree (``SBT5xx``), in document order: what ``ktbt check``
    prints besides :func:`~ktbt_proto.validate.find_problems`'s problems, without counting
    them as problems (spec/stringbt.md, section 11)."""
    return sorted([*stray_nodes(tree), *actions_rerun(tree)], key=lambda w: (w.line, w.column))
