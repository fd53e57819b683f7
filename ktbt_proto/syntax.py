"""Reading stringBT: a fast parser, and the reference parser built from the normative grammar.

``parse_reference`` drives lark's LALR parser over ``grammar/stringbt.lark``, the definition of
the language, in four stages that fix which error is reported first:

1. size: the input is no larger than ``Limits.max_size``;
2. lexing: the whole input is split into tokens (the first bad character is reported);
3. limits: depth, node count and literal length are checked on the token stream, so a
   100,000-deep input is refused in linear time before any tree is built;
4. syntax: tokens are parsed (the first token that cannot continue a valid text is reported).

``parse`` reads valid text in a single pass over one compiled regular expression, with an
explicit stack (no recursion), building nodes as it goes and keeping comments. The moment
anything is off (a bad character, a limit, a token out of place) it stops and hands the text to
an explainer, which runs stages 2 and 3 with a scanner that reads runs of blanks, comments and
punctuation at C speed, then lets lark's parser name the syntax error. The tests hold ``parse``
to ``parse_reference`` (lark's lexer and parser throughout): the same tree for every valid text,
and the same error code and position for every invalid one, on every conformance vector and on
property-generated input.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field, replace
from functools import cache
from pathlib import Path
from typing import Any

from ktbt_proto.errors import ErrorCode, LimitError, ParseError, StringBTError
from ktbt_proto.files import packaged
from ktbt_proto.limits import DEFAULT_LIMITS, Limits
from ktbt_proto.tree import (
    Action,
    Comments,
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
    Value,
    Wait,
    WaitTimer,
)

NAME_PATTERN = r"[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*"
NAME_RE = re.compile(NAME_PATTERN)
_NOT_BOOL = r"(?!(?:true|false)(?![A-Za-z0-9_.]))"
_NAME = _NOT_BOOL + NAME_PATTERN
_NUMBER = r"-?[0-9]+(?:\.[0-9]+)?(?:[eE][+-]?[0-9]+)?"
_STRING = r'"(?:[^"\\\x00-\x1f]|\\["\\/bfnrt]|\\u[0-9a-fA-F]{4})*"'
_VALUE = rf"(?:{_NUMBER}|{_STRING}|(?:true|false)(?![A-Za-z0-9_.]))"
# Whitespace and comments, allowed between any two tokens. Possessive, so that no input can make
# the matcher backtrack over how to split a run of blanks or of '#' characters.
_W = r"(?:[ \t\r\n]++|#[^\n]*+)*+"
_BADTAG_RE = re.compile(r"<[A-Za-z0-9_]*>")


def _tail_patterns(named: bool) -> dict[str, str]:
    """What may follow a tag: the same patterns with named groups (to read a token) or without
    (to embed in the scanner, where group names must be unique)."""

    def g(name: str, pattern: str) -> str:
        return f"(?P<{name}>{pattern})" if named else f"(?:{pattern})"

    args = g("args", rf"(?:{_W},{_W}{_NAME}{_W}={_W}{_VALUE})*") + rf"{_W}\)"
    return {
        "c": rf"{_W}\({_W}{g('neg', '!')}?{_W}{g('name', _NAME)}{args}"
        rf"|{_W}{g('neg2', '!')}?{_W}{g('name2', _NAME)}",
        "a": rf"{_W}\({_W}{g('name', _NAME)}{args}|{_W}{g('name2', _NAME)}",
        "w": rf"{_W}\({_W}{g('num', _NUMBER)}{_W}\)|{_W}{g('num2', _NUMBER)}",
        "n": rf"{_W}\({_W}{g('num', _NUMBER)}{_W}\)",
        "k": rf"{_W}\({_W}{g('name', _NAME)}{_W}\)",
    }


_T = _tail_patterns(named=False)
# The scanner: one capturing group per kind of token and no other groups, so that findall
# returns plain tuples of strings. The commonest tokens come first. A leaf or an opening tag with
# its parenthesised part is one token; anything that fits no alternative falls to the last group,
# and the text is then left to the reference parser to explain.
_SCAN_RE = re.compile(
    rf"(<c>\(!?{_NAME}\))"  # a condition without arguments or blanks
    rf"|(<a>\({_NAME}\))"  # an action without arguments or blanks
    r"|(<e>)"
    r"|(<(?:sq|msq|sl|msl|neg)>)"
    r"|([ \t\r\n]+)"
    rf"|(<c>(?:{_T['c']}))"  # any other condition
    rf"|(<a>(?:{_T['a']}))"  # any other action
    rf"|(<wt?>(?:{_T['w']}))"
    rf"|(<(?:pl|tt1|tt2)>{_T['n']})"
    rf"|(<k>{_T['k']})"
    r"|(<pl>)"
    r"|(<Root>)"
    r"|(#[^\n]*)"
    r"|([\s\S])"
)
_NAMED = {k: re.compile(v) for k, v in _tail_patterns(named=True).items()}
_TAILS = {
    "<c>": _NAMED["c"],
    "<a>": _NAMED["a"],
    "<w>": _NAMED["w"],
    "<wt>": _NAMED["w"],
    "<pl>": _NAMED["n"],
    "<tt1>": _NAMED["n"],
    "<tt2>": _NAMED["n"],
    "<k>": _NAMED["k"],
}
_ARG_RE = re.compile(rf"{_W},{_W}(?P<key>{_NAME}){_W}={_W}(?P<value>{_VALUE})")
_COMMENT_OR_STRING = re.compile(rf"{_STRING}|#(?P<c>[^\n]*)")

OPEN_TAGS = frozenset(("<sq>", "<msq>", "<sl>", "<msl>", "<pl>", "<neg>", "<tt1>", "<tt2>", "<k>"))
LEAF_TAGS = frozenset(("<c>", "<a>", "<w>", "<wt>"))


def _position_of_end(text: str) -> tuple[int, int]:
    line = text.count("\n") + 1
    return line, len(text) - (text.rfind("\n") + 1) + 1


def _decode(data: str | bytes, limits: Limits) -> str:
    if isinstance(data, bytearray | memoryview):
        data = bytes(data)
    if not isinstance(data, str | bytes):
        raise TypeError(f"parse() takes str or bytes, not {type(data).__name__}")
    if isinstance(data, str):
        data = data.removeprefix("\ufeff")  # a byte-order mark is not part of the text
        if len(data) > limits.max_size:
            raise LimitError(
                ErrorCode.TOO_LARGE,
                f"input is {len(data)} characters, the limit is {limits.max_size}",
            )
        if not data.isascii():
            _refuse_surrogates(data)
        return data
    if len(data) > limits.max_size:
        raise LimitError(
            ErrorCode.TOO_LARGE, f"input is {len(data)} bytes, the limit is {limits.max_size}"
        )
    try:
        return data.decode("utf-8").removeprefix("\ufeff")
    except UnicodeDecodeError as exc:
        good = data[: exc.start].decode("utf-8")
        line, column = _position_of_end(good)
        raise ParseError(
            ErrorCode.INVALID_UTF8,
            f"byte 0x{data[exc.start]:02x} at offset {exc.start} is not valid UTF-8",
            line,
            column,
            source=good,
        ) from None


def _refuse_surrogates(text: str) -> None:
    """A str holding a lone surrogate is not text UTF-8 can carry: refuse it as the bytes it
    would be (``SBT100``), rather than let a ``"\\uD800"`` escape pair up with it."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as exc:
        line, column = _position_of_end(text[: exc.start])
        raise ParseError(
            ErrorCode.INVALID_UTF8,
            f"character U+{ord(text[exc.start]):04X} is a lone surrogate, which UTF-8 cannot carry",
            line,
            column,
            source=text[: exc.start],
        ) from None


