"""A message whose reading raises anything at all is a counted refusal, and the robot goes on
with its tree and knowledge as they were (spec/protocol.md section 2.1): the decoders, the
receive pipeline, a catalog's entries and a network callback, each made to raise; the warnings
of a flood thinned to a few lines and a count."""

from __future__ import annotations

import logging
from typing import Any

import pytest

from ktbt_proto.exchange import core, events, messages, receiving, refusals
from ktbt_proto.exchange.application import ApplicationTimedAgent
from ktbt_proto.exchange.member import ListedSequences
from ktbt_proto.exchange.messages import MessageRefused, Query, Response, decode, encode
from ktbt_proto.exchange.receiving import Refused
from ktbt_proto.transport import MemoryNetwork
from tests.exchange.test_agent import CONTROL, KNOWER, SEQUENCE, registry

GREEN = "<c>(TargetSeen,colour=2)"


def fail_on_marker(monkeypatch: pytest.MonkeyPatch, stage: refusals.Stage) -> None:
    """The test hook, as ``KTBT_FAULT_READING=stage`` sets it in a process."""
    monkeypatch.setattr(refusals, "_stage", stage)


def test_the_hook_raises_only_at_its_stage_and_only_on_the_marker(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    refusals.fault("item", "ktbt-fault")  # unset: nothing happens
    fail_on_marker(monkeypatch, "item")
    refusals.fault("message", b"ktbt-fault")
    refusals.fault("item", "<a>(X)")
    for data in ("<a>(ktbt-fault)", b"{ktbt-fault}", {"subtree": "ktbt-fault"}):
        with pytest.raises(refusals.InjectedFault):
            refusals.fault("item", data)


def test_a_decoder_that_raises_refuses_the_message_naming_the_exception(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    fail_on_marker(monkeypatch, "message")
    data = encode(Query(id="q1", sender="r1", sequence='<c>(A,s="ktbt-fault")'))
    with pytest.raises(MessageRefused) as info:
        decode(data)
    assert info.value.reason == "internal error reading a message: InjectedFault"
    with pytest.raises(MessageRefused, match="internal error reading a message: InjectedFault"):
        messages.decode_fields(
            {"v": 1, "type": "query", "id": "q1", "sender": "r1", "sequence": "ktbt-fault"}
        )

    class Broken:
        def validate_json(self, *_: Any, **__: Any) -> Any:
            raise AssertionError  # what the parser once raised

    monkeypatch.setattr(events, "_ADAPTER", Broken())
    with pytest.raises(MessageRefused, match="reading a message: AssertionError"):
        events.decode_event(b"{}")


def test_a_reader_that_raises_is_a_refusal_from_the_sender(monkeypatch: pytest.MonkeyPatch) -> None:
    answer = Response(id="q", sender="mallory", sequence=GREEN, subtree="<sq><c>true.5<e>")
    with pytest.raises(Refused) as parsed:
        receiving.read_item(answer)  # the parser's own error, positioned
    assert parsed.value.reason == "from mallory: SBT101 unexpected character '.'"

    def explode(*_: Any, **__: Any) -> Any:
        raise AssertionError

    monkeypatch.setattr(receiving, "parse", explode)
    with pytest.raises(Refused) as raised:
        receiving.read_item(answer.model_copy(update={"subtree": "<a>(Pick)"}))
    assert raised.value.reason == "from mallory: internal error reading a message: AssertionError"


def test_an_agent_refuses_what_it_cannot_read_keeps_its_tree_and_learns_after(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    net = MemoryNetwork()
    learner = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"))
    teacher = ApplicationTimedAgent("t", KNOWER, registry(), net.join("t"))
    before = learner.control.tree
    caplog.set_level(logging.WARNING)
    real = receiving.read_item
    raising = True

    def read(*args: Any, **kwargs: Any) -> Any:
        if raising:
            raise AssertionError
        return real(*args, **kwargs)

    monkeypatch.setattr(core, "read_item", read)
    learner.ask(SEQUENCE)
    teacher.receive()
    heard = teacher.heard("l")
    assert heard is not None and teacher.answer(heard)
    assert learner.receive() == 0
    assert learner.metrics.refused == 1 and not learner.knows(SEQUENCE)
    reason = "from t: internal error reading a message: AssertionError"
    assert learner.metrics.refusals[-1][1] == reason
    assert f"l refused knowledge: {reason}" in caplog.text
    assert learner.control.tree is before and len(learner.knowledge) == 0
    raising = False  # an honest answer after it is learned
    learner.close_query()
    learner.ask(SEQUENCE)
    teacher.receive()
    heard = teacher.heard("l")
    assert heard is not None and teacher.answer(heard)
    assert learner.receive() == 1 and learner.knows(SEQUENCE)
    item = learner.knowledge.lookup(GREEN)
    assert item is not None and item.source == "t"
    assert learner.control.tree is not before


def test_a_catalog_entry_that_cannot_be_read_is_refused_once_and_the_rest_read(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    fail_on_marker(monkeypatch, "item")
    said: list[str] = []
    listed = ListedSequences("l", registry(), said.append)
    hostile = [{"sequence": "<c>true."}, {"sequence": "<c>(ktbt-fault)"}, {"sequence": GREEN}]
    assert listed.read({"mallory": hostile}) == [GREEN]
    assert listed.refused == 1
    assert listed.read({"mallory": hostile}) == []  # skipped from then on, not counted again
    assert listed.refused == 1


def test_a_callback_that_raises_is_a_refusal_never_an_exception() -> None:
    class Host:
        def __init__(self) -> None:
            self.reasons: list[str] = []

        def _refuse(self, reason: str) -> None:
            self.reasons.append(reason)

        @refusals.guarded("a query")
        def on_query(self, data: bytes) -> None:
            raise KeyError(data)

    host = Host()
    host.on_query(b"\x00")
    assert host.reasons == ["a query: internal error reading a message: KeyError"]


def test_a_flood_of_refusals_is_a_few_lines_and_a_count(monkeypatch: pytest.MonkeyPatch) -> None:
    lines: list[str] = []
    clock = [100.0]
    monkeypatch.setattr("ktbt_proto.exchange.refusals.time.monotonic", lambda: clock[0])
    warn = refusals.Throttle(lines.append, burst=3, period=10)
    for n in range(50):
        warn(f"refused {n}")
    assert lines == ["refused 0", "refused 1", "refused 2"] and warn.held_back == 47
    clock[0] += 10
    warn("refused 50")
    assert lines[3:] == [
        "47 more refusals were not logged (at most 3 lines a 10 s)",
        "refused 50",
    ]
    assert warn.held_back == 0
