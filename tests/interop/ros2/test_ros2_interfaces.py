"""The ROS 2 interfaces carry the protocol exactly (spec/protocol.md section 11): a signed
answer and a signed fleet event go through their ROS messages, serialized as DDS sends them,
and come back equal, their signatures verifying from the fields alone; the build is cached;
the project still imports lark 1.x after the ROS wheels. These tests serialize messages with
rclpy and start no ROS node, so no DDS participant discovers anything: the tests that start
nodes run them in a network namespace of their own (``rosns.RosNamespace``)."""

from __future__ import annotations

import json
import platform
import sysconfig
from pathlib import Path
from typing import Any

import pytest

from ktbt_proto.exchange.events import EventPublisher, decode_event
from ktbt_proto.exchange.messages import ErrorReply, Query, Response, decode_fields, encode
from ktbt_proto.exchange.signing import Identity, hop_bytes, item_bytes, verify
from ktbt_proto.tools.ros2 import interfaces
from tests.interop.ros2.rosns import SEQUENCE, SUBTREE

# The tests that use ROS are slow: the first in an environment builds the interfaces.


def through_dds(msg: Any) -> Any:
    """``msg`` serialized as DDS sends it and read back."""
    from rclpy.serialization import deserialize_message, serialize_message

    return deserialize_message(serialize_message(msg), type(msg))


def read_back(message: Query | Response | ErrorReply, to: str) -> dict[str, Any]:
    """The ROS message for ``message`` serialized by rclpy, as DDS carries it, and read back as
    a robot reads it (its fields, by ``cdr``)."""
    from rclpy.serialization import serialize_message

    from ktbt_proto.transport import cdr
    from ktbt_proto.transport.ros2 import to_msg

    layout = {Query: cdr.QUERY, Response: cdr.ANSWER, ErrorReply: cdr.ERROR}[type(message)]
    return cdr.read(serialize_message(to_msg(message, to)), layout)


@pytest.mark.usefixtures("ros2_built")
@pytest.mark.slow
def test_a_signed_answer_survives_its_ros_message_and_its_signatures_verify() -> None:
    from ktbt_proto.transport.ros2 import wire_fields

    author, sender = Identity.generate(), Identity.generate()
    item = author.sign_item(SEQUENCE, SUBTREE)
    sent = sender.sign_reply(
        Response.of("q1", "teacher", SEQUENCE, item.subtree, item.author, item.signature)
    )
    fields = read_back(sent, "learner")
    assert fields["to"] == "learner"
    assert wire_fields(fields, "response") == json.loads(encode(sent))
    received = decode_fields(wire_fields(fields, "response"))
    assert received == sent
    assert isinstance(received, Response)
    assert verify(author.public, received.signature or "", item_bytes(SEQUENCE, received.subtree))
    assert verify(sender.public, received.hop or "", hop_bytes(received.model_copy(
        update={"key": None, "hop": None})))  # fmt: skip


@pytest.mark.usefixtures("ros2_built")
@pytest.mark.slow
def test_an_unsigned_answer_a_query_and_an_error_survive_theirs() -> None:
    from ktbt_proto.transport.ros2 import wire_fields

    for message, kind in (
        (Response.of("q1", "teacher", SEQUENCE, SUBTREE), "response"),
        (Query(id="q1", sender="learner", sequence=SEQUENCE), "query"),
        (ErrorReply(id="0", sender="teacher", code="refused", message="malformed"), "error"),
    ):
        fields = wire_fields(read_back(message, "x"), kind)
        assert fields == json.loads(encode(message))  # the JSON form, field for field
        assert decode_fields(fields) == message


@pytest.mark.usefixtures("ros2_built")
@pytest.mark.slow
def test_a_signed_fleet_event_survives_its_ros_message() -> None:
    from ktbt_proto.interop.ros2.showing import event_json, event_msg

    identity = Identity.generate()
    sent: list[bytes] = []
    publisher = EventPublisher("learner", sent.append, identity)
    publisher({"t": "2026-12-01T21:00:00.125+00:00", "event": "merged", "sequence": SEQUENCE,
               "teacher": "teacher", "tick": 0})  # fmt: skip
    publisher({"t": "2026-12-01T21:00:01.000+00:00", "event": "refused", "reason": "junk",
               "where": "transport"})  # fmt: skip
    publisher({"t": "2026-12-01T21:00:02.000+00:00", "event": "refused", "reason": "junk",
               "where": "transport", "key": "/ktbt/answers"})  # fmt: skip
    for data in sent:
        msg = through_dds(event_msg(data))
        assert decode_event(event_json(msg)) == decode_event(data)  # the signature verified
    assert through_dds(event_msg(sent[1])).tick == -1
    # section 10's `on` is `refused_on` in the message: `on` is a YAML 1.1 boolean
    assert through_dds(event_msg(sent[2])).refused_on == "/ktbt/answers"


