"""The core every agent shares (``ktbt_proto.exchange.core.AgentCore``): the one accept pipeline
of spec/protocol.md section 2, its memory (section 4.2) and its persistence (section 5), driven
through an application-timed agent (section 4.1) on the real in-memory network (section 6).

What tests/exchange/test_agent*.py and test_memory.py show already is not repeated here: this
module shows the order of what an accepted or refused answer records (section 8), that a refused
answer leaves the query open for the next (the *first acceptable* answer wins), a lesson refused
for memory and accepted once room is made, the learning placeholder (``slot``, rule 6), the
bounded list of refusal reasons, and a resume that keeps provenance, refuses a saved item its
tree has no place for, removes what a killed save left, leaves an unreadable path alone, and
never overwrites a damaged file set aside before.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import ktbt_proto as kp
from ktbt_proto.exchange.application import ApplicationTimedAgent
from ktbt_proto.exchange.memory_policy import MemoryPolicy, WhenFull
from ktbt_proto.exchange.messages import Query, Response
from ktbt_proto.exchange.security import Security
from ktbt_proto.exchange.signing import Identity
from ktbt_proto.exchange.transferlog import TransferLog
from ktbt_proto.files import temporary_name
from ktbt_proto.transport import MemoryNetwork
from tests.exchange.test_agent import CONTROL, KNOWER, SEQUENCE, registry

GREEN = "<c>(TargetSeen,colour=2)"
BLUE = "<c>(TargetSeen,colour=3)"


def knower(*colours: int) -> str:
    """A control tree that knows the colours given."""
    skills = "".join(f"<sq><c>(TargetSeen, colour={c})<a>(Pick, colour={c})<e>" for c in colours)
    return f"<sl><k>(prior){skills}<e><k>(new)<e><a>(Walk)<e>"


class Recorded:
    """A transfer log without a file whose events are kept in order (a sink, section 8)."""

    def __init__(self) -> None:
        self.log = TransferLog(None)
        self.events: list[dict[str, Any]] = []
        self.log.add_sink(self.events.append)

    def kinds(self) -> list[str]:
        return [str(e["event"]) for e in self.events]


def teach(learner: ApplicationTimedAgent, teacher: ApplicationTimedAgent) -> int:
    """The teacher answers the learner's open query; how many answers the learner accepted."""
    teacher.receive()
    heard = teacher.heard(learner.name)
    assert heard is not None
    teacher.answer(heard)
    return learner.receive()


def compact(agent: ApplicationTimedAgent) -> str:
    return kp.format_tree(agent.control.tree, "compact")


# -- the accept pipeline (section 2) ----------------------------------------------------------


def test_an_accepted_answer_is_recorded_as_received_then_merged_stamped_with_now() -> None:
    net, recorded = MemoryNetwork(), Recorded()
    learner = ApplicationTimedAgent(
        "l", CONTROL, registry(), net.join("l"), security=Security(log=recorded.log)
    )
    teacher = ApplicationTimedAgent("t", KNOWER, registry(), net.join("t"))
    assert learner.log is recorded.log  # the security settings' log
    query = learner.ask(SEQUENCE)
    learner.now = 7
    assert teach(learner, teacher) == 1
    assert recorded.kinds() == ["query-sent", "answer-received", "merged"]
    received, merged = recorded.events[1:]
    assert (received["sender"], received["id"], received["sequence"]) == ("t", query.id, GREEN)
    assert (merged["sequence"], merged["teacher"], merged["tick"]) == (GREEN, "t", 7)
    assert learner.metrics.learned == {GREEN: (7, "t")}
    item = learner.knowledge.lookup(GREEN)
    assert item is not None and (item.source, item.learned_at, item.segment) == ("t", 7, "new")


