"""Ten robots learning the four colour skills from one teacher: over ROS 2 (``ktbt ros2 run``,
each robot in a namespace of its own, ``__ns:=/robotN``) and over zenoh (``ktbt peer run``
fleet members started by the fleet tool's runner, ``ktbt_proto/tools/fleet/``), alternating.

Both fleets are started the fleet tool's way: the learners first, every one up (a ROS node
active, a zenoh peer's session open), then the teacher; convergence is the time from the
teacher being up to the last learner knowing all four items (its log's ``merged`` events), as
:func:`ktbt_proto.tools.fleet.check.convergence_time` counts it. Both run the same programs'
defaults: the demo robot's control tree, 100 ticks a second, queries open 200 ticks, and the
teacher a fleet member that also learns nothing (it knows everything).
"""

from __future__ import annotations

import contextlib
import json
import os
import statistics
from datetime import datetime
from pathlib import Path
from typing import Any

from ktbt_proto.tools.fleet.plan import FleetConfig
from ktbt_proto.tools.fleet.runner import EXAMPLE_KNOWLEDGE, authored_items
from ktbt_proto.tools.fleet.runner import run as run_zenoh_fleet

from ..timing import markdown_table

BOUND = 60.0
"""Seconds the teacher's knowledge has to reach every learner."""


def _ros_time(line: str) -> float | None:
    """The time of a ROS console line (``[INFO] [1767600000.123456789] [name]: text``)."""
    try:
        return float(line.split("] [", 2)[1])
    except (IndexError, ValueError):
        return None


def _merges(path: Path, items: set[str]) -> dict[str, float]:
    """A transfer log's merges of ``items``: sequence -> the first time (epoch seconds)."""
    found: dict[str, float] = {}
    if not path.exists():
        return found
    for line in path.read_text(errors="replace").splitlines():
        try:
            entry = json.loads(line)
        except ValueError:
            continue
        seq = entry.get("sequence")
        if entry.get("event") == "merged" and seq in items and seq not in found:
            found[seq] = datetime.fromisoformat(entry["t"]).timestamp()
    return found


def _count(path: Path, events: tuple[str, ...]) -> int:
    """Lines of a transfer log recording one of ``events``."""
    if not path.exists():
        return 0
    total = 0
    for line in path.read_text(errors="replace").splitlines():
        try:
            total += json.loads(line).get("event") in events
        except (ValueError, AttributeError):
            continue
    return total


def run_ros_fleet(folder: Path, robots: int) -> dict[str, Any]:
    from tests.interop.ros2.rosns import RosNamespace

    from . import UP_TIMEOUT, wait_for

    items = set(authored_items(EXAMPLE_KNOWLEDGE))
    ns = RosNamespace(folder)
    try:
        learners = [f"robot{i}" for i in range(1, robots + 1)]
        for name in learners:
            ns.ktbt(
                "ros2", "run", "--autostart", "--ros-args", "-r", f"__ns:=/{name}",
                "-p", f"log:={folder / name}.jsonl", name=name,
            )  # fmt: skip

        def active(name: str) -> float | None:
            path = folder / f"{name}.log"
            if not path.exists():
                return None
            for line in ns.log(name).splitlines():
                if line.endswith(f"{name}: active"):
                    return _ros_time(line)
            return None

        learners_up = wait_for(
            lambda: all(active(n) is not None for n in learners),
            "the ROS learners did not all become active",
            UP_TIMEOUT,
        )
        ns.ktbt(
            "ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/teacher",
            "-p", f"knowledge:={EXAMPLE_KNOWLEDGE}", "-p", f"log:={folder / 'teacher'}.jsonl",
            name="teacher",
        )  # fmt: skip
        wait_for(lambda: active("teacher") is not None, "the ROS teacher did not come up")
        reference = active("teacher")
        assert reference is not None

        def knowing() -> dict[str, dict[str, float]]:
            return {n: _merges(folder / f"{n}.jsonl", items) for n in learners}

        with contextlib.suppress(TimeoutError):  # reported as not converged
            wait_for(lambda: all(len(m) == len(items) for m in knowing().values()), "", BOUND)
        merges = knowing()
        converged = all(len(m) == len(items) for m in merges.values())
        last = max((max(m.values()) for m in merges.values() if m), default=reference)
        # As the fleet tool counts them: queries sent and answers sent, by every robot.
        messages = sum(
            _count(folder / f"{n}.jsonl", ("query-sent", "answer-sent"))
            for n in [*learners, "teacher"]
        )
        learned = sum(len(m) for m in merges.values())
        return {
            "robots": robots,
            "learners_up_s": round(learners_up, 2),
            "messages_per_item": round(messages / learned, 2) if learned else None,
            "convergence_s": round(max(0.0, last - reference), 3) if converged else None,
            "knew_all": sum(len(m) == len(items) for m in merges.values()),
            "learned": learned,
        }
    finally:
        ns.close()


