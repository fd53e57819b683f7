"""The core wheel, installed as a robot developer installs it: built from this tree, put into a
new virtual environment outside the repository with only its own dependencies, and used there
(`ktbt fmt`, `ktbt check`, `ktbt tour`, and two peers exchanging knowledge on loopback).

The wheel is built once without build isolation (hatchling comes with the dev extra); the core
dependencies come from pip's cache or the index, never the simulator's."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import zipfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.zenoh_helpers import endpoint, free_port

# Builds the wheel and installs it into fresh virtual environments.
pytestmark = [pytest.mark.network, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[2]
SIM_ONLY = ("numpy", "pymunk", "pyarrow", "matplotlib", "pygame")
CORE_LIMIT = 60_000_000
"""Bytes: what the core distribution and its dependencies may weigh on disk."""


class Env:
    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.bin = folder / "venv" / "bin"
        self.work = folder / "work"  # the current folder of every command: no repository here
        self.work.mkdir()
        self.environ = {
            k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")
        }
        self.environ["PATH"] = f"{self.bin}{os.pathsep}{os.environ.get('PATH', '')}"

    def run(self, *args: str, stdin: str | None = None) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            args,
            cwd=self.work,
            env=self.environ,
            capture_output=True,
            text=True,
            input=stdin,
            timeout=600,
        )

    def python(self, code: str) -> str:
        done = self.run(str(self.bin / "python"), "-c", code)
        assert done.returncode == 0, done.stderr
        return done.stdout.strip()


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation",
         "--disable-pip-version-check", "-w", str(out), str(ROOT)],
        check=True, capture_output=True, timeout=300,
    )  # fmt: skip
    (found,) = out.glob("ktbt-*.whl")
    return found


@pytest.fixture(scope="module")
def core(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Env:
    env = Env(tmp_path_factory.mktemp("core"))
    subprocess.run(
        [sys.executable, "-m", "venv", str(env.folder / "venv")], check=True, timeout=300
    )
    done = env.run(
        str(env.bin / "python"), "-m", "pip", "install", "--quiet", "--no-compile",
        "--disable-pip-version-check", str(wheel),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return env


def test_the_wheel_carries_types_licence_urls_and_examples(wheel: Path) -> None:
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        (metadata,) = [n for n in names if n.endswith(".dist-info/METADATA")]
        meta = z.read(metadata).decode()
    assert "ktbt_proto/py.typed" in names
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
    assert "ktbt_proto/examples/sar_control.sbt" in names
    assert "ktbt_proto/examples/knowledge/colours.sbt" in names
    assert "ktbt_proto/grammar/stringbt.lark" in names
    for page in ("index.html", "monitor.js", "monitor.css"):
        assert f"ktbt_proto/tools/monitor/static/{page}" in names
    assert "License-Expression: MIT" in meta
    core = [line for line in meta.splitlines() if line.startswith("Requires-Dist:")]
    unconditional = {
        line.split()[1].split(">")[0].split("<")[0] for line in core if ";" not in line
    }
    assert unconditional == {"lark", "pydantic", "eclipse-zenoh", "typer", "pynacl"}


def test_the_core_install_is_light(core: Env) -> None:
    for module in SIM_ONLY:
        found = core.python(f"import importlib.util; print(importlib.util.find_spec({module!r}))")
        assert found == "None", f"{module} is installed in the core environment"
    site = Path(core.python("import sysconfig; print(sysconfig.get_paths()['purelib'])"))
    tooling = ("pip", "setuptools", "_distutils_hack", "pkg_resources", "distutils-precedence")
    size = sum(
        f.stat().st_size
        for top in site.iterdir()
        if not top.name.startswith(tooling)
        for f in ([top] if top.is_file() else top.rglob("*"))
        if f.is_file() and "__pycache__" not in f.parts
    )
    assert size < CORE_LIMIT, f"the core install weighs {size / 1e6:.1f} MB"


def test_the_language_commands_work_from_the_wheel(core: Env) -> None:
    tree = core.work / "tree.sbt"
    tree.write_text("# a skill\n<sq><c>(TargetSeen, colour=2)<a>(PickTreasure)<e>\n")
    fmt = core.run("ktbt", "fmt", str(tree))
    assert fmt.returncode == 0, fmt.stderr
    assert tree.read_text() == (
        "# a skill\n<sq>\n    <c>(TargetSeen, colour=2)\n    <a>(PickTreasure)\n<e>\n"
    )
    check = core.run("ktbt", "check", str(tree))
    assert (check.returncode, check.stdout, check.stderr) == (0, "", "")
    broken = core.work / "broken.sbt"
    broken.write_text("<sq><a>(X, speed=)<e>\n")
    check = core.run("ktbt", "check", str(broken))
    assert check.returncode == 1 and check.stdout.startswith(f"{broken}:1:18: SBT103 ")
    tour = core.run("ktbt", "tour")
    assert tour.returncode == 0, tour.stderr
    assert "r2 asked, r1 answered" in tour.stdout and "(paper_control.sbt)" in tour.stdout
    sim = core.run("ktbt", "sim", "list")
    assert sim.returncode == 2
    assert sim.stderr.count("\n") == 1 and "pip install 'ktbt[sim]'" in sim.stderr
    assert "warning" not in tour.stderr  # the sim plugin loads without its extra


@pytest.fixture
def teacher(core: Env) -> Iterator[str]:
    examples = Path(core.python("import ktbt_proto.tools.demo as d; print(d.examples_folder())"))
    port = free_port()
    proc = subprocess.Popen(
        [str(core.bin / "ktbt"), "peer", "serve", "--id", "teacher", "--knowledge",
         str(examples / "sar_control.sbt"), "--listen", endpoint(port)],
        cwd=core.work, env={**core.environ, "PYTHONUNBUFFERED": "1"},
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()
        assert first == "teacher: serving 2 skills; Ctrl-C to stop\n", first
        yield endpoint(port)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()


def test_two_peers_exchange_knowledge_from_the_wheel(core: Env, teacher: str) -> None:
    """The flagship example's prior knowledge is served, flat as the paper writes it."""
    asked = core.run(
        "ktbt", "peer", "ask", "--sequence", "TargetSeen(colour=1)", "--connect", teacher,
        "--timeout", "10",
    )  # fmt: skip
    assert asked.returncode == 0, asked.stderr
    assert asked.stdout == (
        "# from teacher\n<sq>\n    <a>(PickTreasure)\n    <a>(AssignCollectionPoint, colour=1)\n"
        "<e>\n"
    )
