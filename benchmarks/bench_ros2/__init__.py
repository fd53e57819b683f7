"""KT-BT over ROS 2 (spec/protocol.md section 11) beside its anchors, in one run, measured the
way a user compares. ``python -m benchmarks.bench_ros2`` (or ``python -m
benchmarks`` for every module) prints Markdown tables and writes the numbers to
``benchmarks/results/ros2.json``.

Every ROS process runs in one network namespace with only loopback up,
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and a ``ROS_DOMAIN_ID`` of the run's own
(``tests/interop/ros2/rosns.py``'s :class:`RosNamespace`, the project's one definition of a
namespace for ROS processes), and is ended by its pid when the run ends. Each measure compares
ours with what a user would write, on the same executor and in the same process layout, on
each of rclpy's two executors (the events executor ``ktbt ros2 run`` spins by default, and the
``SingleThreadedExecutor`` of ``--executor single`` and ``rclpy.spin``):

1. **Transfer** (:mod:`.transfer`): the shipped lifecycle node at its default 100 Hz, teacher
   and learner in two processes, against a hand-written rclpy pair in two processes (raw: a
   ready answer; floor: the answer built, parsed, merged and ticked), from the learner needing
   a sequence to the item merged and ticked; the two pairs' processes all up at once, timed in
   alternating blocks, :data:`TRANSFER_RUNS` runs of each executor; ours cut into phases.
   A robot embedded with ``attach`` (its defaults) is timed beside them.
2. **Idle CPU**: ``ktbt ros2 run --autostart`` (100 Hz, nothing to learn: it is given the four
   colour skills it would ask about) beside a bare rclpy node with a 100 Hz timer
   (:mod:`.bare_node`), on each executor, all four at once: each process's CPU time (user +
   system, ``/proc/PID/stat``) over the same windows.
3. **Fleet** (:mod:`.fleet`): ten robots in namespaces of their own (``__ns:=/robotN``)
   learning the four colour skills from one teacher, beside a zenoh fleet of the same size run by
   the fleet tool (``ktbt fleet run``'s runner), alternating: convergence is when the last
   learner knew all four, counted from when the teacher came up, as the fleet tool counts it.

The load average is recorded beside each part: the machine is shared.
Where ROS 2 cannot run (no wheels for the platform, the interfaces not built, no network
namespace) it says so in one line and measures nothing.
"""

from __future__ import annotations

import argparse
import bisect
import importlib.metadata
import importlib.util
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ktbt_proto.tools.fleet.runner import EXAMPLE_KNOWLEDGE

from ..timing import machine, markdown_table, percentile, write_json

ROOT = Path(__file__).resolve().parents[2]
EXECUTORS = ("events", "single")
"""rclpy's events executor (``ktbt ros2 run``'s default) and its ``SingleThreadedExecutor``
(``--executor single``, ``rclpy.spin``'s): each contender is compared on each."""
TRANSFER_ROUNDS = 200
"""Timed rounds of each contender in one run, in :data:`TRANSFER_BLOCKS` alternating blocks."""
TRANSFER_BLOCKS = 8
ATTACH_SHARE = 0.25
"""The attached robot's rounds, as a share of the others' (each takes about 0.3 s)."""
TRANSFER_RUNS = 3
IDLE_SECONDS = 15.0
IDLE_WINDOWS = 5
IDLE_RATE = 100.0
"""The node's default tick rate, and the bare node's timer's."""
SETTLE = 2.0
"""Seconds the idle processes run before the first window opens: their start-up (imports, DDS
discovery's first announcements) is not what is measured."""
FLEET_ROBOTS = 10
FLEET_TRIALS = 3
TARGET_RATIO = 1.5
"""Transfer (ours / raw, same executor) and idle CPU (ours / bare, same executor): at most."""
FLEET_TARGET = 2.0
"""The ROS fleet's convergence: at most this many times the zenoh fleet's."""
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