def _limit_error(deep: bool, limits: Limits, line: int, col: int) -> LimitError:
    if deep:
        return LimitError(
            ErrorCode.TOO_DEEP,
            f"node nested deeper than the depth limit of {limits.max_depth}",
            line,
            col,
        )
    return LimitError(ErrorCode.TOO_MANY_NODES, f"more than {limits.max_nodes} nodes", line, col)


def _literal_error(value: str, limits: Limits, line: int, col: int) -> LimitError:
    return LimitError(
        ErrorCode.LITERAL_TOO_LONG,
        f"literal of {len(value)} characters, the limit is {limits.max_literal}",
        line,
        col,
    )


def _number(text: str) -> int | float:
    if "." in text or "e" in text or "E" in text:
        return float(text)
    return int(text)


def _finite(value: Value) -> bool:
    """Whether a literal's value is one the language has (``1e400`` reads as infinity)."""
    return not isinstance(value, float) or math.isfinite(value)


def _infinite_error(raw: str, line: int, column: int, text: str) -> ParseError:
    return ParseError(
        ErrorCode.INVALID_VALUE,
        f"number {raw[:40]} is beyond the range of a double",
        line,
        column,
        source=text,
    )


def _value(text: str) -> Value:
    first = text[0]
    if first == '"':
        value: str = json.loads(text)
        return value
    if first == "t" or first == "f":
        return text == "true"
    return _number(text)


