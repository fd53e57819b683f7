"""The monitor's items table under hostile but valid peers (ktbt_proto/tools/monitor/state.py): when
it is full, the peers holding the most of it give way first, so a peer, or a few, listing junk
sequences cannot crowd out what the rest of the fleet knows; what is refused or evicted is
counted; and a page that applies the changes ends with the snapshot's state."""

from __future__ import annotations

from collections import Counter
from typing import Any

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from ktbt_proto.exchange.events import FleetEvent, signed_bytes
from ktbt_proto.exchange.signing import Identity
from ktbt_proto.exchange.trust import TrustStore
from ktbt_proto.items import parse_sequence, sequence_digest
from ktbt_proto.tools.monitor import state as fleet_module
from ktbt_proto.tools.monitor.state import FleetState

T = "2026-12-01T00:00:00.000+00:00"
COLOURS = [f"<c>(TargetSeen,colour={c})" for c in range(1, 5)]


def junk(n: int, tag: str = "J") -> list[str]:
    """Valid sequences of conditions that no honest peer knows."""
    return [f"<c>({tag}{k},x={k})" for k in range(n)]


class Page:
    """What monitor.js makes of a snapshot and the changes after it: peers (with what each
    knows, and how) and items."""

    def __init__(self, fleet: FleetState) -> None:
        self.fleet = fleet
        self.version, state = fleet.snapshot()
        self.items: dict[str, str] = dict(state["items"])
        self.peers = {p["peer"]: {"status": p["status"], **p["knows"]} for p in state["peers"]}

    def catch_up(self) -> None:
        while True:
            version, changes = self.fleet.changes_since(self.version)
            assert changes is not None, "the page fell behind the changes kept"
            if not changes:
                return
            self.version = version
            for change in changes:
                self.apply(change)

    def apply(self, change: dict[str, Any]) -> None:
        kind = change["k"]
        if kind == "peer":
            self.peers.setdefault(change["peer"], {})["status"] = change["status"]
        elif kind == "unpeer":
            del self.peers[change["peer"]]
        elif kind == "item":
            self.items[change["item"]] = change["sequence"]
        elif kind == "unitem":
            del self.items[change["item"]]
        elif kind == "know":
            known = self.peers.setdefault(change["peer"], {})
            if change["how"]:
                known[change["item"]] = change["how"]
            else:
                known.pop(change["item"], None)

    def state(self) -> tuple[dict[str, str], dict[str, dict[str, str]]]:
        return self.items, self.peers


def shown(fleet: FleetState) -> tuple[dict[str, str], dict[str, dict[str, str]]]:
    """The snapshot's state, as the page holds it."""
    _, state = fleet.snapshot()
    return state["items"], {
        p["peer"]: {"status": p["status"], **p["knows"]} for p in state["peers"]
    }


def check(fleet: FleetState) -> None:
    """The table's bounds, and nobody knows an item the table does not name; what the fleet
    keeps up to date as peers learn and forget (each item's knowers and their ranks, each
    peer's load, the items nobody knows) is what it would count afresh."""
    assert len(fleet.items) <= fleet_module.MAX_ITEMS
    knowers: dict[str, set[str]] = {}
    tiers: dict[str, list[int]] = {}
    for peer in fleet.peers.values():
        assert set(peer.knows) <= set(fleet.items), peer.name
        for item in peer.knows:
            knowers.setdefault(item, set()).add(peer.name)
            tiers.setdefault(item, [0] * fleet_module.TIERS)[fleet._tier(peer)] += 1
    assert knowers == fleet._knowers and tiers == fleet._tiers
    for peer in fleet.peers.values():
        load = sum(1 / len(knowers[item]) for item in peer.knows)
        assert peer.load == pytest.approx(load, abs=1e-6), peer.name
    assert set(fleet._unknown) == set(fleet.items) - set(knowers)


class Events:
    """Numbered events of each peer, as publishers send them."""

    def __init__(self, fleet: FleetState) -> None:
        self.fleet, self.n = fleet, Counter[str]()

    def send(self, peer: str, kind: str, sequence: str, **fields: object) -> None:
        event = FleetEvent.model_validate(
            {"peer": peer, "n": self.n[peer], "t": T, "event": kind,
             "item": sequence_digest(sequence), "sequence": sequence, **fields}
        )  # fmt: skip
        self.n[peer] += 1
        self.fleet.event(event)


