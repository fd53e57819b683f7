"""The blackboard: the paper's "state manager", where sensing writes and behaviours read.

A plain ``dict`` subclass, so that reading a flag on the hot path is one C-level lookup and
conditions can be bound straight to ``Blackboard.get``.
"""

from __future__ import annotations

from typing import Any


class Blackboard(dict[str, Any]):
    """Flags and values by name. Missing flags read as false (``bb.flag("x")``)."""

    def flag(self, name: str) -> bool:
        return bool(self.get(name, False))

    def __repr__(self) -> str:
        return f"Blackboard({dict.__repr__(self)})"
