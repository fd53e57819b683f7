"""An open document as the server holds it, and the three ways of naming a place in it.

- an **offset**: an index into the text, in code points (what Python's ``str`` indexes);
- a **stringBT position**: 1-based line and column, lines ending at LF only and columns counting
  code points (spec/stringbt.md section 1, what every ``StringBTError`` carries);
- an **LSP position**: 0-based line and character, lines ending at LF, CR LF or a lone CR, and
  characters counted in the code units the client and server agreed on (UTF-16 unless the client
  offers UTF-8 or UTF-32).

The two kinds of line differ on a lone CR (whitespace to stringBT, a line break to LSP), and the
two kinds of column on any character outside ASCII: "é" is one code point and one UTF-16 unit,
an emoji one code point and two UTF-16 units. Every conversion goes through the offset. Changes
are applied here too, rather than by the LSP library, so that a line break LSP does not know
(U+2028 in a string literal) can never shift an edit.
"""

from __future__ import annotations

import re
from bisect import bisect_right
from collections.abc import Sequence
from functools import cached_property

from lsprotocol import types as lsp

UTF8, UTF16, UTF32 = "utf-8", "utf-16", "utf-32"
_LSP_BREAK = re.compile(r"\r\n|\r|\n")


def units(segment: str, encoding: str) -> int:
    """How many code units ``segment`` takes in ``encoding`` (a lone surrogate, which a client's
    JSON can carry, counts as one UTF-16 unit and three UTF-8 bytes, as the client counts it)."""
    if encoding == UTF32 or segment.isascii():
        return len(segment)
    if encoding == UTF8:
        return len(segment.encode("utf-8", "surrogatepass"))
    return len(segment.encode("utf-16-le", "surrogatepass")) // 2


def _chars(segment: str, units: int, encoding: str) -> int:
    """How many code points of ``segment`` its first ``units`` code units hold; a count that
    ends inside a character (half a surrogate pair) stops before it."""
    if units <= 0:
        return 0
    if encoding == UTF32 or segment.isascii():
        return min(units, len(segment))
    if encoding != UTF8:  # UTF-16, the protocol's default
        data = segment.encode("utf-16-le", "surrogatepass")[: 2 * units]
        text = data.decode("utf-16-le", "surrogatepass")
        if text and "\ud800" <= text[-1] <= "\udbff" and len(text) <= len(segment):
            # The cut fell between the halves of a pair: the pair's character was not reached.
            whole = segment[: len(text)]
            if whole[-1] != text[-1]:
                return len(text) - 1
        return min(len(text), len(segment))
    data = segment.encode("utf-8", "surrogatepass")[:units]
    return len(data.decode("utf-8", "ignore"))


