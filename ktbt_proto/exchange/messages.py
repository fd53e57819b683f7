"""Wire messages of the KT-BT protocol: query, response and error, versioned pydantic models.

Messages travel as UTF-8 JSON. Whatever a peer sends, :func:`decode` either returns a valid
message or raises :class:`MessageRefused` with a reason a receiver can log; nothing else escapes.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    TypeAdapter,
    ValidationError,
    ValidationInfo,
    model_validator,
)

from ktbt_proto.exchange.refusals import fault, internal_error

PROTOCOL_VERSION = 1
MAX_MESSAGE_BYTES = 65_536
"""Default size limit of one encoded message; a larger one is refused before decoding."""

MAX_REASON = 200
"""A refusal reason is clipped to this many characters, so that it always fits an error reply."""

_ENVELOPE = 512
"""More than a response's JSON takes besides its strings (names, quotes, the two keys)."""
NAME_PATTERN = r"^[A-Za-z0-9_.-]{1,64}$"
KEY_PATTERN = r"^[A-Za-z0-9_-]{43}$"
SIGNATURE_PATTERN = r"^[A-Za-z0-9_-]{86}$"
WIRE = {"wire": True}


def require_version_and_type(schema: dict[str, Any]) -> None:
    """On the wire ``v`` and ``type`` are required (spec section 1); in code they default."""
    required = schema.setdefault("required", [])
    for name in ("type", "v"):
        if name not in required:
            required.insert(0, name)


class _Message(BaseModel):
    model_config = ConfigDict(
        extra="forbid", frozen=True, json_schema_extra=require_version_and_type
    )

    v: Literal[1] = Field(default=1, description="Protocol version (the integer 1).")
    id: str = Field(pattern=NAME_PATTERN, description="Query id; a response or error echoes it.")
    sender: str = Field(pattern=NAME_PATTERN, description="The sending agent's name.")

    @model_validator(mode="before")
    @classmethod
    def _wire_fields(cls, data: Any, info: ValidationInfo) -> Any:
        return wire_fields(data, info)


def wire_fields(data: Any, info: ValidationInfo) -> Any:
    """Received (``context=WIRE``), a message names ``v``; ``v`` is never a boolean."""
    if isinstance(data, dict):
        if info.context == WIRE and "v" not in data:
            raise ValueError("a message names its protocol version 'v'")
        if not isinstance(data.get("v", 1), int) or isinstance(data.get("v"), bool):
            raise ValueError("'v' must be the integer 1")  # true == 1 in Python, not here
    return data


MAX_MORE = 63
"""Further sequences one query may name (``more``), so that a query asks for 64 at most."""


class Query(_Message):
    """ "Who knows what to do when these conditions hold?" (the paper's s_q).

    One query may ask for several sequences (spec/protocol.md section 1): ``sequence``, then
    ``more``, each distinct; a peer answers each one it knows with a response of its own
    (same ``id``, that ``sequence``). A query without ``more`` is the single-sequence query of
    every earlier peer, and is answered exactly as before."""

    type: Literal["query"] = "query"
    sequence: str = Field(
        min_length=1,
        max_length=4096,
        description="The condition sequence, in canonical compact stringBT: <c>(A)<c>(!B)...",
    )
    more: tuple[Annotated[str, Field(min_length=1, max_length=4096)], ...] | None = Field(
        default=None,
        min_length=1,
        max_length=MAX_MORE,
        description="Further sequences asked in the same query, each distinct (section 1).",
    )

    @model_validator(mode="after")
    def _distinct(self) -> Query:
        if self.more is not None and len(set(self.more) | {self.sequence}) != 1 + len(self.more):
            raise ValueError("a query names each sequence once")
        return self

    @property
    def sequences(self) -> tuple[str, ...]:
        """Every sequence this query asks for, ``sequence`` first."""
        return (self.sequence, *(self.more or ()))

    @classmethod
    def asking(cls, sender: str, sequences: Sequence[str]) -> Query:
        """A new query (a fresh id) for ``sequences``, in canonical form, distinct, at most
        ``1 + MAX_MORE`` of them: one query, however many are missing (section 1)."""
        first, *rest = dict.fromkeys(sequences)
        return cls(id=cls.new_id(), sender=sender, sequence=first, more=tuple(rest) or None)

    @staticmethod
    def new_id() -> str:
        """32 random hex digits (as a UUID's, without its slow formatting)."""
        return os.urandom(16).hex()


