"""When a learner that is missing knowledge may ask again (spec/protocol.md section 4.5)."""

from __future__ import annotations

import random
from dataclasses import dataclass, field

BACKOFF_FIRST = 0.25
"""Seconds a learner holds back after its first unanswered query, doubling with each one."""
BACKOFF_MOST = 2.0
"""The longest it holds back: knowledge that is missing is asked for again at least this often
(after the wait and the cool-down)."""


@dataclass
class Backoff:
    """When a learner may ask next (spec/protocol.md section 4.5): at once at first, then
    after each query nobody answered, ``first`` seconds later, doubling up to ``most``; at
    once again when it learns something or a new peer appears.

    Each hold is stretched by up to ``jitter`` of itself, drawn from a generator seeded with
    ``seed`` (the member's name): a fleet whose queries were lost together does not ask again
    in step, and a run with the same names draws the same holds."""

    first: float = BACKOFF_FIRST
    most: float = BACKOFF_MOST
    hold: float = 0.0
    until: float = 0.0
    seed: str = ""
    jitter: float = 0.5
    _rng: random.Random = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self._rng = random.Random(f"ktbt-backoff:{self.seed}")

    def lost(self, now: float) -> None:
        self.hold = self.first if self.hold == 0 else min(self.hold * 2, self.most)
        self.until = now + self.hold * (1 + self.jitter * self._rng.random())

    def reset(self, now: float) -> None:
        self.hold, self.until = 0.0, now

    def ready(self, now: float) -> bool:
        return now >= self.until
