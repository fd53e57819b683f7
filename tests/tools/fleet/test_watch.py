"""``ktbt fleet run --monitor``'s watch (``ktbt_proto/tools/fleet/watch.py``): the real ``ktbt
monitor`` started for one run, reaching each fleet member over a unix socket in a folder of
the run's own and serving its page there too, so that :func:`view` reads what the page shows
(spec/protocol.md section 10, docs/howto/fleet.md).

ShownTopics here with real processes on loopback and unix sockets only: the monitor is started, says
where to watch, shows a real ``ktbt peer serve`` that listens on its member's socket (present,
and what it knows), and is stopped with its folder removed; a monitor that ends during the run
is reported, one that cannot start (its address taken) is a ``MonitorFailed`` with its words,
a monitor dies with a runner killed by SIGKILL, and through routers it links to one.
``view`` is None where no monitor answers.
"""

from __future__ import annotations

import http.server
import json
import os
import re
import shutil
import signal
import socket
import socketserver
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import pytest

from ktbt_proto.tools.fleet.plan import FleetConfig
from ktbt_proto.tools.fleet.watch import MonitorFailed, endpoint, view, watching
from tests.fleet_helpers import MONITOR_PID, alive
from tests.zenoh_helpers import ROOT, end, wait_until

pytestmark = pytest.mark.network  # it starts ktbt monitor and peers on loopback

CONFIG = FleetConfig(peers=2, name="watched")  # members p0 and t1
KNOWLEDGE = "<k>(prior)\n<sq><c>(TargetSeen, colour=2)<a>(PickTreasure)<e>\n<e>\n"


def test_a_member_is_reached_on_a_socket_in_the_watch_folder() -> None:
    assert endpoint("/tmp/ktbt-watch-x", "p0") == "unixsock-stream//tmp/ktbt-watch-x/p0.sock"


def test_nothing_to_view_where_no_monitor_answers(tmp_path: Path) -> None:
    assert view(str(tmp_path)) is None  # no socket at all
    left = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    left.bind(str(tmp_path / "http.sock"))  # what a monitor killed -9 leaves: bound, not served
    left.close()
    assert view(str(tmp_path)) is None


class _Unix(socketserver.ThreadingMixIn, socketserver.UnixStreamServer):
    daemon_threads = True


@contextmanager
def serving(folder: Path, status: int, body: bytes) -> Iterator[None]:
    """Another program on the watch folder's socket: it answers, but not as the monitor."""

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            self.send_response(status)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, format: str, *args: object) -> None:
            pass  # a unix socket's client has no address to log

    server = _Unix(str(folder / "http.sock"), Handler)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05})
    thread.start()
    try:
        yield
    finally:
        server.shutdown()
        server.server_close()
        thread.join()
        (folder / "http.sock").unlink()


@pytest.mark.parametrize(
    ("status", "body"),
    [(404, b"not found"), (200, b"<html>"), (200, json.dumps({"peers": []}).encode())],
    ids=["not-found", "not-json", "not-a-state"],
)
def test_an_answer_that_is_not_the_monitors_state_is_nothing_to_view(
    tmp_path: Path, status: int, body: bytes
) -> None:
    with serving(tmp_path, status, body):
        assert view(str(tmp_path)) is None


def test_the_monitor_shows_a_member_on_its_socket_and_is_stopped_with_its_folder(
    tmp_path: Path,
) -> None:
    said: list[str] = []
    knowledge = tmp_path / "colours.sbt"
    knowledge.write_text(KNOWLEDGE)
    with watching(CONFIG, "127.0.0.1:0", tmp_path, said.append) as watch:
        folder = watch.config.watch
        assert folder and Path(folder).is_dir() and (Path(folder) / "http.sock").is_socket()
        assert watch.config == replace(CONFIG, watch=folder)  # the rest of the run as it was
        assert view(folder) == {"knows": {}, "status": {}, "drops": {}, "events": 0}
        printed = (tmp_path / "monitor.out").read_text()
        url = re.search(r"http://127\.0\.0\.1:\d+/", printed)
        assert url is not None
        assert watch.proc is not None
        assert said == [
            f"watched: ktbt monitor started, pid {watch.proc.pid}",
            f"watched: watch it at {url.group(0)}",
        ]
        teacher = subprocess.Popen(
            [sys.executable, "-m", "ktbt_proto", "peer", "serve", "--id", "t1",
             "--knowledge", str(knowledge), "--listen", endpoint(folder, "t1"),
             "--publish-events"],
            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, text=True,
        )  # fmt: skip
        try:
            # Present as soon as its liveliness is seen; what it knows once its catalog is read.
            assert wait_until(
                lambda: (
                    (view(folder) or {}).get("knows", {}).get("t1") == ["<c>(TargetSeen,colour=2)"]
                ),
                30,
            ), view(folder)
            shown = view(folder)
            assert shown is not None and shown["status"] == {"t1": "present"}
        finally:
            end(teacher)
        proc = watch.proc
    assert proc.returncode is not None  # stopped by its pid when the run ended
    assert watch.ended == []
    assert not Path(folder).exists()


