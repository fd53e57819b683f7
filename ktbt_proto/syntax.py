"""Reading stringBT: the fast parser, and the reference parser built from the normative grammar.

Both parsers work in the same four stages, so they report the same first error for any input:

1. size: the input is no larger than ``Limits.max_size``;
2. lexing: the whole input is split into tokens (the first bad character is reported);
3. limits: depth, node count and literal length are checked on the token stream, so a
   100,000-deep input is refused in linear time before any tree is built;
4. syntax: tokens are parsed into a tree (the first token that cannot continue is reported).

``parse`` (the fast path) is a hand-written, non-recursive parser over one compiled regular
expression; ``parse_reference`` drives lark's LALR parser over ``grammar/stringbt.lark``, the
definition of the language. The tests hold the two to the same trees and the same errors on
every conformance vector and on property-generated input.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import replace
from functools import cache
from pathlib import Path
from typing import Any

from .errors import ErrorCode, LimitError, ParseError, StringBTError
from .limits import DEFAULT_LIMITS, Limits
from .tree import (
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
    Sequence,
    Tree,
    Value,
    Wait,
    WaitTimer,
)

NAME_PATTERN = r"[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*"
NAME_RE = re.compile(NAME_PATTERN)
_NUMBER = r"-?[0-9]+(?:\.[0-9]+)?(?:[eE][+-]?[0-9]+)?"
_STRING = r'"(?:[^"\\\x00-\x1f]|\\["\\/bfnrt]|\\u[0-9a-fA-F]{4})*"'
_BADTAG_RE = re.compile(r"<[A-Za-z0-9_]*>")
_NOT_BOOL = r"(?!(?:true|false)(?![A-Za-z0-9_.]))"

OPEN_TAGS = frozenset(("<sq>", "<msq>", "<sl>", "<msl>", "<pl>", "<neg>", "<tt1>", "<tt2>", "<k>"))
LEAF_TAGS = frozenset(("<c>", "<a>", "<w>", "<wt>"))

# One alternation; the two fused alternatives read the commonest leaves, `<c>(!X)` and `<a>(X)`
# without arguments or spaces, as single tokens (they are what the canonical form is made of).
_TOKEN_RE = re.compile(
    rf"(?P<ws>[ \t\r\n]+)"
    rf"|(?P<cleaf><c>\((?P<neg>!?){_NOT_BOOL}(?P<cname>{NAME_PATTERN})\))"
    rf"|(?P<aleaf><a>\({_NOT_BOOL}(?P<aname>{NAME_PATTERN})\))"
    r"|(?P<tag><(?:Root|sq|msq|sl|msl|pl|neg|tt1|tt2|k|c|a|w|wt|e)>)"
    r"|(?P<comment>#[^\n]*)"
    r"|(?P<bool>(?:true|false)(?![A-Za-z0-9_.]))"
    rf"|(?P<name>{NAME_PATTERN})"
    rf"|(?P<number>{_NUMBER})"
    rf"|(?P<string>{_STRING})"
    r"|(?P<punct>[(),=!])"
    r"|(?P<badtag><[A-Za-z0-9_]*>)"
)

# A token: (kind, value, line, column). Kinds are the group names above, with comments split
# into "lcomment" (alone on their line) and "tcomment" (after something on the same line).
Token = tuple[str, Any, int, int]


def _describe(tok: Token | None) -> str:
    if tok is None:
        return "end of input"
    kind, value = tok[0], tok[1]
    if kind == "cleaf":
        return "<c>"
    if kind == "aleaf":
        return "<a>"
    if kind in ("tag", "punct"):
        return f"'{value}'"
    return f"{kind} {value!r}" if kind != "string" else "a string"


def _position_of_end(text: str) -> tuple[int, int]:
    line = text.count("\n") + 1
    return line, len(text) - (text.rfind("\n") + 1) + 1


def _decode(data: str | bytes, limits: Limits) -> str:
    if isinstance(data, str):
        if len(data) > limits.max_size:
            raise LimitError(
                ErrorCode.TOO_LARGE,
                f"input is {len(data)} characters, the limit is {limits.max_size}",
            )
        return data
    if len(data) > limits.max_size:
        raise LimitError(
            ErrorCode.TOO_LARGE, f"input is {len(data)} bytes, the limit is {limits.max_size}"
        )
    try:
        return data.decode("utf-8")
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


def _lex(text: str, limits: Limits) -> list[Token]:
    """Stages 2 and 3: the token list, or the first lexical error, else the first limit error."""
    tokens: list[Token] = []
    append = tokens.append
    match = _TOKEN_RE.scanner(text).match
    line, line_start, last_line = 1, 0, 0
    depth = nodes = 0
    max_depth, max_nodes, max_lit = limits.max_depth, limits.max_nodes, limits.max_literal
    limit_error: StringBTError | None = None
    end = len(text)
    pos = 0
    while pos < end:
        m = match()
        if m is None:
            col = pos - line_start + 1
            bad = _BADTAG_RE.match(text, pos)
            if bad:
                raise ParseError(
                    ErrorCode.UNKNOWN_TAG,
                    f"unknown tag {bad.group()}",
                    line,
                    col,
                    source=text,
                )
            raise ParseError(
                ErrorCode.UNEXPECTED_CHARACTER,
                f"unexpected character {text[pos]!r}",
                line,
                col,
                source=text,
            )
        kind = m.lastgroup
        pos = m.end()
        if kind == "ws":
            value = m.group()
            newlines = value.count("\n")
            if newlines:
                line += newlines
                line_start = m.start() + value.rfind("\n") + 1
            continue
        col = m.start() - line_start + 1
        if kind == "tag":
            value = m.group()
            if value in OPEN_TAGS or value in LEAF_TAGS:
                nodes += 1
                if limit_error is None and (depth >= max_depth or nodes > max_nodes):
                    limit_error = _limit_error(depth, nodes, limits, line, col)
                if value in OPEN_TAGS:
                    depth += 1
            elif value == "<e>" and depth:
                depth -= 1
            append((kind, value, line, col))
        elif kind == "cleaf" or kind == "aleaf":
            nodes += 1
            if limit_error is None and (depth >= max_depth or nodes > max_nodes):
                limit_error = _limit_error(depth, nodes, limits, line, col)
            if kind == "cleaf":
                name = m.group("cname")
                append((kind, (bool(m.group("neg")), name), line, col))
            else:
                name = m.group("aname")
                append((kind, name, line, col))
            if len(name) > max_lit and limit_error is None:
                start = m.start("cname" if kind == "cleaf" else "aname")
                limit_error = _literal_error(name, limits, line, start - line_start + 1)
        elif kind == "comment":
            text_ = m.group()[1:].rstrip()
            append(("tcomment" if last_line == line else "lcomment", text_, line, col))
            continue
        else:
            value = m.group()
            if kind == "badtag":
                raise ParseError(
                    ErrorCode.UNKNOWN_TAG, f"unknown tag {value}", line, col, source=text
                )
            if len(value) > max_lit and limit_error is None and kind != "punct":
                limit_error = _literal_error(value, limits, line, col)
            append((kind, value, line, col))
        last_line = line
    if limit_error is not None:
        limit_error.excerpt = StringBTError(
            limit_error.code, "", limit_error.line, limit_error.column, source=text
        ).excerpt
        raise limit_error
    return tokens


def _limit_error(depth: int, nodes: int, limits: Limits, line: int, col: int) -> LimitError:
    if depth >= limits.max_depth:
        return LimitError(
            ErrorCode.TOO_DEEP,
            f"node nested deeper than the depth limit of {limits.max_depth}",
            line,
            col,
        )
    return LimitError(
        ErrorCode.TOO_MANY_NODES, f"more than {limits.max_nodes} nodes", line, col
    )


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


def _value(tok: Token) -> Value:
    kind, text = tok[0], tok[1]
    if kind == "number":
        return _number(text)
    if kind == "string":
        value: str = json.loads(text)
        return value
    return text == "true"


_CONTAINER_BUILDERS: dict[str, Callable[[tuple[Node, ...], Any, Any], Container]] = {
    "<sq>": lambda ch, arg, kw: Sequence(ch, **kw),
    "<msq>": lambda ch, arg, kw: Sequence(ch, memory=True, **kw),
    "<sl>": lambda ch, arg, kw: Selector(ch, **kw),
    "<msl>": lambda ch, arg, kw: Selector(ch, memory=True, **kw),
    "<pl>": lambda ch, arg, kw: Parallel(ch, threshold=arg, **kw),
    "<neg>": lambda ch, arg, kw: Inverter(ch, **kw),
    "<tt1>": lambda ch, arg, kw: WaitTimer(ch, ticks=arg, **kw),
    "<tt2>": lambda ch, arg, kw: RunTimer(ch, ticks=arg, **kw),
    "<k>": lambda ch, arg, kw: Placeholder(ch, name=arg, **kw),
}


class _Frame:
    """An open container while its children are being read."""

    __slots__ = ("arg", "children", "comments", "pos", "tag", "trailing")

    def __init__(self, tag: str, pos: tuple[int, int], arg: Any, comments: tuple[str, ...]):
        self.tag = tag
        self.pos = pos
        self.arg = arg
        self.children: list[Node] = []
        self.comments = comments
        self.trailing: str | None = None


def parse(data: str | bytes, *, limits: Limits = DEFAULT_LIMITS) -> Tree:
    """Parse stringBT text (str, or UTF-8 bytes) into a :class:`Tree`.

    Raises a :class:`ParseError` or :class:`LimitError` (both :class:`StringBTError`) for any
    input that is not stringBT; never another exception, whatever the input. The tree is not
    validated: call :func:`ktbt_proto.validate` for arity, names and registry checks.
    """
    text = _decode(data, limits)
    try:
        return _Parser(text, _lex(text, limits)).run()
    except StringBTError as err:
        if not err.excerpt:
            err.excerpt = StringBTError(err.code, "", err.line, err.column, source=text).excerpt
        raise


class _Parser:
    """Stage 4 of the fast path: tokens to tree, with an explicit stack (no recursion)."""

    __slots__ = ("i", "mid_comments", "text", "tokens")

    def __init__(self, text: str, tokens: list[Token]) -> None:
        self.text = text
        self.tokens = tokens
        self.i = 0
        self.mid_comments: list[str] = []

    def _error(self, tok: Token | None, expected: str, code: ErrorCode | None = None) -> ParseError:
        if tok is None:
            line, col = _position_of_end(self.text)
        else:
            line, col = tok[2], tok[3]
        return ParseError(
            code or ErrorCode.UNEXPECTED_TOKEN,
            f"unexpected {_describe(tok)}, expected {expected}",
            line,
            col,
            expected=(expected,),
        )

    def _next(self) -> Token | None:
        """The next token inside a node's parentheses; comments there move to the next node."""
        tokens, i = self.tokens, self.i
        while i < len(tokens):
            tok = tokens[i]
            i += 1
            if tok[0] == "lcomment" or tok[0] == "tcomment":
                self.mid_comments.append(tok[1])
                continue
            self.i = i
            return tok
        self.i = i
        return None

    def _expect(self, kinds: tuple[str, ...], expected: str) -> Token:
        tok = self._next()
        if tok is None or tok[0] not in kinds:
            raise self._error(tok, expected)
        return tok

    def _expect_punct(self, char: str) -> Token:
        tok = self._next()
        if tok is None or tok[1] != char or tok[0] != "punct":
            raise self._error(tok, f"'{char}'")
        return tok

    def _args(self) -> tuple[tuple[tuple[str, Value], ...], Token | None]:
        """`(, name = value)*` then `)`: the arguments of a leaf, after its name."""
        args: list[tuple[str, Value]] = []
        tok = self._next()
        while tok is not None and tok[0] == "punct" and tok[1] == ",":
            key = self._expect(("name",), "an argument name")
            self._expect_punct("=")
            value = self._expect(("number", "string", "bool"), "a number, string, true or false")
            args.append((key[1], _value(value)))
            tok = self._next()
        if tok is None or tok[0] != "punct" or tok[1] != ")":
            raise self._error(tok, "',' or ')'")
        return tuple(args), tok

    def _leaf(self, tag: str, pos: tuple[int, int]) -> Node:
        tok = self._next()
        if tag == "<w>" or tag == "<wt>":
            unit = "ticks" if tag == "<w>" else "seconds"
            if tok is not None and tok[0] == "number":
                return Wait(_number(tok[1]), unit, pos=pos)
            if tok is None or tok[1] != "(" or tok[0] != "punct":
                raise self._error(tok, "'(' or a number")
            number = self._expect(("number",), "a number")
            self._expect_punct(")")
            return Wait(_number(number[1]), unit, pos=pos)
        negated = False
        if tok is not None and tok[0] == "punct" and tok[1] == "(":
            tok = self._next()
            if tag == "<c>" and tok is not None and tok[0] == "punct" and tok[1] == "!":
                negated = True
                tok = self._next()
            if tok is None or tok[0] != "name":
                raise self._error(tok, "a name" if negated or tag == "<a>" else "'!' or a name")
            args, _ = self._args()
        else:
            if tag == "<c>" and tok is not None and tok[0] == "punct" and tok[1] == "!":
                negated = True
                tok = self._next()
                if tok is None or tok[0] != "name":
                    raise self._error(tok, "a name")
            elif tok is None or tok[0] != "name":
                raise self._error(tok, "'(' or a name" if tag == "<a>" else "'(', '!' or a name")
            args = ()
        if tag == "<c>":
            return Condition(tok[1], negated, args, pos=pos)
        return Action(tok[1], args, pos=pos)

    def _open_arg(self, tag: str) -> Any:
        """The parenthesised argument of `<pl>` (optional), `<tt1>`, `<tt2>` and `<k>`."""
        if tag == "<pl>":
            tokens, i = self.tokens, self.i
            while i < len(tokens) and tokens[i][0] in ("lcomment", "tcomment"):
                i += 1
            if i >= len(tokens) or tokens[i][1] != "(" or tokens[i][0] != "punct":
                return None
        elif tag not in ("<tt1>", "<tt2>", "<k>"):
            return None
        self._expect_punct("(")
        if tag == "<k>":
            value = self._expect(("name",), "a placeholder name")[1]
        else:
            value = _number(self._expect(("number",), "a number")[1])
        self._expect_punct(")")
        return value

    def run(self) -> Tree:
        tokens = self.tokens
        n = len(tokens)
        stack: list[_Frame] = []
        pending: list[str] = []
        root: Node | None = None
        # What a trailing comment on the current line belongs to: a frame (opening line of a
        # container) or the index of a node in its parent's children (None parent = root).
        last_frame: _Frame | None = None
        last_node: tuple[list[Node] | None, int] | None = None
        saw_root_tag = False
        while self.i < n:
            tok = tokens[self.i]
            self.i += 1
            kind, value = tok[0], tok[1]
            if kind == "lcomment":
                pending.append(value)
                continue
            if kind == "tcomment":
                if last_frame is not None:
                    last_frame.trailing = value
                elif last_node is not None:
                    siblings, idx = last_node
                    node = siblings[idx] if siblings is not None else root
                    assert node is not None
                    where = "end_trailing" if isinstance(node, Container) else "trailing"
                    node = _with_comments(node, **{where: value})
                    if siblings is not None:
                        siblings[idx] = node
                    else:
                        root = node
                else:
                    pending.append(value)
                last_frame = last_node = None
                continue
            last_frame = last_node = None
            if kind == "tag" and value == "<e>":
                if not stack:
                    raise self._error(tok, "end of input", ErrorCode.UNMATCHED_END)
                frame = stack.pop()
                node = _build(frame, pending)
                pending = []
            else:
                if not stack and root is not None:
                    raise self._error(tok, "end of input", ErrorCode.EXTRA_ROOT)
                pos = (tok[2], tok[3])
                if kind == "cleaf":
                    node = Condition(value[1], value[0], pos=pos)
                elif kind == "aleaf":
                    node = Action(value, pos=pos)
                elif kind == "tag" and value in OPEN_TAGS:
                    frame = _Frame(value, pos, self._open_arg(value), tuple(pending))
                    pending = self.mid_comments
                    self.mid_comments = []
                    stack.append(frame)
                    last_frame = frame
                    continue
                elif kind == "tag" and value in LEAF_TAGS:
                    node = self._leaf(value, pos)
                elif kind == "tag" and value == "<Root>" and self.i == _first_significant(tokens):
                    saw_root_tag = True
                    continue
                else:
                    raise self._error(tok, "a node" + (" or <e>" if stack else ""))
                if pending:
                    node = _with_comments(node, leading=tuple(pending))
                pending = self.mid_comments
                self.mid_comments = []
            if stack:
                siblings = stack[-1].children
                siblings.append(node)
                last_node = (siblings, len(siblings) - 1)
            else:
                root = node
                last_node = (None, 0)
        if stack:
            opener = stack[-1]
            err = self._error(None, "<e>", ErrorCode.UNEXPECTED_END)
            err.message = (
                f"input ends inside {opener.tag} opened at {opener.pos[0]}:{opener.pos[1]}; "
                "expected <e>"
            )
            raise err
        if root is None:
            if saw_root_tag:
                raise self._error(None, "a node", ErrorCode.UNEXPECTED_END)
            raise self._error(None, "a node", ErrorCode.EMPTY)
        return Tree(root, footer=tuple(pending))


