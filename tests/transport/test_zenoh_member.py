"""Fleet members that survive a real network (spec/protocol.md sections 3, 4.5 and 5), as real
``ktbt peer`` processes on loopback: teachers and learners are one program and knowledge travels
hops with its author's bytes; a member killed with SIGKILL comes back, as the same zenoh peer,
with what it saved; a save file it cannot read is set aside, never overwritten; a learner
started before any teacher learns when one appears."""

from __future__ import annotations

import json
import signal
from pathlib import Path

import pytest

from ktbt_proto.exchange.backoff import Backoff
from ktbt_proto.exchange.knowledge import KnowledgeBase
from ktbt_proto.exchange.messages import Query
from ktbt_proto.exchange.signing import Identity, item_bytes, verify
from ktbt_proto.items import sequence_key
from ktbt_proto.tools.peer import PeerSettings
from ktbt_proto.transport.zenoh import stable_zid
from tests.zenoh_helpers import ROOT, endpoint, free_port, ktbt_process, ktbt_run, serving

KNOWLEDGE = ROOT / "examples" / "knowledge" / "colours.sbt"
pytestmark = pytest.mark.network  # ktbt peer processes on loopback


def run(name: str, port: int, *extra: str) -> list[str]:
    return ["peer", "run", "--id", name, "--listen", endpoint(port), *extra]


@pytest.mark.slow
def test_teachers_and_learners_are_one_program_and_knowledge_travels_two_hops(
    tmp_path: Path,
) -> None:
    """t (``peer run --knowledge``, signed) -> r1 -> r2: peers do not relay and gossip is off,
    so r2, which reaches r1 only, learns from r1; under ``--policy trusted`` r2 believes only
    t's signature as the author's (and r1's as the sender's), so the item it saved is t's, byte
    for byte."""
    key, hop = tmp_path / "t.key", tmp_path / "r1.key"
    author = Identity.generate()
    author.save(key)
    Identity.generate().save(hop)
    trust = tmp_path / "trust.txt"
    trust.write_text(f"{author.public}\n")
    quiet = tmp_path / "no-gossip.json5"
    quiet.write_text(json.dumps({"scouting": {"gossip": {"enabled": False}}}))
    pt, p1, p2 = free_port(), free_port(), free_port()
    green = "TargetSeen(colour=2)"
    with (
        ktbt_process(
            *run("t", pt, "--knowledge", str(KNOWLEDGE), "--key", str(key), "--config", str(quiet)),
            "--sequence", "TargetSeen(colour=1)", "--duration", "120",
            ready="will meet",
        ),
        ktbt_process(
            *run("r1", p1, "--connect", endpoint(pt), "--sequence", green, "--duration", "120"),
            "--key", str(hop), "--config", str(quiet),
            ready=f"learned {green} from t",
        ),
    ):  # fmt: skip
        r2 = ktbt_run(
            *run("r2", p2, "--connect", endpoint(p1), "--sequence", green, "--exit-when-done"),
            "--duration", "60", "--policy", "trusted", "--trust", str(trust),
            "--save", str(tmp_path / "r2.json"), "--config", str(quiet),
        )  # fmt: skip
    assert r2.returncode == 0, r2.stdout + r2.stderr
    assert f"r2: learned {green} from r1" in r2.stdout
    (item,) = KnowledgeBase.load(tmp_path / "r2.json")
    assert item.source == "r1" and item.author == author.public and item.signature is not None
    shown = ktbt_run("kb", "show", str(tmp_path / "r2.json"))
    assert "(valid)" in shown.stdout
    subtree = "<sq><a>(PickTreasure)<a>(AssignCollectionPoint,colour=2)<e>"
    assert verify(author.public, item.signature, item_bytes(item.key, subtree))


@pytest.mark.slow
def test_a_member_killed_with_sigkill_comes_back_the_same_peer_with_what_it_saved(
    tmp_path: Path,
) -> None:
    save = tmp_path / "r.json"
    pt, pr = free_port(), free_port()
    colours = [f"TargetSeen(colour={c})" for c in (1, 2, 3)]
    with serving(pt):
        with ktbt_process(
            *run("r", pr, "--connect", endpoint(pt), "--save", str(save)),
            "--sequence", colours[0], "--sequence", colours[1], "--duration", "120",
            ready=f"learned {colours[1]}",
        ) as first:  # fmt: skip
            first.send_signal(signal.SIGKILL)
            assert first.wait(timeout=15) == -signal.SIGKILL
        assert [k.key for k in KnowledgeBase.load(save)] == [
            "<c>(TargetSeen,colour=1)",
            "<c>(TargetSeen,colour=2)",
        ]
        again = ktbt_run(
            *run("r", pr, "--connect", endpoint(pt), "--save", str(save), "--exit-when-done"),
            *(arg for c in colours for arg in ("--sequence", c)), "--duration", "60",
        )  # fmt: skip
    assert again.returncode == 0, again.stdout + again.stderr
    assert "r: knows 2, will meet 3 sequences" in again.stdout  # everything it had saved
    assert f"r: learned {colours[2]} from teacher" in again.stdout
    assert "learned TargetSeen(colour=1)" not in again.stdout  # not learned twice
    assert len(KnowledgeBase.load(save)) == 3
    with PeerSettings("r").transport() as same:  # what both runs opened: the same zenoh peer
        assert str(same.session.info.zid()) == stable_zid("r")


