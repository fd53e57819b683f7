"""The three statuses a node returns when ticked."""

from __future__ import annotations

from enum import Enum


class Status(Enum):
    """SUCCESS and FAILURE end a node's activation; RUNNING asks to be ticked again."""

    SUCCESS = "SUCCESS"
    FAILURE = "FAILURE"
    RUNNING = "RUNNING"

    def __repr__(self) -> str:
        return f"Status.{self.name}"


SUCCESS = Status.SUCCESS
FAILURE = Status.FAILURE
RUNNING = Status.RUNNING
