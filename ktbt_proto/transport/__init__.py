"""How agents reach each other (``spec/protocol.md`` sections 3, 6 and 11): the transport
interface an agent talks through, and its implementations: an in-memory network (``memory``),
zenoh (``zenoh``), ROS 2 (``ros2``, over its own CDR reader and writer, ``cdr``), the bounded
inbox and the answers given at once that the two network transports share (``inbox``), and the
stream of a simulated fleet's events (``stream``). The network transports are imported from
their modules: importing this package loads no network library."""

from ktbt_proto.exchange.transport import Transport
from ktbt_proto.transport.memory import MemoryNetwork, MemoryTransport

__all__ = ["MemoryNetwork", "MemoryTransport", "Transport"]
