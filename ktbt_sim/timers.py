"""Wait and cool-down: the release's counters, in closed form (``spec/simulator.md`` §7).

The release keeps ``waitTimeCount`` and ``coolDownCount`` per robot, and two components
(``RegLearnBT`` then ``TeachBT``) each call ``WaitCheck`` then ``CoolDownCheck`` once per
iteration, so the counters move twice per iteration. We number those calls: iteration ``t`` holds
call ``2t`` (RegLearnBT's) and call ``2t + 1`` (TeachBT's). Three events start a wait and arm the
cool-down: a delivery (in the behaviour-tree tick, before call ``2t``), a query (right after
call ``2t``) and a teach (right after call ``2t + 1``).

The counters are deterministic, so instead of stepping them we keep, per robot, the call at which
the wait ends (``wait_end``) and the call at which the cool-down ends (``cool_end``):

- ``WaitCheck`` adds 1 while the count is at most ``waitLimit`` and ends the wait on the call
  after: from a count of ``w0``, the wait ends at call ``p + waitLimit + 1 - w0``, where ``p`` is
  the first call after the event. The count is 0 unless the robot's last cool-down has not
  finished (a delivery during a cool-down), when it is still ``waitLimit + 1`` and the wait ends
  at the very next call.
- The ending call sets the cool-down count to ``coolDownLimit`` and, in the same call,
  ``CoolDownCheck`` takes 1 off; the count reaches 0 ``coolDownLimit - 1`` calls later and the
  call after that ends the cool-down, re-enables target sensing and resets the wait count:
  ``cool_end = wait_end + coolDownLimit``.
- Every cool-down call before that disables target sensing.

With the release's 1000 and 1000 a query keeps its robot waiting for 501 iterations and cooling
for 500, as the release's data shows (§7).
"""

from __future__ import annotations

import numpy as np

NEVER = -(10**12)
"""``wait_end`` and ``cool_end`` of a robot that has never waited."""


class Timers:
    """The counters of ``n`` robots."""

    def __init__(self, n: int, wait_limit: int = 1000, cooldown_limit: int = 1000) -> None:
        self.wait_limit = wait_limit
        self.cooldown_limit = cooldown_limit
        self.wait_end = np.full(n, NEVER, dtype=np.int64)
        self.cool_end = np.full(n, NEVER, dtype=np.int64)

    def start(self, i: int, call: int) -> None:
        """A wait (and cool-down) starts for robot ``i``; ``call`` is the first counter call
        after the event."""
        w0 = self.wait_limit + 1 if self.cool_end[i] >= call else 0
        end = call + max(self.wait_limit + 1 - w0, 0)
        self.wait_end[i] = end
        self.cool_end[i] = end + self.cooldown_limit

    def waiting(self, call: int) -> np.ndarray:
        """Robots whose wait flag is on just before counter call ``call``."""
        return self.wait_end >= call

    def busy(self, call: int) -> np.ndarray:
        """Robots whose cool-down flag is on just before ``call`` (it is on during the wait
        too): they may neither query nor teach."""
        return self.cool_end >= call

    def sensing_off(self, call: int) -> np.ndarray:
        """Robots whose target sensing the cool-down keeps off after counter call ``call - 1``
        (between the end of the wait and the end of the cool-down)."""
        return (self.wait_end < call) & (self.cool_end >= call)
