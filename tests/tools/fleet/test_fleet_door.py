"""``ktbt fleet run`` converges for a vocabulary that is not the search-and-rescue one: the
door-opening robot of ``tests/door_robot.py``, a small fleet of real ``ktbt peer`` processes,
its sequences taken from the knowledge file (spec/protocol.md section 4.5)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.door_robot import FLAT, VOCABULARY
from tests.fleet_helpers import sweep
from tests.zenoh_helpers import ROOT

pytestmark = [pytest.mark.slow, pytest.mark.network]


def test_a_door_robot_fleet_converges(tmp_path: Path) -> None:
    vocabulary, control, knowledge = (
        tmp_path / "door.toml",
        tmp_path / "door_control.sbt",
        tmp_path / "door.sbt",
    )
    vocabulary.write_text(VOCABULARY)
    control.write_text("<sl><k>(new)<e><a>(Push)<e>\n")
    knowledge.write_text(f"<k>(prior)\n    {FLAT}\n    <sq><c>(!DoorClosed)<a>(Push)<e>\n<e>\n")
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ktbt_proto", "fleet", "run", "--peers", "4",
         "--knowledge", str(knowledge), "--vocabulary", str(vocabulary),
         "--control", str(control), "--bound", "30", "--no-live", "--out", str(out)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        output, _ = proc.communicate(timeout=120)
    finally:
        _, left, ours = sweep(proc, out / "events.jsonl")
    assert not left and not ours
    assert proc.returncode == 0, output
    summary = json.loads((out / "summary.json").read_text())
    verdicts = {v["name"]: v for v in summary["verdicts"]}
    assert verdicts["convergence"]["status"] == "pass", output
    assert "search-and-rescue" not in output
    launches = [
        json.loads(line)
        for line in (out / "events.jsonl").read_text().splitlines()
        if json.loads(line)["kind"] == "launch"
    ]
    assert len(launches) == 4
    # Every learner saved both door items.
    saved = [json.loads(p.read_text()) for p in (out / "peers").glob("*.json")]
    learners = [s for s in saved if s.get("knowledge")]
    assert learners and all(len(s["knowledge"]) == 2 for s in learners)
