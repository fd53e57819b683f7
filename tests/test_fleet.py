"""One small fleet scenario end to end: real ``ktbt peer`` processes through the fault layer,
a silent half/half partition, a peer killed with SIGKILL and restarted, packet loss where
nftables is installed (else the run reports loss as skipped, never passed). The run must pass
its own checks, and leave no process and no namespace behind."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.fleet_helpers import sweep
from tests.zenoh_helpers import ROOT, wait_until

pytestmark = [pytest.mark.slow, pytest.mark.network]  # make test-fast skips it


def test_a_small_fleet_converges_through_a_partition_a_kill_and_loss(tmp_path: Path) -> None:
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ktbt_proto", "fleet", "run", "--peers", "6", "--partition", "8s",
         "--churn", "0.2", "--loss", "0.1", "--seed", "3", "--bound", "30", "--teacher", "serve",
         "--no-live", "--out", str(out)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        output, _ = proc.communicate(timeout=90)
    finally:
        _, left, ours = sweep(proc, out / "events.jsonl")
    assert not left, f"the run left peers running: {left}"
    assert not ours, f"the run left its namespace: {ours}"
    summary = json.loads((out / "summary.json").read_text())
    verdicts = {v["name"]: v for v in summary["verdicts"]}
    assert proc.returncode == 0, output
    assert summary["passed"], output
    assert verdicts["fault: partition-silent"]["status"] == "pass"
    assert verdicts["fault: churn"]["status"] == "pass"
    assert verdicts["kill -9 loses nothing saved"]["status"] == "pass"
    kills = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]
    saved = sum(len(e["saved"]) for e in kills if e["kind"] == "kill")
    assert saved > 0, "the kill had nothing saved to lose"
    assert verdicts["convergence"]["status"] == "pass"
    if os.geteuid() == 0 and shutil.which("nft") and shutil.which("ip"):
        assert verdicts["fault: loss"]["status"] == "pass", verdicts["fault: loss"]
    else:
        assert verdicts["fault: loss"]["status"] == "skipped"
        pytest.skip(f"packet loss skipped: {verdicts['fault: loss']['detail']}")


def test_ctrl_c_twice_mid_run_leaves_no_peer_and_no_namespace(tmp_path: Path) -> None:
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ktbt_proto", "fleet", "run", "--peers", "4", "--churn", "0.5",
         "--churn-rounds", "3", "--seed", "5", "--bound", "60", "--teacher", "serve",
         "--no-live", "--out", str(out)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    record = out / "events.jsonl"
    try:
        assert wait_until(
            lambda: record.exists() and '"learners-up"' in record.read_text(), seconds=60
        ), "the learners never came up"
        proc.send_signal(signal.SIGINT)
        proc.send_signal(signal.SIGINT)  # lands in the cleanup: must change nothing
        output, _ = proc.communicate(timeout=90)
    finally:
        pids, left, ours = sweep(proc, record)
    assert pids, "no peer was launched"
    assert not left, f"the run left peers running: {left}"
    assert not ours, f"the run left its namespace: {ours}"
    kinds = [json.loads(line)["kind"] for line in record.read_text().splitlines()]
    assert kinds[-1] == "end", kinds[-5:]
    summary = json.loads((out / "summary.json").read_text())
    assert not summary["passed"] and summary["aborted"] == "interrupted", output
    assert proc.returncode == 1, output
