"""KT-BT embedded in someone else's ROS 2 node (``spec/protocol.md`` section 11, "Embedding"):
``attach`` (``embed``), and what every ROS 2 host shows and offers (``showing``: the events,
tree and catalog topics, the list and forget services, the fleet's catalogs read). Importing
this package loads nothing of ROS; its modules need rclpy."""

__all__: list[str] = []