class Driven:
    """A learner's process (:mod:`.transfer`), driven one JSON request and answer a line."""

    def __init__(self, ns: Any, role: str, kind: str, name: str) -> None:
        args = [sys.executable, "-m", f"{__name__}.transfer", "--role", role, "--executor", kind]
        self.name, self.proc = name, ns.start(args, name, stdin=True, cwd=ROOT)
        self.ns = ns

    def ask(self, **request: Any) -> Any:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps(request) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            last = (self.ns.log(self.name).strip().splitlines() or ["(empty log)"])[-1]
            raise RuntimeError(f"{self.name} exited with {self.proc.wait()}: {last}")
        return json.loads(line)

    def quit(self) -> None:
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            self.proc.stdin.close()
            self.proc.wait(timeout=30)


def transfer_run(ns: Any, kind: str, rounds: int, tag: str) -> dict[str, Any]:
    """Every pair on executor ``kind``, their six processes up at once (ours, the attached
    robot with a teacher of its own, the hand-written pair); timed in alternating blocks
    (:data:`TRANSFER_BLOCKS`), the attached robot :data:`ATTACH_SHARE` of the rounds."""
    worker = [sys.executable, "-m", f"{__name__}.transfer", "--executor", kind]
    marks = ns.tmp / f"teacher-ours-{tag}.json"
    load = os.getloadavg()[0]
    args = {
        "teacher-ours": ["--role", "teacher-ours", "--marks", str(marks)],
        "teacher-attach": ["--role", "teacher-ours", "--marks", str(marks) + ".attach",
                           "--topics", "/ktbt_attach"],
        "teacher-hand": ["--role", "teacher-hand"],
    }  # fmt: skip
    names = {who: f"{who}-{tag}" for who in args}
    teachers = {who: ns.start([*worker, *args[who]], names[who], cwd=ROOT) for who in args}
    learners: dict[str, Driven] = {}
    try:
        for who in ("teacher-ours", "teacher-attach"):
            wait_for(in_log(ns, names[who], ": active", teachers[who]),
                     f"ktbt ros2 run ({who}) did not become active")  # fmt: skip
        wait_for(in_log(ns, names["teacher-hand"], "ready", teachers["teacher-hand"]),
                 "the hand-written teacher did not start")  # fmt: skip
        for who in ("learner-ours", "learner-attach", "learner-hand"):
            learners[who] = Driven(ns, who, kind, f"{who}-{tag}")
        began = time.monotonic()
        for who, learner in learners.items():
            if not learner.ask(op="ready")["ok"]:
                raise TimeoutError(f"{who}: the teacher was not reached")
        connect_s = time.monotonic() - began
        ours: list[int] = []
        phases: list[dict[str, int]] = []
        idle_ticks: list[int] = []
        attached: list[int] = []
        attach_phases: list[dict[str, int]] = []
        hand: dict[str, list[dict[str, int]]] = {"raw": [], "floor": []}
        refused = 0
        order = ("learner-ours", "learner-attach", "learner-hand")
        for block in range(TRANSFER_BLOCKS):
            shift = block % len(order)
            for who in order[shift:] + order[:shift]:
                n = rounds // TRANSFER_BLOCKS
                if who == "learner-attach":
                    n = int(n * ATTACH_SHARE)
                got = learners[who].ask(op="rounds", n=max(1, n))
                if who == "learner-ours":
                    ours += got["ours"]
                    phases += got["phases"]
                    idle_ticks += got["idle_ticks"]
                    refused = got["refused"]
                elif who == "learner-attach":
                    attached += got["attach"]
                    attach_phases += got["phases"]
                else:
                    hand["raw"] += got["raw"]
                    hand["floor"] += got["floor"]
    finally:
        for learner in learners.values():
            learner.quit()
        for proc in teachers.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=30)
    teacher_ours = _teacher_calls(json.loads(marks.read_text()) if marks.exists() else [])
    last = (ns.log(names["teacher-hand"]).strip().splitlines() or ["{}"])[-1]
    teacher_hand = json.loads(last) if last.startswith("{") else {}
    result = summarize(kind, ours, phases, hand, teacher_ours, teacher_hand, {
        "connect_s": round(connect_s, 2), "learner_refused": refused,
        "load_average": [round(load, 2), round(os.getloadavg()[0], 2)],
        "idle_tick": _stats(idle_ticks),
    })  # fmt: skip
    result["attach"] = _stats(attached)
    result["attach_phases"] = {
        name: _median_us([p[name] for p in attach_phases]) for name in attach_phases[0]
    }
    result["attach_ratio"] = round(result["attach"]["median"] / result["raw"]["median"], 2)
    return result


