"""Wire messages: round trips, and nothing but MessageRefused for whatever a peer sends."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from ktbt_proto.exchange.answers import TEMPLATE_ID, answer_to, encoded_answer
from ktbt_proto.exchange.messages import (
    MAX_MESSAGE_BYTES,
    ErrorReply,
    MessageRefused,
    Query,
    Response,
    decode,
    decode_fields,
    decode_learned,
    encode,
    encode_learned,
)
from ktbt_proto.exchange.signing import Identity, SignedItem

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
    """spec/vectors/messages.json: queries naming one sequence or several (section 1), read
    from their text and, as the ROS 2 binding reads them, from their fields (section 11)."""
    data = json.dumps(vector["message"]).encode()
    if not vector["valid"]:
        with pytest.raises(MessageRefused):
            decode(data)
        if isinstance(vector["message"], dict):
            with pytest.raises(MessageRefused):
                decode_fields(vector["message"])
        return
    message = decode(data)
    assert decode_fields(vector["message"]) == message
    if "asks" in vector:
        assert isinstance(message, Query) and list(message.sequences) == vector["asks"]
        assert json.loads(encode(message)) == vector["message"]


def test_a_query_names_at_most_64_sequences_each_once() -> None:
    keys = [f"<c>(S{i})" for i in range(65)]
    assert Query.asking("r", keys[:64]).sequences == tuple(keys[:64])
    assert Query.asking("r", ["<c>(A)", "<c>(A)", "<c>(B)"]).sequences == ("<c>(A)", "<c>(B)")
    with pytest.raises(ValueError):
        Query.asking("r", keys)


_TEXT = st.text(max_size=40) | st.sampled_from(["q1", "r2", "<c>(A)", "<a>(B)", "x" * 43])
_KEYS = ["v", "type", "id", "sender", "sequence", "more", "subtree", "author", "signature"]
_KEYS += ["key", "hop", "code", "message", "extra"]
_FIELDS = st.dictionaries(
    st.sampled_from(_KEYS),
    st.integers(0, 255)
    | st.sampled_from(["query", "response", "error"])
    | _TEXT
    | st.lists(_TEXT, max_size=3),
)


@settings(max_examples=400, deadline=None)
@given(_FIELDS, st.sampled_from([64, 200, MAX_MESSAGE_BYTES]))
def test_a_message_read_from_its_fields_is_judged_as_its_text(
    fields: dict[str, Any], max_bytes: int
) -> None:
    """What a ROS message's fields can hold (strings, a byte-sized ``v``, a list of strings),
    read by ``decode_fields``, gets the verdict its JSON text gets from ``decode``: the same
    message, or a refusal (section 11)."""
    data = json.dumps(fields, ensure_ascii=False).encode("utf-8")
    try:
        expected: Query | Response | ErrorReply | str = decode(data, max_bytes)
    except MessageRefused as refused:
        expected = refused.reason
    try:
        got: Query | Response | ErrorReply | str = decode_fields(fields, max_bytes)
    except MessageRefused as refused:
        got = refused.reason
    assert type(got) is type(expected)
    if not isinstance(expected, str):
        assert got == expected


def test_a_message_read_from_its_fields_is_refused_by_the_size_of_its_text() -> None:
    """The size limit is the JSON text's, whatever the fields' own lengths: control characters
    take six bytes each there."""
    fields = {"v": 1, "type": "query", "id": "q1", "sender": "r1", "sequence": "\x01" * 4000}
    assert len(json.dumps(fields).encode()) > 20_000
    with pytest.raises(MessageRefused, match="exceeds the limit"):
        decode_fields(fields, 20_000)
    assert isinstance(decode_fields(fields, 30_000), Query)


_IDS = st.from_regex(r"[A-Za-z0-9_.-]{1,64}", fullmatch=True)
_TEXT = st.text(min_size=1, max_size=40)


@settings(max_examples=200, deadline=None)
@given(_IDS, _TEXT, _TEXT, st.booleans())
def test_an_answer_made_once_is_the_answer_encoded_for_every_id(
    id: str, sequence: str, subtree: str, signed: bool
) -> None:
    """A server without a key pair gives the query's id to bytes made once per item
    (``encoded_answer``): exactly what the response built and encoded for that id would be, a
    sequence or subtree holding quotes, escapes, non-ASCII or the template's own id included."""
    author = Identity.generate() if signed else None
    subtree += f'"{TEMPLATE_ID}"' if len(subtree) % 2 else TEMPLATE_ID
    item = author.sign_item(sequence, subtree) if author is not None else SignedItem(subtree)
    head, tail = encoded_answer("teacher", sequence, item)
    query = Query(id=id, sender="learner", sequence=sequence)
    assert head + id.encode() + tail == encode(answer_to(query, "teacher", item, None))
    assert decode(head + id.encode() + tail) == answer_to(query, "teacher", item, None)


def test_an_answer_too_large_to_send_is_not_made() -> None:
    with pytest.raises(ValidationError):
        encoded_answer("teacher", "<c>(A)", SignedItem("<a>(" + "\u2028" * 59_990 + ")"))


LEARNED = VECTORS.with_name("learned.json")


@pytest.mark.parametrize("vector", json.loads(LEARNED.read_text()), ids=lambda v: str(v["name"]))
def test_announcement_vectors(vector: dict[str, Any]) -> None:
    """spec/vectors/learned.json: an announcement of what a peer learned (section 3) is a JSON
    array of 1 to 64 distinct sequences; anything else is refused."""
    data = vector["payload"].encode()
    if not vector["valid"]:
        with pytest.raises(MessageRefused):
            decode_learned(data)
        return
    assert list(decode_learned(data)) == vector["sequences"]
    assert decode_learned(encode_learned(vector["sequences"])) == decode_learned(data)


def test_an_announcement_larger_than_a_message_is_refused_before_it_is_read() -> None:
    with pytest.raises(MessageRefused, match="exceeds the limit"):
        decode_learned(b'["<c>(A)"' + b" " * MAX_MESSAGE_BYTES + b"]")
