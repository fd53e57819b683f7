"""Build BehaviorTree.CPP once per version and compiler, and C++ programs against it.

The source is the source distribution of ``behaviortreepy`` (it carries BehaviorTree.CPP's whole
tree with its third-party folder), fetched with pip. The library is built in Release without its
tests, examples, tools, SQLite logger or Groot2 interface, and installed (with the header of its
bundled tinyxml2, whose symbols the library exports) under
``~/.cache/ktbt/btcpp-<version>-<compiler>/`` (``$KTBT_CACHE`` overrides ``~/.cache/ktbt``): outside
the clone, so a fresh clone reuses it. A file lock makes parallel test processes wait for one
build instead of starting two. Programs and plugin libraries are cached by a digest of their
sources.

``python -m tests.btcpp.build`` builds the library and prints its prefix and build time, then
builds the example programs and KT-BT's plugin library (``examples/btcpp/ktbt_nodes.cpp``).
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

BTCPP_VERSION = "4.8.2"
SDIST = ("behaviortreepy", "0.1.4")
REPO = Path(__file__).resolve().parents[2]
HEADERS = REPO / "ktbt_btcpp"
CMAKE_OPTIONS = (
    "-DCMAKE_BUILD_TYPE=Release",
    "-DBUILD_TESTING=OFF",
    "-DBTCPP_EXAMPLES=OFF",
    "-DBTCPP_BUILD_TOOLS=OFF",
    "-DBTCPP_SQLITE_LOGGING=OFF",
    "-DBTCPP_GROOT_INTERFACE=OFF",
)


class BuildError(RuntimeError):
    """A step of the build failed; the message holds the end of its output."""


def cache_root() -> Path:
    if os.environ.get("KTBT_CACHE"):
        return Path(os.environ["KTBT_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ktbt"


def compiler() -> str:
    cxx = os.environ.get("CXX", "g++")
    out = subprocess.run([cxx, "-dumpfullversion"], capture_output=True, text=True, check=True)
    return f"{Path(cxx).name}{out.stdout.strip()}-{platform.machine()}"


@contextmanager
def locked(path: Path) -> Iterator[None]:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _run(command: list[str], cwd: Path | None = None) -> None:
    done = subprocess.run(["nice", *command], cwd=cwd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        tail = (done.stdout + done.stderr)[-3000:]
        raise BuildError(f"{' '.join(command)} failed ({done.returncode}):\n{tail}")


def _source(work: Path) -> Path:
    name, version = SDIST
    _run(
        [
            sys.executable,
            "-m",
            "pip",
            "download",
            "--quiet",
            "--no-deps",
            "--no-binary",
            ":all:",
            f"{name}=={version}",
            "-d",
            str(work),
        ]
    )
    archive = next(work.glob(f"{name}-{version}.tar.gz"))
    with tarfile.open(archive) as tar:
        tar.extractall(work, filter="data")
    source = work / f"{name}-{version}" / "BehaviorTree.CPP"
    if f"<version>{BTCPP_VERSION}</version>" not in (source / "package.xml").read_text():
        raise BuildError(f"{name} {version} does not carry BehaviorTree.CPP {BTCPP_VERSION}")
    return source


def tinyxml2_header(prefix: Path) -> Path:
    """BehaviorTree.CPP's bundled tinyxml2, whose symbols the library exports: copied beside
    its headers, so a program (the example robot) parses XML with the engine's own parser."""
    return prefix / "include" / "tinyxml2" / "tinyxml2.h"