def _teacher_calls(marks: list[list[Any]]) -> list[list[int]]:
    """Our teacher's query callbacks that answered: [entry, the answer's ``publish`` entered
    and returned, exit, ns reading the query, ns serialising the answer, ns in its other
    ``publish`` calls (fleet events)], from its marks."""
    calls = []
    for _, start, end in (m for m in marks if m[0] == "on_query"):
        inner = [m for m in marks if m[0] != "on_query" and start <= m[1] and m[2] <= end]
        serialize = [m for m in inner if m[0] == "serialize"]
        if not serialize:
            continue  # answered nothing (its own query, a sequence it does not know)
        publish = next(m for m in inner if m[0] == "publish" and m[1] >= serialize[0][2])
        read = sum(m[2] - m[1] for m in inner if m[0] == "read")
        others = sum(m[2] - m[1] for m in inner if m[0] == "publish" and m is not publish)
        ser = serialize[0][2] - serialize[0][1]
        calls.append([start, publish[1], publish[2], end, read, ser, others])
    return calls


def legs(rounds: list[dict[str, int]], calls: list[list[int]]) -> list[dict[str, int]]:
    """Each round's network time (the learner's ``publish`` returned -> its answer callback
    entered) cut at the teacher's callback that answered it (both processes read one monotonic
    clock): the way out (DDS, the teacher's wake and take), the teacher's callback up to its
    ``publish`` and the way back (``publish``, DDS, the learner's wake and take). A round whose
    teacher callback is not found keeps its network time whole."""
    calls = sorted(calls)
    entries = [c[0] for c in calls]
    cut = []
    for r in rounds:
        published, answer = r.pop("at_published"), r.pop("at_answer")
        i = bisect.bisect_left(entries, published)
        if i < len(calls) and calls[i][1] <= answer:
            call = calls[i]
            r |= {
                "out_leg": call[0] - published,
                "teacher_to_publish": call[1] - call[0],
                "back_leg": answer - call[1],
                "teacher_publish_call": call[2] - call[1],
            }
            if len(call) > 4:
                r |= {
                    "teacher_read": call[4],
                    "teacher_serialize": call[5],
                    "teacher_events": call[6],
                }
        cut.append(r)
    return cut


def _median_us(samples: Sequence[float]) -> float:
    return round(statistics.median(samples) / 1000, 1) if samples else 0.0


def _stats(samples: Sequence[int]) -> dict[str, float]:
    ordered = sorted(samples)
    return {
        "median": _median_us(ordered),
        "p10": round(percentile(ordered, 0.1) / 1000, 1),
        "p90": round(percentile(ordered, 0.9) / 1000, 1),
        "n": len(ordered),
    }


