"""What a network transport holds for its agent between two reads (spec/protocol.md sections 2
and 4.3), and the answers it gives at once to one query (section 1), one definition for every
network transport (zenoh, ROS 2).

Both are bounded, and a message that does not fit is a refusal with its reason, never a silent
drop and never a message pushed out: the first answer, which wins, stays (section 2). The
transport says how it refuses (its own counter, logger and transfer log) through ``refuse``.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

from pydantic import ValidationError

from ktbt_proto.exchange.answers import answer_to
from ktbt_proto.exchange.messages import Query, Response
from ktbt_proto.exchange.signing import Identity, SignedItem
from ktbt_proto.exchange.transferlog import Event, TransferLog
from ktbt_proto.exchange.transport import Received

Refuse = Callable[..., None]
"""A transport's own refusal: ``refuse(reason, **fields)`` counts, logs at WARNING and records."""

_Made = TypeVar("_Made")

Lookup = Callable[[str], str | SignedItem | None]
"""What a robot answers for one sequence key: the subtree's text, an item already signed
(``answers.answers``, ``live_answers``), or None."""


class Inbox:
    """The messages for the agent (``limit``), the answers overheard from others
    (``overheard_limit``, section 4.3) and the ids of this robot's own latest queries (an
    overheard copy of an answer to one of them is left to the answer itself). Thread-safe: the
    network's callbacks put, the agent's tick drains; ``arrived`` is called after each put
    (a host resting until something arrives wakes)."""

    ASKED = 256
    """This robot's own query ids remembered."""

    def __init__(
        self,
        refuse: Refuse,
        limit: int = 1024,
        overheard_limit: int = 64,
        arrived: Callable[[], object] = lambda: None,
    ) -> None:
        self.refuse, self.limit, self.overheard_limit = refuse, limit, overheard_limit
        self.arrived = arrived
        self._lock = threading.Lock()
        self._messages: deque[Received] = deque()
        self._overheard: deque[Response] = deque()
        self._asked: deque[str] = deque(maxlen=self.ASKED)

    def asked(self, query_id: str) -> None:
        """This robot sent query ``query_id``."""
        with self._lock:
            self._asked.append(query_id)

    def deliver(self, message: Received, **fields: Any) -> None:
        """Into the inbox, unless it is full: then the newcomer is refused, and what arrived
        first is kept."""
        with self._lock:
            full = len(self._messages) >= self.limit
            if not full:
                self._messages.append(message)
        self.arrived()
        if full:
            self.refuse(
                f"inbox full ({self.limit} messages): a {message.type} is dropped", **fields
            )

    def withdraw(self, queries: set[tuple[str, str]]) -> None:
        """Take out the queries named (sender, id) that wait: answered meanwhile by the
        network's callback, they are not the agent's to answer again (section 4.5)."""
        with self._lock:
            kept = [
                m
                for m in self._messages
                if not (isinstance(m, Query) and (m.sender, m.id) in queries)
            ]
            self._messages = deque(kept)

    def overhear(
        self, answer: Response, screen: Callable[[Response], str | None] | None, **fields: Any
    ) -> None:
        """An answer to another robot (section 4.3): one to a query of ours is left to the
        answer itself; the rest must pass the trust policy (``screen``) and find room."""
        with self._lock:
            if answer.id in self._asked:
                return
        why = screen(answer) if screen is not None else None
        if why is not None:
            self.refuse(f"overheard from {answer.sender}: {why}", **fields)
            return
        with self._lock:
            full = len(self._overheard) >= self.overheard_limit
            if not full:
                self._overheard.append(answer)
        self.arrived()
        if full:
            self.refuse(
                f"{self.overheard_limit} overheard answers waiting: one from {answer.sender} "
                "is dropped",
                **fields,
            )

    def __len__(self) -> int:
        """How many messages wait, overheard answers included."""
        with self._lock:
            return len(self._messages) + len(self._overheard)

    def drain(self) -> list[Received]:
        """Everything waiting, the agent's messages first, and empty after."""
        with self._lock:
            messages = [*self._messages, *self._overheard]
            self._messages.clear()
            self._overheard.clear()
        return messages


class AnswersGiven:
    """The answers a robot gives at once, inside the network's callback (section 4.5): for one
    query, a response for each sequence it asks that ``lookup`` knows (section 1), each made
    by ``answer_to`` as every answer is (sections 2 and 7), the query recorded as
    ``query-received`` and each answer as ``answer-sent`` (section 8). A sequence answered to
    the same query (sender and id) within ``window`` seconds is not answered again: an asker
    sends its open query to a peer that appears, which may have had the broadcast already
    (section 4.5). The latest ``limit`` queries are remembered; ``warn`` is told of an item too
    large for any peer to accept. ``clock``: the host's seconds (the ROS node's clock, sim time
    included, section 11); a clock gone back starts the window again."""

    def __init__(
        self,
        name: str,
        window: float,
        limit: int,
        warn: Callable[[str], None],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.name, self.window, self.limit, self.warn = name, window, limit, warn
        self.clock = clock
        self._lock = threading.Lock()
        self._given: dict[tuple[str, str], tuple[float, set[str]]] = {}

    def answers(
        self, query: Query, lookup: Lookup, identity: Identity | None, log: TransferLog | None
    ) -> Iterator[Response]:
        """The responses to ``query`` not given yet, the query recorded as received first;
        each response is recorded once the caller has sent it (when the next is asked for)."""
        return self.made(
            query, lookup, log, lambda seq, item: answer_to(query, self.name, item, identity, seq)
        )

    def made(
        self,
        query: Query,
        lookup: Lookup,
        log: TransferLog | None,
        make: Callable[[str, SignedItem], _Made],
    ) -> Iterator[_Made]:
        """:meth:`answers`, each answer made by ``make`` from its sequence and item: a
        response, or what a transport sends of it (its bytes); ``make`` raises pydantic's
        ``ValidationError`` for an answer too large to send."""
        if log is not None:
            more = {"more": list(query.more)} if query.more else {}
            log.record(
                Event.QUERY_RECEIVED,
                peer=self.name,
                sender=query.sender,
                id=query.id,
                sequence=query.sequence,
                **more,
            )
        now, key = self.clock(), (query.sender, query.id)
        with self._lock:
            when, given = self._given.pop(key, (now, set()))
            if not 0 <= now - when <= self.window:
                when, given = now, set()
            self._given[key] = (when, given)
            if len(self._given) > self.limit:
                del self._given[next(iter(self._given))]
        for sequence in query.sequences:
            with self._lock:
                if sequence in given:
                    continue
            found = lookup(sequence)
            if found is None:
                continue
            item = found if isinstance(found, SignedItem) else SignedItem(found)
            try:
                response = make(sequence, item)
            except ValidationError as exc:  # too large to send: no peer could accept it
                reason = exc.errors()[0].get("msg", "invalid")
                self.warn(f"{self.name} cannot answer {sequence[:80]}: {reason}")
                continue
            with self._lock:
                given.add(sequence)
            yield response
            if log is not None:
                log.record(
                    Event.ANSWER_SENT,
                    peer=self.name,
                    to=query.sender,
                    id=query.id,
                    sequence=sequence,
                    author=item.author,
                )