def test_a_refused_answer_is_recorded_and_leaves_the_query_open_for_an_acceptable_one() -> None:
    """The first *acceptable* answer wins: one to another sequence, and one the learner cannot
    run, are refused (rules 2 and 5), the tree stays as it was, and the query stays open, so
    the honest answer after them is merged."""
    net, recorded = MemoryNetwork(), Recorded()
    learner = ApplicationTimedAgent(
        "l", CONTROL, registry(), net.join("l"), security=Security(log=recorded.log)
    )
    teacher = ApplicationTimedAgent("t", KNOWER, registry(), net.join("t"))
    stranger = net.join("s")
    query = learner.ask(SEQUENCE)
    before = compact(learner)
    stranger.send("l", Response(id=query.id, sender="s", sequence=BLUE, subtree="<a>(Walk)"))
    stranger.send("l", Response(id=query.id, sender="s", sequence=GREEN, subtree="<a>(Fly)"))
    assert learner.receive() == 0
    assert [why for _, why in learner.metrics.refusals] == [
        f"from s: answers {BLUE}, not the question",
        "from s: SBT306 unknown action 'Fly'",
    ]
    assert compact(learner) == before and learner.unanswered == [GREEN]
    assert recorded.kinds()[1:] == ["answer-received", "refused", "answer-received", "refused"]
    assert teach(learner, teacher) == 1
    assert learner.knows(SEQUENCE) and learner.metrics.learned[GREEN][1] == "t"
    assert learner.metrics.responses_received == 3 and learner.metrics.learned_direct == 1


def test_the_first_acceptable_answer_wins_and_a_different_later_one_is_late() -> None:
    """Two teachers answer the same query differently: the first answer is merged, the second
    is a late answer (counted apart, logged as ``late-answer``, never checked nor merged)."""
    net, recorded = MemoryNetwork(), Recorded()
    learner = ApplicationTimedAgent(
        "l", CONTROL, registry(), net.join("l"), security=Security(log=recorded.log)
    )
    walks = KNOWER.replace("<a>(Pick, colour=2)", "<a>(Walk)")
    assert walks != KNOWER
    first = ApplicationTimedAgent("u", KNOWER, registry(), net.join("u"))
    second = ApplicationTimedAgent("t", walks, registry(), net.join("t"))
    query = learner.ask(SEQUENCE)
    for teacher in (first, second):
        teacher.receive()
        heard = teacher.heard("l")
        assert heard is not None and teacher.answer(heard)
    assert learner.receive() == 1
    item = learner.knowledge.lookup(GREEN)
    assert item is not None and item.source == "u"
    assert kp.format_tree(item.subtree, "compact") == "<a>(Pick,colour=2)"
    assert (learner.metrics.late_answers, learner.metrics.refused) == (1, 0)
    assert recorded.kinds()[1:] == ["answer-received", "merged", "late-answer"]
    assert recorded.events[-1]["sender"] == "t" and recorded.events[-1]["id"] == query.id


def test_learned_knowledge_goes_into_the_slot_and_a_missing_slot_is_a_refusal() -> None:
    """Rule 6: the learner's placeholder for learned knowledge must exist (``SBT401``)."""
    net = MemoryNetwork()
    into_prior = ApplicationTimedAgent("p", CONTROL, registry(), net.join("p"), slot="prior")
    nowhere = ApplicationTimedAgent("n", CONTROL, registry(), net.join("n"), slot="missing")
    teacher = ApplicationTimedAgent("t", KNOWER, registry(), net.join("t"))
    into_prior.ask(SEQUENCE)
    assert teach(into_prior, teacher) == 1
    assert f"<k>(prior)<sq>{GREEN}<a>(Pick,colour=2)<e><e><k>(new)<e>" in compact(into_prior)
    before = compact(nowhere)
    nowhere.ask(SEQUENCE)
    assert teach(nowhere, teacher) == 0
    assert (
        nowhere.metrics.refusals[-1][1] == "from t: SBT401 the tree has no placeholder <k>(missing)"
    )
    assert compact(nowhere) == before and not nowhere.knows(SEQUENCE)


def test_only_the_latest_refusal_reasons_are_kept_and_every_refusal_counted() -> None:
    net = MemoryNetwork()
    learner = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"))
    stranger = net.join("s")
    learner.now = 5
    for n in range(300):
        stranger.send(
            "l", Response(id=f"q{n}", sender=f"s{n}", sequence=GREEN, subtree="<a>(Pick)")
        )
    assert learner.receive() == 0
    assert learner.metrics.refused == 300 and len(learner.metrics.refusals) == 256
    assert learner.metrics.refusals[0] == (5, "from s44: an answer to no open question")
    assert learner.metrics.refusals[-1] == (5, "from s299: an answer to no open question")


