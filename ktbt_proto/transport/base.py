"""The transport interface an agent talks through."""

from __future__ import annotations

from typing import Protocol

from ..messages import ErrorReply, Query, Response

Message = Query | Response | ErrorReply


class Transport(Protocol):
    """Broadcast a query to whoever can hear, answer one peer, and collect what arrived.

    ``receive`` never blocks: an agent drains it once per tick. Inboxes are bounded: when one
    is full the newcomer is refused and counted (``refused``), so a flood can neither exhaust
    memory nor push out what came first (spec/protocol.md section 2).
    """

    name: str

    def broadcast(self, message: Message) -> None: ...

    def send(self, to: str, message: Message) -> None: ...

    def receive(self) -> list[Message]: ...

    def close(self) -> None: ...
