"""The monitor's fleet state: what events make of it, its bounds, and the page's catch-up; the
command without its extra and with a bad address."""

from __future__ import annotations

import subprocess
import sys

import pytest

from ktbt_proto.events import FleetEvent, digest
from ktbt_proto.monitor import fleet as fleet_module
from ktbt_proto.monitor.fleet import Fleet

from .zenoh_helpers import ROOT

GREEN = "<c>(TargetSeen,colour=2)"
T = "2026-12-01T00:00:00.000+00:00"


def ev(peer: str, n: int, kind: str, **fields: object) -> FleetEvent:
    return FleetEvent.model_validate({"peer": peer, "n": n, "t": T, "event": kind, **fields})


def test_a_merge_is_a_transfer_a_matrix_cell_and_a_point_of_the_timeline() -> None:
    fleet = Fleet()
    fleet.peer_joined("t")
    fleet.catalog("t", [GREEN])
    fleet.event(ev("r1", 0, "merged", item=digest(GREEN), sequence=GREEN, teacher="t"), True)
    version, state = fleet.snapshot()
    peers = {p["peer"]: p for p in state["peers"]}
    assert peers["t"]["knows"] == {digest(GREEN): "known"}
    assert peers["r1"]["knows"] == {digest(GREEN): "learned"}
    assert state["transfers"][0]["teacher"] == "t" and state["transfers"][0]["signed"]
    assert state["timeline"][-1]["count"] == 2
    fleet.event(ev("r1", 1, "forgotten", item=digest(GREEN), sequence=GREEN, reason="idle"), True)
    _, changes = fleet.changes_since(version)
    assert changes is not None
    assert {"k": "know", "peer": "r1", "item": digest(GREEN), "how": None} in changes
    assert changes[-1]["k"] == "peer"  # the peer's counters, once per batch


def test_gaps_in_a_peers_numbering_and_unanswered_queries_are_counted(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    fleet = Fleet()
    fleet.event(ev("r1", 0, "query-sent", id="q1", sequence=GREEN), False)
    fleet.event(ev("r1", 5, "query-sent", id="q2", sequence=GREEN, dropped=3), False)
    fleet.event(ev("r1", 6, "answer-received", id="q2", sender="t", sequence=GREEN), False)
    monkeypatch.setattr(fleet_module, "LOST_AFTER", -1.0)  # every open query is now late
    fleet.tend()
    peer = fleet.peers["r1"]
    assert (peer.lost_events, peer.dropped, peer.queries_lost) == (4, 3, 1)


def test_tables_are_bounded_and_what_does_not_fit_is_counted(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(fleet_module, "MAX_PEERS", 3)
    monkeypatch.setattr(fleet_module, "MAX_ITEMS", 2)
    fleet = Fleet()
    for n in range(10):
        fleet.peer_joined(f"p{n}")
        fleet.catalog("p0", [f"<c>(X{n})"])
    assert len(fleet.peers) == 3 and len(fleet.items) == 2
    assert fleet.drops["full"] == 7 + 8
    fleet = Fleet()
    fleet.peer_joined("<" * 1000)
    assert [len(name) for name in fleet.peers] == [fleet_module.MAX_NAME]


def test_a_page_that_fell_behind_gets_a_snapshot_and_batches_are_bounded(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(fleet_module, "CHANGES", 100)
    fleet = Fleet()
    for n in range(500):
        fleet.event(ev("r1", n, "query-sent", id=f"q{n}"), False)
    _, changes = fleet.changes_since(0)
    assert changes is None  # too far behind: the page asks for a snapshot
    latest, state = fleet.snapshot()
    assert len(state["peers"][0]["recent"]) == fleet_module.RECENT
    fleet.event(ev("r1", 500, "query-sent", id="q500"), False)
    reached, changes = fleet.changes_since(latest, most=1)
    assert changes is not None and len(changes) == 1 and reached == latest + 1


def test_the_command_without_its_extra_says_how_to_install_it() -> None:
    blocked = (
        "import sys; sys.modules['starlette'] = None; sys.modules['uvicorn'] = None; "
        "sys.argv = ['ktbt', 'monitor', '--connect', 'tcp/127.0.0.1:1']; "
        "from ktbt_proto.cli import main; main()"
    )
    done = subprocess.run(
        [sys.executable, "-c", blocked], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 2
    assert (
        done.stderr.strip() == "ktbt monitor needs the monitor extra: pip install 'ktbt[monitor]'"
    )


def test_a_bad_address_is_one_line() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "ktbt_proto", "monitor", "--connect", "tcp/127.0.0.1:1",
         "--http", "nowhere"],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2 and "is not HOST:PORT" in done.stderr
    assert "Traceback" not in done.stderr
