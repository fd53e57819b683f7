"""Overhearing (spec/protocol.md section 4.3): answers to others' queries learned at once
(``update``), kept and used when needed without a query (``buffer``), or refused (``off``);
never trusted more than a direct answer."""

from __future__ import annotations

import ktbt_proto as kp
from ktbt_proto.exchange.agent import Agent
from ktbt_proto.exchange.application import ApplicationTimedAgent
from ktbt_proto.exchange.knowledge import KnowledgeBase
from ktbt_proto.exchange.messages import Response
from ktbt_proto.exchange.overhearing import Overhear, Overhearing, ServerOverhearing
from ktbt_proto.exchange.security import Security
from ktbt_proto.exchange.signing import Identity
from ktbt_proto.exchange.trust import Policy, TrustStore
from ktbt_proto.items import sequence_key
from ktbt_proto.tools.demo import demo_registry
from ktbt_proto.transport import MemoryNetwork
from tests.exchange.test_agent import CONTROL, KNOWER, SEQUENCE, registry


def trio(
    overhear: Overhear,
    security: Security = Security(),  # noqa: B008
) -> tuple[ApplicationTimedAgent, ApplicationTimedAgent, ApplicationTimedAgent, MemoryNetwork]:
    net = MemoryNetwork(overhear=True)
    learner = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"))
    teacher = ApplicationTimedAgent("t", KNOWER, registry(), net.join("t"))
    ear = ApplicationTimedAgent(
        "e", CONTROL, registry(), net.join("e"), ear=Overhearing(overhear), security=security
    )
    return learner, teacher, ear, net


def exchange(learner: ApplicationTimedAgent, teacher: ApplicationTimedAgent) -> None:
    learner.ask(SEQUENCE)
    teacher.receive()
    query = teacher.heard("l")
    assert query is not None and teacher.answer(query)
    assert learner.receive() == 1


def test_update_learns_an_overheard_answer_at_once() -> None:
    learner, teacher, ear, _net = trio(Overhear.UPDATE)
    exchange(learner, teacher)
    assert ear.receive() == 1
    assert ear.knows(SEQUENCE)
    assert (ear.metrics.overheard, ear.metrics.learned_passive) == (1, 1)
    assert ear.metrics.queries_sent == 0
    assert (
        ear.metrics.learned[kp.format_tree(kp.parse("<c>(TargetSeen,colour=2)"), "compact")][1]
        == "t"
    )
    assert learner.metrics.learned_direct == 1 and learner.metrics.learned_passive == 0


def test_buffer_keeps_an_overheard_answer_and_uses_it_without_asking() -> None:
    net = MemoryNetwork(overhear=True)
    learner = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"))
    teacher = ApplicationTimedAgent("t", KNOWER, registry(), net.join("t"))
    ear = Agent(
        "e", CONTROL, registry(), net.join("e"), ear=Overhearing(Overhear.BUFFER)
    )  # tree-timed
    exchange(learner, teacher)
    ear.tick()  # reads the transport; nothing encountered yet, so nothing asked
    assert ear.metrics.learned_passive == 0 and ear.metrics.queries_sent == 0
    assert not ear.knows(SEQUENCE) and ear.buffered == ["<c>(TargetSeen,colour=2)"]
    ear.blackboard["target"] = 2
    ear.encounter(SEQUENCE)  # the tree's learner meets the sequence
    for _ in range(3):
        net.step()
        ear.tick()
    assert ear.knows(SEQUENCE) and ear.metrics.learned_buffered == 1
    assert ear.metrics.queries_sent == 0 and ear.buffered == []
    assert ear.blackboard.get("picked", 0) >= 1  # and it used what it learned


def test_off_refuses_an_answer_addressed_to_another() -> None:
    learner, teacher, ear, _net = trio(Overhear.OFF)
    exchange(learner, teacher)
    assert ear.receive() == 0
    assert not ear.knows(SEQUENCE) and ear.metrics.refused == 1


def test_an_overheard_answer_that_fails_a_check_is_refused_and_counted() -> None:
    net = MemoryNetwork(overhear=True)
    learner = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"))
    teacher = ApplicationTimedAgent("t", KNOWER, registry(), net.join("t"))
    reg = kp.Registry()
    reg.add_condition("TargetSeen", lambda bb, colour: False)
    reg.add_action("Walk", lambda bb: kp.SUCCESS)
    ear = ApplicationTimedAgent(
        "e", CONTROL, reg, net.join("e"), ear=Overhearing(Overhear.UPDATE)
    )  # no Pick
    before = kp.format_tree(ear.control.tree, "compact")
    exchange(learner, teacher)
    assert ear.receive() == 0
    assert ear.metrics.refused == 1 and "Pick" in ear.metrics.refusals[-1][1]
    assert ear.metrics.overheard_refused == 1
    assert kp.format_tree(ear.control.tree, "compact") == before


