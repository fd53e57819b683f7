"""btview watches a robot learn: ``ktbt peer run --groot`` and ``ktbt peer serve --groot``, real
processes talking zenoh on loopback, read by btview's own ``snapshot`` (spec/groot2.md)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.groot2_helpers import reserve_ports
from tests.zenoh_helpers import ROOT, endpoint, ktbt_process, wait_until

pytest.importorskip("btview", reason="pip install -e '.[dev]'")
pytest.importorskip("zmq", reason="pip install 'ktbt[groot]'")

KNOWLEDGE = ROOT / "examples" / "knowledge" / "colours.sbt"


def btview(*args: str) -> str:
    """What btview prints ('' if it failed: the publisher is not up yet)."""
    done = subprocess.run(
        [sys.executable, "-m", "btview", *args, "--no-color"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    return done.stdout if done.returncode == 0 else ""


def snapshot(port: int) -> str:
    return btview("snapshot", "--port", str(port))


def tree_uuid(port: int) -> str:
    lines = btview("info", "--port", str(port), "--samples", "1").splitlines()
    return next((line.split()[-1] for line in lines if line.startswith("tree uuid")), "")


def test_btview_sees_the_control_tree_then_what_the_robot_learned() -> None:
    robot_groot, teacher_groot, robot_port, teacher_port = reserve_ports(2, 2)
    with ktbt_process(
        "peer", "run", "--id", "r1", "--listen", endpoint(robot_port),
        "--sequence", "TargetSeen(colour=2)", "--duration", "600", "--groot", str(robot_groot),
        ready="Groot2 on port",
    ):  # fmt: skip
        assert wait_until(lambda: "RandomWalk" in snapshot(robot_groot), 60)
        before, first = snapshot(robot_groot), tree_uuid(robot_groot)
        assert "k:new" in before and "DeliverToZone" in before and len(first) == 32
        assert "TargetSeen" not in before and "PickTreasure" not in before
        with ktbt_process(
            "peer", "serve", "--id", "teacher", "--knowledge", str(KNOWLEDGE),
            "--listen", endpoint(teacher_port), "--connect", endpoint(robot_port),
            "--groot", str(teacher_groot), ready="Groot2 on port",
        ):  # fmt: skip
            taught = snapshot(teacher_groot)
            assert all(f"TargetSeen(colour={c})" in taught for c in (1, 2, 3, 4)), taught
            assert wait_until(lambda: "PickTreasure" in snapshot(robot_groot), 90)
        after = snapshot(robot_groot)
        assert tree_uuid(robot_groot) not in ("", first)  # learning gave the tree a new UUID
    lines = after.splitlines()
    new = next(i for i, line in enumerate(lines) if "k:new" in line)
    item = "\n".join(lines[new : new + 6])
    for node in ("TargetSeen(colour=2)", "PickTreasure", "AssignCollectionPoint(colour=2)"):
        assert node in item, after
    assert "RandomWalk" in after and "DeliverToZone" in after


def test_sigterm_stops_a_robot_held_at_a_breakpoint() -> None:
    """A client keeps polling (so the heartbeat never releases the hook) while the tick waits
    at a breakpoint: SIGTERM still ends the robot."""
    import contextlib
    import json
    import signal

    import zmq

    from tests.groot2_helpers import client

    port, listen = reserve_ports(1, 1)
    with ktbt_process(
        "peer", "run", "--id", "r1", "--listen", endpoint(listen),
        "--sequence", "TargetSeen(colour=2)", "--duration", "300", "--groot", str(port),
        ready="Groot2 on port",
    ) as proc, client(port, timeout=2) as c:  # fmt: skip
        sub = c.context.socket(zmq.SUB)
        sub.setsockopt(zmq.SUBSCRIBE, b"")
        sub.setsockopt(zmq.RCVTIMEO, 200)
        sub.connect(f"tcp://127.0.0.1:{port + 1}")

        def hook(uid: int, mode: int) -> bytes:
            return json.dumps(
                {"uid": uid, "position": 0, "enabled": True, "mode": mode, "once": False,
                 "desired_status": "SKIPPED"}
            ).encode()  # fmt: skip

        def notice(uid: int) -> bool:
            try:
                return bool(sub.recv_multipart()[1] == str(uid).encode())
            except zmq.Again:
                return False

        assert wait_until(lambda: c.request("S")[0] != b"error", 30)
        assert c.request("I", hook(2, 1))[0] != b"error"  # a notice every tick: SUB joined
        assert wait_until(lambda: notice(2), 30)
        assert c.request("I", hook(1, 0))[0] != b"error"  # the root: a breakpoint
        assert wait_until(lambda: notice(1), 30)  # the tick waits there now
        c.request("S")
        assert proc.poll() is None
        proc.send_signal(signal.SIGTERM)

        def ended() -> bool:
            with contextlib.suppress(zmq.Again):
                c.request("S")  # the client is still there: the heartbeat is fresh
            return proc.poll() is not None

        try:
            assert wait_until(ended, 20), "the robot did not stop at a breakpoint"
        finally:
            sub.close(linger=0)
