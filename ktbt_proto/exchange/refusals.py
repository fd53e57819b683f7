"""What a robot does with a message it cannot read: refuse it, count it, go on
(``spec/protocol.md`` section 2.1).

A peer is hostile until proven otherwise, and no reader is perfect: a parser, a decoder or a
check may one day raise something other than the refusal it promises. At every boundary where a
peer's bytes enter (a transport's callbacks, the decoders of section 1, an agent's receive
pipeline, a catalog, the monitor's listener) whatever reading raises becomes a refusal whose
reason names the exception's type (:func:`internal_error`), counted and logged like any other;
the robot runs on with its tree and knowledge as they were. Refusals are logged at WARNING
through a :class:`Throttle`, so that a flood is a few lines and a count, not a line a message.

The test hook (:func:`fault`) lets a test make reading raise inside a real process, where it
cannot patch the code: with the environment variable ``KTBT_FAULT_READING`` set to ``message``
(the decoders of section 1) or ``item`` (a received item's conditions and subtree, a catalog's
entries), reading any text that holds ``ktbt-fault`` raises :class:`InjectedFault`. Unset, as
it always is outside the tests, it costs one comparison.
"""

from __future__ import annotations

import functools
import os
import threading
import time
from collections.abc import Callable, Mapping
from typing import Concatenate, Literal, ParamSpec, Protocol, TypeVar

INTERNAL = "internal error reading a message"
FAULT_VARIABLE = "KTBT_FAULT_READING"
FAULT_MARKER = "ktbt-fault"
Stage = Literal["message", "item"]

_stage = os.environ.get(FAULT_VARIABLE, "")


class InjectedFault(RuntimeError):
    """Raised by :func:`fault` for a test; never raised unless ``KTBT_FAULT_READING`` is set."""


def internal_error(exc: BaseException) -> str:
    """The reason a refusal gives for a reader that raised: its type, never its text (which may
    echo a peer's bytes at length)."""
    return f"{INTERNAL}: {type(exc).__name__}"


def fault(stage: Stage, data: str | bytes | Mapping[str, object]) -> None:
    """The test hook: raise :class:`InjectedFault` when ``KTBT_FAULT_READING`` names ``stage``
    and ``data`` (text, bytes, or a message's fields) holds the marker ``ktbt-fault``."""
    if _stage != stage:
        return
    if isinstance(data, bytes):
        found = FAULT_MARKER.encode() in data
    elif isinstance(data, str):
        found = FAULT_MARKER in data
    else:
        found = any(FAULT_MARKER in str(value) for value in data.values())
    if found:
        raise InjectedFault(f"{FAULT_VARIABLE}={stage}: a fault injected for a test")


class Throttle:
    """Rate-limited warnings: at most ``burst`` lines in any ``period`` seconds; the lines held
    back are counted and said in one line when the next is let through. The refusals themselves
    are all counted by their owner; only the log is thinned."""

    def __init__(self, warn: Callable[[str], None], burst: int = 10, period: float = 10.0) -> None:
        self.warn, self.burst, self.period = warn, burst, period
        self._lock = threading.Lock()
        self._start = -period
        self._shown = 0
        self.held_back = 0
        """Lines not logged since the last one that was."""

    def __call__(self, line: str) -> None:
        now = time.monotonic()
        with self._lock:
            if now - self._start >= self.period:
                self._start, self._shown = now, 0
            show = self._shown < self.burst
            held = 0
            if show:
                self._shown += 1
                held, self.held_back = self.held_back, 0
            else:
                self.held_back += 1
        if held:
            self.warn(f"{held} more refusals were not logged (at most {self.burst} lines a "
                      f"{self.period:g} s)")  # fmt: skip
        if show:
            self.warn(line)


class Refuses(Protocol):
    """A host of callbacks that counts, logs and records its refusals (a transport)."""

    def _refuse(self, reason: str) -> None: ...


_R = TypeVar("_R", bound=Refuses)
_P = ParamSpec("_P")


def guarded(
    what: str,
) -> Callable[[Callable[Concatenate[_R, _P], None]], Callable[Concatenate[_R, _P], None]]:
    """A network callback that reads a peer's bytes, made to refuse (``what: internal error
    reading a message: T``) rather than raise into the network's thread or the executor: an
    exception escaping a callback is lost in zenoh and ends an rclpy spin."""

    def wrap(callback: Callable[Concatenate[_R, _P], None]) -> Callable[Concatenate[_R, _P], None]:
        @functools.wraps(callback)
        def guard(owner: _R, /, *args: _P.args, **kwargs: _P.kwargs) -> None:
            try:
                callback(owner, *args, **kwargs)
            except Exception as exc:
                owner._refuse(f"{what}: {internal_error(exc)}")

        return guard

    return wrap
