"""Memory-limited agents (spec/protocol.md section 4.2): capacity, refusal or eviction of the
least recently used item, forgetting after idle ticks and per-item expiry, with real messages on
the in-memory network and the forgetting reaching the running tree and the saved file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ktbt_proto as kp
from ktbt_proto.exchange.application import ApplicationTimedAgent
from ktbt_proto.exchange.memory_policy import MemoryPolicy, WhenFull
from ktbt_proto.exchange.security import Security
from ktbt_proto.transport import MemoryNetwork

COLOURS = (1, 2, 3, 4)
CONTROL = "<sl><k>(prior)<e><k>(new)<e><a>(Walk)<e>"
KNOWS_ALL = (
    "<sl><k>(prior)"
    + "".join(f"<sq><c>(TargetSeen, colour={c})<a>(Pick, colour={c})<e>" for c in COLOURS)
    + "<e><k>(new)<e><a>(Walk)<e>"
)
KNOWS_RED = (
    "<sl><k>(prior)<sq><c>(TargetSeen, colour=1)<a>(Pick, colour=1)<e><e><k>(new)<e><a>(Walk)<e>"
)


def registry() -> kp.Registry:
    reg = kp.Registry()

    @reg.condition("TargetSeen")
    def target_seen(bb: kp.Blackboard, colour: int) -> bool:
        return bool(bb.get("target") == colour)

    @reg.action("Pick")
    def pick(bb: kp.Blackboard, colour: int = 0) -> kp.Status:
        bb["picked"] = [*bb.get("picked", []), colour]
        return kp.SUCCESS

    @reg.action("Walk")
    def walk(bb: kp.Blackboard) -> kp.Status:
        return kp.SUCCESS

    return reg


def pair(
    control: str = CONTROL, **memory: object
) -> tuple[ApplicationTimedAgent, ApplicationTimedAgent]:
    net = MemoryNetwork()
    policy = MemoryPolicy(**memory)  # type: ignore[arg-type]
    learner = ApplicationTimedAgent("l", control, registry(), net.join("l"), memory=policy)
    teacher = ApplicationTimedAgent("t", KNOWS_ALL, registry(), net.join("t"))
    return learner, teacher


def teach(learner: ApplicationTimedAgent, teacher: ApplicationTimedAgent, colour: int) -> bool:
    learner.ask([f"TargetSeen(colour={colour})"])
    teacher.receive()
    query = teacher.heard("l")
    assert query is not None
    teacher.answer(query)
    accepted = learner.receive() == 1
    learner.close_query()
    return accepted and learner.knows([f"TargetSeen(colour={colour})"])


def see(agent: ApplicationTimedAgent, colour: int | None, ticks: int = 1) -> None:
    agent.blackboard["target"] = colour
    for _ in range(ticks):
        agent.now += 1
        agent.control.tick()
        agent.tend_memory()


def test_a_full_memory_refuses_a_lesson_and_counts_it() -> None:
    learner, teacher = pair(capacity=1, count_innate=False)
    assert teach(learner, teacher, 2)
    assert not teach(learner, teacher, 3)
    assert learner.metrics.refused == 1 and "memory full" in learner.metrics.refusals[-1][1]
    assert learner.knows(["TargetSeen(colour=2)"]) and not learner.knows(["TargetSeen(colour=3)"])


def test_innate_knowledge_counts_when_the_policy_says_so() -> None:
    learner, teacher = pair(KNOWS_RED, capacity=1)  # the release's rule: innate counts
    assert not teach(learner, teacher, 2)
    learner, teacher = pair(KNOWS_RED, capacity=1, count_innate=False)
    assert teach(learner, teacher, 2)


def test_eviction_forgets_the_least_recently_used_item() -> None:
    learner, teacher = pair(capacity=2, count_innate=False, when_full=WhenFull.EVICT)
    assert teach(learner, teacher, 2)
    assert teach(learner, teacher, 3)
    see(learner, 2, ticks=3)  # green is used; yellow is not
    assert teach(learner, teacher, 4)
    known = [c for c in COLOURS if learner.knows([f"TargetSeen(colour={c})"])]
    assert known == [2, 4]
    assert learner.metrics.forgotten == 1
    see(learner, 3)  # yellow no longer does anything: the tree forgot it too
    assert 3 not in learner.blackboard.get("picked", [])


def test_everything_learned_is_forgotten_after_idle_ticks_and_innate_stays() -> None:
    learner, teacher = pair(KNOWS_RED, forget_after=5)
    assert teach(learner, teacher, 2)
    assert teach(learner, teacher, 3)
    see(learner, 2, ticks=3)  # using green keeps everything
    see(learner, None, ticks=4)
    assert learner.knows(["TargetSeen(colour=3)"])
    see(learner, None, ticks=1)  # five idle ticks since green was last used
    assert [c for c in COLOURS if learner.knows([f"TargetSeen(colour={c})"])] == [1]
    assert learner.metrics.forgotten == 2 and not learner.metrics.learned
    picked = len(learner.blackboard["picked"])
    see(learner, 2)
    assert len(learner.blackboard["picked"]) == picked  # green does nothing any more


def test_an_unused_item_expires_on_its_own() -> None:
    learner, teacher = pair(expire_after=4)
    assert teach(learner, teacher, 2)
    assert teach(learner, teacher, 3)
    for _ in range(3):
        see(learner, 2, ticks=2)
    assert learner.knows(["TargetSeen(colour=2)"])
    assert not learner.knows(["TargetSeen(colour=3)"])


def test_forgetting_reaches_the_saved_file_and_the_log(tmp_path: Path) -> None:
    from ktbt_proto.exchange.transferlog import TransferLog

    net = MemoryNetwork()
    path = tmp_path / "l.json"
    learner = ApplicationTimedAgent(
        "l",
        CONTROL,
        registry(),
        net.join("l"),
        knowledge_path=path,
        security=Security(log=TransferLog(tmp_path / "l.log")),
    )
    teacher = ApplicationTimedAgent("t", KNOWS_ALL, registry(), net.join("t"))
    assert teach(learner, teacher, 2)
    assert len(json.loads(path.read_text())["knowledge"]) == 1
    assert learner.forget(["TargetSeen(colour=2)"]) is True
    assert json.loads(path.read_text())["knowledge"] == []
    assert learner.forget(["TargetSeen(colour=2)"]) is False
    events = [json.loads(line) for line in (tmp_path / "l.log").read_text().splitlines()]
    assert [e["reason"] for e in events if e["event"] == "forgotten"] == ["asked"]


def test_innate_knowledge_is_never_forgotten() -> None:
    learner, _ = pair(KNOWS_RED, forget_after=1)
    assert learner.forget(["TargetSeen(colour=1)"]) is False
    see(learner, None, ticks=5)
    assert learner.knows(["TargetSeen(colour=1)"])


@pytest.mark.parametrize(
    "bad", [{"capacity": 0}, {"forget_after": -1}, {"expire_after": 1.5}, {"when_full": "drop"}]
)
def test_a_policy_that_makes_no_sense_is_refused(bad: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        MemoryPolicy(**bad)  # type: ignore[arg-type]


@settings(max_examples=30, deadline=None)
@given(
    capacity=st.integers(1, 3),
    count_innate=st.booleans(),
    when_full=st.sampled_from(["refuse", "evict"]),
    lessons=st.lists(st.sampled_from(COLOURS), min_size=1, max_size=8),
)
def test_capacity_is_never_exceeded(
    capacity: int, count_innate: bool, when_full: str, lessons: list[int]
) -> None:
    learner, teacher = pair(
        KNOWS_RED, capacity=capacity, count_innate=count_innate, when_full=when_full
    )
    innate = 1
    for colour in lessons:
        teach(learner, teacher, colour)
        learned = len(learner.metrics.learned)
        held = learned + (innate if count_innate else 0)
        assert held <= max(capacity, innate if count_innate else 0)
        assert learner.knows(["TargetSeen(colour=1)"])  # innate knowledge is never evicted
        see(learner, colour)
