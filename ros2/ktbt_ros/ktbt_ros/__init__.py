"""KT-BT's ROS 2 executables as a ROS package (spec/protocol.md section 11, "ROS 2 binding").

The package holds no robot of its own: ``ktbt_node`` and ``ktbt_bridge`` (:mod:`ktbt_ros.main`)
run the ``ktbt`` Python package's ``ktbt ros2 run`` and ``ktbt ros2 bridge``, so that a ROS user
starts them the way ROS starts any node (``ros2 run ktbt_ros ktbt_node``, a launch file's
``Node(package="ktbt_ros", executable="ktbt_node")``) and finds example parameter files where
ROS keeps them (``share/ktbt_ros/config``).
"""
