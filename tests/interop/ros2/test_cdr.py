"""The protocol's ROS messages read and written without rclpy's message objects
(``ktbt_proto.transport.cdr``, spec/protocol.md section 11), held to rclpy's own serializer:
every message written reads back equal through rclpy and is as long as rclpy's; what is
read, from rclpy's bytes or from corrupted ones, rclpy reads the same, and what rclpy cannot
read is refused. These tests serialize with rclpy and start no ROS node."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ktbt_proto.transport import cdr

pytestmark = [pytest.mark.usefixtures("ros2_built"), pytest.mark.slow]

_TEXT = st.text(max_size=12) | st.text(st.characters(codec="utf-8"), max_size=12)
_LAYOUTS = {"Query": cdr.QUERY, "Answer": cdr.ANSWER, "ErrorReply": cdr.ERROR}


def _ros_type(name: str) -> Any:
    import ktbt_interfaces.msg as msgs

    return getattr(msgs, name)


@st.composite
def messages(draw: st.DrawFn) -> tuple[str, dict[str, Any]]:
    """A message type and fields a ROS message of it can hold (no NUL: rclpy cuts a string at
    its first, and so does :func:`cdr.write`, tested apart)."""
    name = draw(st.sampled_from(sorted(_LAYOUTS)))
    text = _TEXT.map(lambda t: t.replace("\x00", ""))
    fields: dict[str, Any] = {"v": draw(st.integers(0, 255))}
    for field in _LAYOUTS[name]:
        fields[field] = draw(st.lists(text, max_size=4)) if field == cdr.SEQUENCE else draw(text)
    return name, fields


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages())
def test_what_is_written_is_what_rclpy_writes_and_reads_back(
    message: tuple[str, dict[str, Any]],
) -> None:
    from rclpy.serialization import deserialize_message, serialize_message

    name, fields = message
    kind, layout = _ros_type(name), _LAYOUTS[name]
    written = cdr.write(fields, layout)
    assert deserialize_message(written, kind) == kind(**fields)
    assert cdr.read(written, layout) == fields
    # rclpy's padding bytes are whatever its buffer held: the same bytes elsewhere
    ours, theirs = cdr.read(serialize_message(kind(**fields)), layout), fields
    assert ours == theirs
    assert len(serialize_message(kind(**fields))) == len(written)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages(), st.data())
def test_corrupted_bytes_are_read_as_rclpy_reads_them_or_refused(
    message: tuple[str, dict[str, Any]], data: st.DataObject
) -> None:
    from rclpy.serialization import deserialize_message

    name, fields = message
    kind, layout = _ros_type(name), _LAYOUTS[name]
    written = bytearray(cdr.write(fields, layout))
    for _ in range(data.draw(st.integers(1, 4))):
        at = data.draw(st.integers(0, len(written) - 1))
        written[at] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):
        written = written[: data.draw(st.integers(0, len(written)))]
    try:
        ours = cdr.read(bytes(written), layout)
    except cdr.CdrError as refused:
        assert str(refused) and "\n" not in str(refused)
        return
    theirs = deserialize_message(bytes(written), kind)
    assert ours == {"v": theirs.v, **{f: getattr(theirs, f) for f in layout}}


def test_a_string_is_written_and_read_up_to_its_first_nul_as_rclpy_does() -> None:
    from rclpy.serialization import deserialize_message

    fields = {"v": 1, "id": "0", "sender": "a", "to": "", "code": "c", "message": "x\x00y"}
    written = cdr.write(fields, cdr.ERROR)
    assert deserialize_message(written, _ros_type("ErrorReply")).message == "x"
    assert cdr.read(written, cdr.ERROR)["message"] == "x"
    # A NUL inside a string's bytes (another writer's, or a hostile one's), and what follows
    # it not even UTF-8: rclpy reads up to the NUL, and so does this.
    inner = (
        b"\x00\x01\x00\x00\x01\x00\x00\x00"
        + b"".join(
            len(t).to_bytes(4, "little") + t + b"\x00" * (-len(t) % 4)
            for t in (b"q1\x00", b"r1\x00", b"x\x00\xff\xfe\x00")
        )
        + (0).to_bytes(4, "little")
    )
    theirs = deserialize_message(inner, _ros_type("Query"))
    assert cdr.read(inner, cdr.QUERY) == {
        "v": 1, "id": "q1", "sender": "r1", "sequence": theirs.sequence, "more": []
    }  # fmt: skip
    assert theirs.sequence == "x"


@pytest.mark.parametrize(
    ("data", "why"),
    [
        (b"", "plain CDR"),
        (b"\x00\x07\x00\x00\x01\x00\x00\x00", "plain CDR"),  # XCDR2: refused
        (b"\x00\x01\x00\x00\x01\x00\x00\x00", "ends"),
        (b"\x00\x01\x00\x00\x01\x00\x00\x00\xff\xff\xff\x7f", "does not hold"),
    ],
)
def test_what_is_not_a_message_is_refused_with_its_reason(data: bytes, why: str) -> None:
    with pytest.raises(cdr.CdrError, match=why):
        cdr.read(data, cdr.ANSWER)


def test_big_endian_data_is_read() -> None:
    written = (
        b"\x00\x00\x00\x00\x01\x00\x00\x00"
        + b"".join(
            len(t + b"\x00").to_bytes(4, "big") + t + b"\x00" + b"\x00" * (-(len(t) + 1) % 4)
            for t in (b"q1", b"r1", b"<c>(A)")
        )
        + (0).to_bytes(4, "big")
    )
    assert cdr.read(written, cdr.QUERY) == {
        "v": 1, "id": "q1", "sender": "r1", "sequence": "<c>(A)", "more": []
    }  # fmt: skip


@pytest.mark.parametrize("name", sorted(_LAYOUTS))
def test_a_field_beyond_its_bound_is_refused_though_rclpy_reads_it(name: str) -> None:
    """A bound (``string<=64 id``) does not change the bytes, and rclpy does not check it when
    it reads: this does, in characters, for every string field; at the bound, of characters
    that take two bytes each, it reads the field."""
    from rclpy.serialization import deserialize_message, serialize_message

    kind, layout = _ros_type(name), _LAYOUTS[name]
    base: dict[str, Any] = {"v": 1, **{f: [] if f == cdr.SEQUENCE else "" for f in layout}}
    for field in layout:
        bound = cdr.BOUNDS[field]
        for text, refused in (("é" * bound, False), ("x" * (bound + 1), True)):
            value = [text] if field == cdr.SEQUENCE else text
            data = serialize_message(kind(**{**base, field: value}))
            assert getattr(deserialize_message(data, kind), field) == value  # rclpy reads it
            if refused:
                with pytest.raises(cdr.CdrError, match=rf"^{field}: {bound + 1} characters, "):
                    cdr.read(data, layout)
                with pytest.raises(cdr.CdrError, match="bound"):
                    cdr.write({**base, field: value}, layout)
            else:
                assert cdr.read(data, layout)[field] == value
                written = cdr.write({**base, field: value}, layout)  # padding zeroed
                assert deserialize_message(written, kind) == kind(**{**base, field: value})
                assert len(written) == len(data)


def test_more_beyond_its_bound_is_refused() -> None:
    """``more`` is ``string<=4096[<=63]``: 63 strings are read, 64 refused (rclpy reads them,
    though it refuses to write them)."""
    from rclpy.serialization import deserialize_message

    def query(count: int) -> bytes:
        fields = {"v": 1, "id": "q1", "sender": "r1", "sequence": "<c>(A)", "more": []}
        head = cdr.write(fields, cdr.QUERY)[:-4]  # all but the empty sequence's count
        more = b"".join(
            (len(t) + 1).to_bytes(4, "little") + t + b"\x00" * (1 + -(len(t) + 1) % 4)
            for t in (b"<c>(B%02d)" % i for i in range(count))
        )
        return head + count.to_bytes(4, "little") + more

    assert len(cdr.read(query(cdr.MAX_MORE), cdr.QUERY)["more"]) == cdr.MAX_MORE
    assert len(deserialize_message(query(64), _ros_type("Query")).more) == 64
    with pytest.raises(cdr.CdrError, match=r"^more: 64 strings, more than its bound \(63\)"):
        cdr.read(query(64), cdr.QUERY)
