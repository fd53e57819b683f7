"""The ROS package ``ktbt_ros`` (ament_python), built by colcon (spec/protocol.md section 11,
"ROS 2 binding").

ROS finds a package and its executables by where they are installed, not by Python's metadata,
so this file installs what ROS's tools look for: the package's marker in the ament resource
index (``share/ament_index/resource_index/packages/ktbt_ros``, which ``ros2 run`` and
``ament_index_python`` read), its ``package.xml`` in ``share/ktbt_ros``, the example parameter
files and knowledge file in ``share/ktbt_ros/config``, and the two console scripts, which
``setup.cfg`` sends to ``lib/ktbt_ros`` (what ``ros2 run ktbt_ros ktbt_node`` starts). The
scripts are thin: they run ``ktbt ros2 run`` and ``ktbt ros2 bridge`` of the ``ktbt`` Python
package, which must be installed in the interpreter that runs colcon (``pip install .`` in a
clone of KT-BT; it is not a rosdep key, so ``package.xml`` cannot declare it).
"""

from __future__ import annotations

from pathlib import Path

from setuptools import setup  # type: ignore[import-untyped, unused-ignore]

PACKAGE = "ktbt_ros"
HERE = Path(__file__).resolve().parent


def config_files() -> list[str]:
    """The example files to install under ``share/ktbt_ros/config``, relative to this folder
    (setuptools wants relative paths), in a stable order."""
    return sorted(
        path.relative_to(HERE).as_posix()
        for path in (HERE / "config").iterdir()
        if path.suffix in (".yaml", ".sbt")
    )


setup(
    name=PACKAGE,
    version="0.1.0",
    packages=[PACKAGE],
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml", "README.md"]),
        (f"share/{PACKAGE}/config", config_files()),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="KT-BT maintainers",
    maintainer_email="maintainers@users.noreply.h-seed-9de48332.example",
    description="KT-BT's lifecycle node and bridge as ROS 2 executables.",
    license="MIT",
    entry_points={
        "console_scripts": [
            f"ktbt_node = {PACKAGE}.main:node",
            f"ktbt_bridge = {PACKAGE}.main:bridge",
        ],
    },
)
