"""When a fleet member on a ROS node steps (spec/protocol.md section 11, "The node" and
"Embedding"): once a tick of its host's timer, and at once between two ticks when an answer to
its query arrives or it is told what to meet, so that a transfer waits for no tick.

The step between ticks runs from a timer of the node's default callback group, armed when a
step is wanted (``reset``) and disarmed as it runs: rclpy's events executor runs no guard
condition, and a task of the executor belongs to no callback group, so on an executor of
several threads it could run beside the user's own tree tick; the timer runs on every executor
and, like every other callback of the member, never beside another of that group.
"""

from __future__ import annotations

from collections.abc import Callable

from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.node import Node

__all__ = ["STEPS_BETWEEN_TICKS", "Stepping"]

STEPS_BETWEEN_TICKS = 2
"""Steps a member takes at most between two of its host's ticks (section 11): a flood of
answers steps it no more often than this."""


class Stepping:
    """The steps of one fleet member on ``node``: :meth:`tick` from its host's timer (``step``
    called with True), :meth:`soon` when an answer arrived or it was told what to meet (``step``
    called with False, from the executor, after the callback that asked for it), at most
    :data:`STEPS_BETWEEN_TICKS` times between two ticks."""

    def __init__(self, node: Node, step: Callable[[bool], None]) -> None:
        self.node, self._step = node, step
        self._between = 0
        self.closed = False
        # Steady time: armed, it fires at once whatever the host's clock (the host's step
        # does nothing while a simulation's clock has not started).
        self._wake = node.create_timer(
            0.0, self._woken, clock=Clock(clock_type=ClockType.STEADY_TIME), autostart=False
        )

    def tick(self) -> None:
        """A tick of the host's timer: one step that ticks (section 4.5)."""
        self._between = 0
        self._step(True)

    def again(self) -> None:
        """Steps between ticks may be taken again (a node that was inactive, activated)."""
        self._between = 0

    def soon(self) -> None:
        """Step once more before the next tick, unless enough steps were taken since the last
        (or it was closed)."""
        if self.closed or self._between >= STEPS_BETWEEN_TICKS:
            return  # the next tick takes what arrived
        self._between += 1
        self._wake.reset()

    def _woken(self) -> None:
        self._wake.cancel()
        if not self.closed:
            self._step(False)

    def close(self) -> None:
        """Take its timer off the node."""
        if not self.closed:
            self.closed = True
            self.node.destroy_timer(self._wake)