def summarize(
    kind: str,
    ours: list[int],
    phases: list[dict[str, int]],
    hand: dict[str, list[dict[str, int]]],
    teacher_ours: list[list[int]],
    teacher_hand: dict[str, list[list[int]]],
    extra: dict[str, Any],
) -> dict[str, Any]:
    """One run's figures: each contender's times (µs), the median of each phase (µs), the
    ratios to the raw pair."""

    def medians(rounds: list[dict[str, int]]) -> dict[str, float]:
        names = dict.fromkeys(k for r in rounds for k in r if k != "total")
        return {n: _median_us([r[n] for r in rounds if n in r]) for n in names}

    result: dict[str, Any] = {
        "executor": kind,
        "rounds": len(ours),
        "raw": _stats([r["total"] for r in hand["raw"]]),
        "floor": _stats([r["total"] for r in hand["floor"]]),
        "ours": _stats(ours),
        "ours_phases": medians(legs(phases, teacher_ours)),
        "hand_phases": {
            contender: medians(legs(hand[contender], teacher_hand.get(contender, [])))
            for contender in ("raw", "floor")
        },
        **extra,
    }
    r, f, o = result["raw"]["median"], result["floor"]["median"], result["ours"]["median"]
    result["ratio"] = round(o / r, 2)
    result["floor_ratio"] = round(f / r, 2)
    result["added_over_raw"] = round((o - r) / r, 2)
    return result


def run_transfer(ns: Any, rounds: int, runs: int) -> dict[str, Any]:
    """``runs`` runs of each executor, the executors alternating."""
    result: dict[str, Any] = {kind: [] for kind in EXECUTORS}
    for run in range(runs):
        for kind in EXECUTORS if run % 2 == 0 else EXECUTORS[::-1]:
            result[kind].append(transfer_run(ns, kind, rounds, f"{kind}-{run}"))
    for kind in EXECUTORS:
        for key in ("ratio", "attach_ratio"):
            ratios = [r[key] for r in result[kind]]
            result[f"{kind}_{key}"] = {"median": statistics.median(ratios), "min": min(ratios),
                                       "max": max(ratios)}  # fmt: skip
    return result


# -- 2. idle CPU ------------------------------------------------------------------------------


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of process ``pid`` (every thread), in seconds."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_idle(ns: Any, seconds: float, windows: int) -> dict[str, Any]:
    """Ours (``ktbt ros2 run --autostart``, its default tick rate) and a bare node with a
    timer at that rate, on each executor, all four up at once; their CPU over the same
    windows, one after the other."""
    procs: dict[str, Any] = {}
    for kind in EXECUTORS:
        procs[f"ours_{kind}"] = ns.ktbt(
            "ros2", "run", "--autostart", "--executor", kind, "--ros-args",
            "-r", f"__ns:=/idle_{kind}", "-p", f"knowledge:={EXAMPLE_KNOWLEDGE}",
            name=f"idle-ours-{kind}",
        )  # fmt: skip
        node = [sys.executable, "-m", f"{__name__}.bare_node", "--rate", str(IDLE_RATE)]
        procs[f"bare_{kind}"] = ns.start([*node, "--executor", kind], f"idle-bare-{kind}")
    for name, proc in procs.items():
        text = ": active" if name.startswith("ours") else "ready"
        wait_for(in_log(ns, f"idle-{name.replace('_', '-')}", text, proc), f"{name} did not start")
    time.sleep(SETTLE)
    measured: list[dict[str, Any]] = []
    for _ in range(windows):
        for name, proc in procs.items():
            if proc.poll() is not None:
                raise RuntimeError(f"the {name} idle node exited with {proc.returncode}")
        load = os.getloadavg()[0]
        began = time.monotonic()
        before = {name: cpu_seconds(p.pid) for name, p in procs.items()}
        time.sleep(seconds)
        after = {name: cpu_seconds(p.pid) for name, p in procs.items()}
        wall = time.monotonic() - began
        window: dict[str, Any] = {
            "seconds": round(wall, 2),
            "load_average": [round(load, 2), round(os.getloadavg()[0], 2)],
            **{name: round(1000 * (after[name] - before[name]) / wall, 2) for name in procs},
        }
        for kind in EXECUTORS:
            bare = window[f"bare_{kind}"]
            window[f"ratio_{kind}"] = round(window[f"ours_{kind}"] / bare, 2) if bare else None
        measured.append(window)
    result: dict[str, Any] = {
        "rate_hz": IDLE_RATE,
        "window_s": seconds,
        "windows": measured,
        "clock_ticks_per_s": os.sysconf("SC_CLK_TCK"),
        "rss_mb": {name: _rss_mb(p.pid) for name, p in procs.items()},
    }
    for name in procs:
        result[f"{name}_ms_per_s"] = statistics.median(w[name] for w in measured)
    for kind in EXECUTORS:
        ratios = [w[f"ratio_{kind}"] for w in measured if w[f"ratio_{kind}"] is not None]
        result[f"ratio_{kind}"] = {"median": statistics.median(ratios), "min": min(ratios),
                                   "max": max(ratios)}  # fmt: skip
    return result


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return round(int(line.split()[1]) / 1024, 1)
    return 0.0


