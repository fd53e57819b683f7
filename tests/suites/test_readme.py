"""The README runs: every Python block and every shell command in it, as a newcomer would run
them from a clone, in a scratch copy of the examples, with real peers on loopback.

What the test changes, and why (nothing else is touched):

- lines that start with ``make`` are not run: they are how this very test is run;
- the zenoh ports 7447 and 7448 become free ports, and ``0.0.0.0`` becomes ``127.0.0.1``, so
  the test never collides with another process and never leaves loopback;
- ``ktbt demo`` and ``ktbt sim run`` get ``--trials 1 --iterations 200`` appended (the last
  value of an option wins): the studies take minutes at full size, and their sizes are options;
- ``ktbt sim view`` without ``--record`` gets ``--iterations 20`` and SDL's dummy video driver,
  since a window would otherwise wait for someone to close it.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.zenoh_helpers import free_port

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text(encoding="utf-8")
BLOCKS = re.findall(r"^```(\w*)\n(.*?)^```", README, re.S | re.M)
PYTHON = [code for lang, code in BLOCKS if lang == "python"]
SHELL = [code for lang, code in BLOCKS if lang == "sh"]
SMALL = " --trials 1 --iterations 200"


def test_the_readme_has_what_this_test_runs() -> None:
    assert len(PYTHON) >= 3 and len(SHELL) >= 4
    commands = [line for block in SHELL for line in block.splitlines()]
    for command in ("ktbt fmt", "ktbt check", "ktbt peer serve", "ktbt peer ask", "ktbt sim run"):
        assert any(line.startswith(command) for line in commands), command


@pytest.fixture
def clone(tmp_path: Path) -> Path:
    """What a newcomer's clone has that the README names: the examples."""
    shutil.copytree(ROOT / "ktbt_proto" / "examples", tmp_path / "ktbt_proto" / "examples")
    return tmp_path


def test_python_blocks_run_in_order(clone: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(clone)
    namespace: dict[str, object] = {"__name__": "readme"}
    for k, code in enumerate(PYTHON):
        exec(compile(code, f"README.md python block {k + 1}", "exec"), namespace)
    assert (clone / "r1.json").is_file()  # the agent saved what it learned


def adapt(block: str, ports: dict[str, str]) -> str:
    """The block as a bash script, changed only as the module docstring says."""
    out = []
    for line in block.splitlines():
        if line.startswith("make "):
            continue
        for port, free in ports.items():
            line = line.replace(port, free)
        line = line.replace("0.0.0.0", "127.0.0.1")
        command, hash_, rest = _split_comment(line)
        if command.startswith(("ktbt demo", "ktbt sim run")):
            command += SMALL
        elif command.startswith("ktbt sim view") and "--record" not in command:
            command += " --iterations 20"
        out.append(command + hash_ + rest)
    return "\n".join(out) + "\n"


def _split_comment(line: str) -> tuple[str, str, str]:
    """(command, separator, comment): a comment starts at '#' after a blank, outside quotes."""
    quote = ""
    for i, char in enumerate(line):
        if quote:
            quote = "" if char == quote else quote
        elif char in "'\"":
            quote = char
        elif char == "#" and i > 0 and line[i - 1].isspace():
            return line[:i].rstrip(), "  ", line[i:]
    return line.rstrip(), "", ""


@pytest.mark.network
@pytest.mark.parametrize(
    "index",
    [
        pytest.param(k, marks=[pytest.mark.slow] if "ktbt sim" in block else [])
        for k, block in enumerate(SHELL)
    ],
    ids=lambda k: f"block{k + 1}",
)
def test_shell_blocks_run(index: int, clone: Path) -> None:
    ports = {"7447": str(free_port()), "7448": str(free_port())}
    script = adapt(SHELL[index], ports)
    bin_dir = str(Path(sys.executable).parent)
    env = {
        **os.environ,
        "PATH": bin_dir + os.pathsep + os.environ.get("PATH", ""),
        "SDL_VIDEODRIVER": "dummy",
        "PYTHONUNBUFFERED": "1",
    }
    # Background peers are stopped however the script ends.
    prologue = "set -euo pipefail\ntrap 'kill $(jobs -p) 2>/dev/null || true; wait' EXIT\n"
    done = subprocess.run(
        ["bash", "-c", prologue + script],
        cwd=clone,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, f"{script}\n--- stdout\n{done.stdout}\n--- stderr\n{done.stderr}"
    assert "Traceback" not in done.stdout + done.stderr
