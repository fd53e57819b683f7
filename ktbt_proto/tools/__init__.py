"""What people and scripts run: the ``ktbt`` command line (``cli``), the peer commands
(``peer``), the tour and demo vocabulary (``demo``), the fuzzer (``fuzz``), the fleet monitor
(``monitor``), the fleet tool (``fleet``) and the ROS 2 commands (``ros2``). Nothing below
imports this package.

Each tool is run, not imported by name: this package exports nothing and loads nothing, so
that starting one command does not load every other's dependencies.
"""

__all__: list[str] = []
