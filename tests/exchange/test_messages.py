"""Wire messages: round trips, and nothing but MessageRefused for whatever a peer sends."""

from __future__ import annotations

import json

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
