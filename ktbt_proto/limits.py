"""Limits on untrusted input, checked before any deep work (spec: "Limits")."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Limits:
    """Bounds that keep hostile or accidental input from exhausting memory, time or the stack.

    The defaults admit any tree a person would write (the paper's control tree is depth 5, 20
    nodes) and a 1 MB generated tree; a peer receiving knowledge over the network should pass
    something much tighter.
    """

    max_size: int = 4_000_000
    """Characters of text (or bytes, for bytes input)."""
    max_depth: int = 128
    """Nesting depth; the root is at depth 1."""
    max_nodes: int = 200_000
    """Nodes in the whole tree."""
    max_literal: int = 1024
    """Characters in one name, number or string literal (as written)."""
    max_number: float | None = None
    """Largest magnitude of any number in the tree (tick counts, seconds, thresholds, argument
    values), checked by validation; None: any finite number. A literal of 256 digits is short,
    yet a wait of 10^200 ticks never ends: knowledge from a peer needs this bound too."""

    def __post_init__(self) -> None:
        for name in ("max_size", "max_depth", "max_nodes", "max_literal"):
            if getattr(self, name) < 1:
                raise ValueError(f"Limits.{name} must be at least 1")
        if self.max_number is not None and not self.max_number >= 0:
            raise ValueError("Limits.max_number must be a number >= 0, or None")
        if self.max_literal > 4000:
            # Python refuses int() of longer digit strings; keep literals convertible.
            raise ValueError("Limits.max_literal must be at most 4000")


DEFAULT_LIMITS = Limits()