def run_zenoh(folder: Path, robots: int) -> dict[str, Any]:
    config = FleetConfig(peers=robots + 1, teachers=1, name="bench-zenoh", bound=BOUND)
    summary = run_zenoh_fleet(config, folder, lambda line: None)
    return {
        "robots": robots,
        "passed": summary["passed"],
        "convergence_s": summary["convergence_s"],
        "learned": summary["learned"],
        "messages_per_item": summary["messages_per_item"],
    }


def run_fleets(folder: Path, robots: int, trials: int) -> dict[str, Any]:
    """``trials`` of each, alternating (ROS first in odd trials, zenoh first in even ones);
    each with the load average (1 min) when it began and ended."""
    ros: list[dict[str, Any]] = []
    zenoh: list[dict[str, Any]] = []
    for trial in range(trials):
        for kind in ("ros2", "zenoh") if trial % 2 == 0 else ("zenoh", "ros2"):
            where = folder / f"{kind}-{trial}"
            where.mkdir()
            load = os.getloadavg()[0]
            done = run_ros_fleet(where, robots) if kind == "ros2" else run_zenoh(where, robots)
            done["load_average"] = [round(load, 2), round(os.getloadavg()[0], 2)]
            (ros if kind == "ros2" else zenoh).append(done)

    def median(runs: list[dict[str, Any]]) -> float | None:
        times = [r["convergence_s"] for r in runs]
        return None if None in times else round(statistics.median(times), 3)

    result: dict[str, Any] = {
        "robots": robots,
        "items": len(authored_items(EXAMPLE_KNOWLEDGE)),
        "trials": trials,
        "ros2": ros,
        "zenoh": zenoh,
        "ros2_median_s": median(ros),
        "zenoh_median_s": median(zenoh),
    }
    r, z = result["ros2_median_s"], result["zenoh_median_s"]
    result["ratio"] = round(r / z, 2) if r is not None and z else None
    return result


def report_fleet(fleet: dict[str, Any], target: float) -> str:
    def cell(runs: list[dict[str, Any]]) -> str:
        times = [r["convergence_s"] for r in runs]
        return ", ".join("-" if t is None else f"{t:.2f}" for t in times)

    def per_item(runs: list[dict[str, Any]]) -> str:
        counts = [r["messages_per_item"] for r in runs if r.get("messages_per_item") is not None]
        return f"{statistics.median(counts):.1f}" if counts else "-"

    def med(value: float | None) -> str:
        return "-" if value is None else f"{value:.2f}"

    table = markdown_table(
        [f"{fleet['robots']} learners + 1 teacher, {fleet['items']} items", "median s", "trials s",
         "messages per item"],
        [
            ["ROS 2: `ktbt ros2 run`, `__ns:=/robotN`", med(fleet["ros2_median_s"]),
             cell(fleet["ros2"]), per_item(fleet["ros2"])],
            ["zenoh: `ktbt peer run` (fleet tool, mesh)", med(fleet["zenoh_median_s"]),
             cell(fleet["zenoh"]), per_item(fleet["zenoh"])],
        ],
    )  # fmt: skip
    ratio = fleet["ratio"]
    loads = [x for r in [*fleet["ros2"], *fleet["zenoh"]] for x in r.get("load_average", [])]
    met = "met" if ratio is not None and ratio <= target else "missed"
    note = "Convergence: from the teacher up to the last learner knowing every item. " + (
        f"ROS 2 / zenoh (medians): {ratio:.2f}x; target ≤ {target:g}x: {met}."
        if ratio is not None
        else "A fleet did not converge: target missed."
    )
    if loads:
        note += f" Load average {min(loads):.1f} to {max(loads):.1f}."
    return "\n\n".join([table, note])
