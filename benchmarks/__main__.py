"""Run every benchmark module (``bench_*.py``) in this package, in name order."""

from __future__ import annotations

import importlib
import pkgutil
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import cast


def main(argv: Sequence[str] | None = None) -> int:
    """Run each module's ``main`` with no arguments; the exit status is the worst of theirs."""
    del argv  # modules take their own options when run alone
    here = str(Path(__file__).resolve().parent)
    names = sorted(m.name for m in pkgutil.iter_modules([here]) if m.name.startswith("bench_"))
    status = 0
    for i, name in enumerate(names):
        if i:
            print()
        module = importlib.import_module(f"{__package__ or 'benchmarks'}.{name}")
        run = cast(Callable[[Sequence[str]], int], module.main)
        status = max(status, run([]))
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