def parse(data: str | bytes, *, limits: Limits = DEFAULT_LIMITS) -> Tree:
    """Parse stringBT text (str, or UTF-8 bytes) into a :class:`Tree`, comments kept.

    Raises a :class:`ParseError` or :class:`LimitError` (both :class:`StringBTError`) for any
    input that is not stringBT; never another exception, whatever the input. The tree is not
    validated: call :func:`ktbt_proto.validate` for arity, names and registry checks.
    """
    text = _decode(data, limits)
    tree = _parse_fast(text, limits)
    if tree is None:
        # Not valid (or not within limits): the grammar says exactly why.
        tree = _explain(text, limits)
    return tree


_new = object.__new__
_KINDS: dict[str, tuple[type[Container], dict[str, Any]]] = {
    "<sq>": (SequenceNode, {}),
    "<msq>": (SequenceNode, {"memory": True}),
    "<sl>": (Selector, {}),
    "<msl>": (Selector, {"memory": True}),
    "<pl>": (Parallel, {}),
    "<neg>": (Inverter, {}),
    "<tt1>": (WaitTimer, {}),
    "<tt2>": (RunTimer, {}),
    "<k>": (Placeholder, {}),
}
_ARG_FIELD = {"<pl>": "threshold", "<tt1>": "ticks", "<tt2>": "ticks", "<k>": "name"}


def _tail_comments(span: str) -> list[str]:
    """Comments written inside a node's parentheses (rare): they move to the next node."""
    return [
        comment_text(m.group("c"))
        for m in _COMMENT_OR_STRING.finditer(span)
        if m.group("c") is not None
    ]


def comment_text(raw: str) -> str:
    """A comment's text: without the '#', one space after it, or trailing blanks."""
    raw = raw.rstrip()
    return raw[1:] if raw.startswith(" ") else raw


