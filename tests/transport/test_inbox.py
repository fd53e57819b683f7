"""What a network transport holds for its agent, and the answers it gives at once
(``ktbt_proto.transport.inbox``), one definition for zenoh and ROS 2.

``Inbox`` (spec/protocol.md sections 2 and 4.3): bounded, the newcomer refused with its reason
when it is full and what came first kept (the first answer wins); overheard answers bounded
apart, screened by the trust policy, and a copy of an answer to one of the robot's own queries
left to that answer; drained in order, and safe to fill from several threads.

``AnswersGiven`` (sections 1, 3, 4.5 and 8): one response for each sequence asked that the
robot knows, none twice to the same query within the answer window, the latest ``limit``
queries remembered, each query recorded as received before its answers are recorded as sent,
and an answer too large for any peer to accept warned about and skipped.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from ktbt_proto.exchange.messages import Query, Response
from ktbt_proto.exchange.signing import Identity, SignedItem, item_bytes, verify
from ktbt_proto.exchange.transferlog import TransferLog
from ktbt_proto.exchange.transport import NetworkError, Received
from ktbt_proto.exchange.trust import Policy, refusal
from ktbt_proto.transport.inbox import AnswersGiven, Inbox

GREEN = "<c>(TargetSeen,colour=2)"
BLUE = "<c>(TargetSeen,colour=3)"
RED = "<c>(TargetSeen,colour=1)"


class Refusals:
    """A transport's refusal, as ``refuse(reason, **fields)``: kept in order."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.seen: list[tuple[str, dict[str, Any]]] = []

    def __call__(self, reason: str, **fields: Any) -> None:
        with self.lock:
            self.seen.append((reason, fields))

    @property
    def reasons(self) -> list[str]:
        return [reason for reason, _ in self.seen]


def answer(n: int, sender: str = "t", id: str | None = None) -> Response:
    return Response(id=id or f"q{n}", sender=sender, sequence=GREEN, subtree=f"<a>(Pick,n={n})")


def query(n: int, sender: str = "a") -> Query:
    return Query(id=f"q{n}", sender=sender, sequence=GREEN)


# -- Inbox ------------------------------------------------------------------------------------


def test_a_full_inbox_refuses_the_newcomer_with_its_reason_and_keeps_what_came_first() -> None:
    refused = Refusals()
    inbox = Inbox(refused, limit=3)
    first: list[Received] = [answer(1), query(2), NetworkError("q3", "Timeout")]
    for message in first:
        inbox.deliver(message)
    assert len(inbox) == 3 and refused.seen == []
    inbox.deliver(query(4), key="ktbt/v1/knowledge/a")
    inbox.deliver(answer(5))
    assert refused.seen == [
        ("inbox full (3 messages): a query is dropped", {"key": "ktbt/v1/knowledge/a"}),
        ("inbox full (3 messages): a response is dropped", {}),
    ]
    assert inbox.drain() == first
    assert len(inbox) == 0 and inbox.drain() == []
    inbox.deliver(answer(6))  # room again once drained
    assert inbox.drain() == [answer(6)] and len(refused.seen) == 2


def test_overheard_answers_are_bounded_apart_from_the_agents_messages() -> None:
    """A flood of published answers takes no direct answer's place (section 4.3), and a full
    inbox leaves room for what is overheard: two queues, two bounds."""
    refused = Refusals()
    inbox = Inbox(refused, limit=2, overheard_limit=2)
    for n in range(4):
        inbox.overhear(answer(n, sender=f"p{n}"), None, key=f"ktbt/v1/answers/p{n}")
    assert refused.seen == [
        ("2 overheard answers waiting: one from p2 is dropped", {"key": "ktbt/v1/answers/p2"}),
        ("2 overheard answers waiting: one from p3 is dropped", {"key": "ktbt/v1/answers/p3"}),
    ]
    inbox.deliver(answer(10))
    inbox.deliver(answer(11))
    assert len(refused.seen) == 2  # the agent's own messages still found room
    inbox.deliver(answer(12))
    assert refused.reasons[-1] == "inbox full (2 messages): a response is dropped"
    assert len(inbox) == 4
    # The agent's messages first, then what was overheard, each in the order it came.
    assert inbox.drain() == [answer(10), answer(11), answer(0, "p0"), answer(1, "p1")]
    assert len(inbox) == 0


def test_an_overheard_copy_of_an_answer_to_an_own_query_is_left_to_the_answer() -> None:
    refused = Refusals()
    inbox = Inbox(refused)
    inbox.asked("mine")
    inbox.overhear(answer(1, id="mine"), None)
    inbox.overhear(answer(2, id="theirs"), None)
    assert inbox.drain() == [answer(2, id="theirs")]
    assert refused.seen == []  # left alone, not refused: the reply itself brings it


