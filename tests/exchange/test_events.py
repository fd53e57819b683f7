"""Fleet events (spec/protocol.md section 10): the model, its bounds, signatures, the rate limit
and the transfer log's sink hook."""

from __future__ import annotations

import io
import json
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from ktbt_proto.exchange.events import (
    MAX_EVENT_BYTES,
    EventPublisher,
    FleetEvent,
    decode_event,
    encode_event,
    from_log,
    schema_text,
    signed_bytes,
)
from ktbt_proto.exchange.messages import MessageRefused
from ktbt_proto.exchange.signing import Identity
from ktbt_proto.exchange.transferlog import Event, TransferLog
from ktbt_proto.items import sequence_digest

SPEC = Path(__file__).resolve().parents[2] / "spec"
SEQ = "<c>(TargetSeen,colour=2)"


def test_event_schema_file_matches_the_model() -> None:
    committed = (SPEC / "schemas" / "event.json").read_text()
    assert committed == schema_text(), "regenerate spec/schemas/event.json from the model"
    assert {"v", "type", "peer", "event"} <= set(json.loads(committed)["required"])


def test_spec_names_the_bounds() -> None:
    text = (SPEC / "protocol.md").read_text(encoding="utf-8")
    section = text[text.index("## 10. Fleet events") :]
    assert f"{MAX_EVENT_BYTES:,} bytes" in section
    for field in FleetEvent.model_fields:
        assert f"`{field}`" in section, field


def test_the_sink_sees_every_event_the_log_records(tmp_path: Path) -> None:
    seen: list[dict[str, Any]] = []
    log = TransferLog(tmp_path / "r1.log")
    log.add_sink(seen.append)
    log.record(Event.MERGED, peer="r1", sequence=SEQ, teacher="t", author=None)
    log.record(Event.REFUSED, peer="r1", reason="SBT310 colour=7")
    log.close()
    lines = [json.loads(line) for line in (tmp_path / "r1.log").read_text().splitlines()]
    assert seen == lines
    assert [e["event"] for e in seen] == ["merged", "refused"]


def test_a_log_may_have_sinks_and_no_file() -> None:
    seen: list[dict[str, Any]] = []
    log = TransferLog(None)
    log.add_sink(seen.append)
    log.record(Event.QUERY_SENT, peer="r1", id="q1", sequence=SEQ)
    log.close()
    assert seen[0]["sequence"] == SEQ and log.counts["query-sent"] == 1


def test_every_kind_the_log_records_can_be_published() -> None:
    out: list[bytes] = []
    publish = EventPublisher("r1", out.append)
    for kind in Event:
        publish({"t": "2026-12-01T00:00:00.000+00:00", "event": kind, "peer": "r1"})
    publish({"t": "x", "event": "Not A Kind", "peer": "r1"})  # never raises into the log
    assert [decode_event(p).event for p in out] == list(Event)
    assert publish.dropped == 1


def test_an_event_names_its_item_by_digest_and_round_trips() -> None:
    entry = {"t": "2026-12-01T00:00:00.000+00:00", "event": "merged", "peer": "r1"}
    event = from_log({**entry, "sequence": SEQ, "teacher": "t", "tick": 4}, 3)
    assert event.item == sequence_digest(SEQ) and len(event.item or "") == 64
    assert decode_event(encode_event(event)) == event


def test_hostile_fields_are_clipped_or_left_out_and_the_event_stays_small() -> None:
    entry = {
        "t": "2026-12-01T00:00:00.000+00:00",
        "event": "query-received",
        "peer": "t",
        "sequence": "\x01" * 4096,  # escapes to six characters each
        "sender": "<script>alert(1)</script>",  # not a name: left out
        "reason": "<img src=x onerror=alert(1)>" * 50,
        "key": "ktbt/v1/knowledge/" + "x" * 500,
    }
    event = from_log(entry, 0)
    assert event.sender is None
    assert event.item == sequence_digest(entry["sequence"])
    assert len(event.reason or "") == 200 and len(event.on or "") == 200
    assert len(encode_event(event)) <= MAX_EVENT_BYTES - 200
    assert decode_event(encode_event(event)) == event


