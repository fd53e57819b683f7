"""How much an agent remembers, and for how long (spec/protocol.md section 4.2).

Robots with little memory were the paper's future work; the authors' release already had a
mode for them (a memory size that refuses lessons, and forgetting of everything learned after a
while without use). A policy states the same choices, plus the alternatives a robot stack may
prefer: evicting the least recently used item instead of refusing a lesson, and letting each
item expire on its own.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum


class WhenFull(StrEnum):
    """What a full memory does with a lesson (section 4.2): an option's value, as
    :class:`~ktbt_proto.exchange.trust.Policy` is."""

    REFUSE = "refuse"
    EVICT = "evict"


@dataclass(frozen=True)
class MemoryPolicy:
    """``capacity``: knowledge items the agent may hold (None: no limit). ``count_innate``:
    whether the knowledge it was built with counts against it (the release's rule: yes).
    ``when_full``: ``refuse`` the lesson (the release's rule) or ``evict`` the learned item
    used least recently. ``forget_after``: after this many ticks in which no learned item was
    used and nothing was learned, everything learned is forgotten at once (the release's rule).
    ``expire_after``: a learned item unused for this many ticks is forgotten on its own.
    Innate knowledge is never forgotten."""

    capacity: int | None = None
    count_innate: bool = True
    when_full: WhenFull = WhenFull.REFUSE
    forget_after: int | None = None
    expire_after: int | None = None

    def __post_init__(self) -> None:
        for name in ("capacity", "forget_after", "expire_after"):
            value = getattr(self, name)
            if value is not None and (not isinstance(value, int) or value < 1):
                raise ValueError(f"{name} must be a whole number of at least 1, or None")
        if self.when_full not in tuple(WhenFull):
            raise ValueError(f"when_full must be 'refuse' or 'evict', not {self.when_full!r}")
