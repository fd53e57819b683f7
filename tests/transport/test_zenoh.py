"""The protocol over real zenoh sessions on loopback: in one process, across three processes,
with a teacher killed mid-exchange, and from a program written against the spec alone."""

from __future__ import annotations

import functools
import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import zenoh

import ktbt_proto as kp
from ktbt_proto.exchange.agent import Agent, Timing
from ktbt_proto.exchange.knowledge import KnowledgeBase
from ktbt_proto.exchange.messages import ErrorReply, Query, Response, decode, encode
from ktbt_proto.tools.demo import DEMO_CONTROL, demo_registry
from ktbt_proto.transport.zenoh import ZenohSettings, ZenohTransport, peers
from tests.zenoh_helpers import (
    ROOT,
    endpoint,
    free_port,
    ktbt_process,
    ktbt_run,
    make_tls,
    see,
    serving,
    wait_until,
)

pytestmark = pytest.mark.network  # zenoh sessions and ktbt processes on loopback

KNOWLEDGE = ROOT / "examples" / "knowledge" / "colours.sbt"
GREEN = "<c>(TargetSeen,colour=2)"


def settings(port: int, *connect: int) -> ZenohSettings:
    return ZenohSettings(listen=[endpoint(port)], connect=[endpoint(p) for p in connect])


def serve_lookup(kb: KnowledgeBase):  # type: ignore[no-untyped-def]
    def lookup(key: str) -> str | None:
        item = kb.lookup(key)
        return None if item is None else kp.format_tree(item.subtree, "compact")

    return lookup


def test_ask_answer_presence_and_refusals_in_one_process() -> None:
    kb = KnowledgeBase.from_tree(kp.parse(KNOWLEDGE.read_text()))
    a, b = free_port(), free_port()
    with (
        ZenohTransport("teacher", settings(a), lookup=serve_lookup(kb), catalog=kb.keys) as t,
        ZenohTransport("learner", settings(b, a)) as learner,
    ):
        see(learner, "teacher")
        assert peers(learner)["teacher"] == kb.keys()
        answers = learner.ask(Query(id="q1", sender="learner", sequence=GREEN), timeout=2)
        assert answers == [
            Response(
                id="q1",
                sender="teacher",
                sequence=GREEN,
                subtree="<sq><a>(PickTreasure)<a>(AssignCollectionPoint,colour=2)<e>",
            )
        ]
        assert learner.ask(Query(id="q2", sender="learner", sequence="<c>(X)"), 1) == []
        # One query for several sequences: an answer for each one known (section 1).
        blue = "<c>(TargetSeen,colour=3)"
        many = Query.asking("learner", [GREEN, "<c>(X)", blue])
        got = learner.ask(many, timeout=2)
        assert sorted(r.sequence for r in got) == sorted([GREEN, blue])
        assert {r.id for r in got} == {many.id}
        # The same query again at once (sent to a peer as it appears, which had the broadcast
        # already) is not answered twice; a new query is (spec/protocol.md section 3).
        assert learner.ask(many, timeout=1) == []
        assert len(learner.ask(Query.asking("learner", [GREEN, blue]), timeout=2)) == 2
        # A malformed query gets an error reply, and the teacher counts the refusal.
        replies = list(learner.session.get("ktbt/v1/knowledge/*", payload=b"{oops", timeout=2))
        assert replies and all(r.err is not None for r in replies)  # the asker's own, too
        first = replies[0].err
        assert first is not None
        error = decode(first.payload.to_bytes())
        assert isinstance(error, ErrorReply) and error.code == "refused"
        assert t.refused == 1


def test_agents_over_zenoh_teach_through_their_trees() -> None:
    """With ``answer_at_once`` off, the teacher's own teach tree answers, through pending zenoh
    queries (spec section 3)."""
    a, b = free_port(), free_port()
    with (
        ZenohTransport("k", settings(a), query_timeout=2, answer_at_once=False) as tk,
        ZenohTransport("i", settings(b, a), query_timeout=2) as ti,
    ):
        teacher = Agent(
            "k",
            DEMO_CONTROL.replace(
                "<k>(prior)<e>", "<k>(prior)" + KNOWLEDGE.read_text().split("<k>(prior)", 1)[1]
            ),
            demo_registry(),
            tk,
            timing=Timing(wait=300),
        )
        learner = Agent("i", DEMO_CONTROL, demo_registry(), ti, timing=Timing(wait=300))
        learner.encounter(["TargetSeen(colour=3)"])

        def learned() -> bool:
            teacher.tick()
            learner.tick()
            return learner.knows(["TargetSeen(colour=3)"])

        assert wait_until(learned, 20)
        assert learner.metrics.learned["<c>(TargetSeen,colour=3)"][1] == "k"
        assert teacher.metrics.responses_sent == 1

        def all_finished() -> bool:  # once their answer window has passed
            tk.receive()
            return tk._pending == {}

        assert wait_until(all_finished, 10)  # every query the teacher received was finished


