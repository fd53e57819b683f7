"""Finding ROS 2 and building the interface packages (``ktbt_interfaces``, the protocol's, and
``ktbt_example_interfaces``, the example robots') into this Python environment
(spec/protocol.md section 11; docs/tutorials/ros2.md).

ROS 2 comes one of two ways. With the ``ros2`` extra, Jazzy's wheels make the virtual
environment itself a ROS install prefix (``$VENV/lib``, ``share``): :func:`build` then builds
each interface package (``ros2/ktbt_interfaces``, ``ros2/ktbt_example_interfaces``, standard
ament_cmake packages) with cmake into that prefix, where rclpy finds them with no environment
variable, and skips a package while its sources, the interpreter and the prefix are those of
its last build (a stamp records them). With a sourced ROS 2 (``/opt/ros/jazzy``), the packages
are built in the user's colcon workspace like any other, and :func:`build` says so instead of
installing ROS a second time.

Two faults of the wheels are repaired here, as the build needs: their exported CMake files name
the wheel builder's Python and numpy include folders (``/opt/python/cp311-cp311/...``), which
are rewritten to this interpreter's; and they bring lark-parser 0.12, whose files overwrite
lark 1.x's (the project needs lark 1.x), which is reinstalled when found.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import sysconfig
from collections.abc import Callable
from pathlib import Path

PACKAGE = "ktbt_interfaces"
"""The protocol's interfaces (section 11)."""
PACKAGES = (PACKAGE, "ktbt_example_interfaces")
"""What :func:`build` builds: the protocol's interfaces, and the example robots' (the docking
action of the tutorial's ``dock_robot.py``)."""
WHEEL_PLATFORMS = "x86_64 Linux, CPython 3.10-3.13"
"""Where ROS 2 Jazzy's wheels exist (the ``ros2`` extra's environment markers)."""
STAMP = "ktbt-build.json"
LARK = "lark>=1.2,<2"


class Ros2Unavailable(RuntimeError):
    """ROS 2 cannot be used here; the message says what to do, in one line."""


def has_wheels() -> bool:
    """Whether ROS 2 Jazzy's wheels can be installed on this platform."""
    return (
        sys.platform == "linux"
        and platform.machine() == "x86_64"
        and (3, 10) <= sys.version_info[:2] <= (3, 13)
    )


def prefix() -> Path:
    """This environment's prefix: where the wheels put ROS, and where the interfaces go."""
    return Path(sys.prefix)


def wheels_installed() -> bool:
    """Whether the ``ros2`` extra's wheels are in this environment."""
    share = prefix() / "share"
    return (share / "rclpy").is_dir() and (share / "rosidl_default_generators").is_dir()


def system_ros() -> str | None:
    """The distribution of a sourced ROS 2 outside this environment (``ROS_DISTRO`` and an
    ``AMENT_PREFIX_PATH`` that does not name this prefix), or None."""
    distro = os.environ.get("ROS_DISTRO")
    paths = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    if distro and paths and all(Path(p).resolve() != prefix().resolve() for p in paths):
        return distro
    return None


def not_here() -> str:
    """One line saying what to do where ROS 2 is not installed."""
    if has_wheels():
        return "ROS 2 is not installed: pip install 'ktbt[ros2]', then ktbt ros2 build"
    where = (
        f"{platform.machine() or 'this machine'} {sys.platform}, CPython {sys.version.split()[0]}"
    )
    return (
        f"no ROS 2 wheels for {where} (they exist for {WHEEL_PLATFORMS}): install ROS 2 Jazzy "
        "(docs.ros.org), source it, and build ros2/ktbt_interfaces in a colcon workspace"
    )


def source(package: str = PACKAGE) -> Path:
    """An interface package's sources: inside the installed package (a wheel), or at the
    top of a source checkout."""
    here = Path(__file__).resolve().parent
    for candidate in (here / package, here.parents[2] / "ros2" / package):
        if (candidate / "package.xml").is_file():
            return candidate
    raise Ros2Unavailable(f"the {package} sources are missing from this installation")


