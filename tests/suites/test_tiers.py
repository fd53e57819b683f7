"""The tiers stay true: the marks the simulator's tests get from ``conftest.py`` name tests that
exist, and only the marks pyproject declares (strict markers refuse any other)."""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

from tests.conftest import SIMULATOR_TIERS

TESTS = Path(__file__).resolve().parents[1]
DECLARED = {
    line.split(":", 1)[0]
    for line in tomllib.loads((TESTS.parent / "pyproject.toml").read_text(encoding="utf-8"))[
        "tool"
    ]["pytest"]["ini_options"]["markers"]
}


def test_every_tiered_simulator_test_exists() -> None:
    for module, tests in SIMULATOR_TIERS.items():
        tree = ast.parse((TESTS / "sim" / module).read_text(encoding="utf-8"))
        defined = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
        assert set(tests) <= defined, f"{module} has no {sorted(set(tests) - defined)}"
        for marks in tests.values():
            assert set(marks) <= DECLARED