def _first_significant(tokens: list[Token]) -> int:
    """1 + index of the first non-comment token (where `<Root>` may stand)."""
    for i, tok in enumerate(tokens):
        if tok[0] != "lcomment" and tok[0] != "tcomment":
            return i + 1
    return 0


def _with_comments(node: Node, **changes: Any) -> Node:
    return replace(node, comments=replace(node.comments or Comments(), **changes))


def _build(frame: _Frame, end_comments: list[str]) -> Container:
    kw: dict[str, Any] = {"pos": frame.pos}
    if frame.comments or frame.trailing is not None or end_comments:
        kw["comments"] = Comments(
            leading=frame.comments, trailing=frame.trailing, end=tuple(end_comments)
        )
    return _CONTAINER_BUILDERS[frame.tag](tuple(frame.children), frame.arg, kw)


# ---------------------------------------------------------------------------------------------
# The reference parser: lark over the normative grammar.


def grammar_path() -> Path:
    """The normative grammar file, inside the installed package or the source tree."""
    packaged = Path(__file__).with_name("grammar") / "stringbt.lark"
    if packaged.exists():
        return packaged
    return Path(__file__).resolve().parent.parent / "grammar" / "stringbt.lark"


def grammar_text() -> str:
    return grammar_path().read_text(encoding="utf-8")


