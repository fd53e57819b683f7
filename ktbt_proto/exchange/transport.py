"""The transport interface an agent talks through (``spec/protocol.md`` sections 3, 6, 11)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from ktbt_proto.exchange.messages import ErrorReply, Query, Response

if TYPE_CHECKING:
    from ktbt_proto.exchange.core import AgentCore

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

    ``attach(agent)`` is called by an agent once it is built: a network transport then serves
    the agent's catalog and answers from its knowledge (section 4.5); the in-memory transport
    has nothing to serve.
    """

    name: str

    def attach(self, agent: AgentCore) -> None: ...

    def broadcast(self, message: Message) -> None: ...

    def send(self, to: str, message: Message) -> None: ...

    def receive(self) -> list[Received]: ...

    def close(self) -> None: ...
