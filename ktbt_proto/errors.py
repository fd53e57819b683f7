"""The error hierarchy: every problem a user or a peer can cause, with a stable code and a position.

Codes are part of the specification (``spec/stringbt.md``, "Error codes"): programs match on
``code``, people read ``str(error)``. Positions are 1-based; columns count characters (code
points), not bytes, so an editor can jump to them.
"""

from __future__ import annotations

from enum import StrEnum


class ErrorCode(StrEnum):
    """Stable error codes. The value is the code; ``summary`` is the spec's one-line meaning."""

    summary: str

    def __new__(cls, value: str, summary: str) -> ErrorCode:
        obj = str.__new__(cls, value)
        obj._value_ = value
        obj.summary = summary
        return obj

    # Lexical and syntax errors (the parser).
    INVALID_UTF8 = ("SBT100", "input bytes are not valid UTF-8")
    UNEXPECTED_CHARACTER = ("SBT101", "a character that starts no token")
    UNKNOWN_TAG = ("SBT102", "a tag that is not part of the language")
    UNEXPECTED_TOKEN = ("SBT103", "a token the grammar does not allow here")
    UNEXPECTED_END = ("SBT104", "input ended inside an open node")
    UNMATCHED_END = ("SBT105", "<e> with no open composite or decorator to close")
    EXTRA_ROOT = ("SBT106", "another node after the root node is complete")
    EMPTY = ("SBT107", "no node at all (empty input or only comments)")
    # Limits (the parser and the validator).
    TOO_LARGE = ("SBT201", "input larger than the size limit")
    TOO_DEEP = ("SBT202", "node nested deeper than the depth limit")
    TOO_MANY_NODES = ("SBT203", "more nodes than the node limit")
    LITERAL_TOO_LONG = ("SBT204", "name, number or string longer than the literal limit")
    # Validation errors (well-formed text, ill-formed tree).
    DECORATOR_ARITY = ("SBT301", "a decorator without exactly one child")
    EMPTY_COMPOSITE = ("SBT302", "a sequence, selector or parallel without children")
    INVALID_NAME = ("SBT303", "a name that is not a well-formed identifier")
    DUPLICATE_PLACEHOLDER = ("SBT304", "two knowledge placeholders with the same name")
    UNKNOWN_CONDITION = ("SBT305", "a condition the registry does not know")
    UNKNOWN_ACTION = ("SBT306", "an action the registry does not know")
    INVALID_DURATION = ("SBT307", "a tick count or duration out of range")
    INVALID_THRESHOLD = ("SBT308", "a parallel threshold outside 1..number of children")
    DUPLICATE_ARGUMENT = ("SBT309", "the same argument given twice")
    INVALID_VALUE = ("SBT310", "an argument value of the wrong type or out of range")
    INVALID_ARGUMENTS = ("SBT311", "arguments the registered condition or action does not take")
    # Merging knowledge into a placeholder.
    UNKNOWN_SLOT = ("SBT401", "no knowledge placeholder with the requested name")
    KNOWLEDGE_CONFLICT = ("SBT402", "the placeholder answers the same conditions differently")
    BEHAVIOUR_FAILED = ("SBT403", "the application's code failed to build or set up a behaviour")
    # Warnings: the tree is valid, but probably not what was meant.
    NOT_KNOWLEDGE = ("SBT501", "a placeholder holds a node that is not a knowledge item")
    ACTIONS_RERUN = (
        "SBT502",
        "a knowledge item whose earlier actions run again while a later one is RUNNING",
    )


class StringBTError(Exception):
    """Base of every error the language can raise: ``code``, ``line``, ``column``, ``excerpt``.

    ``str(error)`` is ``"line:column: CODE message"`` followed, when the source is known, by the
    offending line and a caret under the column.
    """

    def __init__(
        self,
        code: ErrorCode,
        message: str,
        line: int = 1,
        column: int = 1,
        *,
        source: str | None = None,
        expected: tuple[str, ...] = (),
    ) -> None:
        self.code = code
        self.message = message
        self.line = line
        self.column = column
        self.expected = expected
        self.excerpt = _excerpt(source, line, column) if source is not None else ""
        super().__init__(str(self))

    def __str__(self) -> str:
        head = f"{self.line}:{self.column}: {self.code.value} {self.message}"
        return f"{head}\n{self.excerpt}" if self.excerpt else head

    def __reduce__(self) -> tuple[object, ...]:
        # Keep errors picklable (they cross process boundaries in experiments and peers).
        return (
            _rebuild,
            (
                type(self),
                self.code,
                self.message,
                self.line,
                self.column,
                self.expected,
                self.excerpt,
            ),
        )


def _rebuild(
    cls: type[StringBTError],
    code: ErrorCode,
    message: str,
    line: int,
    column: int,
    expected: tuple[str, ...],
    excerpt: str,
) -> StringBTError:
    err = cls(code, message, line, column, expected=expected)
    err.excerpt = excerpt
    return err


class ParseError(StringBTError):
    """The text is not stringBT (lexical or syntax error)."""


class LimitError(StringBTError):
    """The input or tree exceeds a configured limit; raised before any deep work."""


class ValidationError(StringBTError):
    """The tree is well-formed text but breaks a rule of the language or of a registry.

    ``problems`` holds every problem found, in source order; the error itself is the first.
    """

    problems: tuple[StringBTError, ...] = ()


_EXCERPT_WIDTH = 72


def _excerpt(source: str, line: int, column: int) -> str:
    """The offending line, clipped around the column on very long lines, with a caret."""
    lines = source.split("\n", line)
    if line - 1 >= len(lines):
        return ""
    text = lines[line - 1].rstrip("\r").expandtabs(1)
    col = max(column - 1, 0)
    start = 0
    if len(text) > _EXCERPT_WIDTH:
        start = max(0, min(col - _EXCERPT_WIDTH // 2, len(text) - _EXCERPT_WIDTH))
        text = text[start : start + _EXCERPT_WIDTH]
    return f"    {text}\n    {' ' * (col - start)}^"