@pytest.mark.slow
def test_three_processes_knowledge_spreads_along_a_chain() -> None:
    """teacher -> r1 -> r2: r2 learns from r1 after the teacher has gone (Theorem 2)."""
    pt, p1, p2 = free_port(), free_port(), free_port()
    with (
        serving(pt) as teacher,
        ktbt_process(
            "peer",
            "run",
            "--id",
            "r1",
            "--listen",
            endpoint(p1),
            "--connect",
            endpoint(pt),
            "--sequence",
            "TargetSeen(colour=2)",
            "--duration",
            "60",
            ready="learned TargetSeen(colour=2) from teacher",
        ) as r1,
    ):
        teacher.send_signal(signal.SIGTERM)
        assert teacher.wait(timeout=15) == 0
        r2 = ktbt_run(
            "peer",
            "run",
            "--id",
            "r2",
            "--listen",
            endpoint(p2),
            "--connect",
            endpoint(p1),
            "--sequence",
            "TargetSeen(colour=2)",
            "--exit-when-done",
            "--duration",
            "30",
        )
        assert r2.returncode == 0, r2.stdout + r2.stderr
        assert "r2: learned TargetSeen(colour=2) from r1" in r2.stdout
        assert r1.poll() is None  # still running, still teaching


@pytest.mark.slow
def test_teacher_killed_mid_exchange_then_an_honest_peer_teaches() -> None:
    pt, pl, ph = free_port(), free_port(), free_port()
    with ZenohTransport("i", settings(pl, pt, ph), query_timeout=1.0) as ti:
        learner = Agent(
            "i", DEMO_CONTROL, demo_registry(), ti, timing=Timing(wait=100, cooldown=20)
        )
        with serving(pt, name="doomed") as doomed:
            doomed.send_signal(signal.SIGKILL)
            doomed.wait(timeout=15)
        learner.encounter(["TargetSeen(colour=1)"])

        def lost() -> bool:
            learner.tick()
            return learner.metrics.queries_lost >= 1

        assert wait_until(lost, 30)
        assert not learner.knows(["TargetSeen(colour=1)"])

        def learned() -> bool:
            learner.tick()
            return learner.knows(["TargetSeen(colour=1)"])

        with serving(ph, "--connect", endpoint(pl), name="honest"):
            assert wait_until(learned, 30)
        assert learner.metrics.learned["<c>(TargetSeen,colour=1)"][1] == "honest"


