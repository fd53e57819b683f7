"""Hostile peers on real zenoh sessions (loopback): silent, impostor, replaying, flooding and
lying peers cannot delay, forge or poison what a learner learns (spec/protocol.md sections 2, 3
and 7)."""

from __future__ import annotations

import json
import threading
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import pytest

import ktbt_proto as kp
from ktbt_proto.exchange.agent import Agent, Timing
from ktbt_proto.exchange.answers import answers
from ktbt_proto.exchange.knowledge import KnowledgeBase
from ktbt_proto.exchange.messages import ErrorReply, Query, Response, decode, encode
from ktbt_proto.exchange.security import Security
from ktbt_proto.exchange.signing import Identity
from ktbt_proto.exchange.transferlog import TransferLog, read
from ktbt_proto.exchange.trust import Policy, TrustStore
from ktbt_proto.tools.demo import DEMO_CONTROL, demo_registry
from ktbt_proto.transport.zenoh import ZenohTransport
from tests.zenoh_helpers import ROOT, endpoint, free_port, ktbt_run, see, settings, wait_until

pytestmark = pytest.mark.network  # zenoh sessions and ktbt processes on loopback

KNOWLEDGE = ROOT / "examples" / "knowledge" / "colours.sbt"
GREEN = "<c>(TargetSeen,colour=2)"
HONEST = "<sq><a>(PickTreasure)<a>(AssignCollectionPoint,colour=2)<e>"
FORGED = "<sq><a>(PickTreasure)<a>(AssignCollectionPoint,colour=4)<e>"


@contextmanager
def hostile(name: str, port: int, *connect: int) -> Iterator[tuple[ZenohTransport, list[Any]]]:
    """A peer whose extra queryables a test declares; the queries they hold are dropped at
    the end."""
    held: list[Any] = []
    with ZenohTransport(name, settings(port, *connect), serving=False) as peer:
        try:
            yield peer, held
        finally:
            for q in held:
                q.drop()


def declare(peer: ZenohTransport, key: str, handler: Callable[[Any], None]) -> None:
    peer._declared.append(peer.session.declare_queryable(key, handler))


def teacher_kb() -> KnowledgeBase:
    return KnowledgeBase.from_tree(kp.parse(KNOWLEDGE.read_text()))


@pytest.mark.slow
def test_a_silent_peer_delays_no_one_and_an_impostor_replaces_no_answer() -> None:
    """The answer reaches the learner while a silent peer still holds the query (its timeout is
    30 s); a second reply on the teacher's key is refused, not taken in its place; a reply on
    another peer's key naming the teacher is refused."""
    pt, ps, pi, pl = free_port(), free_port(), free_port(), free_port()
    kb = teacher_kb()
    with (
        ZenohTransport("t", settings(pt), lookup=answers(kb), catalog=kb.keys),
        hostile("silent", ps, pt) as (silent, held),
        hostile("imp", pi, pt) as (imp, _),
        ZenohTransport("me", settings(pl, pt, ps, pi), query_timeout=30) as learner,
    ):
        declare(silent, "ktbt/v1/knowledge/quiet", held.append)  # never answers

        genuine_arrived = threading.Event()
        replying: list[threading.Thread] = []

        def impostor(q: Any) -> None:
            asked = decode(q.payload.to_bytes())
            forged = encode(Response(id=asked.id, sender="t", sequence=GREEN, subtree=FORGED))

            def after_the_genuine_answer() -> None:
                genuine_arrived.wait(10)
                q.reply("ktbt/v1/knowledge/t", forged)  # on the teacher's key
                q.reply("ktbt/v1/knowledge/imp", forged)  # on its own key, naming the teacher
                q.drop()

            replying.append(threading.Thread(target=after_the_genuine_answer))
            replying[-1].start()

        declare(imp, "ktbt/v1/knowledge/t", impostor)
        see(learner, "t", "silent", "imp")
        learner.broadcast(Query(id="q1", sender="me", sequence=GREEN))
        got: list[Any] = []

        def arrived() -> bool:
            got.extend(learner.receive())
            return bool(got)

        try:
            assert wait_until(arrived, 10)
            genuine_arrived.set()
            assert [(m.sender, m.subtree) for m in got] == [("t", HONEST)]
            assert held  # the silent peer still holds the query: the answer did not wait for it
            assert wait_until(lambda: learner.refused >= 2, 10)
            assert learner.receive() == []
        finally:
            genuine_arrived.set()
            for thread in replying:
                thread.join(15)


