"""Fleet events over real zenoh (spec/protocol.md section 10): `ktbt peer serve` and
`ktbt peer run` processes with --publish-events, heard by a plain zenoh subscriber."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import zenoh

from ktbt_proto.exchange.events import FleetEvent, decode_event
from ktbt_proto.exchange.signing import Identity
from ktbt_proto.items import sequence_digest
from ktbt_proto.transport.zenoh import ZenohSettings, open_session
from tests.zenoh_helpers import endpoint, free_port, ktbt_process, serving, settings, wait_until

GREEN = "<c>(TargetSeen,colour=2)"


def test_peers_publish_the_events_their_logs_record(tmp_path: Path) -> None:
    key = tmp_path / "t.key"
    Identity.generate().save(key)
    teacher_key = (tmp_path / "t.key.pub").read_text().strip()
    port, mine = free_port(), free_port()
    heard: list[FleetEvent] = []
    refused: list[str] = []
    lock = threading.Lock()

    def on_event(sample: zenoh.Sample) -> None:
        try:
            event = decode_event(sample.payload.to_bytes())
        except ValueError as exc:
            refused.append(str(exc))
            return
        with lock:
            heard.append(event)

    with serving(port, "--key", str(key), "--publish-events", name="t"):
        session = open_session(ZenohSettings(listen=[endpoint(mine)], connect=[endpoint(port)]))
        try:
            subscriber = session.declare_subscriber("ktbt/v1/events/*", on_event)
            assert wait_until(lambda: bool(list(session.info.peers_zid())), 10)  # connected
            log = tmp_path / "r1.log"
            with ktbt_process(
                "peer", "run", "--id", "r1", "--connect", endpoint(port), "--log", str(log),
                "--sequence", "TargetSeen(colour=2)", "--exit-when-done", "--publish-events",
            ) as robot:  # fmt: skip
                assert robot.wait(timeout=60) == 0

            def merged() -> list[FleetEvent]:
                with lock:
                    return [e for e in heard if e.peer == "r1" and e.event == "merged"]

            assert wait_until(lambda: bool(merged()), 10), heard
            subscriber.undeclare()  # type: ignore[no-untyped-call]
        finally:
            session.close()  # type: ignore[no-untyped-call]
    event = merged()[0]
    assert (event.item, event.teacher, event.sig) == (sequence_digest(GREEN), "t", None)
    written = [json.loads(line) for line in log.read_text().splitlines()]
    assert event.t == next(e["t"] for e in written if e["event"] == "merged")
    ours = [e for e in heard if e.peer == "r1"]  # from when r1 and we first met, none lost
    first = ours[0].n
    assert [e.n for e in ours] == list(range(first, first + len(ours)))
    assert [e.event for e in ours] == [e["event"] for e in written[first:]]
    served = [e for e in heard if e.peer == "t"]
    assert {e.event for e in served} >= {"query-received", "answer-sent"}
    assert all(e.key == teacher_key and e.sig for e in served)  # verified by decode_event
    assert refused == []


def test_in_memory_agents_stream_the_same_events() -> None:
    """A simulator's agents share the in-memory network; their events go out on zenoh, each on
    its agent's own key, exactly as a peer process publishes its own."""
    import ktbt_proto as kp
    from ktbt_proto.exchange.agent import Agent
    from ktbt_proto.exchange.knowledge import KnowledgeBase
    from ktbt_proto.tools.demo import DEMO_CONTROL, demo_registry
    from ktbt_proto.transport import MemoryNetwork
    from ktbt_proto.transport.stream import AgentStream
    from tests.zenoh_helpers import ROOT

    colours = KnowledgeBase.from_tree(
        kp.parse((ROOT / "examples" / "knowledge" / "colours.sbt").read_text())
    )
    reg = demo_registry()
    net = MemoryNetwork(in_range=lambda a, b: True, loss=0.0, latency=0)
    teacher = Agent("t", DEMO_CONTROL, reg, net.join("t"))
    for item in colours:
        teacher.knowledge.add(item)
    robot = Agent("r1", DEMO_CONTROL, reg, net.join("r1"))
    port, mine = free_port(), free_port()
    heard: list[FleetEvent] = []
    session = open_session(ZenohSettings(listen=[endpoint(mine)], connect=[endpoint(port)]))
    try:
        subscriber = session.declare_subscriber(
            "ktbt/v1/events/*",
            lambda s: (
                heard.append(decode_event(s.payload.to_bytes()))
                if str(s.key_expr).endswith(("/t", "/r1"))
                else None
            ),
        )
        with AgentStream([teacher, robot], ZenohSettings(listen=[endpoint(port)])) as stream:
            assert wait_until(lambda: bool(list(session.info.peers_zid())), 10)  # connected
            assert len(stream.publishers) == 2
            robot.encounter([GREEN])
            for _ in range(5):
                net.step()
                teacher.tick()
                robot.tick()
            assert robot.knows([GREEN])
            assert wait_until(lambda: any(e.event == "merged" for e in heard), 10)
        subscriber.undeclare()  # type: ignore[no-untyped-call]
    finally:
        session.close()  # type: ignore[no-untyped-call]
    merged = next(e for e in heard if e.event == "merged")
    assert (merged.peer, merged.teacher, merged.item) == ("r1", "t", sequence_digest(GREEN))
    assert {e.event for e in heard if e.peer == "t"} >= {"query-received", "answer-sent"}


def test_a_closed_transport_no_longer_publishes_its_logs_events() -> None:
    from ktbt_proto.exchange.transferlog import TransferLog
    from ktbt_proto.transport.zenoh import ZenohTransport

    log = TransferLog(None)
    for _ in range(2):  # the same log, reused by a second transport
        with ZenohTransport("a", settings(free_port()), publish_events=True, log=log):
            assert len(log.sinks) == 1
    assert log.sinks == ()