@cache
def _lark() -> Any:
    import lark

    return lark.Lark(grammar_text(), parser="lalr", lexer="basic", propagate_positions=False)


def parse_reference(data: str | bytes, *, limits: Limits = DEFAULT_LIMITS) -> Tree:
    """Parse with lark's LALR parser over the normative grammar (slower; no comments kept).

    The definition of which texts are stringBT and what tree each denotes; used by the tests to
    hold :func:`parse` to the grammar. Raises the same errors as :func:`parse`.
    """
    import lark
    from lark.exceptions import UnexpectedCharacters, UnexpectedInput

    text = _decode(data, limits)
    parser = _lark()
    try:
        toks = list(parser.lex(text))
    except UnexpectedCharacters as exc:
        bad = _BADTAG_RE.match(text, exc.pos_in_stream or 0)
        code = ErrorCode.UNKNOWN_TAG if bad else ErrorCode.UNEXPECTED_CHARACTER
        raise ParseError(code, "lexical error", exc.line, exc.column, source=text) from None
    _reference_limits(toks, limits, text)
    try:
        tree = parser.parse(text)
    except UnexpectedInput as exc:
        raise _reference_syntax_error(text, toks, exc) from None
    root = _ReferenceBuilder().transform(tree)
    return Tree(root)


def _reference_limits(toks: list[Any], limits: Limits, text: str) -> None:
    depth = nodes = 0
    opens = {"SEQ", "MSEQ", "SEL", "MSEL", "PAR", "NEG", "TT1", "TT2", "KB"}
    leaves = {"COND", "ACT", "WAIT", "WAITS"}
    for tok in toks:
        if tok.type in opens or tok.type in leaves:
            nodes += 1
            if depth >= limits.max_depth or nodes > limits.max_nodes:
                err = _limit_error(depth, nodes, limits, tok.line, tok.column)
                err.excerpt = StringBTError(err.code, "", tok.line, tok.column, source=text).excerpt
                raise err
            if tok.type in opens:
                depth += 1
        elif tok.type == "END" and depth:
            depth -= 1
        elif tok.type in ("NAME", "NUMBER", "STRING", "BOOL") and len(tok) > limits.max_literal:
            raise _literal_error(str(tok), limits, tok.line, tok.column)


