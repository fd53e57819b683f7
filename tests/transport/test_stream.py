"""The stream of in-memory agents (``ktbt_proto.transport.stream``), as a simulator run watched
by the monitor uses it (spec/protocol.md section 10): `ktbt sim view
--publish-events`, headless, streams its robots' events, catalogs and trees to a real
:class:`Listener`, whose matrix ends equal to what the robots know, learned from whom, with one
transfer a merge. What the robots know is read off the same run replayed in this process (a
run is set by its scenario and seed)."""

from __future__ import annotations

import contextlib
import re
import subprocess
import sys
import threading
from collections import Counter
from dataclasses import replace
from typing import Any

import pytest

from ktbt_proto.exchange.transferlog import TransferLog
from ktbt_proto.items import sequence_digest
from ktbt_proto.tools.monitor.listen import Listener
from ktbt_proto.tools.monitor.state import FleetState
from ktbt_proto.transport.stream import AgentStream
from ktbt_proto.transport.zenoh import ZenohSettings, catalog_replies, open_session
from tests.zenoh_helpers import endpoint, free_port, ktbt_process, wait_until

pytestmark = [pytest.mark.network, pytest.mark.slow]  # a simulator process and zenoh sessions

ITERATIONS = 400  # the ktbt preset's robots have merged about ten items by then (seed 0)


def replay(iterations: int) -> tuple[Any, list[dict[str, Any]]]:
    """The run of ``ktbt sim view ktbt`` (seed 0) in this process, and its merges."""
    from ktbt_sim.scenario import PRESETS
    from ktbt_sim.world import World

    world = World(PRESETS["ktbt"], seed=0)
    merges: list[dict[str, Any]] = []
    for agent in world.agents:
        log = TransferLog(None)
        agent.security = replace(agent.security, log=log)
        log.add_sink(lambda e: merges.append(e) if e["event"] == "merged" else None)
    world.run(iterations)
    return world, merges


def matrix(fleet: FleetState) -> dict[str, dict[str, str | None]]:
    """Who knows what on the monitor, and from whom (None: known from the start)."""
    return {
        name: {
            item: known.get("teacher") if known["how"] == "learned" else None
            for item, known in peer.knows.items()
        }
        for name, peer in fleet.peers.items()
    }


def catalogs(session: Any) -> dict[str, set[str]]:
    """What each agent's catalog queryable (``ktbt/v1/catalog/<name>``) answers now."""
    return {
        name: {entry["sequence"] for entry in entries}
        for name, entries in catalog_replies(session, timeout=5)
    }


def test_a_simulator_run_streams_to_the_monitor_what_its_robots_know(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")  # headless: SDL draws into nothing
    monkeypatch.setenv("SDL_AUDIODRIVER", "dummy")
    port = free_port()
    fleet = FleetState()
    with ktbt_process(  # on any address, and for longer than a thread can wait: for ever
        "sim", "view", "ktbt", "--iterations", str(ITERATIONS),
        "--publish-events", f"tcp/0.0.0.0:{port}", "--wait-monitor", "1e10",
        ready=f"waiting for a monitor: ktbt monitor --connect {endpoint(port)}", timeout=120,
    ) as proc:  # fmt: skip
        listener = Listener(fleet, ZenohSettings(connect=[endpoint(port)]))
        try:
            assert proc.wait(timeout=120) == 0
            assert proc.stdout is not None
            said = proc.stdout.read()
            assert "no monitor yet" not in said  # the monitor saw the run from its start
            sent = re.search(r"streamed ([\d,]+) events of 40 robots, 0 dropped", said)
            assert sent is not None, said
            # Every event the robots sent reaches the monitor, the last ones too.
            assert wait_until(lambda: fleet.events == int(sent.group(1).replace(",", "")))
        finally:
            listener.close()
    world, merges = replay(ITERATIONS)
    assert len(merges) >= 5
    truth = {
        agent.name: {sequence_digest(k.key): k.source for k in agent.knowledge}
        for agent in world.agents
    }
    assert not fleet.drops and all(p.lost_events == 0 for p in fleet.peers.values())
    assert matrix(fleet) == truth
    transfers = Counter((t["learner"], t["teacher"], t["item"]) for t in fleet.transfers)
    assert transfers == Counter(
        (m["peer"], m["teacher"], sequence_digest(m["sequence"])) for m in merges
    )
    for agent in world.agents:
        assert agent.log is not None
        assert (
            sum(1 for t in fleet.transfers if t["learner"] == agent.name)
            == (agent.log.counts["merged"])
        )
    assert {p.status for p in fleet.peers.values()} == {"heard"}  # no liveliness token


@pytest.mark.parametrize("wait", ["-1", "nan"])
def test_a_wait_for_a_monitor_is_a_number_of_seconds(wait: str) -> None:
    run = subprocess.run(
        [sys.executable, "-m", "ktbt_proto", "sim", "view", "ktbt", "--record", "out.gif",
         "--publish-events", "tcp/127.0.0.1:1", "--wait-monitor", wait],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert run.returncode == 2
    assert f"--wait-monitor {float(wait)}: use a number of seconds of at least 0" in run.stderr


def test_a_stream_waits_for_a_monitor_and_serves_the_agents_trees() -> None:
    """In process: no monitor, no watching; a listener reads the catalogs and gets the trees,
    and the matrix follows the run as it goes."""
    from ktbt_proto.render import render

    world, _ = replay(0)
    port = free_port()
    with contextlib.ExitStack() as stack:
        stream = stack.enter_context(
            AgentStream(world.agents, ZenohSettings(listen=[endpoint(port)]))
        )
        assert not stream.wait_watched(0.2)  # nobody subscribes
        known_before = {a.name: {k.key for k in a.knowledge} for a in world.agents}
        reader = open_session(ZenohSettings(connect=[endpoint(port)]))
        stack.callback(reader.close)
        watched: list[bool] = []  # longer than a thread can wait: for ever
        waiter = threading.Thread(target=lambda: watched.append(stream.wait_watched(1e10)))
        waiter.daemon = True
        waiter.start()
        fleet = FleetState()
        listener = Listener(fleet, ZenohSettings(connect=[endpoint(port)]))
        stack.callback(listener.close)
        waiter.join(30)
        assert watched == [True]
        tree = world.agents[0].control.tree
        assert listener.tree("r0") == render(tree)
        world.run(ITERATIONS)
        truth = {
            a.name: {sequence_digest(k.key): k.source for k in a.knowledge} for a in world.agents
        }
        assert wait_until(lambda: matrix(fleet) == truth, 10)
        assert listener.tree("r0") == render(world.agents[0].control.tree)
        # Each agent's catalog says what it knows now, its merges too.
        known = {a.name: {k.key for k in a.knowledge} for a in world.agents}
        assert any(len(v) > len(known_before[n]) for n, v in known.items())
        assert wait_until(lambda: catalogs(reader) == known, 10)