def _parse_fast(text: str, limits: Limits) -> Tree | None:
    """The single-pass parser; ``None`` means "not valid, ask the reference parser"."""
    max_depth, max_nodes, max_lit = limits.max_depth, limits.max_nodes, limits.max_literal
    new = _new
    offset = 0
    line, line_start, last_line = 1, 0, 0
    nodes = 0
    # Open containers: [tag, children, (line, col), arg, leading comments, trailing comment].
    stack: list[list[Any]] = []
    children: list[Node] | None = None
    root: Node | None = None
    pending: list[str] = []
    # What a trailing comment on this line belongs to: an open frame, or the last node built.
    last_frame: list[Any] | None = None
    last_node: Node | None = None
    started = False
    node: Node
    # finditer, not findall: a refusal comes at the first bad token, not after reading it all.
    for match in _SCAN_RE.finditer(text):
        cl, al, en, op, ws, cg, ag, wg, og, kg, pl, rt, com, bad = match.groups("")
        if ws:
            newlines = ws.count("\n")
            if newlines:
                line += newlines
                line_start = offset + ws.rfind("\n") + 1
            offset += len(ws)
            continue
        col = offset - line_start + 1
        if com:
            offset += len(com)
            comment = comment_text(com[1:])
            if last_line != line:
                pending.append(comment)
            elif last_frame is not None:
                last_frame[5] = comment
                last_frame = None
            elif last_node is not None:
                where = "end_trailing" if isinstance(last_node, Container) else "trailing"
                replaced = _with_comments(last_node, **{where: comment})
                if children is not None and children and children[-1] is last_node:
                    children[-1] = replaced
                elif root is last_node:
                    root = replaced
                last_node = None
            continue
        here = (line, col)
        last_line = line
        last_frame = last_node = None
        if cl or al:
            if root is not None and not stack:
                return None
            nodes += 1
            if len(stack) >= max_depth or nodes > max_nodes:
                return None
            if cl:
                offset += len(cl)
                node = new(Condition)
                d = node.__dict__
                if cl[4] == "!":
                    d["negated"] = True
                    name = cl[5:-1]
                else:
                    name = cl[4:-1]
            else:
                offset += len(al)
                node = new(Action)
                d = node.__dict__
                name = al[4:-1]
            if len(name) > max_lit:
                return None
            d["name"] = name
            d["pos"] = here
            if pending:
                node = _with_comments(node, leading=tuple(pending))
                pending = []
        elif en:
            offset += 3
            if not stack:
                return None
            frame = stack.pop()
            cls, extra = _KINDS[frame[0]]
            node = new(cls)
            d = node.__dict__
            d["children"] = tuple(frame[1])
            d["pos"] = frame[2]
            if extra:
                d.update(extra)
            if frame[3] is not None:
                d[_ARG_FIELD[frame[0]]] = frame[3]
            if frame[4] or frame[5] is not None or pending:
                d["comments"] = Comments(tuple(frame[4]), frame[5], tuple(pending))
                pending = []
            children = stack[-1][1] if stack else None
        elif bad:
            return None
        elif rt:
            offset += 6
            if started:
                return None
            started = True
            continue
        else:
            if root is not None and not stack:
                return None
            nodes += 1
            if len(stack) >= max_depth or nodes > max_nodes:
                return None
            tok = op or pl or og or kg or cg or ag or wg
            start = offset
            offset += len(tok)
            tag = tok[: tok.index(">") + 1]
            moved: list[str] = []
            t = None
            if not (op or pl):
                newlines = tok.count("\n")
                if newlines:
                    line += newlines
                    line_start = start + tok.rfind("\n") + 1
                    last_line = line
                if "#" in tok:
                    moved = _tail_comments(tok[len(tag) :])
                # Matched in the text, not in the token: the literals' lookaheads (``true.5``
                # is the name ``true`` then ``.5``) must see what follows, as the scanner did.
                t = _TAILS[tag].match(text, start + len(tag))
                if t is None or t.end() != offset:
                    return None
            if op or pl or og or kg:
                arg: Any = None
                if t is not None:
                    raw = t.group("name") if kg else t.group("num")
                    if len(raw) > max_lit:
                        return None
                    arg = raw if kg else _number(raw)
                    if not _finite(arg):
                        return None
                frame = [tag, [], here, arg, pending, None]
                pending = moved
                stack.append(frame)
                children = frame[1]
                last_frame = frame
                started = True
                continue
            if t is None:
                return None
            leaf = _leaf(tag, t, here, max_lit)
            if leaf is None:
                return None
            node = leaf
            if pending:
                node = _with_comments(node, leading=tuple(pending))
            pending = moved
        started = True
        if children is not None:
            children.append(node)
        else:
            root = node
        last_node = node
    if stack or root is None:
        return None
    return Tree(root, footer=tuple(pending))


