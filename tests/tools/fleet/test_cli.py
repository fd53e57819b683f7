"""``ktbt fleet check`` and ``ktbt fleet run`` on bad input, as a user runs them: a record that
is not one is an error line and exit 2, a torn last line is a run that did not end, a bad
``--knowledge`` file and a bad or taken ``--monitor`` address are refused before anything
starts."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path

from tests.tools.fleet.test_check import base
from tests.zenoh_helpers import ROOT


def _ktbt(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ktbt_proto", *args],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip


def _write(folder: Path, lines: list[str]) -> Path:
    folder.mkdir()
    (folder / "events.jsonl").write_text("".join(lines))
    return folder


def test_a_record_line_that_is_not_an_object_is_an_error_not_a_traceback(tmp_path: Path) -> None:
    events = [json.dumps(e) + "\n" for e in base()]
    folder = _write(tmp_path / "run", [events[0], "[]\n", *events[1:]])
    done = _ktbt("fleet", "check", str(folder))
    assert done.returncode == 2, done.stderr
    assert "not a fleet record" in done.stderr and "Traceback" not in done.stderr


def test_a_torn_last_line_is_a_run_that_did_not_end(tmp_path: Path) -> None:
    events = [json.dumps(e) + "\n" for e in base()]
    folder = _write(tmp_path / "run", [*events[:-1], events[-1][:5]])
    done = _ktbt("fleet", "check", str(folder))
    assert done.returncode == 1, done.stdout + done.stderr
    assert "fail    completed" in done.stdout


def test_a_bad_knowledge_file_is_refused_with_its_position(tmp_path: Path) -> None:
    bad = tmp_path / "bad.sbt"
    bad.write_text("Sequence(<k>(Cond(a), Act(b)\n")
    out = tmp_path / "run"
    done = _ktbt("fleet", "run", "--peers", "3", "--knowledge", str(bad), "--out", str(out))
    assert done.returncode == 2, done.stdout + done.stderr
    assert "^" in done.stderr and "Traceback" not in done.stderr
    assert not (out / "events.jsonl").exists()


def test_a_bad_or_taken_monitor_address_is_refused_before_any_peer_starts(tmp_path: Path) -> None:
    out = tmp_path / "run"
    done = _ktbt("fleet", "run", "--peers", "3", "--monitor", "nonsense", "--out", str(out))
    assert done.returncode == 2, done.stdout + done.stderr
    assert "HOST:PORT" in done.stderr and "Traceback" not in done.stderr
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = _ktbt("fleet", "run", "--peers", "3", "--monitor", f"127.0.0.1:{port}",
                     "--out", str(out))  # fmt: skip
    assert done.returncode == 2, done.stdout + done.stderr
    assert "ktbt monitor did not start" in done.stderr and "cannot serve" in done.stderr
    assert "Traceback" not in done.stderr
    assert not (out / "events.jsonl").exists()  # no peer was launched


def test_a_graph_that_is_not_connected_or_a_bad_edge_list_is_refused_before_any_peer(
    tmp_path: Path,
) -> None:
    out = tmp_path / "run"
    done = _ktbt("fleet", "run", "--peers", "40", "--topology", "geometric", "--radius", "0.1",
                 "--out", str(out))  # fmt: skip
    assert done.returncode == 2, done.stdout + done.stderr
    error = done.stderr.strip().splitlines()[-1]  # after the note on the demo robot
    assert error.startswith("error: the geometric graph of 40 peers within radius 0.1")
    assert "not connected" in done.stderr and "raise --radius" in done.stderr
    edges = tmp_path / "edges.txt"
    edges.write_text("0 1\n1 two\n")
    done = _ktbt("fleet", "run", "--peers", "3", "--topology", "edges", "--edges", str(edges),
                 "--out", str(out))  # fmt: skip
    assert done.returncode == 2, done.stdout + done.stderr
    assert f"--edges {edges}:2: not a pair of peer indices" in done.stderr
    assert sum(line.startswith("error:") for line in done.stderr.splitlines()) == 1
    assert "Traceback" not in done.stderr
    assert not (out / "events.jsonl").exists()