def test_a_program_written_from_the_spec_asks_a_ktbt_peer() -> None:
    port = free_port()
    with serving(port):
        proc = subprocess.run(
            [
                sys.executable,
                str(ROOT / "examples" / "ask_with_raw_zenoh.py"),
                endpoint(port),
                "<c>(TargetSeen,colour=4)",
            ],
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert proc.returncode == 0, proc.stderr
    answer = json.loads(proc.stdout)
    assert answer["type"] == "response" and answer["sender"] == "teacher"
    assert answer["subtree"] == "<sq><a>(PickTreasure)<a>(AssignCollectionPoint,colour=4)<e>"


@pytest.mark.slow
def test_peer_ask_cli_exit_codes() -> None:
    port = free_port()
    with serving(port):
        ok = ktbt_run(
            "peer",
            "ask",
            "--sequence",
            "TargetSeen(colour=1)",
            "--connect",
            endpoint(port),
            "--timeout",
            "3",
        )
        assert ok.returncode == 0 and ok.stdout.startswith("# from teacher\n<sq>\n")
        none = ktbt_run(
            "peer", "ask", "--sequence", "Nope", "--connect", endpoint(port), "--timeout", "1"
        )
        assert (none.returncode, none.stdout) == (1, "")
        listed = ktbt_run("peer", "list", "--connect", endpoint(port))
        assert listed.returncode == 0 and "teacher: 4 skills" in listed.stdout
    bad = ktbt_run("peer", "ask", "--sequence", "A", "--connect", "nonsense://x")
    assert (bad.returncode, bad.stdout) == (2, "")
    assert (
        bad.stderr == "error: --connect: nonsense://x is not a zenoh endpoint: write nonsense/x\n"
    )


def _ask(port: int, *extra: str) -> subprocess.CompletedProcess[str]:
    return ktbt_run(
        "peer",
        "ask",
        "--sequence",
        "TargetSeen(colour=1)",
        "--connect",
        endpoint(port),
        "--timeout",
        "2",
        *extra,
    )


@pytest.mark.slow
def test_clients_through_a_router() -> None:
    port = free_port()
    with (
        ktbt_process("peer", "router", "--listen", endpoint(port), ready="router listening"),
        ktbt_process(
            "peer",
            "serve",
            "--id",
            "teacher",
            "--knowledge",
            str(KNOWLEDGE),
            "--mode",
            "client",
            "--connect",
            endpoint(port),
            ready="serving",
        ),
    ):
        asked = _ask(port, "--mode", "client")
        assert asked.returncode == 0, asked.stdout + asked.stderr
        assert asked.stdout.startswith("# from teacher\n")


@pytest.mark.slow
def test_user_password_authentication_from_a_config_file(tmp_path: Path) -> None:
    dictionary = tmp_path / "users.txt"
    dictionary.write_text("teacher:s3cret\nlearner:letmein\n")

    def config(user: str, password: str) -> Path:
        path = tmp_path / f"{user}-{password}.json5"
        auth = {"user": user, "password": password, "dictionary_file": str(dictionary)}
        path.write_text(json.dumps({"transport": {"auth": {"usrpwd": auth}}}))
        return path

    port = free_port()
    with serving(port, "--config", str(config("teacher", "s3cret"))):
        good = _ask(port, "--config", str(config("learner", "letmein")))
        assert good.returncode == 0, good.stdout + good.stderr
        refused = _ask(port, "--config", str(config("learner", "guess")))
        assert (refused.returncode, refused.stdout) == (1, "")


@pytest.mark.slow
def test_tls_from_a_config_file(tmp_path: Path) -> None:
    tls = make_tls(tmp_path)
    server = tmp_path / "server.json5"
    server.write_text(
        json.dumps(
            {
                "transport": {
                    "link": {
                        "tls": {
                            "listen_private_key": str(tls["key"]),
                            "listen_certificate": str(tls["cert"]),
                            "root_ca_certificate": str(tls["ca"]),
                        }
                    }
                }
            }
        )
    )
    client = tmp_path / "client.json5"
    client.write_text(
        json.dumps({"transport": {"link": {"tls": {"root_ca_certificate": str(tls["ca"])}}}})
    )
    port = free_port()
    address = f"tls/localhost:{port}"
    with ktbt_process(
        "peer",
        "serve",
        "--id",
        "teacher",
        "--knowledge",
        str(KNOWLEDGE),
        "--listen",
        address,
        "--config",
        str(server),
        ready="serving",
    ):

        def ask(*extra: str) -> subprocess.CompletedProcess[str]:
            return ktbt_run(
                "peer",
                "ask",
                "--sequence",
                "TargetSeen(colour=3)",
                "--connect",
                address,
                "--timeout",
                "2",
                *extra,
            )

        trusted = ask("--config", str(client))
        assert trusted.returncode == 0, trusted.stdout + trusted.stderr
        assert "colour=3" in trusted.stdout
        assert ask().returncode != 0  # no CA, no connection: nothing answers


def test_hostile_peers_cannot_break_asking_or_listing() -> None:
    good, evil, me = free_port(), free_port(), free_port()
    kb = KnowledgeBase.from_tree(kp.parse(KNOWLEDGE.read_text()))
    with (
        ZenohTransport("teacher", settings(good), lookup=serve_lookup(kb), catalog=kb.keys),
        ZenohTransport("evil", settings(evil)) as bad,
    ):
        # The evil peer's catalog is deeply nested JSON, and its answers are garbage.
        bad._declared.append(
            bad.session.declare_queryable(
                "ktbt/v1/catalog/evil2",
                lambda q: (q.reply("ktbt/v1/catalog/evil2", b"[" * 100_000), q.drop()),  # type: ignore[no-untyped-call]
            )
        )
        bad._declared.append(
            bad.session.declare_queryable(
                "ktbt/v1/knowledge/evil2",
                lambda q: (q.reply("ktbt/v1/knowledge/evil2", b"{nope"), q.drop()),  # type: ignore[no-untyped-call]
            )
        )
        with ZenohTransport("me", settings(me, good, evil), serving=False) as asker:
            see(asker, "teacher", "evil")
            assert peers(asker)["teacher"] == kb.keys()
            answers = asker.ask(Query(id="q", sender="me", sequence=GREEN), 2)
            assert [a.sender for a in answers] == ["teacher"]
            assert asker.refused >= 1


def test_pending_queries_are_bounded_and_keyed_by_sender() -> None:
    a, b = free_port(), free_port()
    with (
        ZenohTransport("t", settings(a), max_pending=3, answer_window=60) as teacher,
        ZenohTransport("x", settings(b, a)) as other,
    ):
        see(other, "t")
        finished: list[str] = []
        for n in range(8):  # eight askers at once, more than the teacher holds open
            other.session.get(
                "ktbt/v1/knowledge/t",
                payload=encode(Query(id=f"q{n}", sender=f"s{n}", sequence=GREEN)),
                timeout=60,
                handler=zenoh.handlers.Callback(  # type: ignore[arg-type]
                    lambda _: None, functools.partial(finished.append, f"q{n}")
                ),
            )
        # Three are held open; the five beyond the bound are finished at once, unanswered.
        assert wait_until(lambda: len(finished) == 5)
        assert len(teacher._pending) == 3
        # Answering (sender, id) reaches that sender's query only.
        key = next(iter(teacher._pending))
        teacher.send(
            "someone-else", Response(id=key[1], sender="t", sequence=GREEN, subtree="<a>(X)")
        )
        assert key in teacher._pending
