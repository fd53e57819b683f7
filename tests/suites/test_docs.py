"""The README and every documentation page run as written: every code block in them is run or
checked, as a newcomer would from a clone, each in a scratch folder of its own holding a copy
of the examples, with real peers on loopback.

What each kind of block gets (CONTRIBUTING.md, "Documentation", says the same to writers):

- ``python``: a page's Python blocks run in order in one namespace, twice in the same folder;
  both runs must print the same (a block that saves a file must not depend on an earlier run);
- ``sh``: each block runs alone in bash (``set -euo pipefail``), background jobs stopped at the
  end; lines that start with ``make`` are not run (they are how this very test is run);
- ``console``: a transcript: each ``$ command`` runs in bash and must print exactly the lines
  shown under it (stdout and stderr together);
- ``stringbt`` must parse; ``toml`` must load;
- a block whose first line is ``# file: PATH`` is written to PATH in the scratch folder before
  the page's other blocks run (a robot's vocabulary, a tree), as well as checked;
- a block that cannot run in a test (a server that runs until Ctrl-C, an install, C++) starts
  with the comment ``# not run: REASON`` (``// not run: REASON`` in C++), in any language; the
  test counts such blocks, so they stay few and explicit.

Changes made to what runs, and why (nothing else is touched): the zenoh ports 7447 and 7448
become free ports, so the test never collides with another process; ``ktbt demo`` and
``ktbt sim run`` get ``--trials 1 --iterations 200`` appended (the last value of an option
wins), since the studies take minutes at full size; ``ktbt sim view`` gets SDL's dummy video
driver and ``--iterations 20``, since a window would wait for someone to close it, or with
``--record`` ``--frames 3 --every 10``, since a full recording simulates 30,000 iterations;
a block that runs ``ktbt ros2`` runs in a network namespace of its own with only loopback up,
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and a ``ROS_DOMAIN_ID`` of its own, since DDS
discovers by multicast; a ``source`` line runs with unset variables allowed (``set +u``), as in
the interactive shell a reader types it into, since ROS's setup scripts read some (colcon's
``COLCON_TRACE``). Whatever a block leaves behind must be ignored by the repository's
``.gitignore``, so following the documentation leaves a clone clean.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest

import ktbt_proto as kp
from tests.zenoh_helpers import free_port

ROOT = Path(__file__).resolve().parents[2]
PAGES = [
    ROOT / "README.md",
    ROOT / "benchmarks" / "README.md",
    *sorted(p for p in (ROOT / "docs").rglob("*.md") if "_build" not in p.parts),
]
FENCE = re.compile(r"^(`{3,})([^\s`]*)[^\n]*\n(.*?)^\1[ \t]*$", re.S | re.M)
RUN = {"python", "sh", "console", "stringbt", "toml"}
NOT_RUN = re.compile(r"^(#|//) not run: \S")
FILE = re.compile(r"^# file: (\S+)\s*$")
MOST_NOT_RUN = 7
SMALL = " --trials 1 --iterations 200"


@dataclass(frozen=True)
class Block:
    page: str
    number: int
    lang: str
    code: str

    @property
    def first(self) -> str:
        return self.code.split("\n", 1)[0]

    @property
    def runs(self) -> bool:
        return not NOT_RUN.match(self.first)

    def __str__(self) -> str:
        return f"{self.page} block {self.number} ({self.lang})"


def blocks(page: Path) -> list[Block]:
    """The page's fenced code blocks; MyST directives (```{include}) are not code."""
    name = str(page.relative_to(ROOT))
    found = FENCE.findall(page.read_text(encoding="utf-8"))
    return [
        Block(name, k + 1, lang, code)
        for k, (_, lang, code) in enumerate(found)
        if not lang.startswith("{")
    ]


BLOCKS = [block for page in PAGES for block in blocks(page)]
PYTHON_PAGES = sorted({b.page for b in BLOCKS if b.lang == "python" and b.runs})


