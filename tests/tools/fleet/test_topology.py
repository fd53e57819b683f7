"""Fleets shaped like real ones, as plans (pure: no process): a random geometric graph whose
every pair within the radio range is a link and nothing else, a grid, an edge-list file; the
newer peer of every link dials; the same seed gives the same fleet; a graph that is not
connected, and every bad edge-list file, refused in one line; and the hops from the teacher
(routers are no hop) that the checker measures knowledge against."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import networkx as nx
import pytest

from ktbt_proto.tools.fleet.plan import (
    INSTALL,
    FleetConfig,
    PlanError,
    distances,
    make_plan,
    neighbours,
    positions,
)


def _pairs(config: FleetConfig) -> set[tuple[int, int]]:
    plan = make_plan(config, 1)
    index = {n.name: n.index for n in plan.peers}
    return {(index[li.dialer], index[li.listener]) for li in plan.links}


def _refusal(**config: object) -> str:
    with pytest.raises(PlanError) as caught:
        FleetConfig(**config)  # type: ignore[arg-type]
    message = str(caught.value)
    assert "\n" not in message
    return message


def test_a_geometric_graph_links_exactly_the_peers_within_the_radius() -> None:
    config = FleetConfig(peers=40, topology="geometric", radius=0.2, seed=7)
    placed = positions(config)
    within = {(i, j) for i in range(40) for j in range(i) if math.dist(placed[i], placed[j]) <= 0.2}
    assert _pairs(config) == within  # and the newer (higher) peer of each pair dials
    plan = make_plan(config, 1)
    assert set(plan.positions) == {n.name for n in plan.peers}
    assert nx.is_connected(nx.Graph(list(within)))
    both = make_plan(FleetConfig(peers=40, topology="geometric", radius=0.2, dial="both"), 1)
    assert len(both.links) == 2 * len(within)


def test_the_same_seed_places_the_same_fleet_and_another_seed_another() -> None:
    a = make_plan(FleetConfig(peers=30, topology="geometric", radius=0.3, seed=3), 1)
    b = make_plan(FleetConfig(peers=30, topology="geometric", radius=0.3, seed=3), 1)
    c = make_plan(FleetConfig(peers=30, topology="geometric", radius=0.3, seed=4), 1)
    assert a.to_json() == b.to_json()
    assert a.positions != c.positions and a.to_json()["links"] != c.to_json()["links"]


def test_a_graph_that_is_not_connected_is_refused_naming_the_radius() -> None:
    message = _refusal(peers=40, topology="geometric", radius=0.1, seed=7)
    assert "not connected" in message and "--radius" in message
    assert "needs --radius" in _refusal(peers=10, topology="geometric")
    assert "--radius" in _refusal(peers=10, radius=0.2)  # a radius with another topology
    assert "--radius" in _refusal(peers=10, topology="geometric", radius=float("nan"))
    assert "--radius" in _refusal(peers=10, topology="geometric", radius=-1.0)


def test_a_grid_is_as_square_as_the_peers_allow_filled_row_by_row() -> None:
    nine = _pairs(FleetConfig(peers=9, topology="grid"))
    assert len(nine) == 12  # 3 x 3: 2 x 3 across, 2 x 3 down
    assert {(1, 0), (3, 0), (4, 1), (4, 3), (8, 7), (8, 5)} <= nine
    assert (2, 3) not in nine and (3, 2) not in nine  # no wrap from one row to the next
    ten = make_plan(FleetConfig(peers=10, topology="grid"), 1)  # 4 columns, the last row 2
    assert _pairs(FleetConfig(peers=10, topology="grid")) == {
        (1, 0), (2, 1), (3, 2), (5, 4), (6, 5), (7, 6), (9, 8),
        (4, 0), (5, 1), (6, 2), (7, 3), (8, 4), (9, 5),
    }  # fmt: skip
    hops = distances(ten.to_json())  # the teacher is peer 9, on the last row
    assert hops["t9"] == 0 and hops["p5"] == 1 and hops["p3"] == 4 and max(hops.values()) == 4


def test_an_edge_list_file_becomes_the_links(tmp_path: Path) -> None:
    path = tmp_path / "line.txt"
    # networkx's own writers: plain pairs, pairs with data, weighted pairs; comments
    path.write_text("# a line of 5\n0 1\n2 1 {'weight': 2}\n2 3 0.5\n\n3 4  # last\n")
    config = FleetConfig(peers=5, topology="edges", edges=str(path))
    assert _pairs(config) == {(1, 0), (2, 1), (3, 2), (4, 3)}
    plan = make_plan(config, 1)
    assert distances(plan.to_json()) == {"t4": 0, "p3": 1, "p2": 2, "p1": 3, "p0": 4}
    written = tmp_path / "written.txt"
    nx.write_edgelist(nx.cycle_graph(6), written, data=False)
    assert len(_pairs(FleetConfig(peers=6, topology="edges", edges=str(written)))) == 6


@pytest.mark.parametrize(
    ("text", "said"),
    [
        ("0 1\n1 x\n", ":2: not a pair of peer indices"),
        ("0 1\n1 7\n", ":2: peer 7 is not one of the 3 peers (0 to 2)"),
        ("0 1\n-1 2\n", ":2: peer -1 is not one of the 3 peers"),
        ("0 1\n2 2\n", ":2: peer 2 linked to itself"),
        ("0 1\n2\n", ":2: one peer, not a pair"),
        ("0 1\n", "is not connected (2 parts; peers 2 cannot reach peer 0): link every peer"),
        ("", "is not connected (3 parts"),
    ],
)
def test_a_bad_edge_list_is_refused_in_one_line_naming_its_line(
    tmp_path: Path, text: str, said: str
) -> None:
    path = tmp_path / "edges.txt"
    path.write_text(text)
    message = _refusal(peers=3, topology="edges", edges=str(path))
    assert said in message and str(path) in message


def test_an_edge_list_that_cannot_be_read_is_refused_in_one_line(tmp_path: Path) -> None:
    assert "No such file" in _refusal(peers=3, topology="edges", edges=str(tmp_path / "none"))
    binary = tmp_path / "binary.txt"
    binary.write_bytes(b"0 1\n\xff\xfe 2\n")
    assert "not UTF-8" in _refusal(peers=3, topology="edges", edges=str(binary))
    big = tmp_path / "big.txt"
    big.write_text("0 1\n" * 300_000)
    assert "larger than" in _refusal(peers=3, topology="edges", edges=str(big))
    assert "needs --edges" in _refusal(peers=3, topology="edges")
    assert "--edges" in _refusal(peers=3, edges=str(big))


def test_without_networkx_the_shaped_topologies_name_the_extra(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(sys.modules, "networkx", None)  # import networkx raises ImportError
    assert _refusal(peers=9, topology="grid") == INSTALL
    assert "ktbt[fleet]" in INSTALL
    assert len(make_plan(FleetConfig(peers=5, topology="line"), 1).links) == 4  # no networkx


def test_hops_count_peers_and_a_router_is_no_hop() -> None:
    router = make_plan(FleetConfig(peers=40, topology="router", routers=2), 1).to_json()
    near = neighbours(router)
    assert all(len(others) == 39 for others in near.values())  # through both routers
    assert set(distances(router).values()) == {0, 1}
    line = make_plan(FleetConfig(peers=4, topology="line"), 1).to_json()
    assert distances(line) == {"t3": 0, "p2": 1, "p1": 2, "p0": 3}
    two = make_plan(FleetConfig(peers=5, teachers=2, topology="line"), 1).to_json()
    assert distances(two) == {"t3": 0, "t4": 0, "p2": 1, "p1": 2, "p0": 3}


def test_a_partition_through_routers_cuts_the_chain_between_router_groups() -> None:
    plan = make_plan(FleetConfig(peers=100, topology="router", routers=5, partition=30), 1)
    assert [(li.dialer, li.listener) for li in plan.crossing()] == [("r3", "r2")]
    own = {li.dialer: li.listener for li in plan.links if li.dialer[0] != "r"}
    assert all(plan.half[peer] == plan.half[router] for peer, router in own.items())
    assert plan.half["t99"] == 0 == plan.half["r4"]  # the teacher's group, r3 and r4
    assert sum(plan.half[p.name] == 0 for p in plan.peers) == 40
    two = make_plan(FleetConfig(peers=6, topology="router", routers=2, partition=8), 1)
    assert [(li.dialer, li.listener) for li in two.crossing()] == [("r1", "r0")]
    with pytest.raises(PlanError, match="--routers 2 or more"):
        FleetConfig(peers=10, topology="router", routers=1, partition=8)
