"""Refusals are visible (spec/protocol.md sections 2 and 4): each is logged at WARNING with its
reason and counted, on real agents on the in-memory network; the network's own errors are
counted apart and never logged as refusals."""

from __future__ import annotations

import logging

import pytest

from ktbt_proto.exchange.agent import Agent, Timing
from ktbt_proto.exchange.application import ApplicationTimedAgent
from ktbt_proto.exchange.messages import Response
from ktbt_proto.exchange.transport import NetworkError
from ktbt_proto.transport import MemoryNetwork
from tests.exchange.test_agent import CONTROL, KNOWER, SEQUENCE, registry


def warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


def test_a_refused_answer_is_logged_at_warning_with_its_reason(
    caplog: pytest.LogCaptureFixture,
) -> None:
    net = MemoryNetwork()
    learner = Agent("l", CONTROL, registry(), net.join("l"), timing=Timing(wait=5, cooldown=5))
    learner.encounter(SEQUENCE)
    caplog.set_level(logging.WARNING)
    learner.tick()  # asks
    asked = learner._asking
    assert asked is not None and asked.query is not None
    bad = Response(
        id=asked.query.id, sender="t", sequence=asked.query.sequence, subtree="<a>(Explode)"
    )
    net._post("t", "l", bad)
    learner.tick()
    assert learner.metrics.refused == 1 and not learner.knows(SEQUENCE)
    reason = learner.metrics.refusals[0][1]
    assert "Explode" in reason
    assert warnings(caplog) == [f"l refused knowledge: {reason}"]
    assert caplog.records[-1].name == "ktbt.agent"


def test_an_answer_to_no_open_question_is_a_warning_a_late_one_is_not(
    caplog: pytest.LogCaptureFixture,
) -> None:
    net = MemoryNetwork()
    learner = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"))
    teacher = ApplicationTimedAgent("t", KNOWER, registry(), net.join("t"))
    caplog.set_level(logging.DEBUG)
    query = learner.ask(SEQUENCE)
    learner.close_query()
    teacher.receive()
    heard = teacher.heard("l")
    assert heard is not None and teacher.answer(heard)
    assert learner.receive() == 0 and learner.metrics.late_answers == 1
    assert warnings(caplog) == []  # a late answer is nobody's fault
    stray = Response(id="never", sender="t", sequence=query.sequence, subtree="<a>(Pick)")
    net._post("t", "l", stray)
    learner.receive()
    assert warnings(caplog) == ["l refused knowledge: from t: an answer to no open question"]


def test_a_network_error_is_counted_apart_never_a_refusal(
    caplog: pytest.LogCaptureFixture,
) -> None:
    net = MemoryNetwork()
    transport = net.join("l")
    learner = Agent("l", CONTROL, registry(), transport)
    caplog.set_level(logging.DEBUG)
    transport._inbox.append(NetworkError("q1", "Timeout"))  # type: ignore[arg-type]
    learner.tick()
    assert learner.metrics.network_errors == 1 and learner.metrics.refused == 0
    assert warnings(caplog) == []


def test_a_full_inbox_refusal_is_logged_at_warning(caplog: pytest.LogCaptureFixture) -> None:
    net = MemoryNetwork(inbox_limit=1)
    net.join("l")
    teacher = ApplicationTimedAgent("t", KNOWER, registry(), net.join("t"))
    caplog.set_level(logging.WARNING)
    teacher.ask(SEQUENCE)
    teacher.ask(SEQUENCE)  # the second finds l's inbox full
    assert net._members["l"].refused == 1
    assert warnings(caplog) == ["l refused: inbox full (1 messages): a query from t is dropped"]


def test_timing_refuses_a_negative_wait() -> None:
    with pytest.raises(ValueError, match="wait must be a whole number of ticks"):
        Timing(wait=-1)
