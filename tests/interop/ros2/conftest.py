"""ROS 2 tests: the interfaces are built once per environment (cached, ``ktbt ros2 build``),
and each test's processes run in a network namespace of their own (``rosns``). Where ROS 2
Jazzy has no wheels, the tests skip with one line naming the platform; on x86_64 Linux they
never skip: a missing ROS install or a failed build fails them."""

from __future__ import annotations

import platform
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from ktbt_proto.tools.ros2 import interfaces


@pytest.fixture(scope="session")
def ros2_built() -> None:
    """rclpy and ktbt_interfaces importable in this environment (built if need be)."""
    if not interfaces.has_wheels() and interfaces.system_ros() is None:
        pytest.skip(
            f"no ROS 2 wheels for {platform.machine()} {sys.platform} CPython "
            f"{platform.python_version()} (only {interfaces.WHEEL_PLATFORMS}) and no sourced ROS 2"
        )
    if interfaces.system_ros() is None:
        try:
            interfaces.build(lambda line: print(line, file=sys.stderr))
        except interfaces.Ros2Unavailable as exc:
            pytest.fail(f"ROS 2 on {platform.machine()} {sys.platform}: {exc}")


@pytest.fixture
def rosns(ros2_built: None, tmp_path: Path) -> Iterator[object]:
    """A network namespace for this test's ROS processes, all ended when it ends."""
    from tests.interop.ros2.rosns import RosNamespace

    ns = RosNamespace(tmp_path)
    try:
        yield ns
    finally:
        ns.close()


@pytest.fixture(scope="module")
def module_rosns(
    ros2_built: None, tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest
) -> Iterator[object]:
    """One network namespace shared by a test module's processes (each test still starts, or
    reads, only what it needs: none depends on another's side effects), all ended after it."""
    from tests.interop.ros2.rosns import RosNamespace

    ns = RosNamespace(tmp_path_factory.mktemp(request.module.__name__.rsplit(".", 1)[-1]))
    try:
        yield ns
    finally:
        ns.close()