class Response(_Message):
    """The answer: the action subtree T_ka for the sequence asked.

    The optional fields carry signed provenance (spec section 7): ``author`` and ``signature``
    sign the knowledge item itself and travel with it when a learner teaches it onward;
    ``key`` and ``hop`` sign this one message, binding ``sender`` and ``id`` to the sending
    peer's key. A response never encodes to more than :data:`MAX_MESSAGE_BYTES`, so that no
    peer builds an answer every receiver would refuse."""

    type: Literal["response"] = "response"
    sequence: str = Field(min_length=1, max_length=4096, description="The sequence answered.")
    subtree: str = Field(
        min_length=1, max_length=60_000, description="The subtree, canonical compact stringBT."
    )
    author: str | None = Field(
        default=None, pattern=KEY_PATTERN, description="The item's author: an Ed25519 public key."
    )
    signature: str | None = Field(
        default=None, pattern=SIGNATURE_PATTERN, description="The author's signature of the item."
    )
    key: str | None = Field(
        default=None, pattern=KEY_PATTERN, description="The sending peer's Ed25519 public key."
    )
    hop: str | None = Field(
        default=None,
        pattern=SIGNATURE_PATTERN,
        description="The sending peer's signature of this reply.",
    )

    @classmethod
    def of(
        cls,
        id: str,
        sender: str,
        sequence: str,
        subtree: str,
        author: str | None = None,
        signature: str | None = None,
    ) -> Response:
        """An answer built by a teacher for every query it answers, validated as any
        response is: pydantic's validation, in its compiled core, takes less time than
        ``model_construct``, in Python (2.9 against 4.5 µs, ``benchmarks/bench_transfer.py``),
        and the size check encodes only an answer that could be too large. Absent provenance
        is left out rather than validated as None."""
        if author is None and signature is None:
            return cls(id=id, sender=sender, sequence=sequence, subtree=subtree)
        return cls(
            id=id,
            sender=sender,
            sequence=sequence,
            subtree=subtree,
            author=author,
            signature=signature,
        )

    @model_validator(mode="after")
    def _fits_a_message(self) -> Response:
        if (self.author is None) != (self.signature is None):
            raise ValueError("author and signature come together")
        if (self.key is None) != (self.hop is None):
            raise ValueError("key and hop come together")
        text = (self.id, self.sender, self.sequence, self.subtree, self.author, self.signature)
        if _ENVELOPE + 6 * sum(len(t) for t in text if t is not None) <= MAX_MESSAGE_BYTES:
            return self  # a character encodes to 6 bytes at most: it fits, no need to encode
        size = len(self.model_dump_json(exclude_none=True).encode("utf-8"))
        if size > MAX_MESSAGE_BYTES:
            raise ValueError(
                f"encodes to {size} bytes, more than a message may ({MAX_MESSAGE_BYTES})"
            )
        return self


class ErrorReply(_Message):
    """A peer could not process a query (it is malformed, or too large)."""

    type: Literal["error"] = "error"
    code: str = Field(max_length=32)
    message: str = Field(max_length=1024)


Message = Annotated[Query | Response | ErrorReply, Field(discriminator="type")]
_ADAPTER: TypeAdapter[Query | Response | ErrorReply] = TypeAdapter(Message)


class MessageRefused(ValueError):
    """A received message was not accepted; ``reason`` says why, in one line of at most
    :data:`MAX_REASON` characters (a peer's junk is not echoed at length)."""

    def __init__(self, reason: str) -> None:
        reason = " ".join(reason.split())
        if len(reason) > MAX_REASON:
            reason = reason[: MAX_REASON - 3] + "..."
        super().__init__(reason)
        self.reason = reason


def encode(message: Query | Response | ErrorReply) -> bytes:
    """The message as UTF-8 JSON; optional fields left out when absent."""
    return message.model_dump_json(exclude_none=True).encode("utf-8")