@pytest.mark.parametrize("flooders", [1, 3])
def test_the_honest_fleets_items_survive_peers_listing_junk(flooders: int) -> None:
    fleet = FleetState()
    page = Page(fleet)
    events = Events(fleet)
    liars = [f"junk{k}" for k in range(flooders)]
    for liar in liars:  # present, and listing the same valid junk: the table is full of it
        fleet.peer_joined(liar)
        fleet.catalog(liar, junk(fleet_module.MAX_ITEMS))
    assert len(fleet.items) == fleet_module.MAX_ITEMS and not fleet.drops
    # Then the honest fleet: a teacher serving the colours, ten robots learning them.
    fleet.peer_joined("t")
    fleet.catalog("t", COLOURS)
    for r in range(10):
        fleet.peer_joined(f"r{r}")
        for colour in COLOURS[: 1 + r % 4]:
            events.send(f"r{r}", "merged", colour, teacher="t")
    for liar in liars:  # and more junk, again and again: refused
        fleet.catalog(liar, junk(fleet_module.MAX_ITEMS, tag="K"))
    colours = {sequence_digest(c) for c in COLOURS}
    assert colours <= set(fleet.items)
    assert set(fleet.peers["t"].knows) == colours
    for r in range(10):
        assert set(fleet.peers[f"r{r}"].knows) == {sequence_digest(c) for c in COLOURS[: 1 + r % 4]}
    assert len(fleet.transfers) == sum(1 + r % 4 for r in range(10))
    # The colours took the place of four junk items; the rest of the junk was refused.
    assert fleet.drops == {"evicted": 4, "full": flooders * fleet_module.MAX_ITEMS}
    assert "known by" in fleet.stats()["reasons"]["evicted"][0]
    check(fleet)
    page.catch_up()
    assert page.state() == shown(fleet)


