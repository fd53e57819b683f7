"""The runner's own robustness, on a real fleet object with real proxies on loopback and no
peers: bad log lines are counted and skipped, and a crash in the schedule fails the run with
everything still stopped and recorded."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

from ktbt_proto.tools.fleet.check import check_record
from ktbt_proto.tools.fleet.plan import FleetConfig
from ktbt_proto.tools.fleet.runner import FleetRun, read_saved


def _fleet(tmp_path: Path) -> FleetRun:
    return FleetRun(FleetConfig(peers=3), tmp_path, lambda _text: None, False, None)


def test_log_lines_that_are_not_entries_are_counted_and_skipped(tmp_path: Path) -> None:
    fleet = _fleet(tmp_path)
    member = fleet.members["p0"]
    member.folder.mkdir(parents=True, exist_ok=True)
    member.log.write_text(
        "[]\n"
        '{"event": "merged", "t": "not a time", "sequence": "A"}\n'
        '"a string"\n'
        '{"event": "query-sent", "t": "2026-01-01T00:00:00+00:00", "id": "q"}\n'
    )
    fleet._tail(member)
    fleet.record.close()
    assert fleet.bad == 3
    assert member.counts["query-sent"] == 1


def test_a_crash_in_the_schedule_fails_the_run_and_still_ends_the_record(tmp_path: Path) -> None:
    fleet = _fleet(tmp_path)

    async def crash() -> str | None:
        raise RuntimeError("boom")

    fleet.schedule = crash  # type: ignore[method-assign]
    result = asyncio.run(fleet.run())
    assert result["problem"] is not None and "boom" in result["problem"]
    kinds = [json.loads(line)["kind"] for line in (tmp_path / "events.jsonl").open()]
    assert kinds[-1] == "end" and "aborted" in kinds and "counters" in kinds
    summary = check_record(tmp_path)
    assert not summary["passed"]


def test_a_save_file_with_an_item_twice_is_damage(tmp_path: Path) -> None:
    path = tmp_path / "p0.json"
    entry = {"sequence": "A", "subtree": "x"}
    path.write_text(json.dumps({"knowledge": [entry, {"sequence": "B", "subtree": "y"}]}))
    assert set(read_saved(path)) == {"A", "B"}
    path.write_text(json.dumps({"knowledge": [entry, entry]}))
    saved = read_saved(path)
    assert isinstance(saved, str) and "twice" in saved and "A" in saved
