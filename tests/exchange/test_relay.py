"""Knowledge relayed at once (spec/protocol.md sections 3 and 4.5), over real zenoh sessions on
loopback: a fleet member announces what it learned, and a neighbour that lacks it asks the
announcer at once, so an item crosses a line of members hop by hop without any timed ask; a
hostile announcer (bad bytes, a wrong key, a lie, a flood) is refused and counted, or costs one
bounded ask."""

from __future__ import annotations

import json
import re
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import pytest
import zenoh

from ktbt_proto.exchange import refusals
from ktbt_proto.exchange.application import ApplicationTimedAgent
from ktbt_proto.exchange.knowledge import KnowledgeBase, with_knowledge
from ktbt_proto.exchange.member import RELAY_GRACE, RELAY_HOLD, FleetMember
from ktbt_proto.exchange.messages import encode_learned
from ktbt_proto.files import packaged
from ktbt_proto.items import sequence_key
from ktbt_proto.syntax import parse
from ktbt_proto.tools.demo import DEMO_CONTROL, demo_registry
from ktbt_proto.transport.zenoh import ZenohSettings, ZenohTransport, open_session
from tests.zenoh_helpers import endpoint, free_port, wait_until

pytestmark = pytest.mark.network  # zenoh sessions on loopback

COLOURS = KnowledgeBase.from_tree(
    parse(packaged("examples", "knowledge", "colours.sbt").read_text())
)
KEYS = [item.key for item in COLOURS]
GREEN = sequence_key(["TargetSeen(colour=2)"])
BLOCK = zenoh.CongestionControl.BLOCK
"""How the liar puts: every message delivered, however loaded the machine (zenoh's default drops
under congestion, and a test counts what arrived)."""
COOLDOWN = 60.0
"""Longer than any deadline here: a member that lost a query asks again only when told."""


def line_settings(config: Path, port: int, *connect: int) -> ZenohSettings:
    """A peer on ``port`` dialling ``connect`` only, without gossip (so the links given are the
    only paths: peers do not forward between peers, section 3)."""
    return ZenohSettings(
        listen=[endpoint(port)], connect=[endpoint(p) for p in connect], config=config
    )


@contextmanager
def member(
    name: str, conf: ZenohSettings, knowledge: KnowledgeBase | None = None, wait: float = 0.5
) -> Iterator[tuple[FleetMember, ZenohTransport]]:
    """The demo robot as a fleet member on zenoh that relays (``ktbt peer run``'s wiring):
    told the four colours, or, with ``knowledge``, a teacher told nothing. Its gets last the
    query's wait (2 s at least), as ``ktbt peer run``'s do."""
    with ZenohTransport(name, conf, query_timeout=max(wait, 2.0)) as transport:
        robot = ApplicationTimedAgent(
            name, with_knowledge(DEMO_CONTROL, knowledge), demo_registry(), transport
        )
        todo = [] if knowledge is not None else KEYS
        yield (
            FleetMember(
                robot,
                transport,
                None,
                todo,
                wait=wait,
                cooldown=COOLDOWN,
                say=lambda _: None,
                relay=transport,
            ),
            transport,
        )


def step(*members: FleetMember, now: float | None = None) -> None:
    for m in members:
        m.agent.now += 1
        m.step(time.monotonic() if now is None else now)
    time.sleep(0.01)


def steps_until(members: list[FleetMember], done: Any, seconds: float = 30.0) -> None:
    deadline = time.monotonic() + seconds
    while not done():
        assert time.monotonic() < deadline, {m.name: m.todo for m in members}
        step(*members)


@pytest.fixture
def quiet(tmp_path: Path) -> Path:
    path = tmp_path / "no-gossip.json5"
    path.write_text(json.dumps({"scouting": {"gossip": {"enabled": False}}}))
    return path


