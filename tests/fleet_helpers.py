"""What the tests of ``ktbt fleet run`` share: the sweep after a run, so that nothing it
started outlives it, whatever happened to it."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
from pathlib import Path

MONITOR_PID = re.compile(r"ktbt monitor started, pid (\d+)")


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except OSError:
        return False
    return state != "Z"


def namespaces() -> set[str]:
    if shutil.which("ip") is None:
        return set()
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    return {line.split()[0] for line in listed.splitlines() if line.strip()}


def sweep(
    proc: subprocess.Popen[str], record: Path, output: str = ""
) -> tuple[list[int], list[int], set[str]]:
    """After a run: end it if it still runs, then kill by pid every peer it launched (and the
    monitor its ``output`` names) that is still alive and delete every namespace it made.
    Returns the processes launched, those it had left running and the namespaces it had left,
    for the test to assert on."""
    if proc.poll() is None:
        proc.kill()
        proc.communicate()
    pids = []  # every peer the run started, whatever happened to the run
    if record.exists():
        for line in record.read_text().splitlines():
            event = json.loads(line)
            if event["kind"] == "launch":
                pids.append(event["pid"])
    pids += [int(found) for found in MONITOR_PID.findall(output)]
    left = [pid for pid in pids if alive(pid)]
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    ours = {n for n in namespaces() if n.startswith(f"ktbt-fleet-{proc.pid}-")}
    for name in ours:
        subprocess.run(["ip", "netns", "del", name], check=False)
    return pids, left, ours
