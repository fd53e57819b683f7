"""Wire messages of the KT-BT protocol: query, response and error, versioned pydantic models.

Messages travel as UTF-8 JSON. Whatever a peer sends, :func:`decode` either returns a valid
message or raises :class:`MessageRefused` with a reason a receiver can log; nothing else escapes.
"""

from __future__ import annotations

import uuid
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError

PROTOCOL_VERSION = 1
MAX_MESSAGE_BYTES = 65_536
"""Default size limit of one encoded message; a larger one is refused before decoding."""

_ID = r"^[A-Za-z0-9_.-]{1,64}$"


class _Message(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    v: Literal[1] = 1
    id: str = Field(pattern=_ID, description="Query id; a response or error echoes it.")
    sender: str = Field(pattern=_ID, description="The sending agent's name.")


class Query(_Message):
    """ "Who knows what to do when these conditions hold?" (the paper's s_q)."""

    type: Literal["query"] = "query"
    sequence: str = Field(
        min_length=1,
        max_length=4096,
        description="The condition sequence, in canonical compact stringBT: <c>(A)<c>(!B)...",
    )

    @staticmethod
    def new_id() -> str:
        return uuid.uuid4().hex


class Response(_Message):
    """The answer: the action subtree T_ka for the sequence asked."""

    type: Literal["response"] = "response"
    sequence: str = Field(min_length=1, max_length=4096, description="The sequence answered.")
    subtree: str = Field(
        min_length=1, max_length=60_000, description="The subtree, canonical compact stringBT."
    )


class ErrorReply(_Message):
    """A peer could not process a query (it is malformed, or too large)."""

    type: Literal["error"] = "error"
    code: str = Field(max_length=32)
    message: str = Field(max_length=1024)


Message = Annotated[Query | Response | ErrorReply, Field(discriminator="type")]
_ADAPTER: TypeAdapter[Query | Response | ErrorReply] = TypeAdapter(Message)


class MessageRefused(ValueError):
    """A received message was not accepted; ``reason`` says why, in one line."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


def encode(message: Query | Response | ErrorReply) -> bytes:
    return message.model_dump_json().encode("utf-8")


def decode(data: bytes, max_bytes: int = MAX_MESSAGE_BYTES) -> Query | Response | ErrorReply:
    """Parse and check one received message (size first, then JSON and the schema)."""
    if len(data) > max_bytes:
        raise MessageRefused(f"message of {len(data)} bytes exceeds the limit of {max_bytes}")
    try:
        return _ADAPTER.validate_json(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first.get("loc", ())) or "message"
        raise MessageRefused(f"invalid message: {where}: {first.get('msg', 'invalid')}") from None


def json_schema() -> dict[str, object]:
    """The JSON Schema of a message (``spec/schemas/message.json``)."""
    return _ADAPTER.json_schema()


def schema_text() -> str:
    """What ``spec/schemas/message.json`` holds (a test keeps the file equal to it)."""
    import json

    return json.dumps(json_schema(), indent=2, sort_keys=True) + "\n"