def test_through_routers_the_monitor_links_to_the_first_router_only(tmp_path: Path) -> None:
    """Linked to several routers, the monitor (a zenoh peer) is a path between them outside the
    fault layer, which they route through: each event reached it about 4 times with 5 routers,
    and the fleet slowed 50-fold (tests/tools/monitor/test_browser_100.py, make soak)."""
    config = FleetConfig(peers=6, topology="router", routers=3, name="routed")
    with watching(config, "127.0.0.1:0", tmp_path, lambda line: None) as watch:
        folder = watch.config.watch
        printed = (tmp_path / "monitor.out").read_text()
    linked = re.search(r"listening to the fleet at (\S+);", printed)
    assert linked is not None, printed
    assert linked.group(1) == endpoint(folder, "r0")


def test_a_monitor_that_ends_during_the_run_is_reported(tmp_path: Path) -> None:
    with watching(CONFIG, "127.0.0.1:0", tmp_path, lambda line: None) as watch:
        assert watch.proc is not None
        watch.proc.terminate()  # the monitor this test started, by its pid
        watch.proc.wait(timeout=30)
        folder = watch.config.watch
    (reason,) = watch.ended
    assert reason.startswith(f"ktbt monitor exited with {watch.proc.returncode} during the run: ")
    assert not Path(folder).exists()


def test_a_monitor_that_cannot_start_says_why(tmp_path: Path) -> None:
    taken = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    taken.bind(("127.0.0.1", 0))
    taken.listen()
    port = taken.getsockname()[1]
    said: list[str] = []
    try:
        with (
            pytest.raises(MonitorFailed) as failed,
            watching(CONFIG, f"127.0.0.1:{port}", tmp_path, said.append),
        ):
            pytest.fail("the monitor started on an address already taken")
    finally:
        taken.close()
    assert str(failed.value).startswith("ktbt monitor did not start: ")
    assert f"cannot serve on 127.0.0.1:{port}" in str(failed.value)
    assert "Traceback" not in str(failed.value)
    found = MONITOR_PID.search(said[0])
    assert len(said) == 1 and found is not None and not alive(int(found.group(1)))


RUNNER = """
import sys
from pathlib import Path
from ktbt_proto.tools.fleet.plan import FleetConfig
from ktbt_proto.tools.fleet.watch import watching

with watching(FleetConfig(peers=2), "127.0.0.1:0", Path(sys.argv[1]), print) as watch:
    print("folder", watch.config.watch, flush=True)
    sys.stdin.read()  # until it is killed
"""


def test_the_monitor_dies_with_a_runner_killed_by_sigkill(tmp_path: Path) -> None:
    runner = subprocess.Popen(
        [sys.executable, "-c", RUNNER, str(tmp_path)],
        cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    monitor, folder = 0, ""
    try:
        assert runner.stdout is not None
        for line in runner.stdout:
            found = MONITOR_PID.search(line)
            monitor = int(found.group(1)) if found else monitor
            if line.startswith("folder "):
                folder = line.split(" ", 1)[1].strip()
                break
        assert monitor and folder, "the runner never watched"
        assert alive(monitor)
        runner.send_signal(signal.SIGKILL)
        runner.wait(timeout=30)
        assert wait_until(lambda: not alive(monitor), 30), "the monitor outlived its runner"
        assert not (Path(folder) / "http.sock").exists()  # it took its socket with it
    finally:
        if runner.poll() is None:
            runner.kill()
            runner.wait()
        if monitor and alive(monitor):
            os.kill(monitor, signal.SIGKILL)  # the monitor this test's runner started
        if runner.stdin is not None:
            runner.stdin.close()
        if runner.stdout is not None:
            runner.stdout.close()
        if folder:
            shutil.rmtree(folder, ignore_errors=True)  # a runner killed -9 cannot remove it
