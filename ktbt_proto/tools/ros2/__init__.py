"""ROS 2 tools (``spec/protocol.md`` section 11): the ``ktbt ros2`` commands (``command``), the
lifecycle node ``ktbt ros2 run`` runs (``node``), the bridge between a zenoh fleet and a ROS 2
fleet (``bridge``) and the build of the ``ktbt_interfaces`` package into an environment
(``interfaces``). Nothing of ROS is imported with this package."""

__all__: list[str] = []