def test_queries_come_only_through_the_queryable_and_are_not_replaced() -> None:
    pa, pb = free_port(), free_port()
    with (
        ZenohTransport("victim", settings(pa)) as victim,
        ZenohTransport("evil", settings(pb, pa), serving=False) as evil,
    ):
        see(evil, "victim")
        genuine = Query(id="g1", sender="alice", sequence=GREEN)
        evil.broadcast(genuine)
        assert wait_until(lambda: ("alice", "g1") in victim._pending)
        first = victim._pending[("alice", "g1")][0]
        evil.broadcast(genuine)  # a replay of (sender, id)
        assert wait_until(lambda: victim.refused >= 1)
        assert victim._pending[("alice", "g1")][0] is first
        # A query put in an inbox, or sent back as a reply, is not a received query.
        evil.session.put(
            "ktbt/v1/inbox/victim", encode(Query(id="x", sender="bob", sequence=GREEN))
        )
        assert wait_until(lambda: victim.refused >= 2)
        assert [m.id for m in victim.receive()] == ["g1"]


def test_a_query_sent_back_as_a_reply_and_an_over_long_reason_are_refused() -> None:
    pa, pb = free_port(), free_port()
    with (
        hostile("evil", pa) as (evil, _),
        ZenohTransport("me", settings(pb, pa), serving=False) as me,
    ):

        def mirror(q: Any) -> None:
            q.reply("ktbt/v1/knowledge/evil", q.payload.to_bytes())
            q.drop()

        declare(evil, "ktbt/v1/knowledge/evil", mirror)
        see(me, "evil")
        assert me.ask(Query(id="q", sender="me", sequence=GREEN), 2) == []
        assert me.refused == 1
        # A refusal whose reason would not fit an error reply still gets one.
        replies = list(
            me.session.get(
                "ktbt/v1/knowledge/*", payload=b'{"type":"' + b"q" * 1000 + b'"}', timeout=2
            )
        )
        errors = [decode(r.err.payload.to_bytes()) for r in replies if r.err is not None]
        assert errors and all(isinstance(e, ErrorReply) and e.code == "refused" for e in errors)


def trusted_learner(port: int, *connect: int, security: Security) -> tuple[Agent, ZenohTransport]:
    transport = ZenohTransport("learner", settings(port, *connect), query_timeout=30)
    robot = Agent(
        "learner", DEMO_CONTROL, demo_registry(), transport, timing=Timing(wait=2000),
        security=security,
    )  # fmt: skip
    return robot, transport


