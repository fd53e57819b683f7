# The docking skill a teacher serves (examples/ros2/): when the battery is low, dock
# at dock A. The robot that learns it runs Dock as its own ROS action client.
<k>(new)
    <sq>
        <c>(BatteryLow)
        <a>(Dock, dock="A")
    <e>
<e>
