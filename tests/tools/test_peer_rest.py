"""A ``ktbt peer run`` robot at rest (spec/protocol.md section 4.5, ``tools.peer.Rest``): it
steps at its rest rate only when its member is settled and its tree quiet (pure leaves, no
timers) and steady, over real zenoh sessions on loopback; anything that arrives wakes it, and
a change of the blackboard, something to learn or a leaf that is not pure keeps it at its full
rate."""

from __future__ import annotations

import math
import time
from contextlib import ExitStack
from dataclasses import replace

import pytest

from ktbt_proto.exchange.application import ApplicationTimedAgent
from ktbt_proto.exchange.knowledge import KnowledgeBase, with_knowledge
from ktbt_proto.exchange.member import FleetMember
from ktbt_proto.files import packaged
from ktbt_proto.items import sequence_key
from ktbt_proto.registry import Registry
from ktbt_proto.status import RUNNING, Status
from ktbt_proto.syntax import parse
from ktbt_proto.tools.demo import DEMO_CONTROL, demo_registry
from ktbt_proto.tools.peer import STEADY_STEPS, Rest, quiet
from ktbt_proto.transport.zenoh import ZenohTransport
from tests.zenoh_helpers import free_port, settings, wait_until

GREEN = sequence_key(["TargetSeen(colour=2)"])
BLUE = sequence_key(["TargetSeen(colour=3)"])
COLOURS = KnowledgeBase.from_tree(
    parse(packaged("examples", "knowledge", "colours.sbt").read_text())
)


def test_a_tree_is_quiet_when_every_leaf_is_pure_and_no_timer_counts() -> None:
    reg = demo_registry()
    assert quiet(parse(DEMO_CONTROL), reg)
    assert not quiet(parse("<sl><w>(3)<a>(RandomWalk)<e>"), reg)  # a wait counts ticks
    assert not quiet(parse("<sl><tt1>(5)<a>(RandomWalk)<e><e>"), reg)

    @reg.action("Drive")
    def drive(bb: object) -> Status:  # acts on the world: not declared pure
        return RUNNING

    assert not quiet(parse("<sl><k>(new)<e><a>(Drive)<e>"), reg)
    declared = Registry()
    declared.flags("Carrying")
    declared.declare("action", "Elsewhere")  # a vocabulary file's: fails here, always
    assert quiet(parse("<sq><c>(Carrying)<a>(Elsewhere)<e>"), declared)

    class Stateful:
        def __init__(self, bb: object) -> None:
            self.n = 0

        def tick(self) -> Status:
            self.n += 1
            return RUNNING

    with pytest.raises(TypeError, match="cannot be pure"):  # keeps state: never pure
        declared.add_action("Counter", Stateful, pure=True)
    declared.add_action("Counter", Stateful)
    assert not declared.pure("action", "Counter")


PERIOD, RESTING = 0.01, 0.5


def _step(robot: ApplicationTimedAgent, member: FleetMember, rest: Rest) -> bool:
    """One step as ``ktbt peer run`` takes it; whether it may then wait longer than a period."""
    robot.now += 1
    now = time.monotonic()
    return rest.after(member.step(now), now) > PERIOD


@pytest.mark.network
def test_a_settled_robot_rests_once_steady_and_anything_keeps_it_at_full_rate() -> None:
    with ExitStack() as stack:
        port = free_port()
        transport = stack.enter_context(ZenohTransport("rester", settings(port), query_timeout=2.0))
        robot = ApplicationTimedAgent(
            "rester", with_knowledge(DEMO_CONTROL, COLOURS), demo_registry(), transport
        )
        member = FleetMember(robot, transport, None, [GREEN], 2.0, 0.5, lambda _: None)
        rest = Rest(robot, member, PERIOD, RESTING)
        rested = [_step(robot, member, rest) for _ in range(STEADY_STEPS + 1)]
        assert member.due(time.monotonic()) == math.inf  # settled: no timed act
        assert rested[-1] and not any(rested[: STEADY_STEPS - 1])

        robot.blackboard["target"] = 2  # it picks and delivers, again and again: never at rest
        assert not any(_step(robot, member, rest) for _ in range(3 * STEADY_STEPS))
        assert robot.blackboard["delivered"] > STEADY_STEPS
        del robot.blackboard["target"]  # it delivers what it carries, then walks: at rest
        rested = [_step(robot, member, rest) for _ in range(STEADY_STEPS + 3)]
        assert rested[-1] and not rested[0]

        robot.blackboard["seen"] = []  # a list a leaf could append to: cannot tell, no rest
        assert not any(_step(robot, member, rest) for _ in range(3 * STEADY_STEPS))
        del robot.blackboard["seen"]
        assert [_step(robot, member, rest) for _ in range(STEADY_STEPS + 1)][-1]

        rest.stirred()  # something arrived: full rate again at once
        assert not _step(robot, member, rest)

        robot.memory = replace(robot.memory, expire_after=10_000)  # counts ticks: no rest
        assert not any(_step(robot, member, rest) for _ in range(3 * STEADY_STEPS))