def test_only_the_latest_own_query_ids_are_remembered() -> None:
    inbox = Inbox(Refusals())
    for n in range(Inbox.ASKED + 1):
        inbox.asked(f"own{n}")
    inbox.overhear(answer(0, id="own0"), None)  # the oldest, forgotten: overheard
    inbox.overhear(answer(1, id="own1"), None)  # still remembered: left to its reply
    assert inbox.drain() == [answer(0, id="own0")]


def test_an_overheard_answer_the_trust_policy_refuses_is_refused_with_its_reason() -> None:
    author = Identity.generate()
    signed_item = author.sign_item(GREEN, "<a>(Pick)")
    signed = author.sign_reply(
        Response(id="q1", sender="t", sequence=GREEN, subtree=signed_item.subtree,
                 author=signed_item.author, signature=signed_item.signature)
    )  # fmt: skip
    refused = Refusals()
    inbox = Inbox(refused)

    def screen(response: Response) -> str | None:
        return refusal(response, Policy.SIGNED)

    inbox.overhear(answer(2, sender="u"), screen, key="ktbt/v1/answers/u")
    inbox.overhear(signed, screen)
    assert refused.seen == [
        ("overheard from u: the item is not signed by its author", {"key": "ktbt/v1/answers/u"})
    ]
    assert inbox.drain() == [signed]


def test_messages_put_from_several_threads_while_one_drains_are_kept_or_refused() -> None:
    """Four network threads put while the agent's thread drains: every message is drained once
    or refused, none is lost or doubled, none beyond the bound is ever held, and each thread's
    messages keep their order."""
    threads, each, limit = 4, 2_000, 256
    refused = Refusals()
    inbox = Inbox(refused, limit=limit, overheard_limit=16)
    done = threading.Event()
    drained: list[Received] = []
    sizes: list[int] = []

    def put(t: int) -> None:
        for n in range(each):
            if n % 10 == 0:
                inbox.overhear(answer(n, sender=f"p{t}", id=f"o{t}-{n}"), None)
            else:
                inbox.deliver(query(n, sender=f"a{t}"))

    def drain() -> None:
        while not done.is_set():
            batch = inbox.drain()
            sizes.append(len(batch))
            drained.extend(batch)
        drained.extend(inbox.drain())

    drainer = threading.Thread(target=drain)
    putters = [threading.Thread(target=put, args=(t,)) for t in range(threads)]
    drainer.start()
    for p in putters:
        p.start()
    for p in putters:
        p.join(timeout=60)
    done.set()
    drainer.join(timeout=60)
    assert not drainer.is_alive() and not any(p.is_alive() for p in putters)
    assert len(drained) + len(refused.seen) == threads * each
    assert max(sizes, default=0) <= limit + 16
    keys = [(m.sender, m.id) for m in drained if isinstance(m, Query | Response)]
    assert len(set(keys)) == len(keys) == len(drained)  # nothing doubled
    for t in range(threads):
        mine = [int(m.id[1:]) for m in drained if isinstance(m, Query) and m.sender == f"a{t}"]
        assert mine == sorted(mine)
    assert len(inbox) == 0


# -- AnswersGiven -----------------------------------------------------------------------------


def knows(*sequences: str) -> dict[str, str]:
    """A robot's lookup: the sequences it knows and their subtrees."""
    return {s: f"<a>(Pick,colour={s[-2]})" for s in sequences}


class Recorded:
    def __init__(self) -> None:
        self.log = TransferLog(None)
        self.events: list[dict[str, Any]] = []
        self.log.add_sink(self.events.append)


def given(window: float = 1.0, limit: int = 256) -> tuple[AnswersGiven, list[str]]:
    warned: list[str] = []
    return AnswersGiven("r1", window, limit, warned.append), warned


def test_one_response_for_each_sequence_asked_that_is_known() -> None:
    answers, warned = given()
    asked = Query(id="q1", sender="a", sequence=GREEN, more=(BLUE, RED))
    responses = list(answers.answers(asked, knows(GREEN, RED).get, None, None))
    assert [(r.id, r.sender, r.sequence, r.subtree) for r in responses] == [
        ("q1", "r1", GREEN, "<a>(Pick,colour=2)"),
        ("q1", "r1", RED, "<a>(Pick,colour=1)"),
    ]
    assert all(r.author is None and r.key is None for r in responses) and warned == []


