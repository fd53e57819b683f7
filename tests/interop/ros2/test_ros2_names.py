"""The topic on which a ROS robot announces its name (spec/protocol.md section 11, "Names"):
every name of section 1 is a valid ROS topic name there, read back as itself, and two names
are two topics."""

from __future__ import annotations

import pytest

NAMES = ["robot1", "r-1", "r_1", "r.1", "1robot", "_", "-", ".", "a_b.c-d", "Z" * 64, "0" * 64]


@pytest.mark.usefixtures("ros2_built")
def test_every_name_is_a_ros_topic_read_back_as_itself() -> None:
    from rclpy.validate_full_topic_name import validate_full_topic_name

    from ktbt_proto.transport.ros2 import QUERIES, announced_name, robot_topic

    topics = [robot_topic(QUERIES, name) for name in NAMES]
    for name, topic in zip(NAMES, topics, strict=True):
        assert validate_full_topic_name(topic), topic  # raises if it is not a topic name
        assert announced_name(topic.rsplit("/", 1)[-1]) == name
    assert robot_topic(QUERIES, "robot1") == "/ktbt/queries/robots/robot1"
    assert robot_topic(QUERIES, "r-1") == "/ktbt/queries/robots/r_2d1"
    assert len(set(topics)) == len(NAMES)