def test_one_exchange_counts_on_both_sides() -> None:
    net = MemoryNetwork()
    learner = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"))
    teacher = ApplicationTimedAgent("t", KNOWER, registry(), net.join("t"))
    learner.ask(SEQUENCE, BLUE)  # one query, two sequences: the teacher knows one
    assert teach(learner, teacher) == 1
    learner.close_query()  # answered for one of its sequences: not lost
    learner.ask(BLUE)
    teacher.receive()
    learner.close_query()  # nobody answers: lost
    sent = learner.metrics
    assert (sent.queries_sent, sent.responses_received, sent.learned_direct) == (2, 1, 1)
    assert (sent.queries_lost, sent.refused, sent.late_answers) == (1, 0, 0)
    got = teacher.metrics
    assert (got.queries_received, got.responses_sent, got.queries_sent) == (2, 1, 0)
    assert teacher.last_answer is not None and teacher.last_answer.sequence == GREEN


# -- memory (section 4.2) ---------------------------------------------------------------------


def test_a_lesson_refused_for_memory_is_accepted_once_room_is_made() -> None:
    """``refuse``: the answer is refused ("memory full") and the query stays open; once the
    robot forgets what it learned, the same teacher's answer is merged."""
    net = MemoryNetwork()
    policy = MemoryPolicy(capacity=1, count_innate=False)
    learner = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"), memory=policy)
    teacher = ApplicationTimedAgent("t", knower(2, 3), registry(), net.join("t"))
    learner.ask(SEQUENCE)
    assert teach(learner, teacher) == 1
    learner.ask(BLUE)
    before = compact(learner)
    assert teach(learner, teacher) == 0
    assert learner.metrics.refusals[-1][1] == "from t: memory full (1 items)"
    assert compact(learner) == before and learner.unanswered == [BLUE]
    assert learner.forget(SEQUENCE)
    assert teach(learner, teacher) == 1
    assert learner.knows([BLUE]) and not learner.knows(SEQUENCE)


def test_eviction_never_takes_innate_knowledge_so_a_memory_full_of_it_refuses() -> None:
    net = MemoryNetwork()
    policy = MemoryPolicy(capacity=1, when_full=WhenFull.EVICT)  # the innate item fills it
    robot = ApplicationTimedAgent("l", KNOWER, registry(), net.join("l"), memory=policy)
    teacher = ApplicationTimedAgent("t", knower(3), registry(), net.join("t"))
    robot.ask([BLUE])
    assert teach(robot, teacher) == 0
    assert robot.metrics.refusals[-1][1] == "from t: memory full (1 items)"
    assert robot.knows(SEQUENCE) and not robot.knows([BLUE])
    assert robot.metrics.forgotten == 0


def test_a_full_memory_evicts_nothing_for_an_answer_outside_the_vocabulary() -> None:
    """Rule 5 (the vocabulary) is checked before room is made: an answer the robot refuses
    never costs it what it learned, though its merge is where the vocabulary is checked
    otherwise."""
    net = MemoryNetwork()
    policy = MemoryPolicy(capacity=1, count_innate=False, when_full=WhenFull.EVICT)
    learner = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"), memory=policy)
    teacher = ApplicationTimedAgent("t", knower(2), registry(), net.join("t"))
    learner.ask(SEQUENCE)
    assert teach(learner, teacher) == 1
    asked = Query(id="q", sender="l", sequence=BLUE)
    bad = Response(id="q", sender="t", sequence=BLUE, subtree="<a>(Teleport)")
    assert not learner.accept(bad, asked)
    assert learner.metrics.refusals[-1][1] == "from t: SBT306 unknown action 'Teleport'"
    assert learner.knows(SEQUENCE) and learner.metrics.forgotten == 0


