"""Wire messages: round trips, and nothing but MessageRefused for whatever a peer sends."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ktbt_proto.exchange.messages import ErrorReply, MessageRefused, Query, Response, decode, encode

QUERY = Query(id="q1", sender="r1", sequence="<c>(A)")


@pytest.mark.parametrize(
    "message",
    [
        QUERY,
        Response(id="q1", sender="r2", sequence="<c>(A)", subtree="<a>(B)"),
        ErrorReply(id="q1", sender="r2", code="refused", message="bad"),
    ],
)
def test_round_trip(message: Query | Response | ErrorReply) -> None:
    assert decode(encode(message)) == message


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b"", "invalid message"),
        (b"\xff\xfe", "invalid message"),
        (b"[]", "invalid message"),
        (json.dumps({**json.loads(encode(QUERY)), "v": 2}).encode(), "v"),
        (json.dumps({**json.loads(encode(QUERY)), "extra": 1}).encode(), "extra"),
        (json.dumps({**json.loads(encode(QUERY)), "sender": "a b"}).encode(), "sender"),
        (json.dumps({**json.loads(encode(QUERY)), "sequence": ""}).encode(), "sequence"),
        (json.dumps({**json.loads(encode(QUERY)), "type": "teach"}).encode(), "invalid"),
        (b"{" * 100_000, "exceeds the limit"),
    ],
)
def test_refusals_say_why(payload: bytes, reason: str) -> None:
    with pytest.raises(MessageRefused) as info:
        decode(payload)
    assert reason in info.value.reason


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300) | st.text(max_size=300).map(str.encode))
def test_garbage_is_only_ever_refused(payload: bytes) -> None:
    """Whatever arrives is a message (which reads back as itself) or a refusal in one short
    line; never another exception."""
    try:
        message = decode(payload)
    except MessageRefused as refused:
        # spec/protocol.md section 1: a refusal reason is one line of at most 200 characters
        assert refused.reason and "\n" not in refused.reason and len(refused.reason) <= 200
    else:
        assert decode(encode(message)) == message


VECTORS = Path(__file__).resolve().parents[2] / "spec" / "vectors" / "messages.json"


@pytest.mark.parametrize("vector", json.loads(VECTORS.read_text()), ids=lambda v: str(v["name"]))
def test_message_vectors(vector: dict[str, Any]) -> None:
    """spec/vectors/messages.json: queries naming one sequence or several (section 1)."""
    data = json.dumps(vector["message"]).encode()
    if not vector["valid"]:
        with pytest.raises(MessageRefused):
            decode(data)
        return
    message = decode(data)
    if "asks" in vector:
        assert isinstance(message, Query) and list(message.sequences) == vector["asks"]
        assert json.loads(encode(message)) == vector["message"]


def test_a_query_names_at_most_64_sequences_each_once() -> None:
    keys = [f"<c>(S{i})" for i in range(65)]
    assert Query.asking("r", keys[:64]).sequences == tuple(keys[:64])
    assert Query.asking("r", ["<c>(A)", "<c>(A)", "<c>(B)"]).sequences == ("<c>(A)", "<c>(B)")
    with pytest.raises(ValueError):
        Query.asking("r", keys)
