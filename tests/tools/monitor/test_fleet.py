"""The monitor's fleet state: what events make of it, its bounds, and the page's catch-up; the
command without its extra and with a bad address."""

from __future__ import annotations

import subprocess
import sys

import pytest

from ktbt_proto.exchange.events import FleetEvent, signed_bytes
from ktbt_proto.exchange.signing import Identity
from ktbt_proto.exchange.trust import TrustStore
from ktbt_proto.items import sequence_digest
from ktbt_proto.tools.monitor import state as fleet_module
from ktbt_proto.tools.monitor.state import FleetState
from tests.zenoh_helpers import ROOT

GREEN = "<c>(TargetSeen,colour=2)"
T = "2026-12-01T00:00:00.000+00:00"


def ev(peer: str, n: int, kind: str, **fields: object) -> FleetEvent:
    return FleetEvent.model_validate({"peer": peer, "n": n, "t": T, "event": kind, **fields})


R1 = Identity.generate()


def sign(event: FleetEvent, identity: Identity = R1) -> FleetEvent:
    event = event.model_copy(update={"key": identity.public})
    return event.model_copy(update={"sig": identity.sign(signed_bytes(event))})


def test_a_peers_key_is_pinned_and_replays_are_refused_and_counted() -> None:
    fleet = FleetState()
    mallory = Identity.generate()
    fleet.event(sign(ev("r1", 0, "query-sent", id="q0")))
    fleet.event(sign(ev("r1", 1, "merged", teacher="mallory"), mallory))  # another key
    fleet.event(ev("r1", 2, "merged", teacher="mallory"))  # back to unsigned
    fleet.event(sign(ev("r1", 0, "query-sent", id="q0")))  # the same event again
    fleet.event(sign(ev("r1", 3, "query-sent", id="q3")))
    assert fleet.drops == {"forged": 2, "replayed": 1}
    assert fleet.events == 2 and fleet.peers["r1"].last_n == 3
    reasons = fleet.stats()["reasons"]
    assert mallory.public in reasons["forged"][0] and "unsigned" in reasons["forged"][1]
    assert "0 of r1" in reasons["replayed"][0]
    fleet.peer_joined("r1")
    fleet.peer_left("r1")
    fleet.peer_joined("r1")  # it restarted: its numbering starts over
    fleet.event(sign(ev("r1", 0, "query-sent", id="q0")))
    assert fleet.events == 3


def test_a_trust_store_names_the_key_a_peer_must_sign_with() -> None:
    fleet = FleetState(TrustStore(frozenset({R1.public}), {"r1": R1.public}))
    fleet.event(ev("r1", 0, "query-sent", id="q0"))  # unsigned, from its first event
    fleet.event(sign(ev("r1", 1, "query-sent", id="q1"), Identity.generate()))
    fleet.event(sign(ev("r1", 2, "query-sent", id="q2")))
    assert fleet.drops == {"forged": 2} and fleet.events == 1
    assert "trust store" in fleet.stats()["reasons"]["forged"][0]


def test_an_item_is_named_by_a_sequence_of_its_digest_and_a_clipped_one_is_replaced() -> None:
    fleet = FleetState()
    fleet.event(
        ev("r1", 0, "merged", item=sequence_digest(GREEN), sequence="<c>(Lie)", teacher="t")
    )
    assert sequence_digest(GREEN) not in fleet.items and fleet.drops["malformed"] == 1
    fleet.event(
        ev("r1", 1, "merged", item=sequence_digest(GREEN), sequence="<c>(Target...", teacher="t")
    )
    assert fleet.items[sequence_digest(GREEN)] == "<c>(Target..."
    fleet.catalog("t", [GREEN])
    assert fleet.items[sequence_digest(GREEN)] == GREEN


def test_a_merge_is_a_transfer_a_matrix_cell_and_a_point_of_the_timeline() -> None:
    fleet = FleetState()
    fleet.peer_joined("t")
    fleet.catalog("t", [GREEN])
    fleet.event(
        sign(ev("r1", 0, "merged", item=sequence_digest(GREEN), sequence=GREEN, teacher="t"))
    )
    version, state = fleet.snapshot()
    peers = {p["peer"]: p for p in state["peers"]}
    assert peers["t"]["knows"] == {sequence_digest(GREEN): "known"}
    assert peers["r1"]["knows"] == {sequence_digest(GREEN): "learned"}
    assert state["transfers"][0]["teacher"] == "t" and state["transfers"][0]["signed"]
    assert state["timeline"][-1]["count"] == 2
    fleet.event(
        sign(ev("r1", 1, "forgotten", item=sequence_digest(GREEN), sequence=GREEN, reason="idle"))
    )
    _, changes = fleet.changes_since(version)
    assert changes is not None
    assert {"k": "know", "peer": "r1", "item": sequence_digest(GREEN), "how": None} in changes
    assert changes[-1]["k"] == "peer"  # the peer's counters, once per batch


