"""The front door, ``import ktbt_proto as kp``, loads nothing it does not need: importing the
package, or any module of the language, loads none of zenoh, pydantic and rclpy (a tool that
only parses or formats starts fast and runs without them), and ``kp.__all__`` is a short list
of names that all resolve, each from the module that defines it. Every check runs in a fresh
interpreter, since this one has imported everything already."""

from __future__ import annotations

import importlib.util
import json
import platform
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import ktbt_proto as kp

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("zenoh", "pydantic", "rclpy")
MOST_NAMES = 40
ROS2_ONLY = {"attach"}
"""Names whose module needs rclpy and the built ``ktbt_interfaces``."""


def language() -> list[str]:
    """The language layer's modules, as the import contract in ``pyproject.toml`` names them."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    (layers,) = [c for c in config["tool"]["importlinter"]["contracts"] if c["id"] == "layers"]
    (siblings,) = [layer for layer in layers["layers"] if ":" in layer]
    return sorted(f"ktbt_proto.{name.strip()}" for name in siblings.split(":"))


def fresh(code: str) -> str:
    """What ``code`` prints in a new interpreter."""
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


def loaded_after(statement: str) -> list[str]:
    """The top-level packages of ``HEAVY`` that ``statement`` loads."""
    out = fresh(
        f"{statement}\nimport json, sys\n"
        f"print(json.dumps(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r}))))"
    )
    return list(json.loads(out))


@pytest.mark.parametrize("module", ["ktbt_proto", *language()])
def test_the_package_and_each_language_module_load_no_network_pydantic_or_ros(
    module: str,
) -> None:
    assert loaded_after(f"import {module}") == [], module


def test_importing_the_package_imports_none_of_its_modules() -> None:
    out = fresh("import ktbt_proto, sys; print(sorted(m for m in sys.modules if 'ktbt' in m))")
    assert out.split() == ["['ktbt_proto']"]


def test_the_front_door_is_short_and_every_name_resolves_from_its_module() -> None:
    names = kp.__all__
    assert len(names) <= MOST_NAMES, f"{len(names)} names: the front door holds at most 40"
    assert len(set(names)) == len(names)
    assert set(names) <= set(dir(kp))
    shown = fresh(
        "import ktbt_proto as kp\n"
        f"for name in sorted(set(kp.__all__) - {ROS2_ONLY!r}):\n"
        "    value = getattr(kp, name)\n"
        "    print(name, getattr(value, '__module__', None) or type(value).__module__)\n"
    )
    homes = dict(line.split() for line in shown.splitlines())
    assert set(homes) == set(names) - ROS2_ONLY
    for name, home in homes.items():
        assert home.startswith("ktbt_proto.") and home != "ktbt_proto", (name, home)


def test_a_name_outside_the_front_door_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no attribute 'Query'"):
        _ = kp.Query  # type: ignore[attr-defined]
    with pytest.raises(ImportError):
        exec("from ktbt_proto import Overhearing", {})


def test_functions_named_as_their_modules_stay_functions() -> None:
    """``validate``, ``merge`` and ``render`` share their modules' names: importing the module
    first must not put the module where the function is."""
    out = fresh(
        "import ktbt_proto.validate, ktbt_proto.merge, ktbt_proto.render, ktbt_proto.runtime\n"
        "import ktbt_proto as kp\n"
        "print(*(callable(getattr(kp, n)) for n in ('validate', 'merge', 'render')))\n"
        "from ktbt_proto.validate import find_problems\n"
        "print(find_problems is kp.find_problems)\n"
    )
    assert out.split() == ["True"] * 4


def test_attach_resolves_where_ros2_runs() -> None:
    """``kp.attach`` needs rclpy and the ``ktbt_interfaces`` package built into the
    environment (``ktbt ros2 build``, cached), as the ROS 2 tests do."""
    from ktbt_proto.tools.ros2 import interfaces

    if importlib.util.find_spec("rclpy") is None and interfaces.system_ros() is None:
        pytest.skip(
            f"rclpy is not installed on {platform.machine()} {sys.platform} CPython "
            f"{platform.python_version()} (ROS 2 wheels exist for {interfaces.WHEEL_PLATFORMS})"
        )
    if interfaces.system_ros() is None:
        interfaces.build(lambda line: print(line, file=sys.stderr))
    out = fresh("import ktbt_proto as kp; print(kp.attach.__module__)")
    assert out.strip() == "ktbt_proto.interop.ros2.embed"
