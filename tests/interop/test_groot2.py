"""The Groot2 publisher on a live tree: the UUID rule, hooks and breakpoints, recording, hostile
and stalled clients (spec/groot2.md). Real ZeroMQ sockets on loopback, real ticking threads."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from dataclasses import dataclass

import msgpack
import pytest
import zmq
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import ktbt_proto as kp
from ktbt_proto.interop import groot2
from tests.groot2_helpers import HEADER, Client, client, elements, free_ports, is_uuid4, statuses
from tests.zenoh_helpers import wait_until

CONTROL = "<sl><sq><c>(Carrying)<a>(Deliver)<e><k>(new)<e><a>(Walk)<e>"
GREEN = ["TargetSeen(colour=2)"]
SKILL = "<sq><a>(Pick)<e>"


class Robot:
    """A live tree with logged leaves: Walk runs until halted, Pick sets Carrying."""

    def __init__(self) -> None:
        self.log: list[str] = []
        reg = kp.Registry()
        reg.flags("Carrying")
        log = self.log

        @reg.condition("TargetSeen")
        def seen(bb: kp.Blackboard, colour: int) -> bool:
            return bool(bb.get("target") == colour)

        class Walk:
            def __init__(self, bb: kp.Blackboard) -> None:
                pass

            def tick(self) -> kp.Status:
                log.append("Walk")
                return kp.RUNNING

            def halt(self) -> None:
                log.append("~Walk")

        reg.add_action("Walk", Walk)
        reg.add_action("Deliver", lambda bb: kp.SUCCESS)

        @reg.action("Pick")
        def pick(bb: kp.Blackboard) -> kp.Status:
            log.append("Pick")
            return kp.SUCCESS

        self.live = kp.LiveTree(CONTROL, reg)


@dataclass
class Served:
    robot: Robot
    pub: groot2.Groot2Publisher
    client: Client


@pytest.fixture
def served() -> Iterator[Served]:
    r = Robot()
    port = free_ports()
    pub = groot2.Groot2Publisher(r.live, port)
    try:
        with client(port) as c:
            yield Served(r, pub, c)
    finally:
        pub.close()


def uid_of(c: Client, what: str) -> int:
    return next(uid for uid, kind, name in elements(c.request("T")[1]) if what in (kind, name))


def hook(uid: int, status: str, mode: int = 1, position: int = 0, once: bool = False) -> bytes:
    return json.dumps(
        {
            "uid": uid,
            "position": position,
            "enabled": True,
            "mode": mode,
            "once": once,
            "desired_status": status,
        }
    ).encode()


def test_every_merge_and_forget_gives_a_new_uuid_and_the_new_tree(served: Served) -> None:
    r, c = served.robot, served.client
    first = c.request("T")
    assert is_uuid4(first[0][6:])
    names = [name for _, _, name in elements(first[1])]
    assert "Pick" not in names and "AlwaysFailure" in [k for _, k, _ in elements(first[1])]
    r.live.tick()
    assert c.request("S")[0][6:] == first[0][6:]  # ticking keeps the tree and its UUID
    r.live.merge(SKILL, slot="new", when=GREEN)
    assert c.request("T")[0][6:] == first[0][6:]  # not before the merge takes effect
    r.live.tick()
    learned = c.request("T")
    assert learned[0][6:] != first[0][6:] and is_uuid4(learned[0][6:])
    found = elements(learned[1])
    assert [uid for uid, _, _ in found] == list(range(1, len(found) + 1))
    assert {"TargetSeen(colour=2)", "Pick"} <= {name for _, _, name in found}
    assert len(statuses(c.request("S")[1])) == len(found)
    assert r.live.forget("new", GREEN)
    r.live.tick()
    forgot = c.request("T")
    assert forgot[0][6:] not in (first[0][6:], learned[0][6:])
    assert "Pick" not in {name for _, _, name in elements(forgot[1])}


def test_statuses_follow_the_tree(served: Served) -> None:
    r, c = served.robot, served.client
    assert all(byte == 0 for _, byte in statuses(c.request("S")[1]))  # never ticked: IDLE
    r.live.tick()
    shown = dict(statuses(c.request("S")[1]))
    assert shown[uid_of(c, "Walk")] == 1 and shown[1] == 1  # running
    assert shown[uid_of(c, "Carrying")] == 13 and shown[uid_of(c, "Deliver")] == 0
    r.live.blackboard["Carrying"] = True
    r.live.tick()
    shown = dict(statuses(c.request("S")[1]))
    assert shown[uid_of(c, "Walk")] == 11  # halted: IDLE after RUNNING
    assert shown[uid_of(c, "Deliver")] == 12 and shown[1] == 12
    assert r.log == ["Walk", "~Walk"]


def test_a_replace_hook_forces_a_result_and_tests_a_branch(served: Served) -> None:
    """Forcing ``Carrying`` to SUCCESS runs Deliver without touching the blackboard; a post
    hook that fails a running Walk halts it. Taking the hooks out restores the tree."""
    r, c = served.robot, served.client
    r.live.tick()
    assert len(c.request("I", hook(uid_of(c, "Carrying"), "SUCCESS"))) == 1
    assert r.live.tick() is kp.SUCCESS and "Carrying" not in r.live.blackboard
    assert r.log == ["Walk", "~Walk"]
    assert c.request("A")[0][1] == ord("A")
    assert r.live.tick() is kp.RUNNING and r.log[-1] == "Walk"
    walk = uid_of(c, "Walk")
    c.request("I", hook(walk, "FAILURE", position=1, once=True))
    assert r.live.tick() is kp.FAILURE and r.log[-2:] == ["Walk", "~Walk"]
    assert json.loads(c.request("D")[1]) == []  # "once": gone after it fired
    assert r.live.tick() is kp.RUNNING


def test_a_breakpoint_stops_the_tick_until_unlocked(served: Served) -> None:
    r, pub, c = served.robot, served.pub, served.client
    sub = c.context.socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.setsockopt(zmq.RCVTIMEO, 10_000)
    sub.connect(f"tcp://127.0.0.1:{c.port + 1}")
    r.live.tick()
    carrying = uid_of(c, "Carrying")
    c.request("I", hook(1, "SKIPPED"))  # a notice every tick, until the SUB has joined
    assert wait_until(lambda: r.live.tick() is not None and notice(sub, 1))
    c.request("R", json.dumps({"uid": 1, "position": 0}).encode())
    c.request("I", hook(carrying, "SKIPPED", mode=0))
    results: list[kp.Status] = []
    ticker = threading.Thread(target=lambda: results.append(r.live.tick()))
    ticker.start()
    try:
        assert wait_until(lambda: notice(sub, carrying))
        assert c.request("S")[0][1] == ord("S")  # the server answers while the tree waits
        assert ticker.is_alive() and results == []
        unlock = {"uid": carrying, "position": 0, "desired_status": "SUCCESS"}
        assert c.request("U", json.dumps({**unlock, "remove_when_done": True}).encode())[0][
            1
        ] == ord("U")
        ticker.join(10)
        assert results == [kp.SUCCESS]  # the forced result: Deliver ran
    finally:
        pub.close()  # wakes the tick if an assertion failed first
        ticker.join(10)
        sub.close(linger=0)
    assert not ticker.is_alive()


def notice(sub: zmq.Socket[bytes], uid: int) -> bool:
    """A BREAKPOINT_REACHED for ``uid`` came (others are skipped)."""
    try:
        frames = sub.recv_multipart(zmq.NOBLOCK)
    except zmq.Again:
        return False
    return HEADER.unpack(frames[0])[:2] == (2, ord("N")) and frames[1] == str(uid).encode()


def test_a_breakpoint_is_released_when_the_client_goes_away() -> None:
    r = Robot()
    port = free_ports()
    with groot2.Groot2Publisher(r.live, port) as pub:
        with client(port) as c:
            sub = c.context.socket(zmq.SUB)
            sub.setsockopt(zmq.SUBSCRIBE, b"")
            sub.connect(f"tcp://127.0.0.1:{port + 1}")
            r.live.tick()
            carrying = uid_of(c, "Carrying")
            c.request("I", hook(1, "SKIPPED"))
            assert wait_until(lambda: r.live.tick() is not None and notice(sub, 1))
            c.request("R", json.dumps({"uid": 1, "position": 0}).encode())
            c.request("I", hook(carrying, "SUCCESS", mode=0))
            ticker = threading.Thread(target=r.live.tick)
            ticker.start()
            try:
                assert wait_until(lambda: notice(sub, carrying))
                c.request("S")
                assert ticker.is_alive()  # held at the breakpoint while the client polls
            finally:
                pub.heartbeat = 0.3  # from now on, 0.3 s without a request releases it
                sub.close(linger=0)
        ticker.join(15)  # no request for 0.3 s: every hook is disabled, the tick goes on
        assert not ticker.is_alive()
        assert r.log[-1] == "Walk"  # the breakpoint let the node tick as it was


def test_recording_gives_transitions(served: Served) -> None:
    r, c = served.robot, served.client
    started = c.request("r", b"start")
    assert started[1].isdigit()
    r.live.tick()
    r.live.blackboard["Carrying"] = True
    r.live.tick()
    data = c.request("t")[1]
    records = [
        (int.from_bytes(data[i + 6 : i + 8], "little"), data[i + 8]) for i in range(0, len(data), 9)
    ]
    walk = uid_of(c, "Walk")
    assert (walk, 1) in records and (walk, 0) in records  # RUNNING, then IDLE when halted
    assert records.index((walk, 1)) < records.index((walk, 0))
    assert c.request("t")[1] == b""  # taken
    c.request("r", b"stop")
    r.live.tick()
    assert c.request("t")[1] == b""


def test_blackboard_and_errors(served: Served) -> None:
    r, pub, c = served.robot, served.pub, served.client
    r.live.blackboard.update({"target": 2, "pose": (1.5, 2), "obj": object()})
    board = msgpack.unpackb(c.request("B", b"MainTree")[1])
    assert board["MainTree"]["target"] == 2 and board["MainTree"]["pose"] == [1.5, 2]
    assert isinstance(board["MainTree"]["obj"], str)
    assert c.request("I", b"{not json")[0] == b"error"
    assert c.request("I", b'{"uid": 1}')[0] == b"error"
    assert c.request("I", hook(1, "MAYBE"))[0] == b"error"
    assert sum(pub.errors.values()) == 3


# Malformed requests: each must get the protocol's error reply.
_KINDS = sorted(set(range(256)) - {ord(k) for k in "TSBIRNUDAXrt"})
_header = st.builds(
    lambda protocol, kind, rid: HEADER.pack(protocol, kind, rid),
    st.integers(0, 255),
    st.sampled_from(_KINDS),
    st.integers(0, 2**32 - 1),
)
_short = st.binary(max_size=5) | st.binary(min_size=7, max_size=64)
_wrong_protocol = st.builds(
    lambda protocol, kind, rid: HEADER.pack(protocol, ord(kind), rid),
    st.integers(0, 255).filter(lambda p: p != 2),
    st.sampled_from("TSBIRNUDAXrt"),
    st.integers(0, 2**32 - 1),
)
_bad_json = st.builds(
    lambda kind, body: [HEADER.pack(2, ord(kind), 7), body],
    st.sampled_from("IUR"),
    st.binary(max_size=40).filter(lambda b: not b.strip().startswith((b"{", b"["))),
)
_missing_part = st.builds(lambda kind: [HEADER.pack(2, ord(kind), 9)], st.sampled_from("BIURr"))
MALFORMED = (
    st.lists(_short, min_size=1, max_size=3)
    | st.builds(lambda h, rest: [h, *rest], _header, st.lists(st.binary(max_size=20), max_size=2))
    | st.builds(lambda h: [h], _wrong_protocol)
    | _bad_json
    | _missing_part
)


def test_malformed_requests_get_error_replies_and_nothing_stops() -> None:
    r = Robot()
    port = free_ports()
    stop = threading.Event()
    ticks: list[int] = []

    def tick_forever() -> None:
        while not stop.is_set():
            r.live.tick()
            ticks.append(r.live.ticks)
            stop.wait(0.001)

    ticker = threading.Thread(target=tick_forever)
    sent: list[list[bytes]] = []
    with groot2.Groot2Publisher(r.live, port) as pub, client(port) as c:
        ticker.start()
        try:

            @settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
            @given(MALFORMED)
            def one(frames: list[bytes]) -> None:
                sent.append(frames)
                reply = c.raw(frames)
                assert reply[0] == b"error" and len(reply) == 2 and reply[1], frames

            one()
            assert len(sent) >= 100
            assert sum(pub.errors.values()) >= len(sent) - 0  # every one counted
            before = len(ticks)
            assert wait_until(lambda: len(ticks) > before + 10)  # the tree kept ticking
            assert c.request("S")[0][1] == ord("S")  # and the publisher kept answering
        finally:
            stop.set()
            ticker.join(10)


def test_a_client_that_never_reads_blocks_nothing() -> None:
    """A DEALER that floods tree requests and never reads, a SUB that never reads while
    breakpoint notices go out, and a TCP connection that never speaks: another client is
    answered and the tree ticks."""
    r = Robot()
    port = free_ports()
    import socket

    with groot2.Groot2Publisher(r.live, port) as pub, client(port, timeout=10) as c:
        ctx = c.context
        greedy = ctx.socket(zmq.DEALER)
        greedy.setsockopt(zmq.LINGER, 0)
        greedy.setsockopt(zmq.SNDHWM, 0)
        greedy.setsockopt(zmq.RCVHWM, 1)
        greedy.connect(f"tcp://127.0.0.1:{port}")
        deaf = ctx.socket(zmq.SUB)
        deaf.setsockopt(zmq.SUBSCRIBE, b"")
        deaf.setsockopt(zmq.RCVHWM, 1)
        deaf.connect(f"tcp://127.0.0.1:{port + 1}")
        silent = socket.create_connection(("127.0.0.1", port))
        try:
            r.live.tick()
            for i in range(3000):
                greedy.send_multipart([b"", HEADER.pack(2, ord("T"), i)])
            c.request("I", hook(uid_of(c, "Carrying"), "FAILURE"))  # a notice every tick
            assert wait_until(lambda: pub.requests >= 3000, 60)
            for _ in range(200):
                assert r.live.tick() is kp.RUNNING
            assert c.request("S")[0][1] == ord("S")
        finally:
            silent.close()
            greedy.close(linger=0)
            deaf.close(linger=0)


def test_closing_takes_the_probe_out_and_frees_the_ports() -> None:
    r = Robot()
    port = free_ports()
    with groot2.Groot2Publisher(r.live, port):
        r.live.tick()
    r.live.tick()  # the boundary at which the probe leaves
    assert r.live._tick is r.live._wire.tick  # the compiled closures again
    with groot2.Groot2Publisher(r.live, port), client(port) as c:  # the ports are free again
        r.live.tick()
        assert c.request("S")[0][1] == ord("S")
    with (
        pytest.raises(OSError, match="cannot serve Groot2"),
        groot2.Groot2Publisher(r.live, port),
        groot2.Groot2Publisher(r.live, port),
    ):
        pass


def test_an_agent_is_served_through_its_control_tree() -> None:
    from ktbt_proto.exchange.agent import Agent
    from ktbt_proto.transport import MemoryNetwork

    r = Robot()
    net = MemoryNetwork(in_range=lambda a, b: True, loss=0.0, latency=0)
    agent = Agent("r1", CONTROL, r.live.registry, net.join("r1"))
    port = free_ports()
    with groot2.Groot2Publisher(agent, port), client(port) as c:
        agent.tick()
        assert uid_of(c, "Walk") > 0 and c.request("S")[0][1] == ord("S")
    with pytest.raises(TypeError):
        groot2.Groot2Publisher(object(), port)


def test_without_the_extra_one_line_says_how_to_install() -> None:
    """pyzmq missing (blocked here): the library and ``--groot`` say how to get it, in one line."""
    import subprocess
    import sys

    from tests.zenoh_helpers import ROOT, endpoint, free_port

    block = "import sys; sys.modules['zmq'] = None; "
    library = subprocess.run(
        [sys.executable, "-c", block + "import ktbt_proto.interop.groot2"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert library.returncode == 1
    assert "ImportError: Groot2 monitoring needs pyzmq and msgpack: pip install 'ktbt[groot]'" in (
        library.stderr
    )
    knowledge = ROOT / "examples" / "knowledge" / "colours.sbt"
    args = ["peer", "serve", "--knowledge", str(knowledge), "--listen", endpoint(free_port())]
    run = "from ktbt_proto.tools.cli import main; sys.argv = ['ktbt', *sys.argv[1:]]; main()"
    command = subprocess.run(
        [sys.executable, "-c", block + run, *args, "--groot", str(free_ports())],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert command.returncode == 1
    assert command.stderr.count("\n") == 1 and "pip install 'ktbt[groot]'" in command.stderr


def test_a_rejected_hook_array_changes_nothing(served: Served) -> None:
    """[a valid hook, a hook on a node that is part of its parent's]: an error, and the valid
    one is not stored either."""
    r, c = served.robot, served.client
    r.live.blackboard["Carrying"] = False
    r.live.tick()
    found = elements(c.request("T")[1])
    inner = next(
        (uid for uid, kind, _ in found if kind == "AlwaysFailure"), None
    )  # an empty placeholder's inner node: not hookable
    assert inner is not None
    good = json.loads(hook(uid_of(c, "Walk"), "FAILURE"))
    bad = {**good, "uid": inner}
    assert c.json("I", [good, bad])[0] == b"error"
    assert json.loads(c.request("D")[1]) == []
    assert r.live.tick() is kp.RUNNING


def test_a_tree_has_one_probe_and_only_its_owner_takes_it_out() -> None:
    r = Robot()
    first, second = free_ports(), free_ports()
    with groot2.Groot2Publisher(r.live, first) as pub:
        with pytest.raises(RuntimeError, match="probed already"):
            groot2.Groot2Publisher(r.live, second)
        r.live.unprobe(object())  # type: ignore[arg-type]  # not its probe: nothing changes
        r.live.tick()
        assert r.live._probe is pub and r.live._tick is not r.live._wire.tick
        with client(first) as c:
            assert c.request("S")[0][1] == ord("S")
    r.live.tick()
    assert r.live._probe is None and r.live._tick is r.live._wire.tick
    with groot2.Groot2Publisher(r.live, second), client(second) as c:  # its ports were freed
        r.live.tick()
        assert c.request("S")[0][1] == ord("S")


def test_a_view_that_cannot_be_built_never_raises_into_the_tick(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The XML walk fails (an export whose elements do not match the tree): the error is
    served, the tree ticks on unprobed."""
    r = Robot()
    port = free_ports()
    monkeypatch.setattr(groot2, "to_xml", lambda tree: "<root><BehaviorTree><Sequence/>"
                        "</BehaviorTree></root>")  # fmt: skip
    with groot2.Groot2Publisher(r.live, port), client(port) as c:
        assert r.live.tick() is kp.RUNNING
        reply = c.request("T")
        assert reply[0] == b"error" and reply[1].startswith(b"internal error")


def test_oversized_requests_are_dropped_and_repeated_names_served_once(served: Served) -> None:
    r, c = served.robot, served.client
    r.live.blackboard["target"] = 2
    r.live.tick()
    board = msgpack.unpackb(c.request("B", b";".join([b"MainTree"] * 5000))[1])
    assert list(board) == ["MainTree"]
    with client(c.port, timeout=1) as big, pytest.raises(zmq.Again):
        big.request("I", b"[" + b" " * (2 << 20) + b"]")
    assert c.request("S")[0][1] == ord("S")


def test_the_groot_port_is_checked() -> None:
    from typer.testing import CliRunner

    from ktbt_proto.tools.cli import app

    for port in ("0", "65535"):
        result = CliRunner().invoke(app, ["peer", "run", "--groot", port])
        assert result.exit_code == 2, result.output


def test_hooks_disabled_by_x_stay_disabled_when_requests_come_back(served: Served) -> None:
    """spec/groot2.md section 6: BT.CPP enables them again after a heartbeat lapse; we do not."""
    r, pub, c = served.robot, served.pub, served.client
    r.live.tick()
    c.request("I", hook(uid_of(c, "Carrying"), "SUCCESS"))
    c.request("X")
    pub.heartbeat = 0.2
    assert wait_until(lambda: not pub._hooks_enabled)
    c.request("S")  # the client is back
    assert [h["enabled"] for h in json.loads(c.request("D")[1])] == [False]
    assert r.live.tick() is kp.RUNNING  # Carrying is not forced