_INSIDE_LEAF = frozenset(("LPAR", "RPAR", "COMMA", "EQUAL", "BANG", "NAME", "NUMBER", "STRING", "BOOL"))


def _reference_syntax_error(text: str, toks: list[Any], exc: Any) -> ParseError:
    """Classify lark's error as the fast parser's stages do: by what the parser expected."""
    token = getattr(exc, "token", None)
    if token is None or token.type == "$END":
        line, col = _position_of_end(text)
        code = ErrorCode.UNEXPECTED_END if toks else ErrorCode.EMPTY
        return ParseError(code, "unexpected end of input", line, col, source=text)
    expected = set(getattr(exc, "expected", ()) or ())
    at_boundary = not (expected & _INSIDE_LEAF)
    if token.type == "END" and at_boundary and "END" not in expected:
        code = ErrorCode.UNMATCHED_END
    elif expected == {"$END"}:
        code = ErrorCode.EXTRA_ROOT
    else:
        code = ErrorCode.UNEXPECTED_TOKEN
    return ParseError(
        code,
        f"unexpected {token!s}, expected one of {sorted(expected)}",
        token.line,
        token.column,
        source=text,
        expected=tuple(sorted(expected)),
    )


class _ReferenceBuilder:
    """lark parse tree to nodes, bottom-up with an explicit stack (no recursion)."""

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
        assert isinstance(result, Node)
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
        return Sequence(children, memory=tag.type == "MSEQ", pos=self._pos(tag))

    def selector(self, items: list[Any]) -> Node:
        tag, children = self._container(items)
        return Selector(children, memory=tag.type == "MSEL", pos=self._pos(tag))

    def parallel(self, items: list[Any]) -> Node:
        tag, children = self._container(items)
        threshold = _number(items[1]) if getattr(items[1], "type", "") == "NUMBER" else None
        return Parallel(children, threshold=threshold, pos=self._pos(tag))  # type: ignore[arg-type]

    def inverter(self, items: list[Any]) -> Node:
        tag, children = self._container(items)
        return Inverter(children, pos=self._pos(tag))

    def wait_timer(self, items: list[Any]) -> Node:
        tag, children = self._container(items)
        return WaitTimer(children, ticks=_number(items[1]), pos=self._pos(tag))  # type: ignore[arg-type]

    def run_timer(self, items: list[Any]) -> Node:
        tag, children = self._container(items)
        return RunTimer(children, ticks=_number(items[1]), pos=self._pos(tag))  # type: ignore[arg-type]

    def knowledge(self, items: list[Any]) -> Node:
        tag, children = self._container(items)
        return Placeholder(children, name=str(items[1]), pos=self._pos(tag))

    def arg(self, items: list[Any]) -> tuple[str, Value]:
        key, value = items
        return (str(key), _value((value.type.lower(), str(value), 0, 0)))

    def condition(self, items: list[Any]) -> Node:
        negated = any(getattr(x, "type", "") == "BANG" for x in items)
        name = next(x for x in items if getattr(x, "type", "") == "NAME")
        args = tuple(x for x in items if isinstance(x, tuple))
        return Condition(str(name), negated, args, pos=self._pos(items[0]))

    def action(self, items: list[Any]) -> Node:
        args = tuple(x for x in items if isinstance(x, tuple))
        return Action(str(items[1]), args, pos=self._pos(items[0]))

    def wait(self, items: list[Any]) -> Node:
        unit = "ticks" if items[0].type == "WAIT" else "seconds"
        return Wait(_number(items[1]), unit, pos=self._pos(items[0]))