def _leaf(tag: str, t: re.Match[str], pos: tuple[int, int], max_lit: int) -> Node | None:
    """Build a leaf from its tail match; ``None`` if a literal is over the limit."""
    if tag == "<w>" or tag == "<wt>":
        raw = t.group("num") or t.group("num2")
        if len(raw) > max_lit:
            return None
        duration = _number(raw)
        if not _finite(duration):
            return None
        return Wait(duration, "ticks" if tag == "<w>" else "seconds", pos=pos)
    name = t.group("name") or t.group("name2")
    if len(name) > max_lit:
        return None
    args: tuple[tuple[str, Value], ...] = ()
    raw_args = t.group("args")
    if raw_args:
        pairs = []
        for a in _ARG_RE.finditer(raw_args):
            key, value = a.group("key"), a.group("value")
            if len(key) > max_lit or len(value) > max_lit:
                return None
            parsed = _value(value)
            if not _finite(parsed):
                return None
            pairs.append((key, parsed))
        args = tuple(pairs)
    if tag == "<c>":
        negated = bool(t.group("neg") or t.group("neg2"))
        return Condition(name, negated, args, pos=pos)
    return Action(name, args, pos=pos)


def _with_comments(node: Node, **changes: Any) -> Node:
    return replace(node, comments=replace(node.comments or Comments(), **changes))


# ---------------------------------------------------------------------------------------------
# The reference parser: lark over the normative grammar.


def grammar_path() -> Path:
    """The grammar shipped in the package (identical to the repository's normative
    ``grammar/stringbt.lark``, which a test checks)."""
    return packaged("grammar", "stringbt.lark")


def grammar_text() -> str:
    return grammar_path().read_text(encoding="utf-8")


@cache
def _lark() -> Any:
    import lark

    return lark.Lark(grammar_text(), parser="lalr", lexer="basic", propagate_positions=False)


def parse_reference(data: str | bytes, *, limits: Limits = DEFAULT_LIMITS) -> Tree:
    """Parse with lark's LALR parser over the normative grammar (slower; comments dropped).

    The definition of which texts are stringBT and what tree each denotes: :func:`parse` must
    agree with it, and reports its errors through it.
    """
    return _parse_reference(_decode(data, limits), limits)


_OPENS = frozenset(("SEQ", "MSEQ", "SEL", "MSEL", "PAR", "NEG", "TT1", "TT2", "KB"))
_LEAVES = frozenset(("COND", "ACT", "WAIT", "WAITS"))
_LITERALS = frozenset(("NAME", "NUMBER", "STRING", "BOOL"))
_INSIDE_LEAF = frozenset(
    ("LPAR", "RPAR", "COMMA", "EQUAL", "BANG", "NAME", "NUMBER", "STRING", "BOOL")
)
_READABLE = {
    "LPAR": "'('",
    "RPAR": "')'",
    "COMMA": "','",
    "EQUAL": "'='",
    "BANG": "'!'",
    "NAME": "a name",
    "NUMBER": "a number",
    "STRING": "a string",
    "BOOL": "true or false",
    "END": "<e>",
    "$END": "end of input",
    "ROOT": "<Root>",
}


def _readable(expected: set[str]) -> str:
    return ", ".join(sorted({_READABLE.get(e, "a node") for e in expected}))