def test_an_answer_is_checked_against_the_vocabulary_once(monkeypatch: Any) -> None:
    """``read_item`` leaves the vocabulary to the merge, which checks the whole item (its
    conditions too): each leaf's arguments are checked against the registry once."""
    checked: list[str] = []
    real = kp.Registry.arguments_problem

    def spy(self: kp.Registry, kind: Any, name: str, args: Any) -> str | None:
        checked.append(name)
        return real(self, kind, name, args)

    monkeypatch.setattr(kp.Registry, "arguments_problem", spy)
    learner = ApplicationTimedAgent("l", CONTROL, registry(), MemoryNetwork().join("l"))
    checked.clear()  # the control tree's own leaves, checked when it was built
    answer = Response(id="q", sender="t", sequence=BLUE, subtree="<a>(Pick,colour=3)")
    assert learner.accept(answer, Query(id="q", sender="l", sequence=BLUE))
    assert sorted(checked) == ["Pick", "TargetSeen"]
    assert learner.knows([BLUE])


def test_forget_learned_keeps_innate_knowledge_and_a_forgotten_item_can_be_learned_again() -> None:
    net, recorded = MemoryNetwork(), Recorded()
    robot = ApplicationTimedAgent(
        "l", knower(1), registry(), net.join("l"), security=Security(log=recorded.log)
    )
    teacher = ApplicationTimedAgent("t", knower(2, 3), registry(), net.join("t"))
    robot.ask(SEQUENCE, BLUE)
    assert teach(robot, teacher) == 2
    assert robot.forget(["TargetSeen(colour=4)"]) is False  # never known
    assert robot.forget(["TargetSeen(colour=1)"]) is False  # innate
    assert robot.forget_learned(reason="reset") == 2
    assert [robot.knows([f"TargetSeen(colour={c})"]) for c in (1, 2, 3)] == [True, False, False]
    assert robot.metrics.forgotten == 2 and robot.metrics.learned == {}
    forgotten = [(e["sequence"], e["reason"]) for e in recorded.events if e["event"] == "forgotten"]
    assert forgotten == [(GREEN, "reset"), (BLUE, "reset")]
    robot.now = 9
    robot.ask(SEQUENCE)
    assert teach(robot, teacher) == 1
    assert robot.metrics.learned == {GREEN: (9, "t")} and robot.metrics.learned_direct == 3


# -- persistence (section 5) ------------------------------------------------------------------


def saved_entry(sequence: str, subtree: str, segment: str = "new") -> dict[str, object]:
    return {"sequence": sequence, "subtree": subtree, "segment": segment, "source": "t",
            "learned_at": 1}  # fmt: skip


def test_a_resumed_item_keeps_its_provenance_and_is_taught_onward_with_its_author(
    tmp_path: Path,
) -> None:
    path = tmp_path / "l.json"
    author = Identity.generate()
    net = MemoryNetwork()
    learner = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"), knowledge_path=path)
    teacher = ApplicationTimedAgent(
        "t", KNOWER, registry(), net.join("t"), security=Security(identity=author)
    )
    learner.ask(SEQUENCE)
    assert teach(learner, teacher) == 1
    learned = learner.knowledge.lookup(GREEN)
    assert learned is not None and learned.author == author.public
    net = MemoryNetwork()  # a restart: a new process on a new network
    restarted = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"), knowledge_path=path)
    resumed = restarted.knowledge.lookup(GREEN)
    assert resumed == learned  # teacher, tick, author, signature and time received
    assert restarted.metrics.learned == {GREEN: (0, "t")} and restarted.metrics.refused == 0
    onward = ApplicationTimedAgent("o", CONTROL, registry(), net.join("o"))
    onward.ask(SEQUENCE)
    assert teach(onward, restarted) == 1
    item = onward.knowledge.lookup(GREEN)
    assert item is not None and (item.source, item.author) == ("l", author.public)
    assert item.signature == learned.signature


