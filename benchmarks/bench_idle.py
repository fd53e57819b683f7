"""What one idle ``ktbt peer run`` costs, against a bare zenoh session in the same run.

Run with ``python -m benchmarks.bench_idle`` (or ``python -m benchmarks`` for every module).
Prints a Markdown table and writes ``benchmarks/results/idle.json``.

A ``ktbt peer router`` on loopback, and beside it, each a zenoh client of that router with
multicast scouting off (the fleet study's ``router-100`` shape):

- ours: ``ktbt peer run --demo`` started knowing ``colours.sbt`` and told to meet
  ``TargetSeen(colour=2)``, which it knows: nothing to learn, as a learner once its fleet
  converged (``check.idle_cost``); and the same told nothing (it reads the fleet's catalogs
  every 2 s, spec/protocol.md section 4.5); and one waiting for a teacher that is not there
  (told to meet ``Carrying``, which nobody knows: it asks, waits, holds back and asks again,
  as a fleet's learners before their teacher is up);
- the anchor (the floor): a bare Python process holding one zenoh session opened with the
  very configuration ours opens (the JSON of ``ZenohSettings.zenoh_config``, the same
  ``ZENOH_RUNTIME``), importing nothing but ``zenoh``.

Once all are up and ``--settle`` seconds have passed, each process's CPU time (user and system,
``/proc/<pid>/stat``, counted in ticks of 10 ms) over ``--seconds`` is its cost in ms a second,
and its resident memory (``VmRSS``) at the end its memory. ``--rounds`` windows follow each
other; the CPU time over all of them (each window's is kept too) and the median memory are
reported, and ours over the anchor. Target for an idle peer: at most
3 ms of CPU a second and 50 MB.
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ktbt_proto.files import packaged
from ktbt_proto.tools.fleet.runner import usage
from ktbt_proto.transport.zenoh import RX_WORKERS, ZenohSettings

from .timing import machine, markdown_table, write_json

TARGET_CPU_MS = 3.0
TARGET_RSS_MB = 50.0

_BARE = """import sys, threading, zenoh
session = zenoh.open(zenoh.Config.from_json5(open(sys.argv[1]).read()))
open(sys.argv[2], "w").write("up")
threading.Event().wait()
"""
"""The anchor: one zenoh session, held, and nothing else."""


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def measure(seconds: float, settle: float, rounds: int) -> dict[str, Any]:
    router = f"tcp/127.0.0.1:{_port()}"
    knowledge = str(packaged("examples", "knowledge", "colours.sbt"))
    peer = [sys.executable, "-m", "ktbt_proto", "peer"]
    client = ["--connect", router, "--mode", "client", "--no-multicast"]
    duration = str(int(settle + rounds * seconds + 120))
    env = {**os.environ, "ZENOH_RUNTIME": f"(rx: (worker_threads: {RX_WORKERS}))"}
    procs: dict[str, subprocess.Popen[bytes]] = {}
    with tempfile.TemporaryDirectory(prefix="ktbt-bench-idle-") as folder:
        ready = {
            name: Path(folder) / f"{name}.ready" for name in ("router", "ours", "listed", "waiting")
        }
        ready["bare"] = Path(folder) / "bare.ready"
        config = Path(folder) / "bare.json5"
        settings = ZenohSettings(connect=[router], mode="client", multicast_scouting=False)
        config.write_text(str(settings.zenoh_config()))
        commands = {
            "router": [*peer, "router", "--listen", router, "--no-multicast"],
            "ours": [*peer, "run", "--demo", "--id", "idle", "--knowledge", knowledge,
                     "--sequence", "TargetSeen(colour=2)", *client, "--duration", duration],
            "listed": [*peer, "run", "--demo", "--id", "listing", *client,
                       "--duration", duration],
            "waiting": [*peer, "run", "--demo", "--id", "waiting", "--sequence", "Carrying",
                        *client, "--duration", duration],
            "bare": [sys.executable, "-c", _BARE, str(config), str(ready["bare"])],
        }  # fmt: skip
        try:
            for name, args in commands.items():
                extra = [] if name == "bare" else ["--ready", str(ready[name])]
                procs[name] = subprocess.Popen(
                    [*args, *extra], env=env, stdin=subprocess.DEVNULL,
                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                )  # fmt: skip
                if name == "router":
                    _wait(ready["router"], procs["router"])
            for name, proc in procs.items():
                _wait(ready[name], proc)
            time.sleep(settle)  # after start-up: imports, the first catalogs, zenoh's links
            contenders = ("ours", "listed", "waiting", "bare")
            windows: dict[str, list[tuple[float, float, float]]] = {n: [] for n in contenders}
            load = [os.getloadavg()[0]]
            for _ in range(rounds):
                first = {n: usage(procs[n].pid) for n in contenders}
                began = time.monotonic()
                time.sleep(seconds)
                last = {n: usage(procs[n].pid) for n in contenders}
                took = time.monotonic() - began
                for n in contenders:
                    a, b = first[n], last[n]
                    if a is None or b is None:
                        raise RuntimeError(f"{n} ended during the run")
                    windows[n].append((b[2] - a[2], took, b[0] / 1024))
                load.append(os.getloadavg()[0])
        finally:
            for proc in procs.values():
                if proc.poll() is None:
                    proc.terminate()
            for proc in procs.values():
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
    out: dict[str, Any] = {"load_average": [round(x, 2) for x in load], "windows_s": seconds}
    for n, values in windows.items():
        out[n] = {  # CPU time is counted in 10 ms ticks: the whole run's is the finer figure
            "cpu_ms_per_s": round(sum(v[0] for v in values) / sum(v[1] for v in values), 2),
            "cpu_ms_per_s_windows": [round(v[0] / v[1], 2) for v in values],
            "rss_mb": round(statistics.median(v[2] for v in values), 1),
        }
    return out


def _wait(path: Path, proc: subprocess.Popen[bytes], seconds: float = 60) -> None:
    deadline = time.monotonic() + seconds
    while not path.exists():
        if proc.poll() is not None:
            raise RuntimeError(f"{proc.args!r} ended with {proc.returncode} before it was up")
        if time.monotonic() > deadline:
            raise RuntimeError(f"{proc.args!r} not up after {seconds:.0f} s")
        time.sleep(0.05)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="one window (s)")
    parser.add_argument("--settle", type=float, default=5.0, help="before the first (s)")
    parser.add_argument("--rounds", type=int, default=3, help="windows, one after the other")
    args = parser.parse_args(argv)
    result = measure(args.seconds, args.settle, args.rounds)
    bare = result["bare"]
    rows = []
    for name, what in (
        ("ours", "`peer run`, nothing to learn"),
        ("listed", "`peer run`, told nothing (catalogs every 2 s)"),
        ("waiting", "`peer run`, waiting for a teacher"),
        ("bare", "bare zenoh session (anchor)"),
    ):
        r = result[name]
        cpu_met = "met" if r["cpu_ms_per_s"] <= TARGET_CPU_MS else "missed"
        rss_met = "met" if r["rss_mb"] <= TARGET_RSS_MB else "missed"
        ratio = (
            f"{r['cpu_ms_per_s'] / bare['cpu_ms_per_s']:.2f}x / {r['rss_mb'] / bare['rss_mb']:.2f}x"
            if name != "bare" and bare["cpu_ms_per_s"] > 0
            else ""
        )
        verdict = f"CPU {cpu_met}, RSS {rss_met}" if name != "bare" else ""
        rows.append([what, f"{r['cpu_ms_per_s']:.2f}", f"{r['rss_mb']:.1f}", ratio, verdict])
    print(f"idle peer, {args.rounds} windows of {args.seconds:.0f} s ({machine()}; load average "
          f"{min(result['load_average']):.1f} to {max(result['load_average']):.1f})")  # fmt: skip
    print(
        markdown_table(
            ["process", "CPU ms/s", "RSS MB", "x anchor (CPU / RSS)",
             f"target ≤ {TARGET_CPU_MS:.0f} ms/s, ≤ {TARGET_RSS_MB:.0f} MB"],
            rows,
        )
    )  # fmt: skip
    result["machine"] = machine()
    result["targets"] = {"cpu_ms_per_s": TARGET_CPU_MS, "rss_mb": TARGET_RSS_MB}
    write_json("idle", result)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