def test_an_item_crosses_a_line_of_members_hop_by_hop_without_a_timed_ask(quiet: Path) -> None:
    """t - r1 - r2 - r3, each dialling only its neighbour. The learners start first, ask, and
    lose their queries (nobody knows): each then holds back its 60 s cool-down. The teacher
    appears to r1 alone, which asks it at once; from then on only the announcements can move
    the items on: r2 hears r1's, r3 hears r2's, each asks its announcer at once."""
    ports = [free_port() for _ in range(4)]
    with ExitStack() as stack:
        learners = [
            stack.enter_context(member(f"r{i}", line_settings(quiet, ports[i], ports[i - 1])))
            for i in (1, 2, 3)
        ]
        robots = [m for m, _ in learners]
        # Every learner asked and lost a query, and its cool-down holds it back.
        steps_until(
            robots,
            lambda: all(
                m.agent.metrics.queries_lost >= 1 and m.agent.open_query is None for m in robots
            ),
        )
        teacher, _ = stack.enter_context(member("t", line_settings(quiet, ports[0]), COLOURS))
        everyone = [teacher, *robots]
        steps_until(everyone, lambda: all(m.done for m in robots))
        for m, taught_by in zip(robots, ["t", "r1", "r2"], strict=True):
            assert {source for _, source in m.agent.metrics.learned.values()} == {taught_by}
        transports = [t for _, t in learners]
        assert all(1 <= t.announced <= len(KEYS) for t in transports)  # one put a merge
        assert all(t.refused == 0 for t in transports) and all(m.refused == 0 for m in robots)


class Announcing:
    """A member's relay on its real transport that notes, at each announcement, the writes of
    its save file made so far (the keys each held)."""

    def __init__(self, transport: ZenohTransport, writes: list[list[str]]) -> None:
        self.transport, self.writes = transport, writes
        self.announced: list[tuple[list[str], int]] = []

    def learned(self, keys: list[str]) -> None:
        self.announced.append((list(keys), len(self.writes)))
        self.transport.learned(keys)

    def news(self, now: float) -> list[tuple[str, tuple[str, ...]]]:
        return self.transport.news(now)


