"""``python -m benchmarks.bench_ros2``."""

from __future__ import annotations

import sys

from . import main

sys.exit(main(sys.argv[1:]))
