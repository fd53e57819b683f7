"""What the fleet study makes of its runs, from summaries and histories written by hand (no
timing): the lease table (spec/protocol.md section 3) and the links dialled again; and the
``--lease`` option that the study gives every peer, refused in one line out of its range."""

from __future__ import annotations

import subprocess
import sys
from typing import Any

import pytest

from ktbt_proto.tools.cli.options import zenoh_settings
from ktbt_proto.tools.fleet.check import History, metrics
from ktbt_proto.tools.fleet.plan import FleetConfig
from ktbt_proto.tools.fleet.study import lease_lines, table
from tests.tools.fleet.test_check import base
from tests.zenoh_helpers import ROOT


def _summary(name: str, lease: int | None = None, **numbers: Any) -> dict[str, Any]:
    config: dict[str, Any] = {"peers": 10, "topology": "mesh"}
    if lease is not None:
        config["lease_ms"] = lease
    return {"name": name, "config": config, "verdicts": [], "load_before": 1.5, **numbers}


def _rows(lines: list[str]) -> dict[str, list[str]]:
    rows = [line.strip("|").split("|") for line in lines if line.startswith("| ")]
    return {cells[0].strip(): [c.strip() for c in cells[1:]] for cells in rows[2:]}


def test_the_lease_table_has_a_row_a_lease_with_its_cost_heal_delay_and_redials() -> None:
    summaries = [
        _summary("size-20", links_up=190, links_redialled=0,
                 keep_alive_rates={"1000": 7.8, "4000": 2.0, "10000": 0.8}),
        _summary("partition-30s", convergence_s=0.12, teacher_half_s=0.05),  # before --lease
        _summary("halves-10", lease=4000, teacher_half_s=0.08),
        _summary("partition-30s-lease-1s", 1000, convergence_s=0.3, teacher_half_s=0.2,
                 silent_link_given_up_s=1.3),
        _summary("partition-30s-lease-10s", 10000, convergence_s=None, teacher_half_s=0.1),
        _summary("size-20-lease-1s", 1000, links_up=190, links_redialled=12),
    ]  # fmt: skip
    rows = _rows(lease_lines(summaries))
    assert list(rows) == ["1 s", "4 s", "10 s"]
    assert rows["1 s"][:5] == ["7.8", "1.30", "0.30", "+0.12", "12 of 190 (size-20-lease-1s)"]
    assert rows["4 s"][:5] == ["2.0", "-", "0.12", "-0.03", "0 of 190 (size-20)"]
    assert rows["10 s"][:5] == ["0.8", "-", "-", "+0.02", "-"]  # not converged, no healthy run
    assert rows["1 s"][5] == "1.5/1.5"  # the load before each run the row reads
    assert "What the lease buys and costs" in "\n".join(table(summaries))


def test_without_lease_runs_or_rates_there_is_no_lease_table() -> None:
    assert lease_lines([_summary("size-5", links_up=10, links_redialled=0)]) == []


def test_a_link_up_again_is_a_redial_and_the_probes_own_link_is_not() -> None:
    events = base()
    end = events.pop()
    events += [
        {"t": 0.5, "kind": "link-up", "link": 0, "dialer": "p1", "listener": "p0"},
        {"t": 0.6, "kind": "link-up", "link": 1, "dialer": "t2", "listener": "p0"},
        {"t": 2.0, "kind": "link-up", "link": 0, "dialer": "p1", "listener": "p0"},
        {"t": 3.1, "kind": "probing"},
        {"t": 3.2, "kind": "link-up", "link": 1, "dialer": "t2", "listener": "p0"},
        end,
    ]
    found = metrics(History(events))
    assert (found["links_up"], found["links_redialled"]) == (2, 1)
    assert found["silent_link_given_up_s"] is None  # no silent partition


def test_a_silent_link_is_given_up_when_its_dialer_dials_through_the_held_link() -> None:
    events = base(partition=5.0)
    end = events.pop()
    events += [
        {"t": 2.0, "kind": "fault", "fault": "partition-silent", "phase": "start"},
        {"t": 1.5, "kind": "dialled-held", "link": 2},  # before the partition: not counted
        {"t": 6.0, "kind": "dialled-held", "link": 0},
        {"t": 6.5, "kind": "dialled-held", "link": 0},  # its second redial
        {"t": 7.0, "kind": "dialled-held", "link": 1},
        {"t": 8.0, "kind": "dialled-held", "link": 2},
        end,
    ]
    assert metrics(History(events))["silent_link_given_up_s"] == pytest.approx(5.0)


def _ktbt(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ktbt_proto", *args],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("command", "value", "says"),
    [
        ("run", "100", "greater than or equal to 500"),
        ("serve", "600001", "less than or equal to 600000"),
        ("router", "soon", "valid integer"),
    ],
)
def test_a_lease_out_of_range_is_one_line_naming_the_option(
    command: str, value: str, says: str
) -> None:
    done = _ktbt("peer", command, "--lease", value)
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stderr.startswith("error: --lease: ") and says in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


def test_the_lease_reaches_zenoh_with_four_keep_alives_a_lease() -> None:
    conf = zenoh_settings(None, None, None, False, lease_ms=1500).zenoh_config()
    assert conf.get_json("transport/link/tx/lease") == "1500"
    assert conf.get_json("transport/link/tx/keep_alive") == "4"


def test_an_unknown_scenario_is_refused_in_one_line() -> None:
    done = _ktbt("fleet", "study", "--only", "size-5,size-7")
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stderr.strip() == "error: --only: no such scenario: size-7"