def digest(folder: Path) -> str:
    """SHA-256 over the package's files (names and contents), the interpreter and the prefix:
    what a build depends on."""
    h = hashlib.sha256()
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        h.update(path.relative_to(folder).as_posix().encode() + b"\0")
        h.update(path.read_bytes() + b"\0")
    h.update(f"{sys.executable}\0{prefix()}\0{sys.version}".encode())
    return h.hexdigest()


def stamp_path(package: str = PACKAGE) -> Path:
    return prefix() / "share" / package / STAMP


def up_to_date(package: str = PACKAGE) -> bool:
    """Whether the installed ``package`` was built from these sources for this interpreter."""
    try:
        recorded = json.loads(stamp_path(package).read_text())
    except (OSError, ValueError):
        return False
    site = Path(sysconfig.get_paths()["purelib"])
    return (
        isinstance(recorded, dict)
        and recorded.get("digest") == digest(source(package))
        and (site / package / "__init__.py").is_file()
    )


_BUILDER_PATH = re.compile(r"/opt/python/cp3\d+-cp3\d+[^;\"\s)]*")


def _local_path(found: str) -> str:
    """This interpreter's counterpart of an include folder of the wheel builder's."""
    if found.endswith("numpy/_core/include") or found.endswith("numpy/core/include"):
        import numpy

        return str(numpy.get_include())
    if re.search(r"/include/python3\.\d+$", found):
        return sysconfig.get_paths()["include"]
    return found


def repair_exports(share: Path) -> int:
    """Rewrite the wheel builder's Python and numpy include folders, in every exported CMake
    file of the message packages, to this interpreter's; returns the files changed."""
    changed = 0
    for path in share.glob("*/cmake/*__rosidl_generator_pyExport.cmake"):
        text = path.read_text()
        fixed = _BUILDER_PATH.sub(lambda m: _local_path(m.group(0)), text)
        if fixed != text:
            path.write_text(fixed)
            changed += 1
    return changed


def lark_version() -> str:
    """The lark a new Python process of this environment imports (lark-parser 0.12 and lark
    1.x write the same folder: whichever was installed last wins)."""
    out = subprocess.run(
        [sys.executable, "-c", "import lark; print(lark.__version__)"],
        capture_output=True,
        text=True,
        check=False,
    )
    return out.stdout.strip() or "none"


def restore_lark(say: Callable[[str], None]) -> None:
    """Reinstall lark 1.x when lark-parser 0.12 (a dependency of ROS's rosidl_parser, which
    works with lark 1.x) has overwritten it, and remove the type stubs of 0.12 it leaves
    (``lark-stubs``), which type checkers would take over lark 1.x's own types."""
    found = lark_version()
    if not (found.split(".")[0].isdigit() and int(found.split(".")[0]) >= 1):
        say(f"lark {found} found (from the ROS wheels' lark-parser): reinstalling {LARK}")
        pip = [sys.executable, "-m", "pip", "install", "--quiet", "--force-reinstall"]
        subprocess.run([*pip, "--no-deps", LARK], check=True)
    stubs = Path(sysconfig.get_paths()["purelib"]) / "lark-stubs"
    if stubs.is_dir():
        say(f"removing {stubs} (lark-parser 0.12's types, not lark 1.x's)")
        shutil.rmtree(stubs)


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ktbt" / "ros2"