@pytest.mark.slow
def test_a_save_file_it_cannot_read_is_set_aside_and_never_overwritten(tmp_path: Path) -> None:
    """Three damaged files in a row (another version, truncated, not UTF-8), each set aside
    under its own name, while the learner saves what it learns in a new file."""
    save = tmp_path / "kb.json"
    port = free_port()
    damaged = [b'{"version": 2, "knowledge": []}', b'{"version": 1, "knowledge": [{"seq', b"\xff"]
    with serving(port):
        for content in damaged:
            save.write_bytes(content)
            result = ktbt_run(
                *run("r", free_port(), "--connect", endpoint(port), "--save", str(save)),
                "--sequence", "TargetSeen(colour=2)", "--exit-when-done", "--duration", "60",
            )  # fmt: skip
            assert result.returncode == 0, result.stdout + result.stderr
            assert "r: refused: cannot resume" in result.stdout and "moved to kb.json" in (
                result.stdout
            )
            assert [k.key for k in KnowledgeBase.load(save)] == ["<c>(TargetSeen,colour=2)"]
    aside = sorted(tmp_path.glob("kb.json.damaged-*"))
    assert sorted(p.read_bytes() for p in aside) == sorted(damaged)  # all three, whole


@pytest.mark.slow
def test_a_learner_started_before_any_teacher_learns_when_one_appears(tmp_path: Path) -> None:
    """Both dial: the learner dials the teacher's endpoint (retried for ever) and the teacher
    dials the learner's. The learner asks for both sequences it lacks in one query, and the
    teacher's appearance (its liveliness) has it send that query to the teacher at once,
    which answers each sequence (spec/protocol.md sections 1, 3 and 4.5)."""
    pt, pl = free_port(), free_port()
    log = tmp_path / "r.log"
    wanted = ("--sequence", "TargetSeen(colour=3)", "--sequence", "TargetSeen(colour=4)")
    with ktbt_process(
        *run("r", pl, "--connect", endpoint(pt), *wanted, "--log", str(log)),
        "--exit-when-done", "--duration", "90",
        ready="will meet",
    ) as learner:  # fmt: skip
        assert learner.stdout is not None
        with serving(pt, "--connect", endpoint(pl)):
            assert learner.wait(timeout=60) == 0
            out = learner.stdout.read()
    assert "r: learned TargetSeen(colour=3) from teacher" in out
    events = [json.loads(line) for line in log.read_text().splitlines()]
    kinds = [e["event"] for e in events]
    assert kinds[0] == "session-up"
    first = next(e for e in events if e["event"] == "query-sent")
    assert first["more"] == ["<c>(TargetSeen,colour=4)"]  # both in one query
    seen = kinds.index("peer-seen")
    assert events[seen]["sender"] == "teacher"
    merged = [e for e in events if e["event"] == "merged"]
    asked = next(e for e in events if e["event"] == "answer-received")["id"]
    assert {e["teacher"] for e in merged} == {"teacher"} and len(merged) == 2
    # The answered query went out once the teacher was seen: to it alone, or a new one.
    sent = [i for i, e in enumerate(events) if e["event"] == "query-sent" and e["id"] == asked]
    assert max(sent) > seen