@pytest.mark.slow
def test_trusted_learner_learns_from_the_honest_peer_among_silent_flooding_and_lying_ones(
    tmp_path: Path,
) -> None:
    """The issue's acceptance test: under the trusted policy, with a silent peer, a peer that
    floods 10,000 replies, and an impostor answering first on the teacher's own key (unsigned,
    and signed with its own key), the learner refuses every forgery and learns the honest,
    signed answer."""
    honest, mallory = Identity.generate(), Identity.generate()
    store = TrustStore.parse(f"t {honest.public}\n")
    kb = teacher_kb()
    ports = [free_port() for _ in range(5)]
    pt, ps, pf, pi, pl = ports
    transfer_log = TransferLog(tmp_path / "learner.log")
    with ExitStack() as stack:
        stack.enter_context(transfer_log)
        server_log = stack.enter_context(TransferLog(tmp_path / "t.log"))
        teacher = stack.enter_context(
            ZenohTransport(
                "t",
                settings(pt),
                lookup=answers(kb, honest),
                catalog=kb.keys,
                identity=honest,
                log=server_log,
            )
        )
        silent, held = stack.enter_context(hostile("silent", ps, pt))
        flood, _ = stack.enter_context(hostile("flood", pf, pt))
        imp, _ = stack.enter_context(hostile("imp", pi, pt))
        declare(silent, "ktbt/v1/knowledge/silent", held.append)

        def flooding(q: Any) -> None:
            asked = decode(q.payload.to_bytes())
            junk = encode(Response(id=asked.id, sender="flood", sequence=GREEN, subtree=FORGED))
            for _ in range(10_000):
                q.reply("ktbt/v1/knowledge/flood", junk)
            q.drop()

        def lying(q: Any) -> None:
            asked = decode(q.payload.to_bytes())
            plain = Response(id=asked.id, sender="t", sequence=GREEN, subtree=FORGED)
            item = mallory.sign_item(GREEN, FORGED)
            signed = plain.model_copy(update={"author": item.author, "signature": item.signature})
            q.reply("ktbt/v1/knowledge/t", encode(plain))  # before the teacher can
            q.reply("ktbt/v1/knowledge/t", encode(mallory.sign_reply(signed)))  # its own key
            mine = signed.model_copy(update={"sender": "imp"})
            q.reply("ktbt/v1/knowledge/imp", encode(mallory.sign_reply(mine)))  # not trusted
            q.drop()

        declare(flood, "ktbt/v1/knowledge/flood", flooding)
        declare(imp, "ktbt/v1/knowledge/t", lying)
        robot, transport = trusted_learner(
            pl, pt, ps, pf, pi,
            security=Security(policy=Policy.TRUSTED, trust=store, log=transfer_log),
        )  # fmt: skip
        stack.enter_context(transport)
        transport.log = transfer_log
        see(transport, "t", "silent", "flood", "imp")
        robot.encounter(["TargetSeen(colour=2)"])
        assert wait_until(
            lambda: robot.tick() is None or robot.knows(["TargetSeen(colour=2)"]), 60
        ), robot.metrics.refusals
        item = robot.knowledge.lookup(GREEN)
        assert item is not None and kp.format_tree(item.subtree, "compact") == HONEST
        assert (item.source, item.author) == ("t", honest.public)
        assert teacher.refused == 0
    total = robot.metrics.refused + transport.refused  # sessions closed: the count is final
    assert total >= 1  # the forgeries that arrived were refused and counted
    events = [e for e in read(tmp_path / "learner.log") if isinstance(e, dict)]
    kinds = {e["event"] for e in events}
    assert {"query-sent", "answer-received", "merged"} <= kinds
    assert sum(e["event"] == "refused" for e in events) == total
    merged = [e for e in events if e["event"] == "merged"]
    assert merged[0]["author"] == honest.public
    served = [e["event"] for e in read(tmp_path / "t.log") if isinstance(e, dict)]
    exchange = [e for e in served if e not in ("session-up", "peer-seen")]  # its timeline marks
    assert served[0] == "session-up" and exchange[:2] == ["query-received", "answer-sent"]


def test_serve_refuses_a_knowledge_file_without_end(tmp_path: Path) -> None:
    result = ktbt_run(
        "peer", "serve", "--knowledge", "/dev/zero", "--listen", endpoint(free_port()), timeout=60
    )
    assert result.returncode == 2  # a user error: one line naming the file, exit 2
    assert result.stderr.startswith("/dev/zero:") and "SBT201" in result.stderr
    assert "Traceback" not in result.stderr and len(result.stderr.splitlines()) == 1


@pytest.mark.slow
def test_run_reports_refusals_and_keeps_a_damaged_save_file(tmp_path: Path) -> None:
    save = tmp_path / "kb.json"
    save.write_text('{"version": 1, "knowledge": [{"sequence": "<c>(TargetSeen,colour=9)"')
    (tmp_path / ".kb.json.123.tmp").write_text("torn")
    result = ktbt_run(
        "peer",
        "run",
        "--id",
        "r",
        "--listen",
        endpoint(free_port()),
        "--sequence",
        "TargetSeen(colour=2)",
        "--duration",
        "2",
        "--save",
        str(save),
        "--log",
        str(tmp_path / "r.log"),
    )
    assert result.returncode == 1, result.stdout + result.stderr
    assert "r: refused: cannot resume" in result.stdout
    assert "refused 1," in result.stdout  # the summary counts it
    aside = list(tmp_path.glob("kb.json.damaged-*"))
    assert len(aside) == 1 and aside[0].read_text().startswith('{"version": 1')
    assert not list(tmp_path.glob(".kb.json.*.tmp"))
    assert "refused knowledge: cannot resume" in result.stderr  # logging is configured
    logged = [json.loads(line) for line in (tmp_path / "r.log").read_text().splitlines()]
    assert [e["event"] for e in logged if e["event"] == "refused"] == ["refused"]