def test_an_item_only_named_never_takes_a_known_ones_place(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(fleet_module, "MAX_ITEMS", 4)
    fleet = FleetState()
    events = Events(fleet)
    fleet.catalog("t", COLOURS)
    for k, sequence in enumerate(junk(3)):
        events.send("mallory", "query-sent", sequence, id=f"q{k}")
    assert set(fleet.items) == {sequence_digest(c) for c in COLOURS}
    assert fleet.drops == {"full": 3}
    assert "named" in fleet.stats()["reasons"]["full"][0]


def test_equals_never_churn_and_the_heaviest_gives_way(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(fleet_module, "MAX_ITEMS", 4)
    fleet = FleetState()
    fleet.catalog("a", junk(2, "A"))
    fleet.catalog("b", junk(2, "B"))
    fleet.catalog("a", junk(3, "A"))  # a holds as much as b: its third is refused
    assert fleet.drops == {"full": 1} and len(fleet.peers["a"].knows) == 2
    assert "(it was looked at)" in fleet.stats()["reasons"]["full"][0]
    fleet.catalog("c", junk(1, "C"))  # a newcomer holding nothing takes a's oldest
    assert fleet.drops == {"full": 1, "evicted": 1}
    assert (
        sequence_digest("<c>(A0,x=0)") not in fleet.items
        and sequence_digest("<c>(C0,x=0)") in fleet.items
    )
    spread = [p["count"] for p in fleet.timeline if p["item"] == sequence_digest("<c>(A0,x=0)")]
    assert spread[-1] == 0  # the timeline says nobody knows it now


OPS = st.one_of(
    st.tuples(st.just("learn"), st.integers(0, 2), st.integers(0, 99)),
    st.tuples(st.just("forget"), st.integers(0, 2), st.integers(0, 99)),
    st.tuples(st.just("list"), st.integers(0, 2), st.just(0)),
    st.tuples(st.just("junk"), st.integers(0, 1), st.lists(st.integers(0, 60), max_size=30)),
    st.tuples(st.just("junk"), st.integers(0, 1), st.builds(list, st.just(range(30)))),
    st.tuples(st.just("share"), st.integers(0, 1), st.lists(st.integers(0, 99), max_size=8)),
    st.tuples(st.just("junk-merge"), st.integers(0, 1), st.integers(0, 60)),
    st.tuples(st.just("name"), st.integers(0, 1), st.integers(0, 60)),
    st.tuples(st.just("leave"), st.integers(0, 1), st.just(0)),
)


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    liars=st.integers(1, 2),
    pool=st.integers(1, 7),
    ops=st.lists(OPS, min_size=20, max_size=80),
)
def test_hostile_peers_never_crowd_out_the_honest_fleet(
    monkeypatch: pytest.MonkeyPatch, liars: int, pool: int, ops: list[tuple[str, int, Any]]
) -> None:
    """Three honest peers learn, list and forget items of a pool; one or two hostile peers list
    junk (or honest items), merge junk, name items in queries, come and go, in any order. With
    a table of 24 and a pool small enough for the liars' fair shares beside it (at most
    (24 - liars) / (liars + 1) items), every item an honest peer knows is in the table and
    shown as known by it, after every step; and the page's changes keep it equal to the
    snapshot."""
    monkeypatch.setattr(fleet_module, "MAX_ITEMS", 24)
    pool = min(pool, (24 - liars) // (liars + 1))
    honest = [f"<c>(Honest{k})" for k in range(pool)]
    fleet = FleetState()
    page = Page(fleet)
    events = Events(fleet)
    knows: dict[str, set[str]] = {f"h{k}": set() for k in range(3)}
    for op, who, what in ops:
        if op in ("learn", "forget", "list"):
            name = f"h{who}"
            if op == "learn":
                sequence = honest[what % pool]
                events.send(name, "merged", sequence, teacher=f"h{(who + 1) % 3}")
                knows[name].add(sequence)
            elif op == "forget" and knows[name]:
                sequence = sorted(knows[name])[what % len(knows[name])]
                events.send(name, "forgotten", sequence, reason="idle")
                knows[name].discard(sequence)
            elif op == "list":
                fleet.catalog(name, sorted(knows[name]))
        else:
            liar = f"liar{who % liars}"
            if op == "junk":
                fleet.catalog(liar, [f"<c>(J{k},x={k})" for k in what])
            elif op == "share":
                fleet.catalog(liar, [honest[k % pool] for k in what])
            elif op == "junk-merge":
                events.send(liar, "merged", f"<c>(M{what})", teacher="nobody")
            elif op == "name":
                events.send(liar, "query-sent", f"<c>(Q{what})", id=f"q{events.n[liar]}")
            elif op == "leave":
                fleet.peer_joined(liar)
                fleet.peer_left(liar)
        check(fleet)
        for name, sequences in knows.items():
            if sequences:
                assert {sequence_digest(s) for s in sequences} <= set(fleet.peers[name].knows), name
    event(f"table full: {len(fleet.items) == 24}, evicted: {fleet.drops['evicted'] > 0}")
    page.catch_up()
    assert page.state() == shown(fleet)


def test_names_that_only_sent_an_event_never_evict_a_present_peers_items() -> None:
    """Names are free without the access control: 511 of them merging one junk item each
    give way to one another, not to a peer whose liveliness token is up."""
    fleet = FleetState()
    events = Events(fleet)
    fleet.peer_joined("teacher")
    skills = [f"<c>(Skill{k},x={k})" for k in range(20)]
    fleet.catalog("teacher", skills)
    for k in range(511):
        events.send(f"s{k}", "merged", f"<c>(J{k},x={k})", teacher="x")
    assert set(fleet.peers["teacher"].knows) == {sequence_digest(s) for s in skills}
    assert len(fleet.items) == fleet_module.MAX_ITEMS and fleet.drops["evicted"] == 0
    check(fleet)


def test_a_trusted_name_outranks_a_present_one(monkeypatch: pytest.MonkeyPatch) -> None:
    """A name the trust store binds to a key, once an event signed by that key came (a catalog
    is not signed: before, it ranks as heard), takes the place of items known only by peers
    merely present, however light its load; theirs never take its place; when it leaves, its
    rank stays."""
    monkeypatch.setattr(fleet_module, "MAX_ITEMS", 4)
    me = Identity.generate()
    fleet = FleetState(TrustStore(frozenset({me.public}), {"trusted": me.public}))
    fleet.peer_joined("loud")
    fleet.catalog("loud", junk(2, "L"))
    fleet.peer_joined("quiet")
    fleet.catalog("quiet", junk(2, "Q"))
    fleet.catalog("trusted", junk(3, "T"))  # nothing signed yet: rank 0, refused
    assert fleet.drops == {"full": 3} and not fleet.peers["trusted"].knows
    one = FleetEvent(peer="trusted", n=0, t=T, event="query-sent", key=me.public)
    fleet.event(one.model_copy(update={"sig": me.sign(signed_bytes(one))}))
    fleet.catalog("trusted", junk(3, "T"))  # rank 2: takes items of rank 1, heaviest first
    assert fleet.drops == {"full": 3, "evicted": 3}
    assert len(fleet.peers["trusted"].knows) == 3
    fleet.peer_left("trusted")
    fleet.catalog("loud", junk(4, "L"))  # rank 1: none of the trusted one's, none of quiet's
    assert len(fleet.peers["trusted"].knows) == 3 and len(fleet.peers["quiet"].knows) == 1
    assert fleet.drops == {"evicted": 3, "full": 7}
    check(fleet)


def test_a_catalog_is_checked_before_the_lock_is_taken(monkeypatch: pytest.MonkeyPatch) -> None:
    """Parsing and digesting a catalog's entries is the costly part: done with the lock free,
    so the page's reads and other callbacks never wait on it."""
    fleet = FleetState()
    held: list[bool] = []

    def parse_watched(text: str) -> Any:
        held.append(fleet._lock.locked())
        return parse_sequence(text)

    monkeypatch.setattr(fleet_module, "parse_sequence", parse_watched)
    fleet.catalog("t", COLOURS)
    assert held == [False] * len(COLOURS) and len(fleet.peers["t"].knows) == len(COLOURS)