def test_an_overheard_answer_is_trusted_no_more_than_a_direct_one() -> None:
    learner, teacher, ear, _net = trio(Overhear.UPDATE, Security(policy=Policy.SIGNED))
    exchange(learner, teacher)  # the teacher signs nothing
    assert ear.receive() == 0 and not ear.knows(SEQUENCE)
    assert ear.metrics.refused == 1


def test_a_full_buffer_refuses_the_newcomer() -> None:
    net = MemoryNetwork(overhear=True)
    knows_two = KNOWER.replace(
        "<e><k>(new)", "<sq><c>(TargetSeen, colour=3)<a>(Pick, colour=3)<e><e><k>(new)"
    )
    learner = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"))
    teacher = ApplicationTimedAgent("t", knows_two, registry(), net.join("t"))
    ear = ApplicationTimedAgent(
        "e", CONTROL, registry(), net.join("e"), ear=Overhearing(Overhear.BUFFER, 1)
    )
    for colour in (2, 3):
        learner.ask([f"TargetSeen(colour={colour})"])
        teacher.receive()
        query = teacher.heard("l")
        assert query is not None and teacher.answer(query)
        learner.receive()
        learner.close_query()
    ear.receive()
    assert ear.buffered == ["<c>(TargetSeen,colour=2)"]
    assert ear.metrics.refused == 1 and "buffer full" in ear.metrics.refusals[-1][1]
    assert ear.metrics.overheard_refused == 1


def test_a_fleet_member_learns_from_its_buffer_without_asking() -> None:
    """The fleet member's ``Learner`` (``ktbt peer run``, ``ktbt ros2 run``, ``attach``, spec
    section 4.5) learns a sequence it lacks from an overheard answer kept in its buffer, and
    sends no query for it."""
    from ktbt_proto.exchange.backoff import Backoff
    from ktbt_proto.exchange.member import Learner

    learner, teacher, ear, _net = trio(Overhear.BUFFER)
    exchange(learner, teacher)
    ear.receive()
    assert ear.buffered == ["<c>(TargetSeen,colour=2)"] and not ear.knows(SEQUENCE)
    Learner(ear, Backoff(seed="e"), wait=2.0, cooldown=0.5).step(0.0, [sequence_key(SEQUENCE)], [])
    assert ear.knows(SEQUENCE) and ear.metrics.learned_buffered == 1
    assert ear.metrics.queries_sent == 0 and ear.open_query is None


def test_an_announced_query_names_only_what_is_unanswered_of_it() -> None:
    """A query half answered, announced to a peer that appears (section 4.5): the peer is asked
    the unanswered part only, under the same id, so no teacher answers again what it did."""
    net = MemoryNetwork()
    robot = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"))
    teacher = ApplicationTimedAgent("t", KNOWER, registry(), net.join("t"))
    newcomer = ApplicationTimedAgent("n", CONTROL, registry(), net.join("n"))
    other = "<c>(TargetSeen,colour=3)"
    query = robot.ask(SEQUENCE, other)
    teacher.receive()
    heard = teacher.heard("l")
    assert heard is not None and teacher.answer(heard)
    robot.receive()
    assert robot.knows(SEQUENCE) and robot.unanswered == [other]
    robot.announce("n")
    newcomer.receive()
    announced = newcomer.heard("l")
    assert announced is not None and announced.id == query.id
    assert announced.sequences == (other,)


def test_a_server_buffers_but_serves_only_what_passes_its_policy_and_vocabulary() -> None:
    """A knowledge server's buffer (section 4.3): an answer kept there is checked when a query
    first asks for it, under the server's policy and vocabulary, and served only if it passes."""
    author = Identity.generate()
    store = TrustStore(frozenset({author.public}))
    good = "<sq><a>(PickTreasure)<a>(AssignCollectionPoint,colour=2)<e>"

    def signed(sequence: str, subtree: str) -> Response:
        item = author.sign_item(sequence, subtree)
        unsigned = Response(id="q1", sender="teacher", sequence=sequence, subtree=subtree)
        return author.sign_reply(
            unsigned.model_copy(update={"author": item.author, "signature": item.signature})
        )

    green, red, blue = (f"<c>(TargetSeen,colour={c})" for c in (2, 1, 4))
    server = ServerOverhearing(
        "s", KnowledgeBase(), lambda _: None, Overhear.BUFFER,
        security=Security(policy=Policy.TRUSTED, trust=store), registry=demo_registry(),
    )  # fmt: skip
    server.heard(signed(green, good))
    server.heard(Response(id="q2", sender="liar", sequence=red, subtree=good))  # unsigned
    server.heard(signed(blue, "<a>(SelfDestruct)"))  # trusted, but not in the vocabulary
    assert server.refused == 0  # kept, not checked yet
    found = server.lookup(green)
    assert found is not None and found.author == author.public
    assert server.lookup(red) is None and server.lookup(blue) is None
    assert server.refused == 2 and set(server.learned) == {green}
