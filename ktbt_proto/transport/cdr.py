"""The protocol's three ROS 2 messages (``ktbt_interfaces/msg/Query``, ``Answer`` and
``ErrorReply``) in their serialized form, read and written field by field (spec/protocol.md
section 11, "Receiving").

Why not rclpy's ``deserialize_message`` and ``publish`` of a message object: both go through
a Python message object, whose constructor and per-field setters cost more than reading the
bytes (2.5 times as long to read an answer, measured), and a robot reads every message of the
fleet's topics, its own among them. These three messages hold a ``uint8`` and strings only,
so their serialized form is short and fixed: XCDR version 1 (plain CDR), as every ROS 2
middleware writes it, a 4-byte encapsulation header (``00 01`` little-endian, ``00 00``
big-endian, then two option bytes), ``v``, then each string as a ``uint32`` length aligned
to 4 bytes, counting a terminating NUL, its UTF-8 bytes and the NUL; ``more`` is a ``uint32``
count, then its strings. Other encodings (XCDR version 2) are refused. The tests hold both
directions to rclpy's own serializer: every message this writes, rclpy reads back equal; what
this reads, from rclpy's bytes or corrupted ones, rclpy reads the same, or this refuses it.

Each string is bounded in its ``.msg`` (``string<=64 id``: section 1's limits, in characters,
:data:`BOUNDS`), and ``more`` holds at most :data:`MAX_MORE` strings (``string<=4096[<=63]``).
A bound does not change the bytes, and neither rclpy nor the generated C and C++ code checks a
string's bound when it reads: this does, and refuses a field beyond it (as section 1's decoder
would, later and at more cost), and never writes one.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from typing import Any

QUERY = ("id", "sender", "sequence", "more")
"""``Query``'s fields after ``v``, in the order of ``Query.msg``; ``more`` is a ``string[]``."""
ANSWER = ("id", "sender", "to", "sequence", "subtree", "author", "signature", "key", "hop")
"""``Answer``'s fields after ``v``, in the order of ``Answer.msg``."""
ERROR = ("id", "sender", "to", "code", "message")
"""``ErrorReply``'s fields after ``v``, in the order of ``ErrorReply.msg``."""
SEQUENCE = "more"
"""The one field that holds a sequence of strings."""
BOUNDS = {
    "id": 64, "sender": 64, "to": 64, "sequence": 4096, "more": 4096, "subtree": 60_000,
    "author": 43, "signature": 86, "key": 43, "hop": 86, "code": 32, "message": 1024,
}  # fmt: skip
"""Each string field's bound, in characters, as its ``.msg`` declares it (``string<=N``)."""
MAX_MORE = 63
"""Strings ``more`` holds at most (``string<=4096[<=63]``)."""

_UINT32 = {
    b"\x00\x01": struct.Struct("<I").unpack_from,
    b"\x00\x00": struct.Struct(">I").unpack_from,
}
_HEADER = b"\x00\x01\x00\x00"
_PACK = struct.Struct("<I").pack
_PAD = (b"", b"\x00\x00\x00", b"\x00\x00", b"\x00")


class CdrError(ValueError):
    """The bytes are not a message of the layout asked; the message says why, in one line."""


def read(data: bytes, layout: tuple[str, ...]) -> dict[str, Any]:
    """The fields of the message of ``layout`` that ``data`` holds, by name: ``v`` an int, each
    string a ``str``, ``more`` a ``list[str]``. Raises :class:`CdrError` for anything else (an
    encoding other than XCDR1, a length beyond the data, a string that is not UTF-8, a field
    beyond its bound); a string is read up to its first NUL and bytes after the last field are
    ignored, as rclpy does."""
    uint32 = _UINT32.get(data[:2])
    if uint32 is None or len(data) < 8:
        raise CdrError("not a message in plain CDR (XCDR1)")
    try:
        if layout[-1] != SEQUENCE:
            strings, _ = _strings(data, 8, layout, uint32)
            fields: dict[str, Any] = dict(zip(layout, strings, strict=True))
        else:
            strings, pos = _strings(data, 8, layout[:-1], uint32)
            fields = dict(zip(layout, strings, strict=False))
            (count,) = uint32(data, pos)
            if count > MAX_MORE:
                raise CdrError(f"{SEQUENCE}: {count} strings, more than its bound ({MAX_MORE})")
            if count > (len(data) - pos) // 4:
                raise CdrError(f"{SEQUENCE}: {count} strings, more than the data holds")
            fields[SEQUENCE], _ = _strings(data, pos + 4, (SEQUENCE,) * count, uint32)
    except struct.error:
        raise CdrError("the data ends before the message does") from None
    except UnicodeDecodeError:
        raise CdrError("a string that is not UTF-8") from None
    fields["v"] = data[4]
    return fields


def _strings(data: bytes, pos: int, names: tuple[str, ...], uint32: Any) -> tuple[list[str], int]:
    """The strings of the fields ``names`` from ``pos`` on, each within its bound, and where
    what follows them starts."""
    end = len(data)
    strings: list[str] = []
    append = strings.append
    for name in names:
        (size,) = uint32(data, pos)
        pos += 4
        if size == 0:
            append("")
            continue
        stop = pos + size
        if stop > end or data[stop - 1]:
            raise CdrError(f"a string of {size} bytes that the data does not hold")
        text = data[pos : stop - 1]
        if 0 in text:  # rclpy reads a string up to its first NUL, and so does this
            text = text[: text.index(0)]
        decoded = text.decode("utf-8")
        bound = BOUNDS[name]
        if size > bound and len(decoded) > bound:  # bytes within it: characters are too
            raise CdrError(f"{name}: {len(decoded)} characters, more than its bound ({bound})")
        append(decoded)
        pos = stop + (-stop & 3)
    return strings, pos


def write(fields: Mapping[str, Any], layout: tuple[str, ...]) -> bytes:
    """The little-endian CDR of the message of ``layout`` with ``fields`` (``v`` and every
    field of ``layout``): rclpy's bytes, but for the padding, which rclpy leaves as its buffer
    held it and this zeroes. A string is
    written up to its first NUL character, as rclpy writes it. Raises :class:`CdrError` for a
    field beyond its bound (:data:`BOUNDS`, :data:`MAX_MORE`), which no message of section 1
    holds."""
    buf = bytearray(_HEADER)
    buf.append(fields["v"])
    for name in layout:
        value = fields[name]
        if name == SEQUENCE:
            if len(value) > MAX_MORE:
                raise CdrError(f"{SEQUENCE}: {len(value)} strings, more than its bound")
            buf += _PAD[len(buf) & 3]
            buf += _PACK(len(value))
            texts = value
        else:
            texts = (value,)
        bound = BOUNDS[name]
        for text in texts:
            if len(text) > bound:
                raise CdrError(f"{name}: {len(text)} characters, more than its bound ({bound})")
            encoded = text.encode("utf-8")
            if 0 in encoded:
                encoded = encoded[: encoded.index(0)]
            buf += _PAD[len(buf) & 3]
            buf += _PACK(len(encoded) + 1)
            buf += encoded
            buf.append(0)
    return bytes(buf)
