"""The transport interface an agent talks through."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from ktbt_proto.exchange.messages import ErrorReply, Query, Response

Message = Query | Response | ErrorReply


@dataclass(frozen=True)
class NetworkError:
    """The network's own error about one of this peer's queries (a get that timed out at a
    router or at the asker, say): not a message, and nothing any peer sent, so never a refusal
    (spec/protocol.md section 3). ``id`` is the query's; ``reason`` the network's words."""

    id: str
    reason: str
    type: str = "network-error"


Received = Message | NetworkError
"""What :meth:`Transport.receive` hands over."""


class Transport(Protocol):
    """Broadcast a query to whoever can hear, answer one peer, and collect what arrived.

    ``receive`` never blocks: an agent drains it once per tick. Inboxes are bounded: when one
    is full the newcomer is refused and counted (``refused``), so a flood can neither exhaust
    memory nor push out what came first (spec/protocol.md section 2).

    A transport may also have ``attach(agent)``, which an agent calls once it is built: a
    network transport serves the agent's catalog and answers from its knowledge there (zenoh:
    spec/protocol.md section 4.5).
    """

    name: str

    def broadcast(self, message: Message) -> None: ...

    def send(self, to: str, message: Message) -> None: ...

    def receive(self) -> list[Received]: ...

    def close(self) -> None: ...