def test_a_peer_known_by_its_catalog_is_a_point_of_the_timeline() -> None:
    """The spreading chart counts every peer that knows the item, as the matrix does, also
    one whose merge event never came (dropped, lost, or sent before the monitor heard of the
    item): 5 of 100 such peers kept a line at 95 under a matrix full of them."""
    fleet = FleetState()
    fleet.catalog("t", [GREEN])
    fleet.catalog("r1", [GREEN])
    _, state = fleet.snapshot()
    assert [p["count"] for p in state["timeline"]] == [1, 2]
    fleet.event(
        sign(ev("r2", 0, "merged", item=sequence_digest(GREEN), sequence=GREEN, teacher="t"))
    )
    fleet.catalog("r2", [GREEN])  # heard by its merge already: no second point
    _, state = fleet.snapshot()
    assert [p["count"] for p in state["timeline"]] == [1, 2, 3]


def test_gaps_in_a_peers_numbering_and_unanswered_queries_are_counted(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    fleet = FleetState()
    fleet.event(ev("r1", 0, "query-sent", id="q1", sequence=GREEN))
    fleet.event(ev("r1", 5, "query-sent", id="q2", sequence=GREEN, dropped=3))
    fleet.event(ev("r1", 6, "answer-received", id="q2", sender="t", sequence=GREEN))
    monkeypatch.setattr(fleet_module, "LOST_AFTER", -1.0)  # every open query is now late
    fleet.tend()
    peer = fleet.peers["r1"]
    assert (peer.lost_events, peer.dropped, peer.queries_lost) == (4, 3, 1)


def test_tables_are_bounded_and_what_does_not_fit_is_counted(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(fleet_module, "MAX_PEERS", 3)
    monkeypatch.setattr(fleet_module, "MAX_ITEMS", 2)
    fleet = FleetState()
    for n in range(10):
        fleet.peer_joined(f"p{n}")
        fleet.catalog("p0", [f"<c>(X{n})"])
    assert len(fleet.peers) == 3 and len(fleet.items) == 2
    assert fleet.drops["full"] == 7 + 8
    fleet.peer_left("p1")  # a peer gone makes room for a newcomer; one present never does
    fleet.peer_joined("q")
    assert set(fleet.peers) == {"p0", "p2", "q"}
    fleet.peer_joined("<" * 1000)  # not a peer name
    fleet.catalog("p0", ["not a sequence", "<c>(A"])
    assert "<" * 1000 not in fleet.peers and fleet.drops["malformed"] == 3
    assert "not a peer name" in fleet.stats()["reasons"]["malformed"][0]

    fleet = FleetState()  # items nobody knows make room for new ones
    for n in range(3):
        fleet.event(ev("r1", n, "query-sent", id=f"q{n}", item=sequence_digest(f"<c>(Y{n})"),
                       sequence=f"<c>(Y{n})"))  # fmt: skip
    assert (
        list(fleet.items) == [sequence_digest("<c>(Y1)"), sequence_digest("<c>(Y2)")]
        and not fleet.drops
    )


def test_a_catalog_that_no_longer_lists_an_item_says_it_was_forgotten(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    fleet = FleetState()
    fleet.catalog("t", [GREEN, "<c>(A)"])
    fleet.catalog("t", ["<c>(A)"])
    assert sequence_digest(GREEN) in fleet.peers["t"].knows  # just listed: maybe a race, kept
    monkeypatch.setattr(fleet_module, "LOST_AFTER", -1.0)
    fleet.catalog("t", ["<c>(A)"])
    assert list(fleet.peers["t"].knows) == [sequence_digest("<c>(A)")]


def test_a_page_that_fell_behind_gets_a_snapshot_and_batches_are_bounded(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(fleet_module, "CHANGES", 100)
    fleet = FleetState()
    for n in range(500):
        fleet.event(ev("r1", n, "query-sent", id=f"q{n}"))
    _, changes = fleet.changes_since(0)
    assert changes is None  # too far behind: the page asks for a snapshot
    latest, state = fleet.snapshot()
    assert len(state["peers"][0]["recent"]) == fleet_module.RECENT
    fleet.event(ev("r1", 500, "query-sent", id="q500"))
    reached, changes = fleet.changes_since(latest, most=1)
    assert changes is not None and len(changes) == 1 and reached == latest + 1


def test_the_command_without_its_extra_says_how_to_install_it() -> None:
    blocked = (
        "import sys; sys.modules['starlette'] = None; sys.modules['uvicorn'] = None; "
        "sys.argv = ['ktbt', 'monitor', '--connect', 'tcp/127.0.0.1:1']; "
        "from ktbt_proto.tools.cli import main; main()"
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


def test_a_page_must_name_the_bound_address_or_an_allowed_host() -> None:
    from ktbt_proto.tools.monitor.command import LOOPBACK_NAMES, allowed_hosts

    assert allowed_hosts("127.0.0.1", []) == LOOPBACK_NAMES
    assert allowed_hosts("192.0.2.7", ["robots.example"]) == ["192.0.2.7", "robots.example"]
    assert allowed_hosts("2001:db8::1", []) == ["2001:db8::1", "[2001:db8::1]"]