def _parse_reference(text: str, limits: Limits) -> Tree:
    from lark.exceptions import UnexpectedCharacters, UnexpectedInput

    parser = _lark()
    try:
        toks = list(parser.lex(text))
    except UnexpectedCharacters as exc:
        offset = exc.pos_in_stream or 0
        bad = _BADTAG_RE.match(text, offset)
        if bad:
            code, message = ErrorCode.UNKNOWN_TAG, f"unknown tag {bad.group()}"
        else:
            code, message = ErrorCode.UNEXPECTED_CHARACTER, f"unexpected character {text[offset]!r}"
        raise ParseError(code, message, exc.line, exc.column, source=text) from None
    _reference_limits(toks, limits, text)
    try:
        tree = parser.parse(text)
    except UnexpectedInput as exc:
        raise _reference_syntax_error(text, _Summary.of(toks), exc) from None
    return Tree(_ReferenceBuilder(text).transform(tree))


def _reference_limits(toks: list[Any], limits: Limits, text: str) -> None:
    depth = nodes = 0
    err: LimitError | None = None
    for tok in toks:
        kind = tok.type
        if kind in _OPENS or kind in _LEAVES:
            nodes += 1
            if depth >= limits.max_depth or nodes > limits.max_nodes:
                deep = depth >= limits.max_depth
                err = _limit_error(deep, limits, tok.line, tok.column)
                break
            if kind in _OPENS:
                depth += 1
        elif kind == "END":
            depth = max(depth - 1, 0)
        elif kind in _LITERALS and len(tok) > limits.max_literal:
            err = _literal_error(str(tok), limits, tok.line, tok.column)
            break
    if err is not None:
        err.excerpt = StringBTError(err.code, "", err.line, err.column, source=text).excerpt
        raise err


@dataclass
class _Summary:
    """What the syntax-error messages need to know of the tokens read."""

    tokens: bool = False
    opened: list[tuple[str, int, int]] = field(default_factory=list)
    last_tag: tuple[str, int, int] | None = None

    @classmethod
    def of(cls, toks: list[Any]) -> _Summary:
        summary = cls(tokens=bool(toks))
        for tok in toks:
            if tok.type in _OPENS:
                summary.opened.append((str(tok), tok.line, tok.column))
            elif tok.type == "END" and summary.opened:
                summary.opened.pop()
            if tok.type in _OPENS or tok.type in _LEAVES:
                summary.last_tag = (str(tok), tok.line, tok.column)
        return summary


def _reference_syntax_error(text: str, summary: _Summary, exc: Any) -> ParseError:
    """Classify lark's error by what the parser expected at the offending token."""
    token = getattr(exc, "token", None)
    expected = set(getattr(exc, "expected", ()) or ())
    if token is None or token.type == "$END":
        line, col = _position_of_end(text)
        if not summary.tokens:
            return ParseError(ErrorCode.EMPTY, "no node in the input", line, col, source=text)
        if expected & _INSIDE_LEAF and summary.last_tag is not None:
            tag, tl, tc = summary.last_tag
            message = f"input ends inside {tag} at {tl}:{tc}; expected {_readable(expected)}"
        elif summary.opened:
            tag, ol, oc = summary.opened[-1]
            message = f"input ends inside {tag} opened at {ol}:{oc}; expected <e>"
        else:
            message = "input ends before the node is complete"
        return ParseError(ErrorCode.UNEXPECTED_END, message, line, col, source=text)
    if token.type == "END" and not (expected & _INSIDE_LEAF) and "END" not in expected:
        code, message = ErrorCode.UNMATCHED_END, "<e> closes nothing: no node is open"
    elif expected == {"$END"}:
        code, message = ErrorCode.EXTRA_ROOT, f"{token} after the root node; a tree has one root"
    else:
        message = f"unexpected {token!s}, expected {_readable(expected)}"
        code = ErrorCode.UNEXPECTED_TOKEN
    return ParseError(
        code, message, token.line, token.column, source=text, expected=tuple(sorted(expected))
    )