# -- the run ----------------------------------------------------------------------------------


def run(
    transfer_rounds: int = TRANSFER_ROUNDS,
    transfer_runs: int = TRANSFER_RUNS,
    idle_seconds: float = IDLE_SECONDS,
    idle_windows: int = IDLE_WINDOWS,
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
        "cpus": os.cpu_count(),
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
                    result["transfer"] = run_transfer(ns, transfer_rounds, transfer_runs)
                else:
                    result["idle"] = run_idle(ns, idle_seconds, idle_windows)
            finally:
                ns.close()
    result["load_average_after"] = list(os.getloadavg())
    targets: dict[str, Any] = {"ratio_max": TARGET_RATIO, "fleet_ratio_max": FLEET_TARGET}
    for kind in EXECUTORS:
        if "transfer" in result:
            ratio = result["transfer"][f"{kind}_ratio"]["median"]
            targets[f"transfer_{kind}_met"] = ratio <= TARGET_RATIO
        if "idle" in result:
            targets[f"idle_{kind}_met"] = result["idle"][f"ratio_{kind}"]["median"] <= TARGET_RATIO
    if "fleet" in result and result["fleet"]["ratio"] is not None:
        targets["fleet_met"] = result["fleet"]["ratio"] <= FLEET_TARGET
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

LABEL = {"events": "events executor", "single": "`SingleThreadedExecutor`"}
OURS_PHASES = (
    ("tell", "`set_parameters(sequences=...)`: the node told what it needs"),
    ("wait_ask", "waiting for the node's step (one between ticks, at once)"),
    ("step_to_ask", "the step up to the query (receive, peers, learner)"),
    ("serialize", "the `Query` serialised (CDR)"),
    ("bookkeeping", "the open query's bookkeeping"),
    ("publish", "`publish` (rclpy, Fast DDS)"),
    ("network", "publish returned -> the answer's callback entered"),
    ("out_leg", "  DDS to the teacher, its executor's wake and take"),
    ("teacher_to_publish", "  the teacher's callback up to `publish` (read, look up, build)"),
    ("teacher_read", "    of which reading the query (CDR, section 1 checks)"),
    ("teacher_serialize", "    of which serialising the answer (CDR)"),
    ("teacher_events", "    of which its fleet events published (`~/events`)"),
    ("back_leg", "  the answer's `publish`, DDS back, the learner's wake and take"),
    ("own_query_read_back", "  meanwhile: the learner reading its own query back"),
    ("answer_decode", "answer read (CDR, section 1 checks)"),
    ("answer_check", "answer's bookkeeping (open query, trust screen, inbox)"),
    ("wait_merge", "waiting for the node's step (one between ticks, at once)"),
    ("step_to_accept", "the step up to the answer's checks"),
    ("provenance", "provenance / trust check"),
    ("parse_validate", "the item read: parse + validate against the vocabulary"),
    ("merge", "`merge` into the running tree"),
    ("accept_rest", "the rest of `accept`: transfer log, knowledge base, metrics"),
    ("accept_records", "  of which two events recorded (`TransferLog.record`)"),
    ("accept_publishes", "    of which published on `~/events` (rclpy `publish`)"),
    ("accept_kb_add", "  of which the item added to the knowledge base"),
    ("merge_step_rest", "the rest of the step that merged (0 when a tick's)"),
    ("step_say", "  the `learned ...` INFO line (rclpy logger, /rosout)"),
    ("step_appeared", "  the peers read from the ROS graph"),
    ("tick_wait_run", "waiting for the node's next tick (100 Hz), which runs the item"),
    ("step_to_tick", "that tick's step before the control tree's tick"),
    ("control_tick", "the first tick with the item"),
)


def _range(runs: Sequence[Mapping[str, Any]], key: str, digits: int = 1) -> str:
    """The median over the runs of each run's median, and their range."""
    values = [r[key]["median"] if isinstance(r[key], Mapping) else r[key] for r in runs]
    low, mid, high = min(values), statistics.median(values), max(values)
    return f"{mid:,.{digits}f} ({low:,.{digits}f} to {high:,.{digits}f})"


def report_transfer(t: Mapping[str, Any]) -> list[str]:
    parts = []
    rows: list[list[str]] = []
    for kind in EXECUTORS:
        runs = t[kind]
        loads = [x for r in runs for x in r["load_average"]]
        rows += [
            [f"{LABEL[kind]}: raw rclpy pair, publish `Query` -> `Answer` in the callback",
             _range(runs, "raw"), "1.00x", ""],
            [f"{LABEL[kind]}: floor, the pair + answer built, parse, merge, tick",
             _range(runs, "floor"), _range(runs, "floor_ratio", 2) + "x", ""],
            [f"{LABEL[kind]}: ours, `ktbt ros2 run` nodes at 100 Hz",
             _range(runs, "ours"), _range(runs, "ratio", 2) + "x",
             f"{min(loads):.1f} to {max(loads):.1f}"],
            [f"{LABEL[kind]}: ours, `attach` (its timer at 0.1 s) on a user's node ticking "
             "at 100 Hz", _range(runs, "attach"), _range(runs, "attach_ratio", 2) + "x", ""],
        ]  # fmt: skip
    headers = ["transfer, need -> merged + ticked, two processes a pair",
               "median µs (runs' range)", "vs raw", "load"]  # fmt: skip
    parts.append(markdown_table(headers, rows))
    for kind in EXECUTORS:
        runs = t[kind]
        prow: list[list[str]] = []
        for key, label in OURS_PHASES:
            values = [r["ours_phases"][key] for r in runs if key in r["ours_phases"]]
            if not values:
                continue
            prow.append([label, f"{statistics.median(values):,.1f}"])
        total = [r["ours"]["median"] for r in runs]
        prow.append(["ours, whole transfer (median of the rounds)",
                     f"{statistics.median(total):,.1f}"])  # fmt: skip
        for contender in ("raw", "floor"):
            shares = {
                key: statistics.median(r["hand_phases"][contender][key] for r in runs)
                for key in runs[0]["hand_phases"][contender]
            }
            told = ", ".join(f"{key} {value:,.1f}" for key, value in shares.items())
            whole = statistics.median(r[contender]["median"] for r in runs)
            prow.append([f"{contender} pair, whole: {told}", f"{whole:,.1f}"])
        parts.append(markdown_table([f"where ours' time goes, {LABEL[kind]}", "median µs"], prow))
        phases = " + ".join(
            f"{name} {statistics.median(r['attach_phases'][name] for r in runs):,.0f}"
            for name in runs[0]["attach_phases"]
        )
        parts.append(f"`attach`, {LABEL[kind]}, median µs of each phase: {phases}.")
        ratio = t[f"{kind}_ratio"]
        met = "met" if ratio["median"] <= TARGET_RATIO else "missed"
        parts.append(
            f"Target, {LABEL[kind]}: ours ≤ {TARGET_RATIO:g}x the raw pair on the same "
            f"executor: {ratio['median']:.2f}x ({ratio['min']:.2f}x to {ratio['max']:.2f}x in "
            f"{len(runs)} runs): {met}. Added latency over the raw pair: "
            f"{_range(runs, 'added_over_raw', 2)}x the raw round trip (target ≤ 0.5x). "
            f"One tick of the idle learner between rounds: {_range(runs, 'idle_tick')} µs "
            "(its timer callback, 100 a second)."
        )
    return parts


def report_idle(idle: Mapping[str, Any]) -> list[str]:
    rows = []
    for kind in EXECUTORS:
        for who, label in (
            ("bare", "bare rclpy node, 100 Hz timer"),
            ("ours", "`ktbt ros2 run --autostart`, active, 100 Hz, nothing to learn"),
        ):
            key = f"{who}_{kind}"
            ratio = idle[f"ratio_{kind}"]
            rows.append([
                f"{LABEL[kind]}: {label}",
                f"{idle[f'{key}_ms_per_s']:.1f}",
                ", ".join(f"{w[key]:.1f}" for w in idle["windows"]),
                f"{idle['rss_mb'][key]:.0f}",
                "1.00x" if who == "bare" else
                f"{ratio['median']:.2f}x ({ratio['min']:.2f}x to {ratio['max']:.2f}x)",
            ])  # fmt: skip
    loads = [x for w in idle["windows"] for x in w["load_average"]]
    parts = [
        markdown_table(
            ["idle, all four at once", "CPU ms per s (median)", "windows", "RSS MB", "vs bare"],
            rows,
        )
    ]
    for kind in EXECUTORS:
        ratio = idle[f"ratio_{kind}"]["median"]
        met = "met" if ratio <= TARGET_RATIO else "missed"
        parts.append(
            f"Target, {LABEL[kind]}: ours ≤ {TARGET_RATIO:g}x a bare node on the same executor: "
            f"{ratio:.2f}x ({met}); {len(idle['windows'])} windows of {idle['window_s']:g} s, "
            f"load average {min(loads):.1f} to {max(loads):.1f}."
        )
    return parts


def report(result: Mapping[str, Any]) -> str:
    parts = ["## KT-BT over ROS 2 (Fast DDS, loopback, one network namespace)"]
    if "transfer" in result:
        parts += report_transfer(result["transfer"])
    if "idle" in result:
        parts += report_idle(result["idle"])
    fleet = result.get("fleet")
    if fleet is not None:
        from .fleet import report_fleet

        parts.append(report_fleet(fleet, FLEET_TARGET))
    la, lb = result["load_average"], result["load_average_after"]
    parts.append(
        f"{result['python']}, rclpy {result['rclpy']}, {result['cpus']} CPUs. Load average "
        f"{la[0]:.1f} before, {lb[0]:.1f} after. Whole run: {result['seconds']:.0f} s."
    )
    return "\n\n".join(parts)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_ros2")
    parser.add_argument("--rounds", type=int, default=TRANSFER_ROUNDS,
                        help="transfer rounds of each contender in one run")  # fmt: skip
    parser.add_argument("--runs", type=int, default=TRANSFER_RUNS,
                        help="transfer runs of each executor")  # fmt: skip
    parser.add_argument("--idle-seconds", type=float, default=IDLE_SECONDS)
    parser.add_argument("--idle-windows", type=int, default=IDLE_WINDOWS)
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
    result = run(args.rounds, args.runs, args.idle_seconds, args.idle_windows,
                 args.fleet_trials, only)  # fmt: skip
    print(report(result))
    if not args.no_json:
        path = write_json("ros2", result)
        print(f"\nWrote {path.relative_to(path.parents[2])}")
    return 0
