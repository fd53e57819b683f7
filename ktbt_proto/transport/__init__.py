"""How agents reach each other: one interface, an in-memory network and (later) zenoh."""

from ktbt_proto.exchange.transport import Transport
from ktbt_proto.transport.memory import MemoryNetwork, MemoryTransport

__all__ = ["MemoryNetwork", "MemoryTransport", "Transport"]
