"""``ktbt monitor --uds``: the page's state over a unix socket, for tools on this machine such
as ``ktbt fleet run --monitor``. A socket another monitor serves on is refused and left alone;
one a dead monitor left is replaced; a file that is not a socket is never removed; the socket
is its owner's only, passes the Host check (no browser reaches it), goes when the monitor
stops, and a page left open does not hold the stop (its stream ends, no traceback)."""

from __future__ import annotations

import http.client
import json
import os
import socket
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.zenoh_helpers import ROOT, end, free_port, ktbt_process, wait_until

pytestmark = pytest.mark.network


class Unix(http.client.HTTPConnection):
    def __init__(self, path: Path) -> None:
        super().__init__("evil.example", timeout=5)  # a Host no TCP page could use
        self.path = path

    def connect(self) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.connect(str(self.path))


def _answers(path: Path) -> bool:
    try:
        _state(path)
    except (OSError, AssertionError):
        return False
    return True


def _state(path: Path) -> dict[str, object]:
    connection = Unix(path)
    try:
        connection.request("GET", "/api/state")
        reply = connection.getresponse()
        assert reply.status == 200, reply.status
        state: dict[str, object] = json.loads(reply.read())
        return state
    finally:
        connection.close()


def _monitor(uds: Path) -> list[str]:
    return ["monitor", "--connect", "tcp/127.0.0.1:1", "--http", f"127.0.0.1:{free_port()}",
            "--uds", str(uds)]  # fmt: skip


def test_the_state_over_the_socket_and_a_second_monitor_refused(tmp_path: Path) -> None:
    uds = tmp_path / "http.sock"
    with ktbt_process(*_monitor(uds), ready="Ctrl-C") as first:
        assert wait_until(lambda: _answers(uds), 15)
        state = _state(uds)
        assert state["peers"] == [] and "drops" in state and "v" in state
        assert stat.S_IMODE(uds.stat().st_mode) == 0o600
        identity = uds.stat().st_ino
        second = subprocess.run(
            [sys.executable, "-m", "ktbt_proto", *_monitor(uds)],
            cwd=ROOT, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert second.returncode == 2, second.stdout + second.stderr
        assert "another process serves on it" in second.stderr
        assert "Traceback" not in second.stderr
        assert uds.stat().st_ino == identity  # the first monitor's socket, untouched
        _state(uds)
        stream = Unix(uds)  # a page that never goes away
        stream.request("GET", "/api/stream")
        assert stream.getresponse().status == 200
        began = time.monotonic()
        end(first)
        took = time.monotonic() - began
        stream.close()
        assert first.stdout is not None
        printed = first.stdout.read()
    assert "Traceback" not in printed and "ERROR" not in printed, printed
    assert first.returncode == 0, first.returncode
    assert took < 10, f"an open stream held the stop for {took:.1f} s"
    assert not uds.exists()


def test_a_dead_monitors_socket_is_replaced_and_a_file_never_removed(tmp_path: Path) -> None:
    uds = tmp_path / "http.sock"
    left = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    left.bind(str(uds))
    left.close()  # bound, never listened: what a monitor killed -9 leaves
    with ktbt_process(*_monitor(uds), ready="Ctrl-C"):
        assert wait_until(lambda: _answers(uds), 15)
    precious = tmp_path / "notes.txt"
    precious.write_text("keep me")
    refused = subprocess.run(
        [sys.executable, "-m", "ktbt_proto", *_monitor(precious)],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    assert refused.returncode == 2 and "cannot serve on" in refused.stderr
    assert "Traceback" not in refused.stderr
    assert precious.read_text() == "keep me"
