"""ROS 2 tests: the interfaces are built once per environment (``ros2_built``, in the root
``tests/conftest.py``, as the hosts' contract test uses it too), and each test's processes run
in a network namespace of their own (``rosns``). Where ROS 2 Jazzy has no wheels, the tests
skip with one line naming the platform; on x86_64 Linux they never skip: a missing ROS install
or a failed build fails them."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest


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
