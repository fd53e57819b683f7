"""Overhearing: what a peer does with an answer to someone else's query (``spec/protocol.md``
section 4.3), for an agent and a knowledge server alike.

``update`` learns it at once, through the owner's own ``learn`` (which runs every check of a
direct answer); ``buffer`` keeps it, unchecked, the first answer heard for a sequence winning,
and hands it over when the owner needs that sequence (:meth:`Overhearing.take`), to be checked
then. A newcomer to a full buffer is refused. The owner counts and logs what
:meth:`Overhearing.hear` reports.
A server hears in one thread and looks up in zenoh's, so the buffer is guarded by a lock.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from datetime import UTC, datetime
from enum import StrEnum
from typing import Any

from ktbt_proto.exchange.knowledge import Knowledge, KnowledgeBase
from ktbt_proto.exchange.messages import Response
from ktbt_proto.exchange.receiving import RECEIVE_LIMITS, Refused, check
from ktbt_proto.exchange.refusals import Throttle, guarded
from ktbt_proto.exchange.security import Security
from ktbt_proto.exchange.signing import SignedItem
from ktbt_proto.exchange.transferlog import Event, TransferLog
from ktbt_proto.registry import Registry


class Overhear(StrEnum):
    """What a peer does with answers to others' queries (section 4.3); an option's value, as
    :class:`~ktbt_proto.exchange.trust.Policy` is (each member is its name on the command line
    and in a parameter file)."""

    OFF = "off"
    UPDATE = "update"
    BUFFER = "buffer"


MODES: tuple[Overhear, ...] = tuple(Overhear)


class Heard(StrEnum):
    """What became of one overheard answer."""

    OFF = "off"
    """Not overhearing: an answer to no open question."""
    KNOWN = "known"
    """The sequence is known already: dropped."""
    LEARNED = "learned"
    """``update``: it passed every check and was learned."""
    REFUSED = "refused"
    """``update``: a check failed (the owner's ``learn`` said why)."""
    KEPT = "kept"
    """``buffer``: kept for later, or a first answer for the sequence was kept already."""
    FULL = "full"
    """``buffer``: the buffer is full, the newcomer refused."""


class Overhearing:
    """One peer's overhearing: its mode and its buffer of ``buffer_size`` answers."""

    def __init__(self, mode: Overhear = Overhear.OFF, buffer_size: int = 16) -> None:
        if mode not in MODES:
            raise ValueError(f"overhear must be 'off', 'update' or 'buffer', not {mode!r}")
        self.mode = Overhear(mode)
        self.buffer_size = buffer_size
        self._buffer: dict[str, Response] = {}
        self._lock = threading.Lock()

    def hear(self, answer: Response, known: bool, learn: Callable[[Response], bool]) -> Heard:
        """An answer to someone else's query; ``known``: whether its sequence is known
        already; ``learn``: the owner's checks and merge, True if learned."""
        if self.mode == "off":
            return Heard.OFF
        if known:
            self.drop(answer.sequence)
            return Heard.KNOWN
        if self.mode == "update":
            return Heard.LEARNED if learn(answer) else Heard.REFUSED
        with self._lock:
            if answer.sequence in self._buffer:  # the first answer heard is kept
                return Heard.KEPT
            if len(self._buffer) >= self.buffer_size:
                return Heard.FULL
            self._buffer[answer.sequence] = answer
        return Heard.KEPT

    def take(self, sequence: str) -> Response | None:
        """The kept answer for ``sequence``, used up (None if there is none)."""
        with self._lock:
            return self._buffer.pop(sequence, None)

    def drop(self, sequence: str) -> None:
        with self._lock:
            self._buffer.pop(sequence, None)

    @property
    def buffered(self) -> list[str]:
        """The sequences of the kept answers, in the order heard."""
        with self._lock:
            return list(self._buffer)


class ServerOverhearing:
    """A knowledge server that overhears (section 4.3), through the one :class:`Overhearing` and the
    one set of receive checks (``ktbt_proto.exchange.receiving``): an answer another peer
    published is added to what the server serves, at once (``update``) or, kept in the buffer,
    when a query first asks for it (``buffer``), only if it passes the checks a learner runs
    before it learns: its trust policy and store (``security``; the transport screens with them
    too), the receive limits and, with a ``registry``, its vocabulary. A server never serves
    what it would refuse to learn. The subtree is served as received, so its author's signature
    still holds. Lookups run in zenoh callbacks while the main thread hears: one lock guards the
    tables. ``learned`` is told of each answer learned; a refusal is counted, logged at WARNING
    with its reason and recorded in ``log`` (the server's transfer log, if it keeps one)."""

    def __init__(
        self,
        name: str,
        knowledge: KnowledgeBase,
        served: Callable[[str], SignedItem | None],
        mode: Overhear,
        learned: Callable[[Response], None] = lambda _: None,
        buffer_size: int = 16,
        *,
        security: Security | None = None,
        registry: Registry | None = None,
    ) -> None:
        self.name, self.knowledge, self.served, self.on_learned = name, knowledge, served, learned
        self.ear = Overhearing(mode, buffer_size)
        self.security = security or Security()
        self.registry = registry
        self.log: TransferLog | None = self.security.log
        """Where refusals are recorded; the server's transport may make one (events)."""
        self.learned: dict[str, SignedItem] = {}
        self.refused = 0
        self.lock = threading.Lock()
        self._warn = Throttle(logging.getLogger("ktbt.peer").warning)

    @guarded("an overheard answer")
    def heard(self, message: object) -> None:
        """A message received on the answers topic: an overheard answer, or ignored; whatever
        reading it raises is a refusal (section 2.1)."""
        if not isinstance(message, Response):
            return
        with self.lock:
            heard = self.ear.hear(message, message.sequence in self.knowledge, self._learn)
        if heard is Heard.FULL:
            self._refuse(f"from {message.sender}: overheard answer, buffer full")

    def lookup(self, key: str) -> SignedItem | None:
        """What the server answers for ``key``: its own item, one it overheard, or one kept in
        the buffer (checked and learned now)."""
        found = self.served(key)
        if found is not None:
            return found
        with self.lock:
            found = self.learned.get(key)
            if found is not None:
                return found
            kept = self.ear.take(key)
            return self.learned.get(key) if kept is not None and self._learn(kept) else None

    def catalog(self, entries: Callable[[], list[str | dict[str, Any]]]) -> Callable[[], Any]:
        """``entries`` read under the lock, as the tables may change while zenoh reads."""

        def locked() -> list[str | dict[str, Any]]:
            with self.lock:
                return entries()

        return locked

    def _learn(self, answer: Response) -> bool:
        try:
            conds, subtree = check(
                answer,
                answer.sequence,
                self.security.policy,
                self.security.trust,
                RECEIVE_LIMITS,
                self.registry,
            )
        except Refused as refused:
            self._refuse(refused.reason)
            return False
        received = datetime.now(UTC).isoformat(timespec="seconds")
        self.knowledge.add(
            Knowledge(conds, subtree, "new", answer.sender, None, answer.author,
                      answer.signature, received)
        )  # fmt: skip
        self.learned[answer.sequence] = SignedItem(answer.subtree, answer.author, answer.signature)
        self.on_learned(answer)
        return True

    def _refuse(self, reason: str) -> None:
        self.refused += 1
        self._warn(f"{self.name} refused: {reason}")
        if self.log is not None:
            self.log.record(Event.REFUSED, peer=self.name, reason=reason)
