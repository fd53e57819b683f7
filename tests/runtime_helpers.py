"""Scripted leaves for the runtime tests.

A :class:`Harness` owns a registry, a blackboard and one shared log. Its actions play a script of
statuses, one per tick, and log ``"A"`` for every tick and ``"~A"`` for every halt. Its
conditions read the blackboard flag of their own name and log ``"X?"`` for every evaluation. So a
test can assert, tick by tick, the status of the tree and exactly which leaves were ticked and
halted, in order.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import ktbt_proto as kp
from ktbt_proto.status import FAILURE, RUNNING, SUCCESS, Status

S, F, R = SUCCESS, FAILURE, RUNNING

Step = tuple[Status, list[str]]


class FakeClock:
    """A clock the test advances by hand: ``clock()`` returns ``clock.now``."""

    def __init__(self, now: float = 0.0) -> None:
        self.now = now
        self.calls = 0

    def __call__(self) -> float:
        self.calls += 1
        return self.now


class Harness:
    """A registry of scripted actions and flag conditions that all write to one log."""

    def __init__(self) -> None:
        self.registry = kp.Registry()
        self.bb = kp.Blackboard()
        self.log: list[str] = []

    def action(self, name: str, *script: Status) -> None:
        """Register action ``name``: it returns ``script`` one status per tick (the last one
        then repeats forever), logs ``name`` when ticked and ``~name`` when halted."""
        if not script:
            raise ValueError("an action needs at least one status")
        steps = list(script)
        log = self.log

        def tick(bb: Any) -> Status:
            log.append(name)
            return steps.pop(0) if len(steps) > 1 else steps[0]

        def halt(bb: Any) -> None:
            log.append(f"~{name}")

        self.registry.add_action(name, tick, halt=halt)

    def condition(self, *names: str) -> None:
        """Register conditions that hold when the blackboard flag of the same name is true, and
        log ``name?`` each time they are evaluated."""
        for name in names:
            self.registry.add_condition(name, self._flag(name))

    def _flag(self, name: str) -> Callable[[Any], bool]:
        log = self.log

        def holds(bb: Any) -> bool:
            log.append(f"{name}?")
            return bool(bb.get(name, False))

        return holds

    def live(self, text: str, *, clock: Callable[[], float] | None = None) -> kp.LiveTree:
        if clock is None:
            return kp.LiveTree(text, self.registry, self.bb)
        return kp.LiveTree(text, self.registry, self.bb, clock=clock)

    def tick(self, live: kp.LiveTree) -> Step:
        """Tick once: the status and what the leaves logged during that tick."""
        mark = len(self.log)
        status = live.tick()
        return status, self.log[mark:]

    def run(self, live: kp.LiveTree, n: int) -> list[Step]:
        return [self.tick(live) for _ in range(n)]

    def halt(self, live: kp.LiveTree) -> list[str]:
        """Halt the whole tree: what the leaves logged while it was halted."""
        mark = len(self.log)
        live.halt()
        return self.log[mark:]
