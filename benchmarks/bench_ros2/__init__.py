"""KT-BT over ROS 2 (spec/protocol.md section 11) beside its anchors, in one run (issue 26's
targets). ``python -m benchmarks.bench_ros2`` (or ``python -m benchmarks`` for every module)
prints Markdown tables and writes the numbers to ``benchmarks/results/ros2.json``.

Every ROS process runs in one network namespace with only loopback up,
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and a ``ROS_DOMAIN_ID`` of the run's own
(``tests/interop/ros2/rosns.py``'s :class:`RosNamespace`, the project's one definition of a
namespace for ROS processes), and is ended by its pid when the run ends. Three measures:

1. **Transfer** (:mod:`.transfer`): query -> answer -> checked, merged, first tick, against a
   raw rclpy publish and reply of the same messages and against the floor (the same round trip
   with the transfer's own work and none of the protocol's checks), alternating round by round;
   the teacher's side and the learner's side in two processes (as robots are). Three runs
   (:data:`TRANSFER_RUNS`): ours as ``ktbt ros2 run`` spins it (rclpy's events executor)
   against the anchors as ``rclpy.spin`` spins a node (its ``SingleThreadedExecutor``), on
   which the target is judged, as the idle target is against a bare node spun so; then all three
   on the events executor, and all three on the ``SingleThreadedExecutor``.
2. **Idle CPU**: a ``ktbt ros2 run`` node, active and ticking at 10 Hz with nothing to learn
   (it is given the four colour skills it would ask about: an empty ``sequences`` cannot be
   typed on the command line, rclpy leaves ``[]`` uninitialized), beside a bare rclpy node
   with the same 10 Hz timer (:mod:`.bare_node`), both running at once: each process's CPU time
   (user + system, ``/proc/PID/stat``) over the same wall-clock window.
3. **Fleet** (:mod:`.fleet`): ten robots in namespaces of their own (``__ns:=/robotN``)
   learning the four colour skills from one teacher, beside a zenoh fleet of the same size run by
   the fleet tool (``ktbt fleet run``'s runner), alternating: convergence is when the last
   learner knew all four, counted from when the teacher came up, as the fleet tool counts it.

Where ROS 2 cannot run (no wheels for the platform, the interfaces not built, no network
namespace) it says so in one line and measures nothing.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import importlib.util
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ktbt_proto.tools.fleet.runner import EXAMPLE_KNOWLEDGE

from ..timing import machine, markdown_table, write_json

ROOT = Path(__file__).resolve().parents[2]
TRANSFER_ROUNDS = 1000
IDLE_SECONDS = 20.0
IDLE_RATE = 10.0
SETTLE = 2.0
"""Seconds both idle processes run before the window opens: their start-up (imports, DDS
discovery's first announcements) is not what is measured."""
FLEET_ROBOTS = 10
FLEET_TRIALS = 3
TRANSFER_RUNS = {
    "shipped": ("events", "single"),
    "events": ("events", "events"),
    "single": ("single", "single"),
}
"""The transfer's runs, by name: (ours' executor, the anchors'). ``shipped``, on which the
target is judged: ours as ``ktbt ros2 run`` spins it (rclpy's events executor) against the
anchors as ``rclpy.spin`` spins a node (its ``SingleThreadedExecutor``), as the idle target's
bare node is; then each executor for all three contenders."""
TARGET_RATIO = 1.5
"""Transfer and idle CPU: ours at most this many times the anchor."""
UP_TIMEOUT = 120.0


def unavailable() -> str | None:
    """Why ROS 2 cannot be measured here, in one line; None if it can."""
    from ktbt_proto.tools.ros2 import interfaces

    if not interfaces.has_wheels() and interfaces.system_ros() is None:
        return f"no ROS 2 wheels here (only {interfaces.WHEEL_PLATFORMS})"
    if importlib.util.find_spec("rclpy") is None:
        return "ROS 2 is not installed: pip install -e '.[dev]'"
    if importlib.util.find_spec("ktbt_interfaces") is None:
        return "ktbt_interfaces is not built: run ktbt ros2 build"
    if os.geteuid() != 0 and not _can_unshare():
        return "no network namespace (needs root or unprivileged user namespaces)"
    return None


def _can_unshare() -> bool:
    done = subprocess.run(["unshare", "-rn", "true"], capture_output=True, timeout=20)
    return done.returncode == 0


def wait_for(done: Callable[[], bool], what: str, limit: float = UP_TIMEOUT) -> float:
    """Poll ``done`` until it holds; seconds it took (TimeoutError at ``limit``)."""
    start = time.monotonic()
    while not done():
        if time.monotonic() - start > limit:
            raise TimeoutError(f"{what} within {limit:.0f} s")
        time.sleep(0.05)
    return time.monotonic() - start


def in_log(ns: Any, name: str, text: str, proc: Any) -> Callable[[], bool]:
    """Whether ``text`` is in process ``name``'s log yet; RuntimeError, with the log's last
    line, if the process has ended."""

    def done() -> bool:
        found = (ns.tmp / f"{name}.log").exists() and text in ns.log(name)
        if not found and proc.poll() is not None:
            last = (ns.log(name).strip().splitlines() or ["(empty log)"])[-1]
            raise RuntimeError(f"{name} exited with {proc.returncode}: {last}")
        return found

    return done


# -- 1. transfer ------------------------------------------------------------------------------


def run_transfer(ns: Any, rounds: int) -> dict[str, Any]:
    """The transfer (:mod:`.transfer`) with each executor: the teacher's process started and
    up, the learner's run to its end beside it, then the teacher's ended by its pid."""
    worker = [sys.executable, "-m", f"{__name__}.transfer"]
    result: dict[str, Any] = {}
    for run, (kind, anchor) in TRANSFER_RUNS.items():
        name = f"transfer-teacher-{run}"
        executors = ["--executor", kind, "--anchor-executor", anchor]
        teacher = ns.start([*worker, "--role", "teacher", *executors], name, cwd=ROOT)
        try:
            wait_for(in_log(ns, name, "ready", teacher), "the teacher's process did not start")
            done = subprocess.run(
                [*ns.enter, "--", *worker, "--role", "learner", *executors,
                 "--rounds", str(rounds)],
                capture_output=True, text=True, env=ns.env(), cwd=ROOT, timeout=600 + rounds,
            )  # fmt: skip
            if done.returncode != 0:
                tail = (done.stderr.strip().splitlines() or ["(nothing on stderr)"])[-1]
                raise RuntimeError(f"the learner's process exited with {done.returncode}: {tail}")
            measured: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
        finally:
            if teacher.poll() is None:
                teacher.send_signal(signal.SIGTERM)
            teacher.wait(timeout=30)
        last = (ns.log(name).strip().splitlines() or ["{}"])[-1]
        measured.update(json.loads(last) if last.startswith("{") else {})
        result[run] = measured
    return result


# -- 2. idle CPU ------------------------------------------------------------------------------


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of process ``pid`` (every thread), in seconds."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_idle(ns: Any, seconds: float, rate: float) -> dict[str, Any]:
    """Both processes up at once; their CPU over the same window."""
    ours = ns.ktbt(
        "ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/idle",
        "-p", f"tick_rate:={rate}", "-p", f"knowledge:={EXAMPLE_KNOWLEDGE}", name="idle-ktbt",
    )  # fmt: skip
    node = [sys.executable, "-m", f"{__name__}.bare_node", "--rate", str(rate)]
    bare = ns.start(node, "idle-bare")
    bare_events = ns.start([*node, "--events"], "idle-bare-events")
    wait_for(in_log(ns, "idle-ktbt", ": active", ours), "the ktbt node did not become active")
    wait_for(in_log(ns, "idle-bare", "ready", bare), "the bare node did not start")
    wait_for(in_log(ns, "idle-bare-events", "ready", bare_events), "the bare node did not start")
    time.sleep(SETTLE)
    procs = {"ours": ours, "bare": bare, "bare_events": bare_events}
    for name, proc in procs.items():
        if proc.poll() is not None:
            raise RuntimeError(f"the {name} idle node exited with {proc.returncode}")
    began = time.monotonic()
    before = {name: cpu_seconds(p.pid) for name, p in procs.items()}
    time.sleep(seconds)
    after = {name: cpu_seconds(p.pid) for name, p in procs.items()}
    wall = time.monotonic() - began
    rss = {name: _rss_mb(p.pid) for name, p in procs.items()}
    result: dict[str, Any] = {
        "seconds": round(wall, 2),
        "rate_hz": rate,
        "clock_ticks_per_s": os.sysconf("SC_CLK_TCK"),
        **{
            name: {
                "cpu_s": round(after[name] - before[name], 3),
                "cpu_ms_per_s": round(1000 * (after[name] - before[name]) / wall, 2),
                "rss_mb": rss[name],
            }
            for name in procs
        },
    }
    bare_cpu = result["bare"]["cpu_s"]
    result["ratio"] = round(result["ours"]["cpu_s"] / bare_cpu, 2) if bare_cpu else None
    events_cpu = result["bare_events"]["cpu_s"]
    result["ratio_same_executor"] = (
        round(result["ours"]["cpu_s"] / events_cpu, 2) if events_cpu else None
    )
    return result


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return round(int(line.split()[1]) / 1024, 1)
    return 0.0


# -- the run ----------------------------------------------------------------------------------


def run(
    transfer_rounds: int = TRANSFER_ROUNDS,
    idle_seconds: float = IDLE_SECONDS,
    fleet_trials: int = FLEET_TRIALS,
    only: Sequence[str] = ("transfer", "idle", "fleet"),
) -> dict[str, Any]:
    from tests.interop.ros2.rosns import RosNamespace

    from .fleet import run_fleets

    started = time.perf_counter()
    result: dict[str, Any] = {
        "python": machine(),
        "rclpy": importlib.metadata.version("ros-jazzy-rclpy")
        if _installed("ros-jazzy-rclpy")
        else "system",
        "load_average": list(os.getloadavg()),
    }
    with tempfile.TemporaryDirectory(prefix="ktbt-bench-ros2-") as tmp:
        for part in only:
            folder = Path(tmp) / part
            folder.mkdir()
            if part == "fleet":
                result["fleet"] = run_fleets(folder, FLEET_ROBOTS, fleet_trials)
                continue
            ns = RosNamespace(folder)
            try:
                if part == "transfer":
                    result["transfer"] = run_transfer(ns, transfer_rounds)
                else:
                    result["idle"] = run_idle(ns, idle_seconds, IDLE_RATE)
            finally:
                ns.close()
    result["load_average_after"] = list(os.getloadavg())
    targets: dict[str, Any] = {"ratio_max": TARGET_RATIO}
    if "transfer" in result:
        shipped = result["transfer"]["shipped"]
        targets["transfer_met"] = shipped["ratio"]["median"] <= TARGET_RATIO
    if "idle" in result and result["idle"]["ratio"] is not None:
        targets["idle_met"] = result["idle"]["ratio"] <= TARGET_RATIO
    result["targets"] = targets
    result["seconds"] = round(time.perf_counter() - started, 1)
    return result


def _installed(dist: str) -> bool:
    try:
        importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return False
    return True


# -- report -----------------------------------------------------------------------------------


def _us(d: Mapping[str, float]) -> list[str]:
    return [f"{d['median']:,.1f}", f"{d['p90']:,.1f}", f"{d['p99']:,.1f}"]


def report(result: Mapping[str, Any]) -> str:
    parts = ["## KT-BT over ROS 2 (Fast DDS, loopback, one network namespace)"]
    t = result.get("transfer")
    if t is not None:
        label = {"events": "events executor", "single": "`SingleThreadedExecutor`"}
        rows: list[list[str]] = []
        for run, (kind, anchor) in TRANSFER_RUNS.items():
            m = t.get(run)
            if m is None:
                continue
            q, r = m["payload_bytes"]["query"], m["payload_bytes"]["response"]
            phases = m["ours_phases"]
            rows += [
                [f"raw rclpy, {label[anchor]}: publish Query -> reply Answer ({q} B / {r} B CDR)",
                 *_us(m["raw"]), "1.00x"],
                [f"floor, {label[anchor]}: the raw pair's round trip, the answer looked up and "
                 "built for the query, then parse -> `merge` + tick, no protocol checks",
                 *_us(m["floor"]), f"{m['floor_ratio']['median']:.2f}x"],
                [f"ours, {label[kind]}: Query -> `broadcast` -> Answer -> parse -> `merge` + tick",
                 *_us(m["ours"]), f"{m['ratio']['median']:.2f}x"],
                ["  of which build + `broadcast` + spin until `receive` has it",
                 *_us(phases["ask"]), ""],
                ["  of which checks + `kp.parse(..., limits=RECEIVE_LIMITS)`",
                 *_us(phases["check_parse"]), ""],
                ["  of which `live.merge` + `live.tick()`", *_us(phases["merge_tick"]), ""],
            ]  # fmt: skip
        parts.append(
            markdown_table(
                ["transfer, two processes", "median µs", "p90 µs", "p99 µs", "vs raw"], rows
            )
        )
        m = t["shipped"]
        met = "met" if result["targets"]["transfer_met"] else "missed"
        same = "; ".join(
            f"{label[k]}: ours {t[k]['ratio']['median']:.2f}x, floor "
            f"{t[k]['floor_ratio']['median']:.2f}x"
            for k in ("events", "single")
            if k in t
        )
        parts.append(
            f"Target: ours as `ktbt ros2 run` spins it ({label['events']}) against raw rclpy as "
            f"`rclpy.spin` runs it ({label['single']}), median ≤ {TARGET_RATIO:g}x: "
            f"{m['ratio']['median']:.2f}x ({met}); p99 {m['ratio']['p99']:.2f}x. All three on "
            f"one executor: {same}. {m['rounds']} interleaved rounds after "
            f"{m['warmup_rounds']} warm-up rounds each; discovery and the first rounds took "
            f"{m['connect_s']:.2f} s."
        )
    idle = result.get("idle")
    if idle is not None:
        rows = [
            [f"bare rclpy node, {idle['rate_hz']:g} Hz timer, `rclpy.spin`", "bare"],
            ["the same, rclpy's events executor (as ours)", "bare_events"],
            [f"`ktbt ros2 run --autostart`, active, ticking at {idle['rate_hz']:g} Hz", "ours"],
        ]
        parts.append(
            markdown_table(
                ["idle, both at once", "CPU s", "CPU ms per s", "RSS MB", "vs bare"],
                [
                    [
                        label,
                        f"{idle[k]['cpu_s']:.2f}",
                        f"{idle[k]['cpu_ms_per_s']:.1f}",
                        f"{idle[k]['rss_mb']:.0f}",
                        f"{idle[k]['cpu_s'] / idle['bare']['cpu_s']:.2f}x"
                        if idle["bare"]["cpu_s"]
                        else "-",
                    ]
                    for label, k in rows
                ],
            )
        )
        met = "met" if result["targets"].get("idle_met") else "missed"
        parts.append(
            f"Target: ours ≤ {TARGET_RATIO:g}x the bare node's CPU: {idle['ratio']:.2f}x ({met}), "
            f"over the same {idle['seconds']:.0f} s window; "
            f"{idle['ratio_same_executor']}x a bare node on the same executor."
        )
    fleet = result.get("fleet")
    if fleet is not None:
        from .fleet import report_fleet

        parts.append(report_fleet(fleet))
    la, lb = result["load_average"], result["load_average_after"]
    parts.append(
        f"{result['python']}, rclpy {result['rclpy']}. Load average {la[0]:.1f} before, "
        f"{lb[0]:.1f} after. Whole run: {result['seconds']:.0f} s."
    )
    return "\n\n".join(parts)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_ros2")
    parser.add_argument("--rounds", type=int, default=TRANSFER_ROUNDS, help="transfer rounds")
    parser.add_argument("--idle-seconds", type=float, default=IDLE_SECONDS)
    parser.add_argument("--fleet-trials", type=int, default=FLEET_TRIALS)
    parser.add_argument(
        "--only", default="transfer,idle,fleet", help="comma-separated: transfer, idle, fleet"
    )
    parser.add_argument("--no-json", action="store_true", help="do not write results/ros2.json")
    args = parser.parse_args(argv)
    only = [p for p in args.only.split(",") if p]
    bad = [p for p in only if p not in ("transfer", "idle", "fleet")]
    if bad:
        parser.error(f"--only: {bad[0]!r}: use transfer, idle or fleet")
    why = unavailable()
    if why is not None:
        print(f"## KT-BT over ROS 2\n\nSkipped: {why}.")
        return 0
    result = run(args.rounds, args.idle_seconds, args.fleet_trials, only)
    print(report(result))
    if not args.no_json:
        path = write_json("ros2", result)
        print(f"\nWrote {path.relative_to(path.parents[2])}")
    return 0