# The explainer's scanner: stages 2 and 3 at C speed for what cannot matter (blanks, comments,
# punctuation are read as one run), the same tokens as lark's lexer for the rest. The agreement
# tests hold ``parse`` (which uses it) to ``parse_reference`` (which uses lark's lexer).
_EXPLAIN_RE = re.compile(
    r"(?P<run>(?:[ \t\r\n]++|#[^\n]*+|[(),=!])++)"
    r"|(?P<tag><(?:Root|sq|msq|sl|msl|pl|neg|tt1|tt2|k|c|a|w|wt|e)>)"
    rf"|(?P<lit>(?:true|false)(?![A-Za-z0-9_.])|{NAME_PATTERN}|{_NUMBER}|{_STRING})"
)
_PUNCT_RE = re.compile(r"[(),=!]")
_COMMENT_RE = re.compile(r"#[^\n]*")


def _explain(text: str, limits: Limits) -> Tree:
    """Stages 2 to 4 for text the fast parser refused: raise the error the grammar defines
    (or, should the text be valid after all, return the grammar's tree)."""
    from lark.exceptions import UnexpectedInput

    match = _EXPLAIN_RE.match
    summary = _Summary()
    depth = nodes = 0
    limit: tuple[ErrorCode | None, int, str] = (None, 0, "")
    deep: bool
    pos, end = 0, len(text)
    opens, leaves = OPEN_TAGS, LEAF_TAGS
    while pos < end:
        m = match(text, pos)
        if m is None:
            line, col = _line_col(text, pos)
            bad = _BADTAG_RE.match(text, pos)
            if bad:
                raise ParseError(
                    ErrorCode.UNKNOWN_TAG, f"unknown tag {bad.group()}", line, col, source=text
                )
            raise ParseError(
                ErrorCode.UNEXPECTED_CHARACTER,
                f"unexpected character {text[pos]!r}",
                line,
                col,
                source=text,
            )
        kind, start, pos = m.lastgroup, pos, m.end()
        if kind == "run":
            # Punctuation counts as a token; a '(' inside a comment does not.
            if not summary.tokens and _PUNCT_RE.search(_COMMENT_RE.sub("", text[start:pos])):
                summary.tokens = True
            continue
        summary.tokens = True
        value = m.group()
        if kind == "tag":
            if value in opens or value in leaves:
                nodes += 1
                if limit[0] is None and (depth >= limits.max_depth or nodes > limits.max_nodes):
                    deep = depth >= limits.max_depth
                    limit = (ErrorCode.TOO_DEEP if deep else ErrorCode.TOO_MANY_NODES, start, "")
                summary.last_tag = (value, start, 0)
                if value in opens:
                    depth += 1
                    summary.opened.append((value, start, 0))
            elif value == "<e>":
                depth = max(depth - 1, 0)
                if summary.opened:
                    summary.opened.pop()
        elif len(value) > limits.max_literal and limit[0] is None:
            limit = (ErrorCode.LITERAL_TOO_LONG, start, value)
    code, offset, literal = limit
    if code is not None:
        line, col = _line_col(text, offset)
        if code is ErrorCode.LITERAL_TOO_LONG:
            err = _literal_error(literal, limits, line, col)
        else:
            err = _limit_error(code is ErrorCode.TOO_DEEP, limits, line, col)
        err.excerpt = StringBTError(err.code, "", line, col, source=text).excerpt
        raise err
    # Offsets to positions, only for the few entries a message may name.
    summary.opened = [(t, *_line_col(text, o)) for t, o, _ in summary.opened[-1:]]
    if summary.last_tag is not None:
        tag, offset, _ = summary.last_tag
        summary.last_tag = (tag, *_line_col(text, offset))
    try:
        tree = _lark().parse(text)
    except UnexpectedInput as exc:
        raise _reference_syntax_error(text, summary, exc) from None
    return Tree(_ReferenceBuilder(text).transform(tree))


def _line_col(text: str, offset: int) -> tuple[int, int]:
    return text.count("\n", 0, offset) + 1, offset - (text.rfind("\n", 0, offset) + 1) + 1