def of(lang: str) -> list[Block]:
    return [b for b in BLOCKS if b.lang == lang and b.runs]


def test_every_block_runs_or_says_why_not() -> None:
    unknown = [str(b) for b in BLOCKS if b.runs and b.lang not in RUN]
    assert not unknown, f"give these a language the test runs, or '# not run: REASON': {unknown}"
    not_run = [str(b) for b in BLOCKS if not b.runs]
    assert len(not_run) <= MOST_NOT_RUN, not_run
    assert len(of("python")) >= 8 and len(of("sh")) >= 6


def test_the_readme_is_a_short_pitch_that_starts_with_make_demo_and_make_test() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 150
    first = next(b for b in BLOCKS if b.page == "README.md")
    commands = [line.split("#")[0].strip() for line in first.code.splitlines()]
    assert commands[:2] == ["make demo", "make test"]
    assert "pip install ktbt" not in text  # the package is installed from the clone
    assert ".venv/bin/ktbt" in text and "source .venv/bin/activate" in text


def test_every_path_the_readme_links_is_committed() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    links = [
        link.split("#")[0]
        for link in re.findall(r"\]\(([^)\s]+)\)", text)
        if not re.match(r"[a-z]+:", link) and not link.startswith("#")
    ]
    assert links
    tracked = set(
        subprocess.run(
            ["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.splitlines()
    )
    for link in links:
        path = link.rstrip("/")
        assert path in tracked or any(t.startswith(path + "/") for t in tracked), link


@pytest.fixture
def clone(tmp_path: Path) -> Path:
    """What a newcomer's clone has that the pages name: the examples and the ROS packages."""
    shutil.copytree(ROOT / "examples", tmp_path / "examples")
    shutil.copytree(ROOT / "ros2", tmp_path / "ros2")
    return tmp_path


def files_in(folder: Path) -> set[str]:
    return {
        str(p.relative_to(folder))
        for p in folder.rglob("*")
        if p.is_file() and "__pycache__" not in p.parts
    }


def assert_left_clean(folder: Path, before: set[str]) -> None:
    """What the blocks wrote is ignored by git in a clone (.gitignore at the root)."""
    made = sorted(files_in(folder) - before)
    if not made:
        return
    ignored = subprocess.run(
        ["git", "check-ignore", "--no-index", "--stdin"],
        cwd=ROOT,
        input="\n".join(made),
        capture_output=True,
        text=True,
    ).stdout.splitlines()
    assert sorted(set(made) - set(ignored)) == [], "add these to .gitignore or write them to out/"


def ports() -> dict[str, str]:
    return {"7447": str(free_port()), "7448": str(free_port())}


def with_ports(code: str, chosen: dict[str, str]) -> str:
    for port, free in chosen.items():
        code = code.replace(port, free)
    return code


def write_files(page: str, folder: Path) -> None:
    for block in BLOCKS:
        match = FILE.match(block.first)
        if block.page == page and match:
            target = folder / match[1]
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(block.code, encoding="utf-8")


@pytest.mark.parametrize("block", of("stringbt"), ids=str)
def test_stringbt_blocks_parse(block: Block) -> None:
    kp.parse(block.code)


@pytest.mark.parametrize("block", of("toml"), ids=str)
def test_toml_blocks_load(block: Block) -> None:
    tomllib.loads(block.code)


def run_python(page: str, folder: Path) -> str:
    namespace: dict[str, object] = {"__name__": "docs"}
    out = io.StringIO()
    chosen = ports()
    with contextlib.redirect_stdout(out):
        for block in of("python"):
            if block.page == page:
                exec(compile(with_ports(block.code, chosen), str(block), "exec"), namespace)
    return out.getvalue()


@pytest.mark.network
@pytest.mark.parametrize("page", PYTHON_PAGES)
def test_python_blocks_run_twice_alike(
    page: str, clone: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(clone)
    write_files(page, clone)
    before = files_in(clone)
    first = run_python(page, clone)
    assert run_python(page, clone) == first
    assert_left_clean(clone, before)


def adapt(block: str, chosen: dict[str, str]) -> str:
    """The block as a bash script, changed only as the module docstring says."""
    out = []
    for line in with_ports(block, chosen).splitlines():
        if line.startswith("make "):
            continue
        command, hash_, rest = _split_comment(line)
        if command.startswith("source "):  # a setup script of ROS's reads unset variables
            command = f"set +u; {command}; set -u"
        elif command.startswith(("ktbt demo", "ktbt sim run")):
            command += SMALL
        elif command.startswith("ktbt sim view"):
            command += " --frames 3 --every 10" if "--record" in command else " --iterations 20"
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


def bash(script: str, folder: Path, check: bool = True) -> subprocess.CompletedProcess[str]:
    bin_dir = str(Path(sys.executable).parent)
    env = {
        **os.environ,
        "PATH": bin_dir + os.pathsep + os.environ.get("PATH", ""),
        "SDL_VIDEODRIVER": "dummy",
        "PYTHONUNBUFFERED": "1",
        "COLUMNS": "100",
    }
    # Background peers are stopped however the script ends.
    prologue = "set -euo pipefail\ntrap 'kill $(jobs -p) 2>/dev/null || true; wait' EXIT\n"
    command = ["bash", "-c", prologue + script]
    if "ktbt ros2" in script:
        # DDS discovers by multicast: a block that starts ROS 2 nodes runs in a network
        # namespace of its own with only loopback up, in a domain of its own.
        env |= {
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
            "ROS_DOMAIN_ID": str(os.getpid() % 100 + 101),
            "ROS_LOG_DIR": tempfile.mkdtemp(prefix="ktbt-docs-ros-"),
        }
        up = 'ip link set lo up && exec "$@"'
        command = ["unshare", "-n" if os.geteuid() == 0 else "-rn", "sh", "-c", up, "sh", *command]
    return subprocess.run(
        command,
        cwd=folder,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )


SLOW = ("ktbt sim", "ktbt demo", "ktbt fleet run", "btview", "ktbt ros2")


def slow(block: Block) -> bool:
    """Over about 5 s on a loaded two-core machine: a study, a fleet, a Groot2 client, or many
    commands (each ``ktbt`` process takes most of a second to start)."""
    commands = [line for line in block.code.splitlines() if line.startswith("ktbt ")]
    return any(s in block.code for s in SLOW) or len(commands) >= 8


@pytest.mark.network
@pytest.mark.parametrize(
    "block",
    [pytest.param(b, marks=[pytest.mark.slow] if slow(b) else []) for b in of("sh")],
    ids=str,
)
def test_shell_blocks_run(block: Block, clone: Path) -> None:
    write_files(block.page, clone)
    before = files_in(clone)
    script = adapt(block.code, ports())
    done = bash(script, clone)
    assert done.returncode == 0, f"{script}\n--- stdout\n{done.stdout}\n--- stderr\n{done.stderr}"
    assert "Traceback" not in done.stdout + done.stderr
    assert_left_clean(clone, before)


def transcript(code: str) -> list[tuple[str, str]]:
    """(command, the output shown under it) for each ``$ `` line."""
    steps: list[tuple[str, list[str]]] = []
    for line in code.splitlines():
        if line.startswith("$ "):
            steps.append((line[2:], []))
        else:
            assert steps, f"output before the first command: {line!r}"
            steps[-1][1].append(line.rstrip())
    return [(command, "\n".join(shown).strip("\n")) for command, shown in steps]


@pytest.mark.network
@pytest.mark.parametrize("block", of("console"), ids=str)
def test_console_transcripts_print_what_they_show(block: Block, clone: Path) -> None:
    write_files(block.page, clone)
    before = files_in(clone)
    for command, shown in transcript(block.code):
        done = bash(command + " 2>&1", clone)
        printed = "\n".join(line.rstrip() for line in done.stdout.splitlines()).strip("\n")
        assert printed == shown, f"$ {command}"
    assert_left_clean(clone, before)
