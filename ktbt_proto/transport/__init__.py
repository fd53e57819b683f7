"""How agents reach each other: one interface, an in-memory network and (later) zenoh."""

from .base import Transport
from .memory import MemoryNetwork, MemoryTransport

__all__ = ["MemoryNetwork", "MemoryTransport", "Transport"]
