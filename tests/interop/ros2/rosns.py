"""ROS 2 processes for tests, each run inside one network namespace per test with only
loopback up, so that DDS discovery (multicast) never leaves the machine and concurrent tests
never see each other (docs/tutorials/ros2.md, "Testing").

A :class:`RosNamespace` starts a holder process (``unshare -n``, ``ip link set lo up``; not
root, ``unshare -rn``: in a user namespace of its own) and runs every other process in its
namespaces (``nsenter``), with ``ROS_AUTOMATIC_DISCOVERY_RANGE=
LOCALHOST``, a ``ROS_DOMAIN_ID`` of the test's own and ``ROS_LOG_DIR`` under the test's tmp
folder. Every process it started is ended by its pid when it closes (SIGTERM, then SIGKILL).
:class:`Probe` is a ROS participant in the namespace that the test drives line by line
(``tests/interop/ros2/probe.py``): it subscribes, waits on messages with deadlines, publishes
and calls services.
"""

from __future__ import annotations

import itertools
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import IO, Any

_DOMAINS = itertools.count((os.getpid() % 50) + 1)
SEQUENCE = "<c>(TargetSeen,colour=2)"
SUBTREE = "<sq><a>(PickTreasure)<a>(AssignCollectionPoint,colour=2)<e>"
"""The skill the tests' robots exchange (``colours.sbt``'s green one)."""
KTBT = [sys.executable, "-m", "ktbt_proto"]
"""``ktbt`` run by this environment's Python (the console script may not be on PATH)."""


class RosNamespace:
    """One network namespace for a test's ROS processes (see the module's docstring)."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.domain = next(_DOMAINS) % 100 + 1
        self.logs = tmp / "ros-logs"
        self.logs.mkdir(parents=True, exist_ok=True)
        self.processes: list[subprocess.Popen[str]] = []
        # As root, a network namespace; otherwise one inside a user namespace of its own.
        root = os.geteuid() == 0
        up = "ip link set lo up && echo up && exec sleep 100000"
        self.holder = subprocess.Popen(
            ["unshare", "-n" if root else "-rn", "sh", "-c", up], stdout=subprocess.PIPE, text=True
        )
        self.enter = ["nsenter", "-t", str(self.holder.pid), "-n"]
        if not root:
            self.enter[1:1] = ["-U", "--preserve-credentials"]
        assert self.holder.stdout is not None
        if self.holder.stdout.readline().strip() != "up":
            self.holder.kill()
            raise RuntimeError("could not bring loopback up in a network namespace")

    def env(self, **extra: str) -> dict[str, str]:
        env = {
            **os.environ,
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
            "ROS_DOMAIN_ID": str(self.domain),
            "ROS_LOG_DIR": str(self.logs),
            "PYTHONUNBUFFERED": "1",
            "RCUTILS_COLORIZED_OUTPUT": "0",
        }
        env.pop("ROS_LOCALHOST_ONLY", None)
        env.update(extra)
        return env

    def start(
        self, args: list[str], name: str, *, stdin: bool = False, cwd: Path | None = None
    ) -> subprocess.Popen[str]:
        """Start ``args`` in the namespace; its stderr (and stdout unless ``stdin``, a probe)
        goes to ``<tmp>/<name>.log``."""
        log: IO[str] = open(self.tmp / f"{name}.log", "w")  # noqa: SIM115 - closed with the process
        proc = subprocess.Popen(
            [*self.enter, "--", *args],
            stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
            stdout=subprocess.PIPE if stdin else log,
            stderr=log,
            text=True,
            env=self.env(),
            cwd=cwd or self.tmp,
        )
        self.processes.append(proc)
        return proc

    def ktbt(self, *args: str, name: str) -> subprocess.Popen[str]:
        return self.start([*KTBT, *args], name)

    def run(self, *args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
        """A ``ktbt`` command run to its end in the namespace."""
        return subprocess.run(
            [*self.enter, "--", *KTBT, *args],
            capture_output=True,
            text=True,
            env=self.env(),
            timeout=timeout,
        )

    def log(self, name: str) -> str:
        return (self.tmp / f"{name}.log").read_text(errors="replace")

    def close(self) -> None:
        """End every process started, by its pid: SIGTERM, then SIGKILL after 10 s."""
        for proc in self.processes:  # a probe ends at the end of its input
            if proc.stdin is not None:
                proc.stdin.close()
        for proc in [*self.processes, self.holder]:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + 10
        for proc in [*self.processes, self.holder]:
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for proc in [*self.processes, self.holder]:
            if proc.stdout is not None:
                proc.stdout.close()


def wait_for_line(ns: RosNamespace, name: str, text: str, timeout: float = 120) -> str:
    """The first line of a process's output holding ``text``; fails at the deadline."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for line in ns.log(name).splitlines():
            if text in line:
                return line
        time.sleep(0.05)
    raise AssertionError(f"{name} never printed {text!r}:\n{ns.log(name)[-2000:]}")


class Probe:
    """The test's own ROS participant in the namespace (``probe.py``), one JSON request and
    one JSON answer a line."""

    def __init__(self, ns: RosNamespace) -> None:
        self.proc = ns.start(
            [sys.executable, "-m", "tests.interop.ros2.probe"], "probe", stdin=True
        )
        self.ask({"op": "ping"}, timeout=60)

    def ask(self, request: dict[str, Any], timeout: float = 30) -> dict[str, Any]:
        """Send one request; its answer (the probe keeps its own deadline, ``timeout``)."""
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps({**request, "timeout": timeout}) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the probe ended (exit {self.proc.wait()})")
        answer: dict[str, Any] = json.loads(line)
        return answer

    def subscribe(self, topic: str, type_name: str, *, latched: bool = False) -> None:
        self.ask({"op": "sub", "topic": topic, "type": type_name, "latched": latched})

    def wait(
        self,
        topic: str,
        timeout: float = 30,
        absent: dict[str, str] | None = None,
        skip: int = 0,
        **match: Any,
    ) -> dict[str, Any]:
        """The first message on ``topic`` (since subscribing, past the first ``skip``) whose
        fields match (a string field contains the value given, others equal it) and contain
        nothing of ``absent``; fails the test at the deadline."""
        request = {
            "op": "wait",
            "topic": topic,
            "match": match,
            "absent": absent or {},
            "skip": skip,
        }
        answer = self.ask(request, timeout)
        assert answer["ok"], f"nothing on {topic} matched {match} in {timeout} s: {answer}"
        return dict(answer["msg"])

    def messages(self, topic: str) -> list[dict[str, Any]]:
        return list(self.ask({"op": "messages", "topic": topic})["messages"])

    def until(self, request: dict[str, Any], timeout: float = 30) -> dict[str, Any]:
        answer = self.ask(request, timeout)
        assert answer["ok"], f"{request} failed: {answer}"
        return answer
