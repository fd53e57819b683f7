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
from ktbt_proto.tree import Condition, Node, Placeholder, SequenceNode, Tree, as_node, walk

__all__ = [
    "item_digest",
    "parse_sequence",
    "read_sequence",
    "sequence_digest",
    "sequence_key",
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
    parts: list[str] = []
    for element in sequence:
        if isinstance(element, Condition):
            parts.append(format_tree(element, "compact"))
        elif isinstance(element, str):
            parts.extend(format_tree(c, "compact") for c in read_sequence(element))
        else:
            raise ParseError(
                ErrorCode.UNEXPECTED_TOKEN, f"a condition is a Condition or a str, not {element!r}"
            )
    return "".join(parts)


def sequence_digest(key: str) -> str:
    """The digest of a condition sequence: SHA-256 of its key (UTF-8), hexadecimal. A fleet
    event names the item it is about by it (``spec/protocol.md`` section 10)."""
    return hashlib.sha256(key.encode("utf-8")).hexdigest()


def item_digest(key: str, subtree: Tree | Node) -> str:
    """The digest of a knowledge item, its sequence and its subtree: the first 16 hexadecimal
    digits of SHA-256 over ``key``, a newline and the compact subtree (UTF-8). Two items with
    the same digest teach the same thing; the fleet checks a saved item against its author's by
    it, and the BehaviorTree.CPP sidecar names its files by it (``spec/stringbt.md`` 12.1)."""
    text = f"{key}\n{format_tree(subtree, 'compact')}"
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


@lru_cache(maxsize=1024)
def parse_sequence(key: str, limits: Limits = DEFAULT_LIMITS) -> tuple[Condition, ...]:
    """The conditions of a sequence key (``<c>(A)<c>(!B)``); raises StringBTError. Cached:
    a robot asks and is asked about the same few sequences again and again."""
    root = parse(f"<sq>{key}<e>", limits=limits).root
    assert isinstance(root, SequenceNode)
    conds = root.children
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


def read_sequence(text: str) -> tuple[Condition, ...]:
    """Conditions from what a user types: ``TargetSeen(colour=2), !_inZoneF`` (what
    :func:`show_sequence` prints), or the wire form ``<c>(TargetSeen,colour=2)<c>(!_inZoneF)``.

    Raises :class:`ParseError` (or another StringBTError) positioned in ``text`` itself, with
    a caret under the offending character, never in an internal rewrite of it."""
    return _read_sequence(text)


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
