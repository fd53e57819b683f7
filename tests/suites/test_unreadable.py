"""Messages a robot cannot read, sent to real ``ktbt`` processes on zenoh (loopback): the answer
that once ended every learner (``<sq><c>true.5<e>``), a catalog listing ``<c>true.``, and
messages whose reading is made to raise (the test hook ``KTBT_FAULT_READING``). Each host, a
learner (``ktbt peer run``), a knowledge server that overhears (``ktbt peer serve``) and the
monitor, lives on, counts the refusal, and still learns from (or shows) an honest peer after it
(spec/protocol.md section 2.1)."""

from __future__ import annotations

import http.client
import json
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from ktbt_proto.exchange.messages import Response, encode
from ktbt_proto.transport.zenoh import ZenohTransport
from tests.zenoh_helpers import (
    ROOT,
    Output,
    endpoint,
    free_port,
    ktbt_process,
    ktbt_run,
    serving,
    settings,
    wait_until,
)

pytestmark = pytest.mark.network  # zenoh sessions and ktbt processes on loopback

GREEN = "<c>(TargetSeen,colour=2)"
BLUE = "<c>(TargetSeen,colour=3)"
KILLER = "<sq><c>true.5<e>"  # 16 bytes of stringBT that once raised AssertionError
FAULTY = "<sq><a>(ktbt-fault)<e>"  # reading it raises, under KTBT_FAULT_READING=item
INTERNAL = "internal error reading a message: InjectedFault"


@contextmanager
def mallory(port: int, *connect: int) -> Iterator[ZenohTransport]:
    """A hostile peer: it lists a catalog a learner cannot read and answers every query for
    the green skill with the killer subtree, and for the blue one with the faulty one."""
    bad = {GREEN: KILLER, BLUE: FAULTY}
    listed = [{"sequence": s} for s in ("<c>true.", "<c>(ktbt-fault)", GREEN, BLUE)]
    with ZenohTransport(
        "mallory", settings(port, *connect), lookup=bad.get, catalog=lambda: listed
    ) as peer:
        yield peer


@pytest.mark.slow
def test_a_learner_refuses_what_it_cannot_read_lives_and_learns_from_an_honest_teacher(
    tmp_path: Path,
) -> None:
    pm, pl, pt = free_port(), free_port(), free_port()
    log = tmp_path / "r.log"
    with (
        mallory(pm),
        ktbt_process(
            "peer", "run", "--id", "r", "--listen", endpoint(pl), "--connect", endpoint(pm),
            "--log", str(log), "--exit-when-done", "--duration", "120",
            ready="will meet", env={"KTBT_FAULT_READING": "item"},
        ) as learner,
    ):  # fmt: skip
        out = Output(learner)
        out.wait_for(
            "refused knowledge: from mallory: SBT101 unexpected character '.'",
            f"refused knowledge: from mallory: {INTERNAL}",
            f"r refused knowledge: the catalog of mallory: {INTERNAL}",
        )
        assert learner.poll() is None, out.text()  # alive after all of it
        with serving(pt, "--connect", endpoint(pl)):
            assert learner.wait(timeout=60) == 0, out.text()
        out.join()
    text = out.text()
    assert "r: learned TargetSeen(colour=2) from teacher" in text
    assert "r: learned TargetSeen(colour=3) from teacher" in text
    assert "Traceback" not in text and "AssertionError" not in text
    summary = next(line for line in out.lines if "queries sent" in line)
    refused = int(summary.split("refused ")[1].split(",")[0])
    assert refused >= 3  # the killer answer, the faulty one and the catalog entry
    logged = [json.loads(line) for line in log.read_text().splitlines()]
    reasons = [e["reason"] for e in logged if e["event"] == "refused"]
    assert f"from mallory: {INTERNAL}" in reasons
    merged = {e["sequence"] for e in logged if e["event"] == "merged"}
    assert {GREEN, BLUE} <= merged


@pytest.mark.slow
def test_a_server_that_overhears_refuses_what_it_cannot_read_and_serves_an_honest_answer() -> None:
    ps, pm, ph = free_port(), free_port(), free_port()
    door = "<c>(DoorOpen)"
    knowledge = ROOT / "examples" / "knowledge" / "colours.sbt"
    with (
        ktbt_process(
            "peer", "serve", "--id", "s", "--knowledge", str(knowledge), "--listen",
            endpoint(ps), "--overhear", "update", ready="serving",
            env={"KTBT_FAULT_READING": "item"},
        ) as server,
        ZenohTransport("mallory", settings(pm, ps), serving=False) as bad,
        ZenohTransport("honest", settings(ph, ps), serving=False) as good,
    ):  # fmt: skip
        out = Output(server)
        faulty = Response(id="x1", sender="mallory", sequence=door, subtree=FAULTY)
        killer = Response(id="x2", sender="mallory", sequence=door, subtree=KILLER)

        def heard_both() -> bool:  # put again until the server's subscription has them
            for answer in (faulty, killer):
                bad.session.put("ktbt/v1/answers/mallory", encode(answer))
            return f"s refused: from mallory: {INTERNAL}" in out.text() and "SBT101" in out.text()

        assert wait_until(heard_both, 30), out.text()
        assert server.poll() is None
        honest = Response(id="h1", sender="honest", sequence=door, subtree="<a>(GoThrough)")
        good.session.put("ktbt/v1/answers/honest", encode(honest))
        out.wait_for("s: learned DoorOpen from honest (overheard)")
        asked = ktbt_run("peer", "ask", "--sequence", "DoorOpen", "--connect", endpoint(ps))
        assert asked.returncode == 0, asked.stdout + asked.stderr
        assert "<a>(GoThrough)" in asked.stdout
    out.join()
    assert "Traceback" not in out.text()


class Unix(http.client.HTTPConnection):
    def __init__(self, path: Path) -> None:
        super().__init__("localhost", timeout=5)
        self.path = path

    def connect(self) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.connect(str(self.path))


def state(uds: Path) -> dict[str, object]:
    connection = Unix(uds)
    try:
        connection.request("GET", "/api/state")
        found: dict[str, object] = json.loads(connection.getresponse().read())
        return found
    finally:
        connection.close()


def test_the_monitor_counts_an_event_it_cannot_read_and_shows_an_honest_peer(
    tmp_path: Path,
) -> None:
    pm, ph = free_port(), free_port()
    uds = tmp_path / "http.sock"
    with (
        ZenohTransport("mallory", settings(pm), serving=False) as bad,
        ktbt_process(
            "monitor", "--connect", endpoint(pm), "--http", f"127.0.0.1:{free_port()}",
            "--uds", str(uds), ready="Ctrl-C", env={"KTBT_FAULT_READING": "message"},
        ) as monitor,
    ):  # fmt: skip
        assert wait_until(uds.exists, 15)

        def dropped() -> bool:
            bad.session.put("ktbt/v1/events/mallory", b'{"ktbt-fault": 1}')
            drops = state(uds)["drops"]
            return isinstance(drops, dict) and drops.get("malformed", 0) >= 1

        assert wait_until(dropped, 30)
        assert monitor.poll() is None
        with ZenohTransport("honest", settings(ph, pm), publish_events=True):

            def shown() -> bool:
                peers = state(uds)["peers"]
                return isinstance(peers, list) and any(p.get("peer") == "honest" for p in peers)

            assert wait_until(shown, 30)
        assert monitor.poll() is None
