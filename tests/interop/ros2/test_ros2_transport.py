"""The ROS 2 transport's own promises (spec/protocol.md section 11), three robots' transports
in one process on Fast DDS, in a network namespace (``transports.py``): an answer reaches its
asker and, on the shared answer topic, the robot that overhears; presence comes from the graph,
a newcomer from the query publisher's count of matched subscriptions;
a repeated answer from one sender, and a flood beyond the inbox, are refused and counted; an
inactive robot does not answer."""

from __future__ import annotations

import json
import sys
from typing import Any

import pytest

from tests.interop.ros2.rosns import SEQUENCE, SUBTREE

pytestmark = [pytest.mark.network, pytest.mark.slow, pytest.mark.timeout(180)]


def test_answers_overhearing_presence_and_bounds(rosns: Any) -> None:
    proc = rosns.start(
        [sys.executable, "-m", "tests.interop.ros2.transports"], "transports", stdin=True
    )
    assert proc.stdin is not None and proc.stdout is not None
    proc.stdin.close()
    out = json.loads(proc.stdout.readline() or "null") if proc.wait(timeout=150) == 0 else None
    assert out is not None, rosns.log("transports")
    assert out["present"] and out["peers"] == ["/o/ktbt", "/t/ktbt"]
    assert out["answered"]
    answer = {"id": "q1", "sender": "teacher", "sequence": SEQUENCE, "subtree": SUBTREE}
    for got in (out["learner_got"], out["listener_got"]):
        assert [{k: a[k] for k in answer} for a in got] == [answer]
    assert out["repeat_refused"] and out["learner_answers_after_repeat"] == 1
    assert out["both_answered"] and out["both"] == ["<c>(TargetSeen,colour=3)", SEQUENCE]
    assert out["teacher_answered"] == 3  # q1 once (not its repeat), then q3's two
    assert out["flood_refused"] == 3 and out["flood_kept"] == ["x0", "x1", "x2"]
    assert out["q2_heard"] and out["inactive_answered"] == 3 and out["q2_answers"] == []
    assert out["joined_before"] == 3  # its own subscription, the teacher's, the listener's
    assert out["joined_late"] and out["joined_after"] == 4
