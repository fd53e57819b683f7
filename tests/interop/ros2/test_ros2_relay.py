"""Knowledge relayed at once on ROS 2 (spec/protocol.md sections 4.5 and 11): a robot's latched
catalog, republished after a merge, is its announcement, and a robot that lacks what it lists
asks at once instead of at its next timed ask. Real ``ktbt ros2 run`` nodes in a network
namespace of the test's own (``rosns``)."""

from __future__ import annotations

from typing import Any

import pytest

from tests.interop.ros2.rosns import SEQUENCE, SUBTREE, Probe, RosNamespace, wait_for_line

pytestmark = [pytest.mark.network, pytest.mark.slow, pytest.mark.timeout(300)]

GREEN = "TargetSeen(colour=2)"


def test_a_robot_asks_at_once_for_what_a_neighbour_just_learned(rosns: Any) -> None:
    """``near`` and ``far`` both meet the green skill and nobody knows it; each keeps its
    query open a minute, and ``far`` would then hold back a minute more. Once every robot has
    seen the others (and sent them its query), the probe teaches ``near`` by answering its
    open query: no robot appears, nothing else changes. ``far``, whose query ``near`` heard
    when it knew nothing, hears ``near``'s catalog change and sends it its query at once."""
    ns: RosNamespace = rosns
    probe = Probe(ns)
    probe.subscribe("/ktbt/queries", "Query")  # present from the start: nobody appears later
    common = ["-p", f"sequences:=[{GREEN}]", "-p", "tick_rate:=20.0"]
    common += ["-p", "wait_ticks:=1200", "-p", "cooldown_ticks:=1200"]  # 60 s each
    for name in ("near", "far"):
        ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", f"__ns:=/{name}", *common,
                name=name)  # fmt: skip
    probe.until({"op": "subscribers", "topic": "/ktbt/queries", "count": 3}, 90)
    for name in ("near", "far"):
        wait_for_line(ns, name, f"{name}: active")
    asked = probe.wait("/ktbt/queries", 60, sender="near")
    probe.wait("/ktbt/queries", 60, sender="far")
    answer = {"v": 1, "id": asked["id"], "sender": "teacher", "to": "near",
              "sequence": SEQUENCE, "subtree": SUBTREE}  # fmt: skip
    probe.until({"op": "publish", "topic": "/ktbt/answers", "type": "Answer", "fields": answer,
                 "subscribers": 2})  # fmt: skip
    wait_for_line(ns, "near", f"near: learned {GREEN} from teacher", 30)
    wait_for_line(ns, "far", f"far: learned {GREEN} from near", 40)
    for name in ("near", "far"):
        assert "Traceback" not in ns.log(name) and "refused" not in ns.log(name), ns.log(name)