def test_a_member_announces_what_it_merged_before_saving_it_in_one_write(
    quiet: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The answers one step reads are merged, announced, and only then saved, in one write
    (sections 4.5 and 5): a neighbour asks while the file is written, not after one write an
    item."""
    writes: list[list[str]] = []
    save = KnowledgeBase.save

    def counted(base: KnowledgeBase, path: str | Path) -> None:
        writes.append(sorted(item.key for item in base))
        save(base, path)

    monkeypatch.setattr(KnowledgeBase, "save", counted)
    saved = tmp_path / "r1.json"
    pt, pl = free_port(), free_port()
    with ExitStack() as stack:
        teacher, _ = stack.enter_context(member("t", line_settings(quiet, pt), COLOURS))
        transport = stack.enter_context(
            ZenohTransport("r1", line_settings(quiet, pl, pt), query_timeout=2.0)
        )
        robot = ApplicationTimedAgent(
            "r1", with_knowledge(DEMO_CONTROL, None), demo_registry(), transport,
            knowledge_path=saved,
        )  # fmt: skip
        relay = Announcing(transport, writes)
        learner = FleetMember(
            robot, transport, None, KEYS, wait=2.0, cooldown=COOLDOWN, say=lambda _: None,
            relay=relay,
        )  # fmt: skip
        steps_until([teacher, learner], lambda: learner.done)
    assert sorted(k for keys, _ in relay.announced for k in keys) == sorted(KEYS)
    assert len(writes) == len(relay.announced)  # one write a step that learned
    for n, (keys, before) in enumerate(relay.announced):
        assert before == n  # the step's own write came after its announcement
        assert set(keys) <= set(writes[n]) and not set(keys) & set(writes[n - 1] if n else [])
    assert sorted(json.loads(saved.read_text())["knowledge"][i]["sequence"]
                  for i in range(len(KEYS))) == sorted(KEYS)  # fmt: skip


def reach(network: ZenohTransport, queries: list[str]) -> None:
    """Until the liar's queryable is reached from the learner's session (it records a probe's
    key), then the probe forgotten: the learner's first query must reach the liar, whose raw
    session has no liveliness token to be seen appearing by."""

    def reached() -> bool:
        network.session.get("ktbt/v1/knowledge/probe", timeout=0.5)
        return wait_until(lambda: "ktbt/v1/knowledge/probe" in queries, 0.5)

    assert wait_until(reached, 60)
    queries.clear()


@contextmanager
def liar(port: int, connect: int, hold: bool = False) -> Iterator[tuple[Any, list[str]]]:
    """A raw zenoh session beside a learner: it announces what it likes, in any name, and its
    queryable on ``ktbt/v1/knowledge/*`` keeps the key of every query it gets (it never
    answers). It finishes each query at once (the asker's get ends: no answer can come), or,
    with ``hold``, only when it closes (an answer may be on its way until then)."""
    session: Any = open_session(ZenohSettings(listen=[endpoint(port)], connect=[endpoint(connect)]))
    queries: list[str] = []
    held: list[Any] = []

    def on_query(query: Any) -> None:
        queries.append(str(query.key_expr))
        if hold:
            held.append(query)
        else:
            query.drop()

    entities = [session.declare_queryable("ktbt/v1/knowledge/*", on_query)]
    try:
        yield session, queries
    finally:
        for query in held:
            query.drop()
        for entity in entities:
            entity.undeclare()
        session.close()


def asked_by(
    stack: ExitStack,
    learner: FleetMember,
    network: ZenohTransport,
    ports: tuple[int, int],
    hold: bool = False,
) -> tuple[Any, list[str], Any, float]:
    """A liar on the first of ``ports`` dialling the learner's, reached; then the learner's
    first step asks (a broadcast, which the liar gets, and with ``hold`` holds) and starts
    hearing announcements: the liar's session, the queries it got, its announcement publisher
    and the member's clock then."""
    session, queries = stack.enter_context(liar(*ports, hold=hold))
    lies: Any = session.declare_publisher("ktbt/v1/learned/liar", congestion_control=BLOCK)
    stack.callback(lies.undeclare)
    reach(network, queries)
    t0 = time.monotonic()
    while not (queries and lies.matching_status.matching):
        assert time.monotonic() < t0 + 60  # discovery, however loaded the machine
        step(learner, now=t0)
    return session, queries, lies, t0


def test_a_hostile_announcer_is_refused_or_costs_one_bounded_ask(
    quiet: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    pl, ph = free_port(), free_port()
    with ExitStack() as stack:
        learner, network = stack.enter_context(
            member("learner", line_settings(quiet, pl), wait=30.0)
        )
        # Its first step asks (a broadcast, which the liar gets and holds) and starts hearing.
        session, queries, lies, t0 = asked_by(stack, learner, network, (ph, pl), hold=True)
        # Bad bytes, the wrong shape, a name no peer has, too large: each a counted refusal.
        bad = [b"\xff", b"[]", b'{"v": 1}', b'["<c>(A)", "<c>(A)"]', b"[" + b" " * 70_000 + b"]"]
        for payload in bad:
            lies.put(payload)
        session.put(
            "ktbt/v1/learned/" + "x" * 65, encode_learned([GREEN]), congestion_control=BLOCK
        )
        # And one whose reading raises (section 2.1's test hook): a refusal like the others.
        monkeypatch.setattr(refusals, "_stage", "message")
        lies.put(encode_learned(["<c>(ktbt-fault)"]))
        assert wait_until(lambda: network.refused == len(bad) + 2, 60)
        monkeypatch.setattr(refusals, "_stage", "")
        assert "an announcement from liar: internal error reading a message: InjectedFault" in (
            caplog.text
        )
        # A lie (it announces what it does not know), a hundred times. Just after its broadcast,
        # which the liar holds, an answer may be on its way: the announcement waits; then the
        # liar is asked, once.
        for _ in range(100):
            lies.put(encode_learned([GREEN]))
        assert wait_until(lambda: network.announcements >= 1)
        for _ in range(10):
            step(learner, now=t0)
        assert len(queries) == 1
        t1 = t0 + RELAY_GRACE
        assert learner.due(t0) == t1  # when a host at rest steps it again for the announcement
        while len(queries) < 2:
            assert time.monotonic() < t0 + 60  # discovery, however loaded the machine
            step(learner, now=t1)
        heard = network.announcements
        for _ in range(100):
            lies.put(encode_learned([GREEN]))
        assert wait_until(lambda: network.announcements > heard)
        for _ in range(20):
            step(learner, now=t1)
        assert len(queries) == 2  # the broadcast, and one ask of the liar within the hold
        lies.put(encode_learned([GREEN]))
        assert wait_until(lambda: network.announcements > heard + 1)
        while len(queries) < 3:  # once the hold is over, one more
            assert time.monotonic() < t0 + 60  # discovery, however loaded the machine
            step(learner, now=t1 + RELAY_HOLD)
        # A flood of announcers, 300 names each announcing one of the four sequences: those
        # beyond the 256 waiting are refused; one announcer of each sequence is asked, alone.
        refused, sent = network.refused, learner.agent.metrics.queries_sent
        for n in range(300):
            session.put(
                f"ktbt/v1/learned/liar{n}",
                encode_learned([KEYS[n % len(KEYS)]]),
                congestion_control=BLOCK,
            )
        assert wait_until(lambda: network.refused == refused + 300 - network.max_pending, 60)
        step(learner, now=t1 + 2 * RELAY_HOLD)

        def flood() -> list[str]:
            return [k for k in queries if re.fullmatch(r"ktbt/v1/knowledge/liar\d+", k)]

        assert wait_until(lambda: len(flood()) == len(KEYS))
        for _ in range(10):
            step(learner, now=t1 + 2 * RELAY_HOLD)
        assert len(flood()) == len(KEYS)  # the others held back: each sequence asked once
        assert learner.todo == KEYS  # nothing learned from a lie, nothing broken
        assert learner.agent.metrics.queries_sent == sent  # the open query, sent on
        assert learner.refused == 0


def test_an_announcement_waits_for_no_answer_that_cannot_come(quiet: Path) -> None:
    """Once every peer its broadcast reached has finished with it (the get ended), no answer
    is on its way: an announcement heard within the grace is taken at once (section 4.5), as
    when a learner's timed ask, answered by none, came just before its neighbour learned."""
    pl, ph = free_port(), free_port()
    with ExitStack() as stack:
        learner, network = stack.enter_context(
            member("learner", line_settings(quiet, pl), wait=30.0)
        )
        _, queries, lies, t0 = asked_by(stack, learner, network, (ph, pl))
        query = learner.agent.open_query
        assert query is not None and learner.learner.sent == {"": t0}
        assert wait_until(lambda: not network.awaiting(query.id))  # the liar finished it
        lies.put(encode_learned([GREEN]))
        assert wait_until(lambda: network.announcements >= 1)
        step(learner, now=t0)  # within the grace of the broadcast
        assert wait_until(lambda: queries[1:] == ["ktbt/v1/knowledge/liar"])
        assert learner.agent.open_query is query  # the open query, sent on to the announcer


def test_an_announcement_kept_while_the_query_closed_is_due_at_once(quiet: Path) -> None:
    """An announcement kept waiting for an answer that may come (section 4.5) is taken at the
    next step once the query has closed: the member says it is due at once, so a host at rest
    does not sleep past it until the backoff's next ask."""
    pl, ph = free_port(), free_port()
    with ExitStack() as stack:
        learner, network = stack.enter_context(member("learner", line_settings(quiet, pl)))
        network.query_timeout = 120.0  # the liar holds the broadcast's get open throughout
        _, queries, lies, t0 = asked_by(stack, learner, network, (ph, pl), hold=True)
        lies.put(encode_learned([GREEN]))
        assert wait_until(lambda: network.announcements >= 1)
        step(learner, now=t0 + 0.4)  # kept: the broadcast's answer may be on its way
        assert learner.due(t0 + 0.4) == t0 + 0.5  # the query's wait
        step(learner, now=t0 + 0.5)  # kept again, then the query's wait is over: closed
        assert learner.agent.open_query is None and len(queries) == 1
        assert learner.due(t0 + 0.5) == t0 + 0.5  # not the backoff's next ask
        step(learner, now=t0 + 0.5)
        assert wait_until(lambda: queries[1:] == ["ktbt/v1/knowledge/liar"])


def test_announcements_stretch_an_open_querys_wait_once_at_most(quiet: Path) -> None:
    """A liar announcing what the learner lacks every hold cannot keep the learner's query
    open for ever (which would put off its timed ask): the first announcer asked stretches the
    wait, later ones are asked without stretching it. Steps on the member's own clock."""
    pl, ph = free_port(), free_port()
    with ExitStack() as stack:
        learner, network = stack.enter_context(
            member("learner", line_settings(quiet, pl), wait=3.0)
        )
        _, queries, lies, t0 = asked_by(stack, learner, network, (ph, pl))
        query = learner.agent.open_query
        assert query is not None
        for when, asked in ((t0 + 1.5, 2), (t0 + 3.6, 3)):  # each past the last one's hold
            heard = network.announcements
            lies.put(encode_learned([GREEN]))
            assert wait_until(lambda: network.announcements > heard)  # noqa: B023
            step(learner, now=when)
            assert wait_until(lambda: len(queries) == asked)  # noqa: B023
            assert learner.agent.open_query is query
        lost = learner.agent.metrics.queries_lost
        step(learner, now=t0 + 4.5)  # the wait, stretched once (to t0 + 1.5 + 3), is over
        assert learner.agent.open_query is None
        assert learner.agent.metrics.queries_lost == lost + 1
