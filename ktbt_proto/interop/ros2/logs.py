"""The library's log records through the ROS logger of the robot whose work made them
(spec/protocol.md section 11, "The node" and "Embedding"), however many robots one process
runs.

The library logs through Python's ``logging`` (``ktbt.agent``, ``ktbt.member``, ...), one
logger tree for the whole process. A ROS host (the lifecycle node, an embedded robot) says
whose work runs now with :func:`speaking` around its own callbacks (a tick, configure), and one
handler on ``ktbt``, installed while any host is there (:func:`hear`), hands each record to
that host's rclpy logger, which filters it by its own level (``--ros-args --log-level``) and
names the node: each line once, under the node that made it. A record made outside any host's
callback (a user's tree ticked by their own timer, a zenoh callback of the bridge) goes to the
one host's logger where the process has one, else to rclpy's ``ktbt`` logger.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any

from rclpy.logging import get_logger

__all__ = ["hear", "speaking", "unhear"]

_speaker: ContextVar[Any] = ContextVar("ktbt_ros2_speaker", default=None)
"""The rclpy logger of the host whose callback runs now (None: no host's)."""


class _ToRosLoggers(logging.Handler):
    """Each record to the rclpy logger of the host speaking (see the module's docstring):
    rclpy's severities are Python's numbers (DEBUG 10 to FATAL 50)."""

    def emit(self, record: logging.LogRecord) -> None:
        logger = _speaker.get() or _alone() or get_logger("ktbt")
        text = record.getMessage()
        if record.levelno >= logging.ERROR:
            logger.error(text)
        elif record.levelno >= logging.WARNING:
            logger.warning(text)
        elif record.levelno >= logging.INFO:
            logger.info(text)
        else:
            logger.debug(text)


_HANDLER = _ToRosLoggers()
_lock = threading.Lock()
_hosts: dict[int, Any] = {}
"""Each host (by ``id``) heard, with its rclpy logger."""
_before: list[int] = []
"""The ``ktbt`` logger's level before the first host came (put back when the last goes)."""


def hear(host: object, logger: Any) -> None:
    """``host`` (a node, an embedded robot) logs through ``logger``: the handler is installed,
    and the library's records let through down to the lowest level of the hosts' loggers."""
    library = logging.getLogger("ktbt")
    with _lock:
        if not _hosts:
            _before[:] = [library.level]
            library.addHandler(_HANDLER)
        _hosts[id(host)] = logger
        library.setLevel(_lowest())


def unhear(host: object) -> None:
    """``host`` is gone; with the last one, the handler goes and the level is put back."""
    library = logging.getLogger("ktbt")
    with _lock:
        if _hosts.pop(id(host), None) is None:
            return
        if _hosts:
            library.setLevel(_lowest())
        else:
            library.removeHandler(_HANDLER)
            library.setLevel(_before[0] if _before else logging.NOTSET)


def _lowest() -> int:
    return min(int(logger.get_effective_level()) for logger in _hosts.values())


def _alone() -> Any:
    """The logger of the process's one host, or None with none or several."""
    loggers = list(_hosts.values())
    return loggers[0] if len(loggers) == 1 else None


@contextmanager
def speaking(logger: Any) -> Iterator[None]:
    """The library's records made inside go to ``logger`` (a host's own callback)."""
    token = _speaker.set(logger)
    try:
        yield
    finally:
        _speaker.reset(token)