def decode(data: bytes, max_bytes: int = MAX_MESSAGE_BYTES) -> Query | Response | ErrorReply:
    """Parse and check one received message (size first, then JSON and the schema)."""
    _check_size(len(data), max_bytes)
    try:
        fault("message", data)
        return _ADAPTER.validate_json(data, context=WIRE)
    except ValidationError as exc:
        raise _refused(exc) from None
    except Exception as exc:  # a reader's own failure is a refusal too (section 2.1)
        raise MessageRefused(internal_error(exc)) from exc


def decode_fields(
    fields: Mapping[str, Any], max_bytes: int = MAX_MESSAGE_BYTES
) -> Query | Response | ErrorReply:
    """:func:`decode` for a message a binding has read field by field (the ROS 2 binding,
    spec/protocol.md section 11): ``fields`` is the JSON object the message is, checked as
    :func:`decode` checks its text (size, schema, ``v``) without the text being made. Its size
    is that of the JSON it encodes to, computed only when it could exceed ``max_bytes``: a
    character encodes to 6 bytes at most. Raises :class:`MessageRefused`, and ``UnicodeError``
    for a string UTF-8 cannot carry."""
    chars = 0
    for value in fields.values():
        if isinstance(value, str):
            chars += len(value)
        elif isinstance(value, list | tuple):
            chars += sum(len(v) + 3 for v in value if isinstance(v, str))
    if _ENVELOPE + 6 * chars > max_bytes:
        _check_size(len(json.dumps(fields, ensure_ascii=False).encode("utf-8")), max_bytes)
    try:
        fault("message", fields)
        return _ADAPTER.validate_python(fields, context=WIRE)
    except ValidationError as exc:
        raise _refused(exc) from None
    except Exception as exc:  # a reader's own failure is a refusal too (section 2.1)
        raise MessageRefused(internal_error(exc)) from exc


def _check_size(size: int, max_bytes: int) -> None:
    if size > max_bytes:
        raise MessageRefused(f"message of {size} bytes exceeds the limit of {max_bytes}")


def _refused(exc: ValidationError) -> MessageRefused:
    first = exc.errors()[0]
    where = ".".join(str(p) for p in first.get("loc", ())) or "message"
    return MessageRefused(f"invalid message: {where}: {first.get('msg', 'invalid')}")


def json_schema() -> dict[str, object]:
    """The JSON Schema of a message (``spec/schemas/message.json``)."""
    return _ADAPTER.json_schema()


def schema_text() -> str:
    """What ``spec/schemas/message.json`` holds (a test keeps the file equal to it)."""
    import json

    return json.dumps(json_schema(), indent=2, sort_keys=True) + "\n"


Learned = Annotated[
    tuple[Annotated[str, Field(min_length=1, max_length=4096)], ...],
    Field(min_length=1, max_length=1 + MAX_MORE),
]
"""An announcement of what a peer just learned (spec/protocol.md section 3): the sequences of
one merge, in canonical compact stringBT, 1 to 64, each named once."""
_LEARNED: TypeAdapter[tuple[str, ...]] = TypeAdapter(Learned)


def encode_learned(sequences: Sequence[str]) -> bytes:
    """The announcement of ``sequences`` (at most 64, each once), as a JSON array."""
    return json.dumps(list(dict.fromkeys(sequences))[: 1 + MAX_MORE]).encode("utf-8")


def decode_learned(data: bytes, max_bytes: int = MAX_MESSAGE_BYTES) -> tuple[str, ...]:
    """The sequences an announcement names (section 3), checked as a message is: size first,
    then a JSON array of 1 to 64 distinct sequences of 1 to 4,096 characters. Raises only
    :class:`MessageRefused`."""
    _check_size(len(data), max_bytes)
    try:
        fault("message", data)
        sequences = _LEARNED.validate_json(data, strict=True)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first.get("loc", ())) or "announcement"
        raise MessageRefused(
            f"invalid announcement: {where}: {first.get('msg', 'invalid')}"
        ) from None
    except Exception as exc:  # a reader's own failure is a refusal too (section 2.1)
        raise MessageRefused(internal_error(exc)) from exc
    if len(set(sequences)) != len(sequences):
        raise MessageRefused("invalid announcement: a sequence named twice")
    return sequences