class _ReferenceBuilder:
    """lark parse tree to nodes, bottom-up with an explicit stack (no recursion).

    A number literal beyond a double's range (``1e400``) is refused here, at the literal: the
    language has no infinite numbers, and formatting one could not read back (``SBT310``)."""

    def __init__(self, text: str) -> None:
        self.text = text

    def _num(self, tok: Any) -> int | float:
        value = _number(str(tok))
        if not _finite(value):
            raise _infinite_error(str(tok), tok.line, tok.column, self.text)
        return value

    def transform(self, tree: Any) -> Node:
        import lark

        out: list[Any] = []
        stack: list[tuple[Any, bool]] = [(tree, False)]
        while stack:
            item, done = stack.pop()
            if not isinstance(item, lark.Tree):
                out.append(item)
                continue
            if not done:
                stack.append((item, True))
                stack.extend((c, False) for c in reversed(item.children))
                continue
            n = len(item.children)
            args = out[len(out) - n :] if n else []
            del out[len(out) - n :]
            out.append(getattr(self, item.data)(args))
        result = out[0]
        if not isinstance(result, Node):
            raise TypeError(f"the grammar built {type(result).__name__}, not a node")
        return result

    @staticmethod
    def _pos(tok: Any) -> tuple[int, int]:
        return (tok.line, tok.column)

    def start(self, items: list[Any]) -> Node:
        node: Node = items[-1]
        return node

    def _container(self, items: list[Any]) -> tuple[Any, tuple[Node, ...]]:
        return items[0], tuple(x for x in items[1:] if isinstance(x, Node))

    def sequence(self, items: list[Any]) -> Node:
        tag, children = self._container(items)
        return SequenceNode(children, memory=tag.type == "MSEQ", pos=self._pos(tag))

    def selector(self, items: list[Any]) -> Node:
        tag, children = self._container(items)
        return Selector(children, memory=tag.type == "MSEL", pos=self._pos(tag))

    def parallel(self, items: list[Any]) -> Node:
        tag, children = self._container(items)
        threshold = self._num(items[1]) if getattr(items[1], "type", "") == "NUMBER" else None
        return Parallel(children, threshold=threshold, pos=self._pos(tag))  # type: ignore[arg-type]

    def inverter(self, items: list[Any]) -> Node:
        tag, children = self._container(items)
        return Inverter(children, pos=self._pos(tag))

    def wait_timer(self, items: list[Any]) -> Node:
        tag, children = self._container(items)
        return WaitTimer(children, ticks=self._num(items[1]), pos=self._pos(tag))  # type: ignore[arg-type]

    def run_timer(self, items: list[Any]) -> Node:
        tag, children = self._container(items)
        return RunTimer(children, ticks=self._num(items[1]), pos=self._pos(tag))  # type: ignore[arg-type]

    def knowledge(self, items: list[Any]) -> Node:
        tag, children = self._container(items)
        return Placeholder(children, name=str(items[1]), pos=self._pos(tag))

    def arg(self, items: list[Any]) -> tuple[str, Value]:
        key, value = items
        parsed = _value(str(value))
        if not _finite(parsed):
            raise _infinite_error(str(value), value.line, value.column, self.text)
        return (str(key), parsed)

    def condition(self, items: list[Any]) -> Node:
        negated = any(getattr(x, "type", "") == "BANG" for x in items)
        name = next(x for x in items if getattr(x, "type", "") == "NAME")
        args = tuple(x for x in items if isinstance(x, tuple))
        return Condition(str(name), negated, args, pos=self._pos(items[0]))

    def action(self, items: list[Any]) -> Node:
        args = tuple(x for x in items if isinstance(x, tuple))
        return Action(str(items[1]), args, pos=self._pos(items[0]))

    def wait(self, items: list[Any]) -> Node:
        pos = self._pos(items[0])
        if items[0].type == "WAIT":
            return Wait(self._num(items[1]), "ticks", pos=pos)
        return Wait(self._num(items[1]), "seconds", pos=pos)