def engine() -> Path:
    """The install prefix of BehaviorTree.CPP (include/, lib/), built if not there yet."""
    prefix = cache_root() / f"btcpp-{BTCPP_VERSION}-{compiler()}"
    stamp, header = prefix / "built", tinyxml2_header(prefix)
    if stamp.exists() and header.exists():
        return prefix
    with locked(prefix.parent / f"{prefix.name}.lock"):
        if stamp.exists() and header.exists():  # another process built it while this one waited
            return prefix
        start = time.monotonic()
        with tempfile.TemporaryDirectory(dir=cache_root()) as scratch:
            work = Path(scratch)
            source = _source(work)
            if not stamp.exists():
                shutil.rmtree(prefix, ignore_errors=True)
                build = work / "build"
                _run(
                    [
                        "cmake",
                        "-S",
                        str(source),
                        "-B",
                        str(build),
                        *CMAKE_OPTIONS,
                        f"-DCMAKE_INSTALL_PREFIX={prefix}",
                    ]
                )
                _run(["cmake", "--build", str(build), "--parallel", str(os.cpu_count() or 1)])
                _run(["cmake", "--install", str(build)])
            header.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source / "3rdparty" / "tinyxml2" / "tinyxml2.h", header)
        if not stamp.exists():
            stamp.write_text(f"{time.monotonic() - start:.1f}\n")
    return prefix


def _digest(sources: tuple[Path, ...]) -> str:
    """The digest of ``sources``, the headers beside them and the header library."""
    digest = hashlib.sha256()
    beside = sorted({header for source in sources for header in source.parent.glob("*.hpp")})
    for path in (*sources, *beside, *sorted(HEADERS.glob("*.hpp"))):
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def _compile(target: Path, sources: tuple[Path, ...], *flags: str) -> Path:
    """``sources`` compiled into ``target`` (once: another process waits for the first)."""
    prefix = engine()
    if target.exists():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    with locked(target.parent / f"{target.name}.lock"):
        if target.exists():
            return target
        partial = target.parent / f"{target.name}.partial"
        cxx = os.environ.get("CXX", "g++")
        _run(
            [
                cxx,
                "-std=c++17",
                "-O1",
                *flags,
                "-I",
                str(prefix / "include"),
                "-I",
                str(HEADERS),
                *map(str, sources),
                "-L",
                str(prefix / "lib"),
                "-lbehaviortree_cpp",
                "-pthread",
                f"-Wl,-rpath,{prefix / 'lib'}",
                "-o",
                str(partial),
            ]
        )
        partial.replace(target)
    return target


def program(name: str, *sources: Path) -> Path:
    """Compile ``sources`` with ``ktbt_btcpp/`` on the include path, linked against the engine;
    cached by the digest of the sources, the headers beside them and the header library."""
    return _compile(engine() / "programs" / f"{name}-{_digest(sources)}", sources)


def plugin(name: str, *sources: Path) -> Path:
    """A BehaviorTree.CPP plugin library, ``lib<name>.so`` (``BT_PLUGIN_EXPORT`` defined, so
    its ``BT_REGISTER_NODES`` is exported), alone in a folder of its own: a loader finds it by
    name (``registerFromPlugin(getOSName(name))``) with the folder on ``LD_LIBRARY_PATH``.
    Cached as :func:`program` is."""
    folder = engine() / "plugins" / f"{name}-{_digest(sources)}"
    return _compile(folder / f"lib{name}.so", sources, "-shared", "-fPIC", "-DBT_PLUGIN_EXPORT")


EXAMPLES = REPO / "examples" / "btcpp"
"""The example programs and the plugin library ``make interop`` builds before its tests."""


def examples() -> dict[str, Path]:
    """The example programs and KT-BT's plugin library, built (``make interop`` builds them
    first, so their build time is not the tests')."""
    return {
        "learner": program("learner", EXAMPLES / "learner.cpp"),
        "nav2_loader": program("nav2_loader", EXAMPLES / "nav2_loader.cpp"),
        "libktbt_nodes.so": plugin("ktbt_nodes", EXAMPLES / "ktbt_nodes.cpp"),
    }


if __name__ == "__main__":
    built = engine()
    print(built, "built in", (built / "built").read_text().strip(), "s")
    start = time.monotonic()
    for path in examples().values():
        print(path)
    print(f"examples ready in {time.monotonic() - start:.1f} s")
