"""Compiled array work: the ``jit`` every mechanism's per-step loop uses (spec/simulator.md,
"Speed").

At the paper's 40 robots a numpy operation costs far more in its call than in its arithmetic,
and a step needed about sixty of them; at 4,000 robots the pairs of nearby robots dominate. So
each mechanism's step is one loop over the robots, compiled by numba on first use and cached on
disk, so that a study's worker processes load the compiled code instead of compiling it again.
The cache is ``NUMBA_CACHE_DIR`` if set, else ``ktbt/numba`` in the user's cache folder
(``XDG_CACHE_HOME`` or ``~/.cache``).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar, cast

os.environ.setdefault(
    "NUMBA_CACHE_DIR",
    str(Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "ktbt" / "numba"),
)

try:
    import numba
except ImportError:  # pragma: no cover - the sim extra installs it
    raise ImportError("the simulator needs the sim extra: pip install 'ktbt[sim]'") from None

F = TypeVar("F", bound=Callable[..., object])


def jit(function: F) -> F:
    """Compile ``function`` in nopython mode, cached on disk."""
    return cast(F, numba.njit(cache=True, nogil=True)(function))