def test_geometric_40_is_a_scenario_met_by_its_time_a_hop_and_the_hops_have_a_table() -> None:
    from ktbt_proto.tools.fleet.study import SCENARIOS

    params = {name: p for name, p, _ in SCENARIOS}["geometric-40"]
    FleetConfig(name="geometric-40", seed=7, **params)  # connected at the study's seed
    item = {"item": "A", "depth": 5, "eccentricity": 4, "last_at_eccentricity_s": 0.32,
            "per_hop_s": 0.08, "detours": 1, "off_graph": 0, "tree": {}}  # fmt: skip
    slow = {**item, "item": "B", "last_at_eccentricity_s": 0.6, "per_hop_s": 0.15}
    geometric = _summary(
        "geometric-40",
        convergence_s=0.7,
        hops=[item, slow],
        per_hop_s=0.15,
        eccentricity=4,
        tree_depth=5,
    )
    geometric["config"]["topology"] = "geometric"
    lines = table([geometric, _summary("size-5", convergence_s=0.1)])
    assert _met(lines) == "no"  # 0.15 s a hop, against at most 0.1
    assert any(
        line.startswith("- geometric-40") and "missed by 0.050 s a hop" in line for line in lines
    )
    hop_rows = [line for line in lines if line.startswith("| geometric-40 | geometric |")]
    assert hop_rows == [
        "| geometric-40 | geometric | 4 | 5 | 0.32 (0.080) / 0.60 (0.150) | 2 | 1.5 |"
    ]
    assert not any(line.startswith("| size-5 | mesh |") for line in lines)  # no hops recorded
    assert _met(table([{**geometric, "per_hop_s": 0.08}])) == "yes"


def _met(lines: list[str]) -> str:
    """The "met" cell of geometric-40's row in the scenario table."""
    row = next(line for line in lines if line.startswith("| geometric-40 | 10 | geometric |"))
    return row.strip("|").split("|")[5].strip()


def test_router_100_spreads_100_clients_over_5_routers_with_a_target() -> None:
    from ktbt_proto.tools.fleet.plan import make_plan
    from ktbt_proto.tools.fleet.study import LIMITS, SCENARIOS

    params = {name: p for name, p, _ in SCENARIOS}["router-100"]
    plan = make_plan(FleetConfig(name="router-100", seed=7, teacher="serve", **params), 1)
    assert len(plan.peers) == 100 and len(plan.routers) == 5
    served = [sum(1 for link in plan.links if link.listener == r.name and link.dialer[0] != "r")
              for r in plan.routers]  # fmt: skip
    assert served == [20] * 5
    assert LIMITS["router-100"] == 3.0 and LIMITS["router-100-partition-30s"] == 2.0
    cut = {name: p for name, p, _ in SCENARIOS}["router-100-partition-30s"]
    parted = make_plan(FleetConfig(name="cut", seed=7, teacher="serve", **cut), 1)
    assert [(li.dialer, li.listener) for li in parted.crossing()] == [("r3", "r2")]
    assert params["settle"] >= 5.0  # long enough for the idle table


def test_the_idle_table_has_a_row_a_role_and_the_target_on_the_learners() -> None:
    def idle(learner_cpu: float, window: float = 10.0) -> dict[str, Any]:
        return {
            "window_s": window,
            "cpu_ms_per_s": {"learner": {"median": learner_cpu, "worst": 9.0},
                             "router": {"median": 2.0, "worst": 2.5}},
            "rss_mb": {"learner": {"median": 48.0, "worst": 52.4},
                       "router": {"median": 53.0, "worst": 53.2}},
        }  # fmt: skip

    lines = table([_summary("router-100", convergence_s=1.0, idle=idle(2.5))])
    assert "| router-100 | learner | 2.5 / 9.0 | 48 / 52 | yes | 10.0 | 1.5 |" in lines
    assert "| router-100 | router | 2.0 / 2.5 | 53 / 53 | - | 10.0 | 1.5 |" in lines
    missed = table([_summary("router-100", convergence_s=1.0, idle=idle(3.5))])
    assert "| router-100 | learner | 3.5 / 9.0 | 48 / 52 | no | 10.0 | 1.5 |" in missed
    short = table([_summary("size-5", convergence_s=1.0, idle=idle(1.0, window=1.0))])
    assert not any(line.startswith("| size-5 | learner |") for line in short)


@pytest.mark.network
def test_one_idle_peer_alone_is_measured_and_set_against_its_target() -> None:
    from ktbt_proto.tools.fleet.study import idle_alone

    alone = idle_alone(seconds=2.0, settle=0.5)
    assert set(alone) == {"peer", "router"}, alone
    for cost in alone.values():
        assert cost["cpu_ms_per_s"] >= 0 and 5 < cost["rss_mb"] < 2_000, alone
    summary = _summary("size-5", convergence_s=0.1, idle_alone={**alone, "load_before": 2.0})
    line = next(line for line in table([summary]) if line.startswith("One idle peer alone"))
    assert f"{alone['peer']['rss_mb']:.1f} MB RSS" in line and "load average 2.0" in line
    cheap = {"peer": {"cpu_ms_per_s": 2.0, "rss_mb": 40.0}, "load_before": 1.0}
    line = next(ln for ln in table([{**summary, "idle_alone": cheap}]) if "idle peer alone" in ln)
    assert "against a target of 3 ms and 50 MB: met" in line
