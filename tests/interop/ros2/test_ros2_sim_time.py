"""A ROS robot keeps its host's time (spec/protocol.md section 11, "Time"): with
``use_sim_time`` and a ``/clock`` running at ten times real speed, its ticks, the cool-down
after a query nobody answered and its catalog period follow the simulated clock, not the wall.
A real ``ktbt ros2 run`` lifecycle node in a network namespace of its own (``rosns``); the
test's probe publishes ``/clock``.

Each check compares readings of the simulated clock (or ticks, which that clock drives) with a
bound that a robot on the wall clock misses several times over: a query nobody answers is asked
again 30 ticks (3 simulated seconds) and a backoff of at most 3 s later on the simulated clock,
300 ticks and more on the wall clock; a catalog that appears is followed within 2 simulated
seconds (and discovery) of being published, where the wall clock's 2 s would be 20."""

from __future__ import annotations

import itertools
import time
from typing import Any

import pytest

from tests.interop.ros2.rosns import SEQUENCE, Probe, RosNamespace, wait_for_line

pytestmark = [pytest.mark.network, pytest.mark.slow, pytest.mark.timeout(300)]

START = 1000.0
"""Simulated seconds at which the test's ``/clock`` starts (far from the wall's epoch)."""


def test_ticks_query_timeouts_and_catalog_periods_follow_the_simulated_clock(rosns: Any) -> None:
    ns: RosNamespace = rosns
    probe = Probe(ns)
    probe.until({"op": "clock", "start": START, "speed": 10})
    probe.subscribe("/lone/ktbt/events", "FleetEvent")
    probe.subscribe("/lone/ktbt/tree", "TreeSnapshot", latched=True)
    probe.subscribe("/ktbt/queries", "Query")  # in the fleet: its catalogs are read
    ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/lone",
            "-p", "use_sim_time:=true", "-p", "tick_rate:=10.0", "-p", "wait_ticks:=20",
            "-p", "cooldown_ticks:=10", "-p", "snapshot_period:=1.0", name="lone")  # fmt: skip
    wait_for_line(ns, "lone", "lone: active", 60)

    # The catalog period: a catalog topic that appears is followed at the robot's next look,
    # every 2 simulated seconds (section 11). Five, one after the other: from publishing each
    # to the robot's subscription, discovery and at most one period; on the wall clock the
    # five would take about 50 simulated seconds together.
    delays = []
    for n in range(5):
        topic = f"/shelf{n}/catalog"
        entry = {"sequence": SEQUENCE}
        published = probe.until(
            {"op": "publish", "topic": topic, "type": "Catalog", "latched": True,
             "subscribers": 0, "fields": {"peer": f"shelf{n}", "items": [entry]}}
        )["sim"]  # fmt: skip
        followed = probe.until({"op": "matched", "topic": topic, "count": 1}, 120)["sim"]
        delays.append(followed - published)
    assert sum(delays) < 30, delays

    # The cool-down after a query nobody answered: the listed sequence is asked, nobody
    # answers, and it is asked again after the wait (20 ticks), the cool-down (10) and the
    # backoff (at most 2 s and half again: 30 ticks), all on the simulated clock. Counted from
    # the last catalog on: a catalog that appears may be asked at once (section 4.5, relayed
    # knowledge), which is not the timed ask measured here.
    asked = sent(probe, 5, skip=len(sent(probe, 0)))
    gaps = [b["tick"] - a["tick"] for a, b in itertools.pairwise(asked)]
    assert all(15 <= gap <= 100 for gap in gaps), gaps  # ticks lost under load: 15, not 30

    # The snapshot period: snapshots every simulated second, stamped by the node's clock with
    # the simulated time (the one at activation may be stamped 0: ROS time before the first
    # /clock reached the node).
    snapshots = probe.messages("/lone/ktbt/tree")
    periodic = [
        s["stamp"]["sec"] + s["stamp"]["nanosec"] / 1e9 for s in snapshots if not s["changed"]
    ]
    assert len(periodic) >= 3 and all(START <= t < START + 10_000 for t in periodic), periodic
    per_second = (len(periodic) - 1) / (periodic[-1] - periodic[0])
    assert 0.5 <= per_second <= 1.5, periodic


def sent(probe: Probe, count: int, timeout: float = 120, skip: int = 0) -> list[dict[str, Any]]:
    """The robot's ``count`` ``query-sent`` events after the first ``skip``, once there are
    that many (``count`` 0: all so far)."""
    deadline = time.monotonic() + timeout
    while True:
        found = [m for m in probe.messages("/lone/ktbt/events") if m["event"] == "query-sent"]
        if count == 0:
            return found
        if len(found) >= skip + count:
            return found[skip : skip + count]
        assert time.monotonic() < deadline, f"{len(found)} queries sent in {timeout} s"
        time.sleep(0.05)