@pytest.mark.usefixtures("ros2_built")
@pytest.mark.slow
def test_the_constants_of_the_interfaces_are_the_protocols_words() -> None:
    from ktbt_interfaces.msg import Catalog, FleetEvent
    from ktbt_interfaces.msg import ErrorReply as ErrorMsg
    from ktbt_interfaces.msg import Query as QueryMsg
    from ktbt_interfaces.srv import Forget

    from ktbt_proto.exchange.events import MAX_SEQUENCE
    from ktbt_proto.exchange.messages import MAX_MORE
    from ktbt_proto.exchange.transferlog import Event
    from ktbt_proto.interop.ros2.showing import MAX_ENTRIES
    from ktbt_proto.transport import cdr

    for kind in Event:  # every kind of section 8, under its name
        assert getattr(FleetEvent, kind.name) == kind.value
    assert FleetEvent.WHERE_TRANSPORT == "transport"
    assert (ErrorMsg.REFUSED, ErrorMsg.UNREAD_ID) == ("refused", "0")
    assert QueryMsg.MAX_MORE == cdr.MAX_MORE == MAX_MORE
    assert Catalog.MAX_ITEMS == MAX_ENTRIES
    fields = FleetEvent.get_fields_and_field_types()
    assert "on" not in fields and fields["sequence"] == f"string<{MAX_SEQUENCE}>"
    for layout, kind in ((cdr.QUERY, QueryMsg), (cdr.ERROR, ErrorMsg)):
        declared = kind.get_fields_and_field_types()
        for name in layout:  # cdr's bounds are the .msg files'
            assert f"string<{cdr.BOUNDS[name]}>" in declared[name], (name, declared[name])
    codes = (Forget.Response.FORGOTTEN, Forget.Response.NOT_KNOWN, Forget.Response.INNATE,
             Forget.Response.INVALID)  # fmt: skip
    assert len(set(codes)) == 4


@pytest.mark.usefixtures("ros2_built")
@pytest.mark.slow
def test_a_catalog_entry_carries_its_time_and_keeps_to_its_bounds() -> None:
    from ktbt_interfaces.msg import Catalog

    from ktbt_proto.interop.ros2.showing import catalog_entries, entry_fields

    learned = {"sequence": SEQUENCE, "author": "a" * 43, "teacher": "teacher",
               "received_at": "2026-12-01T17:28:54+00:00"}  # fmt: skip
    entries = catalog_entries([learned, "<c>(Innate)"])
    assert entries[0].received_at.sec == 1796146134 and entries[0].received_at.nanosec == 0
    msg = through_dds(Catalog(peer="r1", items=entries))
    assert [entry_fields(e) for e in msg.items] == [learned, {"sequence": "<c>(Innate)"}]
    # A zenoh peer's junk, relayed by the bridge: a field beyond its bound, or no text, is left
    # out; a time that is no ISO 8601, or beyond what Time holds (2038), is unknown.
    junk: list[str | dict[str, Any]] = [
        {"sequence": "x" * 4097},
        {"sequence": 5},
        {"sequence": "<c>(A)", "teacher": "t" * 65, "author": 7, "received_at": "yesterday"},
        {"sequence": "<c>(B)", "received_at": "2100-01-01T00:00:00+00:00"},
        {"sequence": "<c>(C)", "received_at": "0001-01-01T00:00:00+01:00"},
    ]
    assert [entry_fields(e) for e in catalog_entries(junk)] == [
        {"sequence": "<c>(A)"}, {"sequence": "<c>(B)"}, {"sequence": "<c>(C)"}
    ]  # fmt: skip
    # At most Catalog.MAX_ITEMS (rclpy refuses to publish more); a service's answer, all.
    many = [f"<c>(A{i})" for i in range(Catalog.MAX_ITEMS + 5)]
    assert len(catalog_entries(many)) == Catalog.MAX_ITEMS
    assert len(catalog_entries(many, None)) == Catalog.MAX_ITEMS + 5


@pytest.mark.usefixtures("ros2_built")
@pytest.mark.slow
def test_a_relative_topic_is_refused_with_one_line() -> None:
    from ktbt_proto.transport.ros2 import Topics

    with pytest.raises(ValueError, match=r"topic queries 'ktbt/queries': use an absolute name"):
        Topics(queries="ktbt/queries")


@pytest.mark.usefixtures("ros2_built")
@pytest.mark.slow
def test_the_build_is_cached_and_lark_is_1x_after_the_ros_install() -> None:
    said: list[str] = []
    if interfaces.system_ros() is None:
        assert interfaces.build(said.append) is False  # built by the fixture: up to date
        assert not any("building" in line for line in said)
        site = Path(sysconfig.get_paths()["purelib"])
        # Both packages built; the docking action is the example's, not the protocol's (and a
        # build removes what an earlier one installed: no action left behind).
        assert (site / "ktbt_example_interfaces" / "action" / "__init__.py").is_file()
        assert not (site / "ktbt_interfaces" / "action").exists()
    major = interfaces.lark_version().split(".")[0]
    assert major.isdigit() and int(major) >= 1, interfaces.lark_version()
    site = Path(sysconfig.get_paths()["purelib"])
    assert not (site / "lark-stubs").exists(), "lark-parser 0.12's stubs hide lark 1.x's types"


def test_a_platform_without_wheels_is_told_what_to_do_in_one_line(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(platform, "machine", lambda: "aarch64")  # the module reads it
    assert not interfaces.has_wheels()
    line = interfaces.not_here()
    assert "\n" not in line
    assert line.startswith("no ROS 2 wheels for aarch64 linux, CPython 3.")
    assert "install ROS 2 Jazzy" in line and "colcon" in line
