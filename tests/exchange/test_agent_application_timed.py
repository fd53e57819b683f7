"""Application-timed agents (spec/protocol.md section 4.1): ask, announce, receive, answer,
close, with real messages on the in-memory network and the same checks as the trees use."""

from __future__ import annotations

import ktbt_proto as kp
from ktbt_proto.exchange.application import ApplicationTimedAgent
from ktbt_proto.exchange.messages import Query, Response, encode
from ktbt_proto.transport import MemoryNetwork
from tests.exchange.test_agent import CONTROL, KNOWER, SEQUENCE, SKILL, registry


def trio(
    audience: dict[str, list[str]] | None = None,
) -> tuple[ApplicationTimedAgent, ApplicationTimedAgent, ApplicationTimedAgent]:
    hears = audience or {}
    net = MemoryNetwork(audience=(lambda s: hears.get(s, ["l", "t", "x"])) if hears else None)
    learner = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"))
    teacher = ApplicationTimedAgent("t", KNOWER, registry(), net.join("t"))
    other = ApplicationTimedAgent("x", CONTROL, registry(), net.join("x"))
    return learner, teacher, other


def test_an_answered_query_is_merged_into_the_live_tree() -> None:
    learner, teacher, other = trio()
    query = learner.ask(SEQUENCE)
    assert learner.open_query == query and learner.metrics.queries_sent == 1
    teacher.receive()
    other.receive()
    heard = teacher.heard("l")
    assert heard is not None and heard.id == query.id
    assert other.answer(heard) is False  # it does not know the sequence: no answer
    assert teacher.answer(heard) is True
    assert learner.receive() == 1
    assert learner.knows(SEQUENCE)
    learner.blackboard["target"] = 2
    learner.control.tick()
    assert learner.blackboard["picked"] == 1
    assert learner.metrics.learned[query.sequence][1] == "t"
    learner.close_query()
    assert learner.metrics.queries_lost == 0 and learner.open_query is None


def test_a_second_answer_and_an_answer_after_the_wait_are_late_not_refused() -> None:
    learner, teacher, _ = trio()
    query = learner.ask(SEQUENCE)
    teacher.receive()
    heard = teacher.heard("l")
    assert heard is not None
    teacher.answer(heard)
    teacher.answer(heard)
    assert learner.receive() == 1
    assert learner.metrics.late_answers == 1  # the duplicate: the query was already answered
    late = Response(id=query.id, sender="t", sequence=query.sequence, subtree="<a>(Pick)")
    learner.close_query()
    learner.transport.network._post("t", "l", late)  # type: ignore[attr-defined]
    assert learner.receive() == 0 and learner.metrics.late_answers == 2
    assert learner.metrics.refused == 0  # an honest answer, too late, is no refusal
    never = Response(id="not-asked", sender="t", sequence=query.sequence, subtree="<a>(Pick)")
    learner.transport.network._post("t", "l", never)  # type: ignore[attr-defined]
    assert learner.receive() == 0 and learner.metrics.refused == 1
    assert "no open question" in learner.metrics.refusals[0][1]


def test_only_the_latest_closed_queries_are_remembered() -> None:
    learner, _, _ = trio()
    first = learner.ask(SEQUENCE)
    for _ in range(ApplicationTimedAgent.RECENT_QUERIES):
        learner.ask(SEQUENCE)  # each ask closes the one before
    learner.close_query()
    old = Response(id=first.id, sender="t", sequence=first.sequence, subtree="<a>(Pick)")
    learner.transport.network._post("t", "l", old)  # type: ignore[attr-defined]
    assert learner.receive() == 0
    assert learner.metrics.refused == 1 and learner.metrics.late_answers == 0


def test_a_query_nobody_answers_is_lost_when_closed() -> None:
    learner, _, _ = trio()
    learner.ask(SEQUENCE)
    learner.close_query()
    assert learner.metrics.queries_lost == 1


def test_an_answer_that_fails_a_check_is_refused_and_nothing_merges() -> None:
    learner, _, _ = trio()
    query = learner.ask(SEQUENCE)
    before = kp.format_tree(learner.control.tree, "compact")
    bad = Response(id=query.id, sender="t", sequence=query.sequence, subtree="<a>(Explode)")
    learner.transport.network._post("t", "l", bad)  # type: ignore[attr-defined]
    assert learner.receive() == 0
    assert learner.metrics.refused == 1 and not learner.knows(SEQUENCE)
    assert kp.format_tree(learner.control.tree, "compact") == before


def test_announce_reaches_a_peer_that_did_not_hear_the_broadcast() -> None:
    learner, teacher, _ = trio({"l": [], "t": ["l"], "x": []})  # nobody hears l's broadcast
    query = learner.ask(SEQUENCE)
    teacher.receive()
    assert teacher.heard("l") is None
    learner.announce("t")
    teacher.receive()
    heard = teacher.heard("l")
    assert isinstance(heard, Query) and heard.id == query.id
    teacher.answer(heard)
    assert learner.receive() == 1
    learner.announce("t")  # answered: nothing more is sent
    teacher.receive()
    assert teacher.metrics.queries_received == 1


def test_a_query_asked_to_named_peers_reaches_them_alone() -> None:
    learner, teacher, other = trio()
    query = learner.ask(SEQUENCE, to=["t"])
    teacher.receive(), other.receive()
    heard = teacher.heard("l")
    assert isinstance(heard, Query) and heard.id == query.id and other.heard("l") is None
    assert learner.metrics.queries_sent == 1 and learner.open_query == query
    teacher.answer(heard)
    assert learner.receive() == 1 and learner.knows(SEQUENCE)


def test_one_query_for_several_sequences_is_answered_for_each_and_merges_each_once() -> None:
    """A query may name several sequences (spec/protocol.md section 1): the teacher answers
    each it knows, the learner merges each once, and a repeated answer is late."""
    net = MemoryNetwork()
    both = f"<sl><k>(prior){SKILL}<sq><c>(TargetSeen, colour=3)<a>(Pick, colour=3)<e><e>"
    learner = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"))
    teacher = ApplicationTimedAgent(
        "t", both + "<k>(new)<e><a>(Walk)<e>", registry(), net.join("t")
    )
    green, blue = "<c>(TargetSeen,colour=2)", "<c>(TargetSeen,colour=3)"
    query = learner.ask(green, blue, "<c>(TargetSeen,colour=4)")
    assert query.sequences == (green, blue, "<c>(TargetSeen,colour=4)")
    teacher.receive()
    heard = teacher.heard("l")
    assert heard is not None and teacher.answer(heard)
    teacher.answer(heard)  # the same answers again
    assert teacher.metrics.responses_sent == 4
    assert learner.receive() == 2
    assert learner.knows([green]) and learner.knows([blue])
    assert learner.unanswered == ["<c>(TargetSeen,colour=4)"]
    assert learner.metrics.late_answers == 2 and learner.metrics.refused == 0
    learner.close_query()
    assert learner.metrics.queries_lost == 0  # answered, if not for every sequence


def test_a_single_sequence_query_is_what_it_always_was() -> None:
    learner, teacher, _ = trio()
    query = learner.ask(SEQUENCE)
    assert query.more is None and b'"more"' not in encode(query)
    teacher.receive()
    heard = teacher.heard("l")
    assert heard is not None and teacher.answer(heard)
    assert learner.receive() == 1 and learner.unanswered == []
