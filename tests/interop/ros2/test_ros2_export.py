"""A ROS 2 robot's learned skills in a Nav2 ``bt_search_directories`` folder (spec/protocol.md
section 11's ``export_learned`` and ``tree_ids``, spec/stringbt.md section 12.2): a real
``ktbt ros2 run`` learner, taught by another over Fast DDS in the test's network namespace,
writes what it learned as a whole BehaviorTree.CPP document under the tree ID it was given;
``tree_ids`` without a folder fails ``configure`` with one line."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from ktbt_proto.files import packaged
from ktbt_proto.formatter import format_tree
from ktbt_proto.interop.btcpp import from_xml
from ktbt_proto.items import sequence_key, split_item
from tests.interop.ros2.rosns import SEQUENCE, SUBTREE, Probe, RosNamespace
from tests.zenoh_helpers import wait_until

pytestmark = [pytest.mark.network, pytest.mark.slow, pytest.mark.timeout(240)]

COLOURS = packaged("examples", "knowledge", "colours.sbt")


def test_a_ros_learner_exports_what_it_learns_under_the_tree_id_given(
    rosns: Any, tmp_path: Path
) -> None:
    ns: RosNamespace = rosns
    folder = tmp_path / "behavior_trees"
    folder.mkdir()
    params = tmp_path / "robots.yaml"
    params.write_text(
        f"""\
/teacher/ktbt:
  ros__parameters:
    knowledge: {COLOURS}
    sequences: ["TargetSeen(colour=1)"]
/learner/ktbt:
  ros__parameters:
    sequences: ["TargetSeen(colour=2)"]
    export_learned: {folder}
    tree_ids: ["PickGreen=TargetSeen(colour=2)"]
/wrong/ktbt:
  ros__parameters:
    tree_ids: ["PickGreen=TargetSeen(colour=2)"]
"""
    )
    probe = Probe(ns)
    probe.subscribe("/learner/ktbt/tree", "TreeSnapshot", latched=True)
    for name in ("teacher", "learner"):
        ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", f"__ns:=/{name}",
                "--params-file", str(params), name=name)  # fmt: skip
    probe.wait("/learner/ktbt/tree", 90, tree="AssignCollectionPoint,colour=2")

    def exported() -> list[Path]:
        return sorted(folder.glob("*.xml"))

    assert wait_until(lambda: len(exported()) == 1, 30), ns.log("learner")
    document = exported()[0].read_text()
    assert '<root BTCPP_format="4" main_tree_to_execute="PickGreen">' in document
    assert '<BehaviorTree ID="PickGreen">' in document
    split = split_item(from_xml(document).root)
    assert split is not None
    assert (sequence_key(split[0]), format_tree(split[1], "compact")) == (SEQUENCE, SUBTREE)

    # tree_ids with no folder to export into: configure fails, saying so in one line.
    wrong = ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/wrong",
                    "--params-file", str(params), name="wrong")  # fmt: skip
    assert wrong.wait(timeout=60) == 1
    assert "tree_ids: names exported trees; give export_learned" in ns.log("wrong")
    assert "Traceback" not in ns.log("wrong")