@pytest.mark.parametrize(
    ("data", "why"),
    [
        (b"x" * (MAX_EVENT_BYTES + 1), "exceeds the limit"),
        (b"not json", "invalid event"),
        (b'{"v": 1, "type": "event", "peer": "<b>", "n": 0, "t": "x", "event": "merged"}', "peer"),
        (b'{"v": 1, "type": "event", "peer": "a", "n": 0, "t": "x", "event": "<b>"}', "event"),
        (
            b'{"v": 1, "type": "event", "peer": "a", "n": 0, "t": "x", "event": "merged", "z": 1}',
            "z",
        ),
        (b'{"peer": "a", "n": 0, "t": "x", "event": "merged"}', "type"),
        (b'{"type": "event", "peer": "a", "n": 0, "t": "x", "event": "merged"}', "'v'"),
        (b'{"v": true, "type": "event", "peer": "a", "n": 0, "t": "x", "event": "merged"}', "'v'"),
        (b'{"v": 1, "type": "event", "peer": "a", "n": "5", "t": "x", "event": "merged"}', "n"),
        (
            b'{"v": 1, "type": "event", "peer": "a", "n": 0, "t": "x", "event": "m", "tick": 1.0}',
            "tick",
        ),
    ],
)
def test_malformed_events_are_refused_with_a_reason(data: bytes, why: str) -> None:
    with pytest.raises(MessageRefused, match=why):
        decode_event(data)


def test_a_signed_peer_signs_its_events_and_a_forgery_is_refused() -> None:
    me = Identity.generate()
    out: list[bytes] = []
    publish = EventPublisher("r1", out.append, identity=me)
    publish(
        {"t": "2026-12-01T00:00:00.000+00:00", "event": "merged", "peer": "r1", "sequence": SEQ}
    )
    event = decode_event(out[0])
    assert event.key == me.public and event.sig is not None
    assert signed_bytes(event).startswith(b"ktbt/v1/event\x00{")
    forged = json.loads(out[0])
    forged["teacher"] = "mallory"
    with pytest.raises(MessageRefused, match="does not verify"):
        decode_event(json.dumps(forged).encode())
    half = {k: v for k, v in json.loads(out[0]).items() if k != "sig"}
    with pytest.raises(MessageRefused, match="together"):
        decode_event(json.dumps(half).encode())


def test_the_publisher_drops_beyond_its_rate_and_says_how_many() -> None:
    out: list[bytes] = []
    now = [0.0]
    publish = EventPublisher("r1", out.append, rate=1.0, burst=5, clock=lambda: now[0])
    entry = {"t": "2026-12-01T00:00:00.000+00:00", "event": "query-sent", "peer": "r1"}
    for _ in range(100):
        publish(entry)
    assert publish.sent == len(out) == 5
    assert publish.dropped == 100 - len(out)
    events = [decode_event(p) for p in out]
    assert [e.n for e in events] == list(range(len(out)))
    now[0] = 1.0  # a second later: one more token
    publish(entry)
    assert decode_event(out[-1]).dropped == publish.dropped > 0


def test_merges_forgets_and_refusals_are_not_dropped_for_a_flood_of_queries() -> None:
    out: list[bytes] = []
    publish = EventPublisher("r1", out.append, rate=1.0, burst=5, clock=lambda: 0.0)
    query = {"t": "2026-12-01T00:00:00.000+00:00", "event": "query-sent", "peer": "r1"}
    for _ in range(100):
        publish(query)
    publish({**query, "event": "merged", "sequence": SEQ, "teacher": "t"})
    publish({**query, "event": "forgotten", "sequence": SEQ})
    assert [decode_event(p).event for p in out[-2:]] == ["merged", "forgotten"]
    for _ in range(100):  # their own bucket is bounded too
        publish({**query, "event": "refused", "reason": "junk"})
    assert publish.sent == 5 + 5


def test_events_leave_in_the_order_of_their_numbers() -> None:
    out: list[int] = []

    def slow_put(payload: bytes) -> None:  # a put that lets other threads run meanwhile
        time.sleep(0.0005)
        out.append(decode_event(payload).n)

    publish = EventPublisher("r1", slow_put, rate=1e9, burst=10**6)
    entry = {"t": "2026-12-01T00:00:00.000+00:00", "event": "query-sent", "peer": "r1"}

    def record() -> None:
        for _ in range(50):
            publish(entry)

    threads = [threading.Thread(target=record) for _ in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert out == list(range(200))


def test_a_log_with_a_publisher_publishes_what_it_writes() -> None:
    out: list[bytes] = []
    stream = io.StringIO()
    log = TransferLog(stream)
    log.add_sink(EventPublisher("r1", out.append))
    log.record(
        Event.REFUSED, peer="r1", reason="from t: SBT310 colour=7", where="transport", key="k/e"
    )
    event = decode_event(out[0])
    written = json.loads(stream.getvalue())
    assert (event.event, event.reason, event.where, event.on, event.t) == (
        "refused",
        written["reason"],
        "transport",
        "k/e",
        written["t"],
    )
