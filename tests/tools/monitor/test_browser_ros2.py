"""``ktbt monitor --ros2`` in a real headless Chromium: ROS 2 robots (``ktbt ros2 run``) found
through the ROS graph show beside zenoh peers, and a ROS robot's learning shows in the matrix;
an event naming another robot on a robot's topics is dropped as on a wrong key.

The robots and the monitor run in one network namespace (``RosNamespace``, so DDS stays on
its loopback); the monitor also serves its page on a unix socket, which the browser, outside
the namespace, reaches through a small TCP relay of the test's own."""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from ktbt_proto.files import packaged
from ktbt_proto.items import sequence_digest
from tests.browser import chromium, unavailable
from tests.interop.ros2.rosns import SEQUENCE, Probe, RosNamespace
from tests.tools.monitor.test_browser import Page, _up
from tests.zenoh_helpers import wait_until

SKIP = unavailable()
pytestmark = [
    pytest.mark.skipif(SKIP is not None, reason=f"no browser: {SKIP}"),
    pytest.mark.network,
    pytest.mark.slow,
    pytest.mark.timeout(300),
]

COLOURS = packaged("examples", "knowledge", "colours.sbt")


@contextlib.contextmanager
def relay(uds: Path) -> Iterator[int]:
    """A TCP port on this loopback whose every connection is carried to the unix socket
    ``uds``; everything closed on the way out."""
    server = socket.create_server(("127.0.0.1", 0))
    opened: list[socket.socket] = [server]

    def pipe(a: socket.socket, b: socket.socket) -> None:
        with contextlib.suppress(OSError):
            while data := a.recv(65536):
                b.sendall(data)
        with contextlib.suppress(OSError):
            b.shutdown(socket.SHUT_WR)

    def accept() -> None:
        while True:
            try:
                client, _ = server.accept()
            except OSError:  # closed: the test is over
                return
            upstream = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            opened.extend([client, upstream])
            try:
                upstream.connect(str(uds))
            except OSError:
                client.close()
                continue
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=pipe, args=(a, b), daemon=True).start()

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    try:
        yield server.getsockname()[1]
    finally:
        for sock in opened:
            sock.close()
        thread.join(timeout=5)


def lifecycle(ns: RosNamespace, transition: str) -> None:
    done = ns.run("ros2", "lifecycle", "/learner/ktbt", transition, "--timeout", "60", timeout=120)
    assert done.returncode == 0, done.stderr


def test_a_ros2_robot_learning_shows_in_the_page(
    ros2_built: None,
    tmp_path: Path,
) -> None:
    ns = RosNamespace(tmp_path)
    try:
        uds = tmp_path / "http.sock"
        ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/teacher",
                "-p", f"knowledge:={COLOURS}", name="teacher")  # fmt: skip
        ns.ktbt("monitor", "--ros2", "--http", "127.0.0.1:8470", "--uds", str(uds),
                name="monitor")  # fmt: skip
        assert wait_until(uds.exists, 60), ns.log("monitor")
        with relay(uds) as port, chromium() as driver:
            url = f"http://127.0.0.1:{port}/"
            assert wait_until(lambda: _up(url), 30), ns.log("monitor")
            driver.get(url)
            page = Page(driver)
            item = sequence_digest(SEQUENCE)
            assert wait_until(lambda: page.status("teacher") == "present", 60)
            assert wait_until(lambda: (page.cell("teacher", item) or {}).get("how") == "known", 30)
            # The learner starts learning once the monitor follows its events (they are not
            # kept for a later reader: a learning before then shows as what it knows).
            probe = Probe(ns)
            ns.ktbt("ros2", "run", "--ros-args", "-r", "__ns:=/learner",
                    "-p", "sequences:=[TargetSeen(colour=2)]", name="learner")  # fmt: skip
            lifecycle(ns, "configure")
            probe.until({"op": "subscribers", "topic": "/learner/ktbt/events", "count": 1}, 60)
            lifecycle(ns, "activate")

            def learned() -> Any:
                return (page.cell("learner", item) or {}).get("how") == "learned"

            assert wait_until(learned, 90), ns.log("learner")
            assert wait_until(lambda: page.status("learner") == "present", 30)
            whos = page.js(
                "return [...document.querySelectorAll('#transfers li')]"
                "  .map(li => [...li.querySelectorAll('.who')].map(e => e.textContent));"
            )
            assert ["teacher", "learner"] in whos, whos
            # Selected, its tree (its latched ~/tree) shows the item it learned.
            page.js("document.querySelector('#matrix tbody tr[data-peer=learner] th').click();")
            assert wait_until(lambda: "TargetSeen(colour=2)" in page.stat("detail-control"), 15), (
                page.stat("detail-control")
            )
            # Another name on the teacher's topics is not believed: dropped as on a wrong key.
            impostor = {"v": 1, "n": 0, "peer": "impostor", "t": "2026-12-01T21:00:00+00:00",
                        "event": "query-sent", "tick": -1}  # fmt: skip
            probe.until({"op": "publish", "topic": "/teacher/ktbt/events", "type": "FleetEvent",
                         "fields": impostor, "subscribers": 1})  # fmt: skip
            assert wait_until(lambda: "wrong key" in page.dropped(), 30), page.dropped()
            assert "impostor" in " ".join(page.dropped()["wrong key"])
            assert page.status("impostor") is None
        assert "Traceback" not in ns.log("monitor")
    finally:
        ns.close()