class Document:
    """One open ``.sbt`` document: its text, its version, and position conversions."""

    def __init__(self, uri: str, text: str, version: int = 0, encoding: str = UTF16) -> None:
        self.uri = uri
        self.text = text
        self.version = version
        self.encoding = encoding
        self._base = len(text)
        self._same = (len(text), len(text))

    def take_edits(self) -> tuple[int, int]:
        """How many code points at the start and at the end of the text the changes applied
        since the last call (or since the document was opened) left as they were; the text as
        it is now is the next call's reference. What lets a check reuse the one before
        (:func:`.diagnostics.check`)."""
        prefix, suffix = self._same
        base, size = self._base, len(self.text)
        prefix = min(prefix, base, size)
        suffix = min(suffix, base - prefix, size - prefix)
        self._base = size
        self._same = (size, size)
        return prefix, suffix

    # -- changes ----------------------------------------------------------------------------

    def apply(self, changes: Sequence[lsp.TextDocumentContentChangeEvent], version: int) -> None:
        """Apply a ``didChange``'s changes in order (incremental ranges, or the whole text)."""
        for change in changes:
            prefix, suffix = self._same
            if isinstance(change, lsp.TextDocumentContentChangePartial):
                start = self.offset_at(change.range.start)
                end = max(start, self.offset_at(change.range.end))
                self._same = (min(prefix, start), min(suffix, len(self.text) - end))
                self._replace(start, end, change.text)
            else:
                self._same = (0, 0)
                self._set(change.text)
        self.version = version

    def _replace(self, start: int, end: int, new: str) -> None:
        """Replace ``text[start:end]`` by ``new``. The line starts are moved rather than found
        again when no line break is removed, added, split (CR|LF) or joined (CR, LF): what a
        keystroke inside a line costs is then that of the lines after it, not of the text."""
        text = self.text
        starts = self.__dict__.get("_lsp_starts")
        was_ascii = self.__dict__.get("_ascii")
        self._set(text[:start] + new + text[end:])
        if was_ascii and new.isascii():
            self.__dict__["_ascii"] = True
        removed = text[start:end]
        if (
            starts is None
            or "\n" in new
            or "\r" in new
            or "\n" in removed
            or "\r" in removed
            or (text[start - 1 : start] == "\r" and text[end : end + 1] == "\n")
        ):
            return
        delta = len(new) - len(removed)
        if delta:
            after = bisect_right(starts, start)
            starts[after:] = [at + delta for at in starts[after:]]
        self.__dict__["_lsp_starts"] = starts

    def _set(self, text: str) -> None:
        self.text = text
        for cached in ("_lsp_starts", "_sbt_starts", "_ascii"):
            self.__dict__.pop(cached, None)

    # -- lines ------------------------------------------------------------------------------

    @cached_property
    def _ascii(self) -> bool:
        return self.text.isascii()

    @cached_property
    def _lsp_starts(self) -> list[int]:
        return [0, *(m.end() for m in _LSP_BREAK.finditer(self.text))]

    @cached_property
    def _sbt_starts(self) -> list[int]:
        starts = [0]
        find, at = self.text.find, 0
        while (at := find("\n", at) + 1) > 0:
            starts.append(at)
        return starts

    def _line_end(self, line: int) -> int:
        """The offset where LSP line ``line``'s text ends (before its line break)."""
        starts = self._lsp_starts
        if line + 1 >= len(starts):
            return len(self.text)
        end = starts[line + 1]
        if self.text[end - 1] == "\n":
            end -= 2 if end >= 2 and self.text[end - 2] == "\r" else 1
        else:
            end -= 1
        return end

    @property
    def line_count(self) -> int:
        return len(self._lsp_starts)

    def line_text(self, line: int) -> str:
        """The text of LSP line ``line`` (0-based), without its line break."""
        starts = self._lsp_starts
        if not 0 <= line < len(starts):
            return ""
        return self.text[starts[line] : self._line_end(line)]

    # -- conversions ------------------------------------------------------------------------

    def offset_at(self, position: lsp.Position) -> int:
        """The offset of an LSP position, clamped to the text (a position past the end of a
        line is its end, past the last line the end of the text, as the protocol says)."""
        starts = self._lsp_starts
        if position.line >= len(starts):
            return len(self.text)
        start = starts[max(position.line, 0)]
        end = self._line_end(position.line)
        if self._ascii:  # a code unit is a code point: no need to read the line
            return start + min(max(position.character, 0), end - start)
        return start + _chars(self.text[start:end], position.character, self.encoding)

    def position_at(self, offset: int) -> lsp.Position:
        """The LSP position of an offset."""
        offset = min(max(offset, 0), len(self.text))
        line = bisect_right(self._lsp_starts, offset) - 1
        start = self._lsp_starts[line]
        offset = min(offset, max(self._line_end(line), start))
        if self._ascii:
            return lsp.Position(line=line, character=offset - start)
        return lsp.Position(line=line, character=units(self.text[start:offset], self.encoding))

    def range_of(self, start: int, end: int) -> lsp.Range:
        return lsp.Range(start=self.position_at(start), end=self.position_at(max(start, end)))

    def sbt_position(self, offset: int) -> tuple[int, int]:
        """The stringBT (line, column) of an offset."""
        line = bisect_right(self._sbt_starts, offset) - 1
        return line + 1, offset - self._sbt_starts[line] + 1
