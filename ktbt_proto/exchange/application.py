"""The application-timed agent: the application says when to ask, announce, read and answer
(``spec/protocol.md`` section 4.1).

The search-and-rescue simulator follows the authors' release, whose wait and cool-down counters
are shared with deliveries and whose teachers choose whom to answer; it ticks no teach or learn
tree and calls these methods instead. Every message is the same ``query`` or ``response`` as a
tree-timed agent's, checked and merged by the same
:class:`~ktbt_proto.exchange.core.AgentCore`, and answered with the same
``ktbt_proto.exchange.answers.answer_to``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from functools import cached_property

from ktbt_proto.exchange.core import AgentCore
from ktbt_proto.exchange.messages import Query, Response
from ktbt_proto.exchange.transferlog import Event
from ktbt_proto.items import sequence_key
from ktbt_proto.tree import Condition

__all__ = ["ApplicationTimedAgent"]


class ApplicationTimedAgent(AgentCore):
    """An agent its application times (section 4.1): :meth:`ask`, :meth:`announce`,
    :meth:`receive`, :meth:`heard`, :meth:`answer` and :meth:`close_query`. The application sets
    ``now`` (the tick its metrics are stamped with), ticks the control tree itself, and calls
    :meth:`tend_memory` (section 4.2). It takes :class:`AgentCore`'s settings."""

    HEARD_LIMIT = 1024
    """Open queries remembered, one per asker (oldest dropped)."""

    _open: Query | None = None
    _answered: frozenset[str] = frozenset()
    """The sequences of the open query answered so far."""

    def ask(
        self, sequence: Iterable[Condition | str] | str, *more: str, to: Sequence[str] = ()
    ) -> Query:
        """Send a query now and keep it open until :meth:`close_query` (a previous open
        query is closed first); :meth:`receive` merges the first acceptable answer to it for
        each sequence it asks. ``more``: further sequences, in canonical form, asked in the
        same query (spec/protocol.md section 1). ``to``: the peers to ask, each alone (as
        :meth:`announce` does); empty, the query is broadcast."""
        if self._open is not None:
            self.close_query()
        query = Query.asking(self.name, [sequence_key(sequence), *more])
        self._open, self._answered = query, frozenset()
        self.metrics.queries_sent += 1
        for peer in to:
            self.announce(peer)
        if not to:
            self.transport.broadcast(query)
            extra = {"more": list(query.more)} if query.more else {}
            self._record(Event.QUERY_SENT, id=query.id, sequence=query.sequence, **extra)
        return query

    @property
    def unanswered(self) -> list[str]:
        """The open query's sequences not answered yet (none without an open query)."""
        if self._open is None:
            return []
        return [s for s in self._open.sequences if s not in self._answered]

    @property
    def open_query(self) -> Query | None:
        """The query :meth:`ask` sent and not yet closed (answered or not)."""
        return self._open

    def announce(self, to: str) -> None:
        """Send the open query again to one peer (one that just came into range), for what is
        still unanswered of it (same id), so that it stays answerable for the asker's whole
        wait and no peer answers again what it answered already."""
        query, missing = self._open, self.unanswered
        if query is not None and missing:
            if len(missing) < len(query.sequences):
                query = Query(
                    id=query.id, sender=query.sender, sequence=missing[0],
                    more=tuple(missing[1:]) or None,
                )  # fmt: skip
            self.transport.send(to, query)
            extra = {"more": list(query.more)} if query.more else {}
            self._record(Event.QUERY_SENT, id=query.id, sequence=query.sequence, to=to, **extra)

    def close_query(self) -> None:
        """The asker's wait is over: a query nobody answered (for none of its sequences)
        counts as lost, and answers to it that arrive later are late answers, counted apart
        (section 2)."""
        if self._open is not None:
            if not self._answered:
                self.metrics.queries_lost += 1
            self._closed_query(self._open.id)
        self._open = None

    def heard(self, sender: str) -> Query | None:
        """The latest query received from ``sender`` by :meth:`receive`, if any."""
        return self._heard.get(sender)

    def receive(self) -> int:
        """Read the transport without ticking any tree: queries are remembered by asker (for
        :meth:`heard`); an answer to the open query is checked and merged (section 2), any
        other answer is late, overheard (section 4.3) or refused. Returns how many answers it
        accepted."""
        return self._read()

    @cached_property
    def _heard(self) -> dict[str, Query]:
        """The latest query from each asker, oldest asker first."""
        return {}

    def _query(self, query: Query) -> None:
        heard = self._heard
        heard.pop(query.sender, None)
        heard[query.sender] = query
        if len(heard) > self.HEARD_LIMIT:
            del heard[next(iter(heard))]

    def _response(self, response: Response) -> int:
        asked = self._open
        if asked is None or asked.id != response.id or response.sequence in self._answered:
            return self._not_mine(response, mine=asked is not None and asked.id == response.id)
        self.metrics.responses_received += 1
        new = response.sequence not in self.knowledge
        if not self.accept(response, asked):
            return 0
        self._answered |= {response.sequence}
        self.metrics.learned_direct += new
        return 1