def test_outgoing_queries_are_bounded_and_catalogs_carry_provenance() -> None:
    pa, pb = free_port(), free_port()
    author = Identity.generate()
    kb = KnowledgeBase(
        item.__class__(item.conditions, item.subtree, item.segment, "k", author=author.public)
        for item in teacher_kb()
    )
    from ktbt_proto.exchange.answers import catalog
    from ktbt_proto.transport.zenoh import catalogs

    with (
        ZenohTransport("t", settings(pa), lookup=answers(kb), catalog=catalog(kb)),
        ZenohTransport("me", settings(pb, pa), serving=False, max_asking=2) as me,
    ):
        see(me, "t")
        entries = catalogs(me)["t"]
        assert entries[0]["author"] == author.public and entries[0]["teacher"] == "k"
        for n in range(50):  # far more than the workers can send at once
            me.broadcast(Query(id=f"q{n}", sender="me", sequence=GREEN))
        assert me.refused >= 1  # refused and counted, not queued without end


def test_peer_list_shows_who_authored_what_a_signed_server_serves(tmp_path: Path) -> None:
    from tests.zenoh_helpers import ktbt_process

    key = tmp_path / "t.key"
    public = Identity.generate().save(key).read_text().strip()
    port = free_port()
    with ktbt_process(
        "peer",
        "serve",
        "--id",
        "t",
        "--key",
        str(key),
        "--knowledge",
        str(KNOWLEDGE),
        "--listen",
        endpoint(port),
        ready="serving",
    ):
        listed = ktbt_run("peer", "list", "--connect", endpoint(port), "--timeout", "5")
    assert listed.returncode == 0, listed.stdout + listed.stderr
    assert f"  TargetSeen(colour=2)  (author {public})" in listed.stdout  # as people type it


def test_no_number_of_silent_peers_holds_an_asker_or_a_thread() -> None:
    """Three silent peers hold every query for the whole query timeout (30 s). Six queries in a
    row are still all sent and answered by the teacher while the silent peers hold them, and
    the open gets hold no thread (spec/protocol.md section 3)."""
    pt, pl = free_port(), free_port()
    quiet = [free_port() for _ in range(3)]
    kb = teacher_kb()
    with ExitStack() as stack:
        stack.enter_context(ZenohTransport("t", settings(pt), lookup=answers(kb)))
        held: list[Any] = []
        for n, port in enumerate(quiet):
            silent, _ = stack.enter_context(hostile(f"silent{n}", port, pt))
            declare(silent, f"ktbt/v1/knowledge/quiet{n}", held.append)  # never answers
        learner = stack.enter_context(
            ZenohTransport("me", settings(pl, pt, *quiet), query_timeout=30)
        )
        see(learner, "t", "silent0", "silent1", "silent2")
        threads = threading.active_count()
        for n in range(6):
            learner.broadcast(Query(id=f"q{n}", sender="me", sequence=GREEN))
        got: list[Any] = []

        def answered() -> bool:
            got.extend(learner.receive())
            return len(got) >= 6

        assert wait_until(answered, 15)
        assert sorted(m.id for m in got) == [f"q{n}" for n in range(6)]
        assert wait_until(lambda: len(held) == 18, 10)  # each silent peer holds all six
        assert threading.active_count() == threads  # six open gets, no thread held for them
        assert learner.network_errors == 0 and learner.refused == 0


def test_the_networks_own_errors_are_counted_apart_not_refused(tmp_path: Path) -> None:
    """A get that times out at the asker: zenoh sends its own reply error (``Timeout``), which
    is the network's, not a peer's message: counted in ``network_errors`` and logged as a
    ``network-error`` event, never decoded nor counted as a refusal."""
    ps, pl = free_port(), free_port()
    log = TransferLog(tmp_path / "me.log")
    with (
        hostile("silent", ps) as (silent, held),
        ZenohTransport("me", settings(pl, ps), query_timeout=0.5, log=log) as transport,
    ):
        declare(silent, "ktbt/v1/knowledge/quiet", held.append)
        see(transport, "silent")
        agent = Agent(
            "me",
            DEMO_CONTROL,
            demo_registry(),
            transport,
            timing=Timing(wait=1000),
            security=Security(log=log),
        )
        agent.encounter(["TargetSeen(colour=2)"])
        agent.tick()  # asks

        def timed_out() -> bool:
            agent.tick()
            return agent.metrics.network_errors >= 1

        assert wait_until(timed_out, 15)
        assert held  # the silent peer really held the query
        assert agent.metrics.refused == 0 and transport.refused == 0
        assert transport.network_errors == 1
    log.close()
    events = [e for e in read(tmp_path / "me.log") if isinstance(e, dict)]
    errors = [e for e in events if e["event"] == "network-error"]
    assert len(errors) == 1 and errors[0]["reason"] == "Timeout" and errors[0]["peer"] == "me"
    assert not [e for e in events if e["event"] == "refused"]