@pytest.mark.network
def test_a_learner_waiting_for_a_teacher_rests_until_its_next_timed_ask() -> None:
    """Something to learn and nobody to teach it: its tree is steady, so it waits until its
    member's next timed act (the open query's wait over, then the backoff's next ask), not a
    tick period, and no longer than its rest."""
    with ZenohTransport("waiter", settings(free_port()), query_timeout=2.0) as transport:
        robot = ApplicationTimedAgent("waiter", DEMO_CONTROL, demo_registry(), transport)
        member = FleetMember(robot, transport, None, [GREEN], 2.0, 0.5, lambda _: None)
        rest = Rest(robot, member, PERIOD, 60.0)
        waits = []
        for _ in range(STEADY_STEPS + 1):
            robot.now += 1
            now = time.monotonic()
            waits.append(rest.after(member.step(now), now))
        query = robot.open_query
        assert query is not None and waits[0] == PERIOD  # it asked at once, at full rate
        opened = member.learner.opened
        assert member.due(now) == opened + 2.0  # the query's wait
        assert waits[-1] == pytest.approx(opened + 2.0 - now)

        later = opened + 2.0  # its wait is over: closed, unanswered; the backoff holds it back
        wait = rest.after(member.step(later), later)
        until = member.learner.backoff.until
        assert robot.open_query is None and until >= later + 0.5 + 0.25
        assert member.due(later) == until and wait == pytest.approx(until - later)
        wait = rest.after(member.step(until), until)  # it asks again when the hold is over
        assert robot.open_query is not None and robot.open_query.id != query.id
        assert wait == pytest.approx(2.0)
        assert Rest(robot, member, PERIOD, RESTING).after([], until) == PERIOD  # not steady yet


@pytest.mark.network
def test_a_peer_that_appears_wakes_a_resting_robot() -> None:
    pa, pb = free_port(), free_port()
    with ZenohTransport("sleeper", settings(pa), query_timeout=2.0) as transport:
        transport.appeared()
        transport.stirred.clear()
        with ZenohTransport("newcomer", settings(pb, pa), query_timeout=2.0):
            assert transport.stirred.wait(15), "no wake when a peer appeared"
            assert wait_until(lambda: "newcomer" in transport.appeared())


@pytest.mark.network
def test_a_resting_learner_asks_at_once_when_a_teacher_appears() -> None:
    """A learner that knows what it meets rests; told another, and a teacher appears, it is
    woken (the host steps it at full rate again) and learns it: its tree runs what it
    learned."""
    pl, pt = free_port(), free_port()
    with ExitStack() as stack:
        transport = stack.enter_context(ZenohTransport("learner", settings(pl), query_timeout=2.0))
        robot = ApplicationTimedAgent("learner", DEMO_CONTROL, demo_registry(), transport)
        member = FleetMember(robot, transport, None, [], 2.0, 0.5, lambda _: None)
        rest = Rest(robot, member, PERIOD, RESTING)
        assert any(_step(robot, member, rest) for _ in range(STEADY_STEPS + 5)), "never at rest"
        member.meet([GREEN])
        teacher_net = stack.enter_context(
            ZenohTransport("teacher", settings(pt, pl), query_timeout=2.0)
        )
        ApplicationTimedAgent(
            "teacher", with_knowledge(DEMO_CONTROL, COLOURS), demo_registry(), teacher_net
        )

        woken = []

        def learned() -> bool:  # each poll one step, as a host's tick
            if transport.stirred.is_set():  # as `ktbt peer run` does at each step
                rest.stirred()
                transport.stirred.clear()
                woken.append(_step(robot, member, rest))
            else:
                _step(robot, member, rest)
            return robot.knows([GREEN])

        assert wait_until(learned, seconds=20), f"todo {member.todo}"
        assert woken and not any(woken)  # each step after an arrival at full rate
        robot.blackboard["target"] = 2
        robot.control.tick()
        assert robot.blackboard.get("Carrying") is True  # the learned item ran: it picked
        assert BLUE not in member.todo