def test_a_saved_item_the_tree_has_no_place_for_is_refused_and_the_rest_resumed(
    tmp_path: Path,
) -> None:
    path = tmp_path / "l.json"
    entries = [saved_entry(GREEN, "<a>(Pick,colour=2)", "elsewhere"),
               saved_entry(BLUE, "<a>(Pick,colour=3)")]  # fmt: skip
    path.write_text(json.dumps({"version": 1, "knowledge": entries}))
    robot = ApplicationTimedAgent("l", CONTROL, registry(), MemoryNetwork().join("l"),
                                  knowledge_path=path)  # fmt: skip
    assert robot.knows([BLUE]) and not robot.knows(SEQUENCE)
    assert [why for _, why in robot.metrics.refusals] == [
        f"saved knowledge {GREEN}: SBT401 the tree has no placeholder <k>(elsewhere)"
    ]
    assert robot.knowledge_path == path  # the file was whole: it stays where it is


def test_what_a_killed_save_left_is_removed_when_the_agent_starts(tmp_path: Path) -> None:
    path = tmp_path / "l.json"
    path.write_text(json.dumps({"version": 1, "knowledge": [saved_entry(GREEN, "<a>(Pick)")]}))
    torn = temporary_name(path)
    torn.write_text('{"version": 1, "knowl')
    robot = ApplicationTimedAgent("l", CONTROL, registry(), MemoryNetwork().join("l"),
                                  knowledge_path=path)  # fmt: skip
    assert robot.knows(SEQUENCE) and robot.metrics.refused == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["l.json"]


def test_a_save_path_that_cannot_be_read_is_left_alone_and_never_saved_over(
    tmp_path: Path,
) -> None:
    folder = tmp_path / "l.json"  # a folder where the file should be
    folder.mkdir()
    net = MemoryNetwork()
    robot = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"), knowledge_path=folder)
    assert robot.knowledge_path is None
    (_, why), *_ = robot.metrics.refusals
    assert why.startswith(f"cannot resume from {folder}: ")
    assert why.endswith("; nothing will be saved over it")
    teacher = ApplicationTimedAgent("t", KNOWER, registry(), net.join("t"))
    robot.ask(SEQUENCE)
    assert teach(robot, teacher) == 1 and robot.knows(SEQUENCE)
    assert folder.is_dir() and list(folder.iterdir()) == []
    assert robot.metrics.refused == 1  # learning saved nothing, and failed at nothing


def test_a_damaged_file_set_aside_takes_a_free_name_and_what_it_held_is_saved_anew(
    tmp_path: Path,
) -> None:
    """A damaged file is moved aside under ``FILE.damaged-TIME``, ``-2`` when that name is
    taken, never over an earlier aside file; its whole items are kept and saved with the next
    item learned."""
    path = tmp_path / "l.json"
    whole = json.dumps({"version": 1, "knowledge": [saved_entry(BLUE, "<a>(Pick,colour=3)")]})
    damaged = whole[: whole.rindex("]")] + ', {"sequence": "<c>(Targ'
    path.write_text(damaged)
    # Earlier aside files for every second around now: the new one must take a ``-2`` name.
    now = datetime.now(UTC)
    earlier = {
        tmp_path / f"l.json.damaged-{(now + timedelta(seconds=s)):%Y%m%dT%H%M%S}"
        for s in range(-120, 121)
    }
    for old in earlier:
        old.write_text("an earlier damaged file")
    net = MemoryNetwork()
    robot = ApplicationTimedAgent("l", CONTROL, registry(), net.join("l"), knowledge_path=path)
    assert robot.knows([BLUE]) and not path.exists()
    (aside,) = set(tmp_path.glob("l.json.damaged-*")) - earlier
    assert aside.name.endswith("-2") and aside.with_name(aside.name[:-2]) in earlier
    assert aside.read_text() == damaged
    assert all(old.read_text() == "an earlier damaged file" for old in earlier)
    (_, why), *_ = robot.metrics.refusals
    assert why.startswith(f"cannot resume from {path}: ")
    assert why.endswith(f"; kept 1 whole items, the file moved to {aside.name}")
    teacher = ApplicationTimedAgent("t", KNOWER, registry(), net.join("t"))
    robot.ask(SEQUENCE)
    assert teach(robot, teacher) == 1
    saved = json.loads(path.read_text())["knowledge"]
    assert [e["sequence"] for e in saved] == [BLUE, GREEN]