def test_an_answer_keeps_its_authors_signature_and_is_hop_signed_by_the_sender() -> None:
    author, sender = Identity.generate(), Identity.generate()
    item = author.sign_item(GREEN, "<a>(Pick)")

    def lookup(sequence: str) -> SignedItem | None:
        return item if sequence == GREEN else None

    answers, _ = given()
    (response,) = answers.answers(query(1), lookup, sender, None)
    assert (response.author, response.signature) == (author.public, item.signature)
    assert verify(author.public, item.signature or "", item_bytes(GREEN, "<a>(Pick)"))
    assert response.key == sender.public
    assert refusal(response, Policy.SIGNED) is None


def test_a_sequence_is_not_answered_twice_to_the_same_query_within_the_window() -> None:
    """An asker sends its open query to a peer as it appears, which may have had the broadcast
    already (section 4.5): what it answered is not answered again; what it learned meanwhile is
    answered; another asker, or another id, is another query."""
    answers, _ = given(window=3600)
    lookup = knows(GREEN)
    both = Query(id="q1", sender="a", sequence=GREEN, more=(BLUE,))
    assert [r.sequence for r in answers.answers(both, lookup.get, None, None)] == [GREEN]
    assert list(answers.answers(both, lookup.get, None, None)) == []
    lookup.update(knows(BLUE))  # learned meanwhile
    assert [r.sequence for r in answers.answers(both, lookup.get, None, None)] == [BLUE]
    assert list(answers.answers(both, lookup.get, None, None)) == []
    other_asker = Query(id="q1", sender="b", sequence=GREEN)
    other_id = Query(id="q2", sender="a", sequence=GREEN)
    for other in (other_asker, other_id):
        assert [r.sequence for r in answers.answers(other, lookup.get, None, None)] == [GREEN]


def test_once_the_window_is_over_the_query_is_answered_again() -> None:
    answers, _ = given(window=0.0)
    asked = query(1)
    assert len(list(answers.answers(asked, knows(GREEN).get, None, None))) == 1
    answered = time.monotonic()
    while time.monotonic() == answered:  # the window of 0 s ends as the clock moves on
        pass
    assert len(list(answers.answers(asked, knows(GREEN).get, None, None))) == 1


def test_only_the_latest_limit_queries_are_remembered() -> None:
    answers, _ = given(window=3600, limit=2)
    lookup = knows(GREEN).get
    for n in (1, 2, 3):
        assert len(list(answers.answers(query(n), lookup, None, None))) == 1
    assert len(list(answers.answers(query(3), lookup, None, None))) == 0  # remembered
    assert len(list(answers.answers(query(1), lookup, None, None))) == 1  # forgotten: again
    assert len(list(answers.answers(query(2), lookup, None, None))) == 1  # pushed out by q1


def test_the_log_records_the_query_received_then_each_answer_once_it_is_sent() -> None:
    recorded = Recorded()
    answers, _ = given()
    asked = Query(id="q1", sender="a", sequence=GREEN, more=(BLUE,))
    responses = answers.answers(asked, knows(GREEN, BLUE).get, None, recorded.log)
    first = next(responses)
    assert [e["event"] for e in recorded.events] == ["query-received"]
    assert recorded.events[0] | {"t": None} == {
        "t": None, "event": "query-received", "peer": "r1", "sender": "a", "id": "q1",
        "sequence": GREEN, "more": [BLUE],
    }  # fmt: skip
    rest = list(responses)  # asking for the next: the first was sent
    assert [first.sequence, *(r.sequence for r in rest)] == [GREEN, BLUE]
    sent = [(e["event"], e["to"], e["id"], e["sequence"]) for e in recorded.events[1:]]
    assert sent == [("answer-sent", "a", "q1", GREEN), ("answer-sent", "a", "q1", BLUE)]
    assert all(e["peer"] == "r1" for e in recorded.events)


def test_an_answer_too_large_for_any_peer_is_warned_about_and_skipped() -> None:
    recorded = Recorded()
    answers, warned = given()
    huge = "<sq>" + "<a>(Pick,colour=2)" * 3_500 + "<e>"  # 63,000 characters: too large
    lookup = {GREEN: huge, BLUE: "<a>(Pick,colour=3)"}.get
    asked = Query(id="q1", sender="a", sequence=GREEN, more=(BLUE,))
    responses = list(answers.answers(asked, lookup, None, recorded.log))
    assert [r.sequence for r in responses] == [BLUE]
    assert len(warned) == 1 and warned[0].startswith(f"r1 cannot answer {GREEN}: ")
    assert [e["event"] for e in recorded.events] == ["query-received", "answer-sent"]
