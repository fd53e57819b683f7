"""A ``ktbt peer run`` robot at rest (spec/protocol.md section 4.5, ``tools.peer.Rest``): it
steps at its rest rate only when its member is settled and its tree quiet (pure leaves, no
timers) and steady, over real zenoh sessions on loopback; anything that arrives wakes it, and
a change of the blackboard, something to learn or a leaf that is not pure keeps it at its full
rate."""

from __future__ import annotations

import time
from contextlib import ExitStack

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


def _step(robot: ApplicationTimedAgent, member: FleetMember, rest: Rest) -> bool:
    robot.now += 1
    return rest.after(member.step(time.monotonic()))


@pytest.mark.network
def test_a_settled_robot_rests_once_steady_and_anything_keeps_it_at_full_rate() -> None:
    with ExitStack() as stack:
        port = free_port()
        transport = stack.enter_context(ZenohTransport("rester", settings(port), query_timeout=2.0))
        robot = ApplicationTimedAgent(
            "rester", with_knowledge(DEMO_CONTROL, COLOURS), demo_registry(), transport
        )
        member = FleetMember(robot, transport, None, [GREEN], 2.0, 0.5, lambda _: None)
        rest = Rest(robot, member)
        rested = [_step(robot, member, rest) for _ in range(STEADY_STEPS + 1)]
        assert member.settled and rested[-1] and not any(rested[: STEADY_STEPS - 1])

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

        member.meet(["TargetSeen(colour=9)"])  # something to learn: never at rest
        assert not any(_step(robot, member, rest) for _ in range(STEADY_STEPS + 2))


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
    """A learner told a sequence it lacks is never at rest; one that knows it rests, and when
    it is told another and a teacher appears, it learns it: its tree runs what it learned."""
    pl, pt = free_port(), free_port()
    with ExitStack() as stack:
        transport = stack.enter_context(ZenohTransport("learner", settings(pl), query_timeout=2.0))
        robot = ApplicationTimedAgent("learner", DEMO_CONTROL, demo_registry(), transport)
        member = FleetMember(robot, transport, None, [], 2.0, 0.5, lambda _: None)
        rest = Rest(robot, member)
        assert any(_step(robot, member, rest) for _ in range(STEADY_STEPS + 5)), "never at rest"
        member.meet([GREEN])
        teacher_net = stack.enter_context(
            ZenohTransport("teacher", settings(pt, pl), query_timeout=2.0)
        )
        ApplicationTimedAgent(
            "teacher", with_knowledge(DEMO_CONTROL, COLOURS), demo_registry(), teacher_net
        )

        def learned() -> bool:  # each poll one step, as a host's tick
            assert not _step(robot, member, rest)  # learning: full rate throughout
            return robot.knows([GREEN])

        assert wait_until(learned, seconds=20), f"todo {member.todo}"
        robot.blackboard["target"] = 2
        robot.control.tick()
        assert robot.blackboard.get("Carrying") is True  # the learned item ran: it picked
        assert BLUE not in member.todo