def test_with_no_query_open_a_peer_that_appears_is_asked_alone() -> None:
    """A newcomer is asked at once, alone: the peers present before were asked already, and a
    broadcast would wake them all again (spec/protocol.md section 4.5). Of several newcomers at
    once, NEWCOMERS_AT_ONCE are asked, each alone: no broadcast reaches a peer not drawn."""
    from ktbt_proto.exchange.application import ApplicationTimedAgent
    from ktbt_proto.exchange.member import NEWCOMERS_AT_ONCE, RELAY_GRACE, Learner
    from ktbt_proto.transport import MemoryNetwork
    from tests.exchange.test_agent import CONTROL, KNOWER, SEQUENCE, registry

    net = MemoryNetwork()
    robot = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"))
    teacher = ApplicationTimedAgent("t", KNOWER, registry(), net.join("t"))
    other = ApplicationTimedAgent("x", CONTROL, registry(), net.join("x"))
    learner = Learner(robot, Backoff(seed="l"), wait=2.0, cooldown=0.5)
    missing = [sequence_key(SEQUENCE)]
    learner.backoff.lost(0.0)  # an unanswered query before: it would not broadcast now
    learner.step(0.1, missing, ["t"])
    teacher.receive(), other.receive()
    heard = teacher.heard("l")
    assert isinstance(heard, Query) and other.heard("l") is None
    teacher.answer(heard)
    robot.receive()
    learner.step(0.2, [], [])
    assert robot.knows(SEQUENCE) and robot.open_query is None
    crowd = [f"n{i}" for i in range(NEWCOMERS_AT_ONCE + 3)]
    agents = {n: ApplicationTimedAgent(n, CONTROL, registry(), net.join(n)) for n in crowd}
    robot2 = ApplicationTimedAgent("m", CONTROL, registry(), net.join("m"))
    second = Learner(robot2, Backoff(seed="m"), wait=2.0, cooldown=0.5)
    second.backoff.lost(0.0)
    second.step(0.1, missing, crowd)
    for agent in [other, *agents.values()]:
        agent.receive()
    asked = [n for n, agent in agents.items() if agent.heard("m") is not None]
    assert len(asked) == NEWCOMERS_AT_ONCE and other.heard("m") is None  # no broadcast
    # More newcomers while that answer may be on its way: none asked yet; once no answer can be
    # on its way (RELAY_GRACE), the newest waiting is sent the open query, the others wait on.
    late = ApplicationTimedAgent("n-late", CONTROL, registry(), net.join("n-late"))
    second.step(0.2, missing, ["n-late"])
    late.receive()
    assert late.heard("m") is None
    assert second.due(0.2, missing) == 0.1 + RELAY_GRACE  # a host at rest wakes then for it
    second.step(0.1 + RELAY_GRACE, missing, [])
    for agent in [late, *agents.values()]:
        agent.receive()
    assert late.heard("m") is not None
    assert sum(agent.heard("m") is not None for agent in agents.values()) == NEWCOMERS_AT_ONCE


def test_backoff_doubles_to_its_bound_and_resets() -> None:
    backoff = Backoff(first=0.25, most=2.0, jitter=0.0)
    assert backoff.ready(0.0)
    holds = []
    for _ in range(6):
        backoff.lost(10.0)
        holds.append(backoff.hold)
    assert holds == [0.25, 0.5, 1.0, 2.0, 2.0, 2.0]
    assert not backoff.ready(11.0) and backoff.ready(12.0)
    backoff.reset(11.0)
    assert backoff.ready(11.0) and backoff.hold == 0


def test_backoff_jitter_spreads_a_fleet_and_repeats_per_member() -> None:
    def holds(seed: str) -> list[float]:
        backoff = Backoff(first=0.25, most=2.0, seed=seed)
        out = []
        for _ in range(6):
            backoff.lost(10.0)
            assert backoff.hold * 1.0 <= backoff.until - 10.0 <= backoff.hold * 1.5
            out.append(backoff.until)
        return out

    fleet = [holds(f"r{n}") for n in range(10)]
    assert len({h[0] for h in fleet}) == 10  # lost together, they do not ask again in step
    assert holds("r3") == fleet[3]  # the same member draws the same holds: a run repeats


def test_zenoh_ids_are_stable_valid_and_distinct() -> None:
    ids = {stable_zid(f"r{n}") for n in range(200)}
    assert len(ids) == 200 and all(len(i) == 32 and i[0] != "0" for i in ids)
    assert stable_zid("r1") == stable_zid("r1")


@pytest.mark.slow
def test_a_member_with_knowledge_answers_every_asker_at_once_as_a_server_does() -> None:
    """Six peers ask a ``peer run --knowledge`` member at the same moment, each waiting 1 s:
    all six are answered (its teach tree alone answers one asker per 0.5 s cool-down)."""
    import threading

    from ktbt_proto.exchange.messages import Query
    from ktbt_proto.transport.zenoh import ZenohTransport
    from tests.zenoh_helpers import reached, settings

    pt = free_port()
    with (
        ktbt_process(
            *run("t", pt, "--knowledge", str(KNOWLEDGE), "--sequence", "TargetSeen(colour=1)"),
            "--duration", "120", ready="will meet",
        ),
    ):  # fmt: skip
        askers = [ZenohTransport(f"a{n}", settings(free_port(), pt)) for n in range(6)]
        try:
            for asker in askers:
                reached(asker, "t")
            got: dict[str, int] = {}

            def ask(asker: ZenohTransport) -> None:
                query = Query(id=Query.new_id(), sender=asker.name, sequence=SEQ)
                got[asker.name] = len(asker.ask(query, timeout=1.0))

            threads = [threading.Thread(target=ask, args=(a,)) for a in askers]
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join()
        finally:
            for asker in askers:
                asker.close()
    assert got == {f"a{n}": 1 for n in range(6)}


SEQ = "<c>(TargetSeen,colour=2)"
