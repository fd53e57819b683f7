"""The fleet member (spec/protocol.md section 4.5), driven one step at a time as every host
drives it (``ktbt peer run``'s sleep loop, the ROS 2 lifecycle node's timer, an embedded
robot's timer), over real zenoh sessions on loopback: what its catalogs list is met, a teacher
that appears is asked at once, what it learned is reported once and exported, a catalog entry
it cannot read is the agent's refusal, and a host that ticks the tree itself is left to."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager

import pytest

from ktbt_proto.exchange.application import ApplicationTimedAgent
from ktbt_proto.exchange.knowledge import KnowledgeBase, with_knowledge
from ktbt_proto.exchange.member import FleetMember
from ktbt_proto.files import packaged
from ktbt_proto.items import sequence_key
from ktbt_proto.runtime import LiveTree
from ktbt_proto.syntax import parse
from ktbt_proto.tools.demo import DEMO_CONTROL, demo_registry
from ktbt_proto.transport.zenoh import ZenohCatalogs, ZenohTransport
from tests.zenoh_helpers import free_port, settings

pytestmark = pytest.mark.network  # zenoh sessions on loopback

GREEN = sequence_key(["TargetSeen(colour=2)"])
COLOURS = KnowledgeBase.from_tree(
    parse(packaged("examples", "knowledge", "colours.sbt").read_text())
)


class Synced:
    """What follows the member's knowledge (the BT.CPP export's place): the keys it was shown."""

    def __init__(self) -> None:
        self.seen: list[set[str]] = []

    def sync(self, knowledge: KnowledgeBase) -> None:
        self.seen.append({item.key for item in knowledge})


@contextmanager
def robot(
    name: str, port: int, *connect: int, knowledge: KnowledgeBase | None = None
) -> Iterator[tuple[ApplicationTimedAgent, ZenohTransport]]:
    """The demo robot on a zenoh session of its own (it answers at once from what it knows)."""
    with ZenohTransport(name, settings(port, *connect), query_timeout=2.0) as transport:
        control = with_knowledge(DEMO_CONTROL, knowledge)
        yield ApplicationTimedAgent(name, control, demo_registry(), transport), transport


def steps(member: FleetMember, until: object, seconds: float = 20) -> None:
    """Step the member as a host does (its clock, then a step) until ``until()`` holds."""
    deadline = time.monotonic() + seconds
    while not until():  # type: ignore[operator]
        assert time.monotonic() < deadline, f"{member.name}: todo {member.todo}"
        member.agent.now += 1
        member.step(time.monotonic())
        time.sleep(0.01)


def test_a_member_told_nothing_meets_what_the_catalogs_list_and_reports_it_once() -> None:
    pt, pl = free_port(), free_port()
    said: list[str] = []
    export = Synced()
    with ExitStack() as stack:
        teacher, _ = stack.enter_context(robot("teacher", pt, knowledge=COLOURS))
        learner, network = stack.enter_context(robot("learner", pl, pt))
        member = FleetMember(
            learner, network, ZenohCatalogs(network), None,
            wait=2.0, cooldown=0.5, say=said.append, export=export,
        )  # fmt: skip
        assert not member.done  # nothing listed yet: not done
        steps(member, lambda: member.done)
        assert {item.key for item in learner.knowledge} == {item.key for item in COLOURS}
        assert member.listed is not None and sorted(member.listed.found) == sorted(
            item.key for item in COLOURS
        )
        learned = [line for line in said if " learned " in line]
        assert len(learned) == 4 and all("from teacher" in line for line in learned)
        assert export.seen[-1] == {item.key for item in COLOURS}
        before = len(said)
        for _ in range(5):  # nothing new: nothing said again
            learner.now += 1
            member.step(time.monotonic())
        assert [line for line in said[before:] if " learned " in line] == []
        assert teacher.metrics.refused == 0 and member.refused == 0


def test_a_member_told_a_sequence_asks_a_teacher_that_appears_and_forgets_on_request() -> None:
    pt, pl = free_port(), free_port()
    with ExitStack() as stack:
        learner, network = stack.enter_context(robot("learner", pl, pt))
        member = FleetMember(
            learner, network, None, [GREEN], wait=30.0, cooldown=30.0, say=lambda _: None
        )
        learner.now += 1
        member.step(time.monotonic())  # asks; nobody there
        assert member.todo == [GREEN]
        stack.enter_context(robot("teacher", pt, pl, knowledge=COLOURS))
        # The teacher appearing is enough: the open query goes to it at once, long before the
        # 30 s wait or cool-down would let the member ask again.
        steps(member, lambda: member.done, seconds=15)
        assert learner.knows(GREEN) and member.todo == []
        assert learner.forget(GREEN) and not learner.knows(GREEN)
        member.forgot(GREEN)
        learner.now += 1
        member.step(time.monotonic())
        assert member.todo == []  # forgotten, not met again unless told
        member.tell([GREEN])
        steps(member, lambda: learner.knows(GREEN), seconds=15)


def test_a_catalog_entry_it_cannot_read_is_the_agents_refusal() -> None:
    pt, pl = free_port(), free_port()
    with ExitStack() as stack:
        hostile = stack.enter_context(
            ZenohTransport(
                "hostile", settings(pt), catalog=lambda: [{"sequence": "<c>true."}, {"x": 1}]
            )
        )
        learner, network = stack.enter_context(robot("learner", pl, pt))
        member = FleetMember(
            learner, network, ZenohCatalogs(network), None, wait=2.0, cooldown=0.5,
            say=lambda _: None,
        )  # fmt: skip
        deadline = time.monotonic() + 15
        while member.listed is not None and "<c>true." not in member.listed.skipped:
            assert time.monotonic() < deadline
            member.step(time.monotonic())
            time.sleep(0.05)
        assert hostile.refused == 0 and member.todo == [] and not member.done


def test_a_host_that_ticks_the_tree_itself_is_left_to_it() -> None:
    pl = free_port()
    with robot("learner", pl) as (learner, network):
        member = FleetMember(
            learner, network, None, [], wait=2.0, cooldown=0.5, say=lambda _: None,
            ticks_control=False,
        )  # fmt: skip
        live = learner.control
        assert isinstance(live, LiveTree)
        for _ in range(3):
            member.step(time.monotonic())
        assert member.done and learner.metrics.queries_sent == 0
        assert live.ticks == 0  # the host's to tick
        ticking = FleetMember(learner, network, None, [], 2.0, 0.5, lambda _: None)
        ticking.step(time.monotonic())
        assert live.ticks == 1
