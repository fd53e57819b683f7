"""``ktbt fleet run --monitor``: ``ktbt monitor`` watching a fleet run from this machine's
loopback (docs/howto/fleet.md).

The monitor reaches every fleet member (one router, when peers are clients) over a unix
socket in a folder of the run's own: a network namespace does not separate sockets bound to a
path, so the monitor runs outside the namespaces the peers live in (the run's, or one a router
group), and its links are outside the fault layer (watching changes no link). It serves its
page on the address asked for and, for the runner inside the namespace, on ``http.sock`` in
the same folder; :func:`view` reads what the page shows from there, and the checker holds it
against the peers' own logs.
"""

from __future__ import annotations

import contextlib
import ctypes
import http.client
import json
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from ktbt_proto.tools.fleet.plan import FleetConfig, make_plan

UP_URL = re.compile(r"http://\S+/")
"""The page's address in ``ktbt monitor``'s first line."""
START_LIMIT = 60.0
"""Seconds the monitor has to answer on its socket."""
PR_SET_PDEATHSIG = 1


class MonitorFailed(RuntimeError):
    """``ktbt monitor`` could not start (the extra is missing, or its address is taken)."""


def endpoint(folder: str, name: str) -> str:
    """Where the monitor reaches a fleet member: a unix socket in the watch folder."""
    return f"unixsock-stream/{Path(folder) / name}.sock"


def view(folder: str) -> dict[str, Any] | None:
    """What the monitor serving on ``<folder>/http.sock`` shows: ``knows`` (peer -> the
    sequences it knows), ``status`` (peer -> present, gone or heard), ``drops``, ``events``;
    None if it does not answer, or not with a state."""

    class Unix(http.client.HTTPConnection):
        def connect(self) -> None:
            self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            self.sock.settimeout(self.timeout)
            self.sock.connect(str(Path(folder) / "http.sock"))

    connection = Unix("localhost", timeout=5)
    try:
        connection.request("GET", "/api/state")
        response = connection.getresponse()
        if response.status != 200:
            return None
        state = json.loads(response.read())
        items: dict[str, str] = state["items"]
        return {
            "knows": {
                p["peer"]: sorted(items[i] for i in p["knows"] if i in items)
                for p in state["peers"]
            },
            "status": {p["peer"]: p["status"] for p in state["peers"]},
            "drops": state["drops"],
            "events": state["events"],
        }
    except (OSError, ValueError, KeyError, TypeError, http.client.HTTPException):
        return None
    finally:
        connection.close()


def _die_with_parent() -> None:
    """In the monitor's child process: SIGTERM when the runner dies, however it dies."""
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


@dataclass
class Watch:
    """The monitor of one run: its folder, its process, and why it ended early, if it did."""

    config: FleetConfig
    """The run's configuration, with the watch folder in it."""
    proc: subprocess.Popen[bytes] | None = None
    ended: list[str] = field(default_factory=list)


@contextlib.contextmanager
def watching(
    config: FleetConfig, http_address: str, out: Path, say: Callable[[str], None]
) -> Iterator[Watch]:
    """A watch folder (short: a socket's path has at most 107 bytes) and ``ktbt monitor`` on
    ``http_address``, connected to every member's socket in it, until the run ends; then the
    monitor is stopped by its pid and the folder removed. The monitor's output goes to
    ``monitor.out`` in the run's folder; it dies with the runner, also by SIGKILL."""
    with tempfile.TemporaryDirectory(prefix="ktbt-watch-", dir=_short_tmp()) as folder:
        watch = Watch(replace(config, watch=folder))
        plan = make_plan(watch.config, 0)
        listening = [
            n.name for n in plan.nodes if n.role == "router" or config.topology != "router"
        ]
        if config.topology == "router":  # one: a zenoh peer linked to several routers is a
            # path between them outside the fault layer, and they route through it (100 peers
            # under 5 routers: each event reached the monitor about 4 times, 197 messages per
            # learned item instead of 14, convergence in 107 s instead of 2 s)
            listening = listening[:1]
        zenoh_conf = Path(folder) / "monitor.json5"  # no gossip, as the fleet's members
        zenoh_conf.write_text(json.dumps({"scouting": {"gossip": {"enabled": False}}}))
        args = [sys.executable, "-m", "ktbt_proto", "monitor", "--http", http_address,
                "--uds", str(Path(folder) / "http.sock"), "--config", str(zenoh_conf)]  # fmt: skip
        for name in listening:
            args += ["--connect", endpoint(folder, name)]
        printed = out / "monitor.out"
        with open(printed, "wb") as sink:
            watch.proc = subprocess.Popen(
                args, stdout=sink, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                env={**os.environ, "PYTHONUNBUFFERED": "1"}, start_new_session=True,
                preexec_fn=_die_with_parent,
            )  # fmt: skip
        proc = watch.proc
        say(f"{config.name}: ktbt monitor started, pid {proc.pid}")
        try:
            deadline = time.monotonic() + START_LIMIT
            while view(folder) is None:
                if proc.poll() is not None or time.monotonic() > deadline:
                    text = printed.read_text(errors="replace").strip()
                    raise MonitorFailed(f"ktbt monitor did not start: {text[-500:]}")
                time.sleep(0.1)
            url = UP_URL.search(printed.read_text(errors="replace"))
            shown = url.group(0) if url else http_address
            say(f"{config.name}: watch it at {shown}")
            yield watch
        finally:
            code = proc.poll()
            if code is not None and not watch.ended:
                tail = printed.read_text(errors="replace").strip()[-300:]
                watch.ended.append(f"ktbt monitor exited with {code} during the run: {tail}")
            if code is None:
                proc.terminate()
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()


def _short_tmp() -> str | None:
    """``/tmp`` where there is one (``TMPDIR`` may be too long a path for sockets)."""
    return "/tmp" if os.path.isdir("/tmp") else None