def build(say: Callable[[str], None], *, force: bool = False, jobs: int = 2) -> bool:
    """Build and install each of :data:`PACKAGES` into this environment unless it is up to
    date (``force``: always). True if one was built. Raises :class:`Ros2Unavailable` with one
    line when it cannot (no ROS wheels, a sourced system ROS, no cmake or compiler, a failed
    step)."""
    distro = system_ros()
    if distro is not None:
        names = " ".join(PACKAGES)
        raise Ros2Unavailable(
            f"a sourced ROS 2 ({distro}) is in use: build ros2/{PACKAGE} in your colcon "
            f"workspace (colcon build --packages-select {names}) and source its install"
        )
    if not wheels_installed():
        raise Ros2Unavailable(not_here())
    restore_lark(say)
    stale = [package for package in PACKAGES if force or not up_to_date(package)]
    if not stale:
        return False
    missing = [tool for tool in ("cmake", "c++") if shutil.which(tool) is None]
    if missing:
        raise Ros2Unavailable(
            f"building {stale[0]} needs {' and '.join(missing)}: apt-get install cmake g++"
        )
    repair_exports(prefix() / "share")
    for package in stale:
        _build_one(package, say, jobs)
    restore_lark(say)
    return True


def _build_one(package: str, say: Callable[[str], None], jobs: int) -> None:
    """Configure, build and install one interface package with cmake into this prefix."""
    src = source(package)
    key = digest(src)
    work = cache_dir() / f"build-{package}-{key[:16]}"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    log = work / "build.log"
    env = {
        **os.environ,
        "CMAKE_PREFIX_PATH": str(prefix()),
        "AMENT_PREFIX_PATH": str(prefix()),
        "PYTHONNOUSERSITE": "1",
    }
    steps = [
        [
            "cmake",
            "-S",
            str(src),
            "-B",
            str(work),
            f"-DCMAKE_INSTALL_PREFIX={prefix()}",
            f"-DPython3_EXECUTABLE={sys.executable}",
            "-DBUILD_TESTING=OFF",
        ],
        ["cmake", "--build", str(work), "-j", str(jobs)],
        ["cmake", "--install", str(work)],
    ]
    say(f"building {package} into {prefix()} (log: {log})")
    with log.open("w") as out:
        for step in steps:
            if step[1] == "--install":
                _uninstall(package)
            done = subprocess.run(step, stdout=out, stderr=subprocess.STDOUT, env=env, check=False)
            if done.returncode != 0:
                raise Ros2Unavailable(
                    f"{package}: {' '.join(step[:2])} failed ({_last_error(log)}); see {log}"
                )
    stamp = {"digest": key, "python": sys.version.split()[0]}
    stamp_path(package).write_text(json.dumps(stamp) + "\n")
    say(f"{package} built and installed")


def _uninstall(package: str) -> None:
    """Remove what an earlier build of ``package`` installed (its Python package, headers,
    share folder and libraries), so that a type removed from its sources is gone from the
    environment too, not left importable from the last build."""
    site = Path(sysconfig.get_paths()["purelib"])
    for folder in (site / package, prefix() / "include" / package, prefix() / "share" / package):
        shutil.rmtree(folder, ignore_errors=True)
    for library in (prefix() / "lib").glob(f"lib{package}__*.so"):
        library.unlink(missing_ok=True)


def _last_error(log: Path) -> str:
    lines = [line.strip() for line in log.read_text(errors="replace").splitlines()]
    errors = [line for line in lines if "error" in line.lower()]
    return (errors or lines or ["no output"])[-1][:160]


def main(args: list[str]) -> int:
    """``python -m ktbt_proto.tools.ros2.interfaces [build]``, for ``make``: lark 1.x put
    back (after the dev install); with ``build``, the interfaces built too where ROS 2 can run
    from the wheels (before the tests), and elsewhere one line saying the ROS tests will skip."""

    def say(line: str) -> None:
        print(line, file=sys.stderr)

    restore_lark(say)
    if args != ["build"]:
        return 0
    if not has_wheels() or system_ros() is not None:
        why = not_here() if not has_wheels() else "a ROS 2 is sourced (build it with colcon)"
        say(f"not building {', '.join(PACKAGES)} here: {why}")
        return 0
    try:
        if not build(say):
            say(f"{', '.join(PACKAGES)}: up to date")
    except Ros2Unavailable as exc:
        say(f"error: {exc}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
