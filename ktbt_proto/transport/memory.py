"""A deterministic in-memory network: who hears whom, loss and latency, all in ticks.

The simulator and the tests use it: the same seed gives the same deliveries, and nothing
depends on threads or wall-clock time.
"""

from __future__ import annotations

import logging
import random
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ktbt_proto.exchange.messages import Response
from ktbt_proto.exchange.transport import Message, Received

if TYPE_CHECKING:
    from ktbt_proto.exchange.core import AgentCore

log = logging.getLogger("ktbt.memory")

InRange = Callable[[str, str], bool]


@dataclass
class MemoryNetwork:
    """Agents join by name. ``in_range(sender, receiver)`` is asked when a message is sent;
    ``loss`` is the probability that one delivery is lost; ``latency`` ticks pass between
    sending and arrival (0: it arrives before the receiver's next ``receive``).

    ``audience(sender)``, if given, names who may hear a broadcast, so that a network of
    thousands does not ask ``in_range`` of every member; ``on_deliver(receiver)`` is told of
    each message put in an inbox, so an owner of many agents knows which ones have mail."""

    in_range: InRange = lambda a, b: True
    audience: Callable[[str], Iterable[str]] | None = None
    on_deliver: Callable[[str], None] | None = None
    loss: float = 0.0
    latency: int = 0
    seed: int = 0
    inbox_limit: int = 1024
    overhear: bool = False
    """Answers sent to one member are also heard by the sender's other listeners (those
    ``audience`` names, or everyone), as on a shared radio channel (spec/protocol.md 4.3)."""
    now: int = 0
    _rng: random.Random = field(init=False)
    _members: dict[str, MemoryTransport] = field(default_factory=dict, init=False)
    _in_flight: list[tuple[int, int, str, Message]] = field(default_factory=list, init=False)
    _sequence: int = field(default=0, init=False)
    delivered: int = field(default=0, init=False)
    lost: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        if not 0.0 <= self.loss <= 1.0:
            raise ValueError("loss must be a probability")
        if self.latency < 0:
            raise ValueError("latency must be >= 0 ticks")
        self._rng = random.Random(self.seed)

    def join(self, name: str) -> MemoryTransport:
        if name in self._members:
            raise ValueError(f"{name!r} has already joined")
        member = MemoryTransport(name, self)
        self._members[name] = member
        return member

    def members(self) -> list[str]:
        return list(self._members)

    def step(self) -> None:
        """Advance one tick and deliver what is due."""
        self.now += 1
        self._deliver_due()

    def _post(self, sender: str, receiver: str, message: Message) -> None:
        if receiver == sender or receiver not in self._members:
            return
        if not self.in_range(sender, receiver):
            return
        if self.loss and self._rng.random() < self.loss:
            self.lost += 1
            return
        self._sequence += 1
        self._in_flight.append((self.now + self.latency, self._sequence, receiver, message))
        if self.latency == 0:
            self._deliver_due()

    def _deliver_due(self) -> None:
        due = [m for m in self._in_flight if m[0] <= self.now]
        if not due:
            return
        self._in_flight = [m for m in self._in_flight if m[0] > self.now]
        for _, _, receiver, message in sorted(due, key=lambda m: (m[0], m[1])):
            member = self._members.get(receiver)
            if member is not None and not member.closed:
                if len(member._inbox) >= self.inbox_limit:
                    # Full: the newcomer is refused, counted and logged; what came first (the
                    # first answer, which wins) stays (spec/protocol.md section 2).
                    member.refused += 1
                    log.warning(
                        "%s refused: inbox full (%d messages): a %s from %s is dropped",
                        receiver,
                        self.inbox_limit,
                        message.type,
                        message.sender,
                    )
                    continue
                member._inbox.append(message)
                self.delivered += 1
                if self.on_deliver is not None:
                    self.on_deliver(receiver)


@dataclass(eq=False)
class MemoryTransport:
    name: str
    network: MemoryNetwork
    closed: bool = False
    refused: int = 0
    """Messages refused because the inbox was full."""
    _inbox: deque[Message] = field(init=False)

    def __post_init__(self) -> None:
        self._inbox = deque()

    def broadcast(self, message: Message) -> None:
        if self.closed:
            return
        network = self.network
        audience = network._members if network.audience is None else network.audience(self.name)
        for receiver in list(audience):
            network._post(self.name, receiver, message)

    def send(self, to: str, message: Message) -> None:
        if self.closed:
            return
        network = self.network
        network._post(self.name, to, message)
        if network.overhear and isinstance(message, Response):
            audience = network._members if network.audience is None else network.audience(self.name)
            for other in list(audience):
                if other != to:
                    network._post(self.name, other, message)

    def attach(self, agent: AgentCore) -> None:
        """Nothing to serve: an in-memory peer is asked and answered by its agent's ticks."""

    def receive(self) -> list[Received]:
        messages: list[Received] = list(self._inbox)
        self._inbox.clear()
        return messages

    def close(self) -> None:
        self.closed = True
        self.network._members.pop(self.name, None)
