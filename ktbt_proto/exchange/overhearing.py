"""Overhearing: what a peer does with an answer to someone else's query (``spec/protocol.md``
section 4.3), for an agent and a knowledge server alike.

``update`` learns it at once, through the owner's own ``learn`` (which runs every check of a
direct answer); ``buffer`` keeps it, unchecked, the first answer heard for a sequence winning,
and hands it over when the owner needs that sequence (:meth:`Ear.take`), to be checked then. A
newcomer to a full buffer is refused. The owner counts and logs what :meth:`Ear.hear` reports.
A server hears in one thread and looks up in zenoh's, so the buffer is guarded by a lock.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from enum import StrEnum
from typing import Literal

from ktbt_proto.exchange.messages import Response

Overhear = Literal["off", "update", "buffer"]
"""What a peer does with answers to others' queries."""
MODES: tuple[Overhear, ...] = ("off", "update", "buffer")


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


class Ear:
    """One peer's overhearing: its mode and its buffer of ``buffer_size`` answers."""

    def __init__(self, mode: Overhear = "off", buffer_size: int = 16) -> None:
        if mode not in MODES:
            raise ValueError(f"overhear must be 'off', 'update' or 'buffer', not {mode!r}")
        self.mode: Overhear = mode
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
