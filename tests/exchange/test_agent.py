"""KT-BT agents on the in-memory transport: the paper's Lemma 1 and Theorems 2 and 3, the
teach and learn rules, refusals of bad knowledge, and persistence across a crash."""

from __future__ import annotations

import json
import multiprocessing
import os
import signal
from pathlib import Path

import networkx as nx
import pytest

import ktbt_proto as kp
from ktbt_proto.exchange.agent import Agent, Timing
from ktbt_proto.exchange.knowledge import KnowledgeBase
from ktbt_proto.exchange.messages import Query, Response
from ktbt_proto.exchange.security import Security
from ktbt_proto.exchange.transferlog import TransferLog
from ktbt_proto.transport import MemoryNetwork, MemoryTransport
from tests.zenoh_helpers import wait_until

CONTROL = "<sl><k>(prior)<e><k>(new)<e><a>(Walk)<e>"
SKILL = "<sq><c>(TargetSeen, colour=2)<a>(Pick, colour=2)<e>"
KNOWER = f"<sl><k>(prior){SKILL}<e><k>(new)<e><a>(Walk)<e>"
SEQUENCE = ["TargetSeen(colour=2)"]


def registry() -> kp.Registry:
    reg = kp.Registry()

    @reg.condition("TargetSeen")
    def target_seen(bb: kp.Blackboard, colour: int) -> bool:
        return bool(bb.get("target") == colour)

    @reg.action("Pick")
    def pick(bb: kp.Blackboard, colour: int = 0) -> kp.Status:
        bb["picked"] = bb.get("picked", 0) + 1
        return kp.SUCCESS

    @reg.action("Walk")
    def walk(bb: kp.Blackboard) -> kp.Status:
        return kp.RUNNING

    return reg


def agent(
    net: MemoryNetwork,
    name: str,
    tree: str = CONTROL,
    *,
    wait: int = 5,
    cooldown: int = 5,
    repeat_every: int = 0,
    log: TransferLog | None = None,
    knowledge_path: str | Path | None = None,
) -> Agent:
    return Agent(
        name,
        tree,
        registry(),
        net.join(name),
        timing=Timing(wait, cooldown, repeat_every),
        security=Security(log=log),
        knowledge_path=knowledge_path,
    )


def run(net: MemoryNetwork, agents: list[Agent], ticks: int) -> None:
    for _ in range(ticks):
        net.step()
        for a in agents:
            a.tick()


def test_lemma_1_two_agents_in_range() -> None:
    net = MemoryNetwork()
    k, i = agent(net, "k", KNOWER), agent(net, "i")
    assert k.knows(SEQUENCE) and not i.knows(SEQUENCE)
    i.encounter(SEQUENCE)
    i.blackboard["target"] = 2
    run(net, [k, i], 4)
    assert i.knows(SEQUENCE)
    assert i.metrics.learned["<c>(TargetSeen,colour=2)"][1] == "k"
    assert "<k>(new)<sq><c>(TargetSeen,colour=2)<a>(Pick,colour=2)<e><e>" in kp.format_tree(
        i.control.tree, "compact"
    )
    run(net, [k, i], 2)
    assert i.blackboard["picked"] >= 1  # the merged knowledge runs
    assert (i.metrics.queries_sent, k.metrics.responses_sent) == (1, 1)


def test_out_of_range_the_query_is_lost_and_not_repeated_during_cooldown() -> None:
    net = MemoryNetwork(in_range=lambda a, b: False)
    k, i = agent(net, "k", KNOWER), agent(net, "i", wait=5, cooldown=20)
    i.encounter(SEQUENCE)
    run(net, [k, i], 10)
    assert not i.knows(SEQUENCE)
    assert (i.metrics.queries_sent, i.metrics.queries_lost) == (1, 1)
    run(net, [k, i], 10)  # tick 20: still cooling down (ticks 6 to 25)
    assert i.metrics.queries_sent == 1
    run(net, [k, i], 10)  # cooldown over: it asks again
    assert i.metrics.queries_sent == 2


@pytest.mark.parametrize(
    "graph",
    [
        nx.path_graph(8),
        nx.star_graph(6),
        nx.cycle_graph(7),
        nx.connected_watts_strogatz_graph(12, 4, 0.3, seed=3),
    ],
    ids=["path", "star", "cycle", "small-world"],
)
def test_theorem_2_one_knower_everyone_learns_on_a_connected_graph(graph: nx.Graph) -> None:
    nodes = sorted(graph.nodes)
    net = MemoryNetwork(in_range=lambda a, b: graph.has_edge(int(a), int(b)))
    agents = [agent(net, str(n), KNOWER if n == nodes[-1] else CONTROL) for n in nodes]
    for a in agents:
        a.encounter(SEQUENCE)
    for _ in range(200):
        run(net, agents, 10)
        if all(a.knows(SEQUENCE) for a in agents):
            break
    assert all(a.knows(SEQUENCE) for a in agents)
    # Knowledge only moved along edges.
    for a in agents:
        if a.name != str(nodes[-1]):
            teacher = a.metrics.learned["<c>(TargetSeen,colour=2)"][1]
            assert graph.has_edge(int(a.name), int(teacher))


def test_theorem_3_p_minus_1_opportunities_suffice_and_fewer_never_do() -> None:
    p = 6
    for opportunities in range(p):
        net = MemoryNetwork()
        agents = [agent(net, "k", KNOWER)] + [agent(net, f"a{n}") for n in range(1, p)]
        learners = agents[1 : 1 + opportunities]
        for learner in learners:  # each faces s_q exactly once, one after the other
            learner.encounter(SEQUENCE)
            run(net, agents, 3)
            learner.encounter(None)
            run(net, agents, 6)
        knowing = sum(a.knows(SEQUENCE) for a in agents)
        assert sum(a.metrics.queries_sent for a in agents) == opportunities
        assert knowing == 1 + opportunities
        assert (knowing == p) == (opportunities >= p - 1)


class Liar:
    """A peer that answers every query with what it is told to send."""

    def __init__(self, net: MemoryNetwork, answer: str, sequence: str | None = None) -> None:
        self.transport: MemoryTransport = net.join("liar")
        self.answer = answer
        self.sequence = sequence

    def tick(self) -> None:
        for message in self.transport.receive():
            if isinstance(message, Query):
                self.transport.send(
                    message.sender,
                    Response(
                        id=message.id,
                        sender="liar",
                        sequence=self.sequence or message.sequence,
                        subtree=self.answer,
                    ),
                )


@pytest.mark.parametrize(
    ("answer", "sequence", "reason"),
    [
        ("<sq><a>(Pick", None, "SBT104"),
        ("garbage $$", None, "SBT101"),
        ("<a>(Teleport)", None, "SBT306"),
        ("<a>(Pick, speed=9)", None, "SBT311"),
        ("<sq>" * 40 + "<a>(Pick)" + "<e>" * 40, None, "SBT202"),
        ("<sq>" + "<a>(Walk)" * 3000 + "<e>", None, "SBT203"),
        ("<a>(Pick)", "<c>(TargetSeen,colour=3)", "not the question"),
    ],
)
def test_bad_answers_are_refused_and_an_honest_peer_teaches_later(
    answer: str, sequence: str | None, reason: str
) -> None:
    net = MemoryNetwork()
    liar = Liar(net, answer, sequence)
    learner = agent(net, "i", wait=4, cooldown=3)
    before = kp.format_tree(learner.control.tree, "compact")
    learner.encounter(SEQUENCE)
    for _ in range(3):
        net.step()
        liar.tick()
        learner.tick()
    assert not learner.knows(SEQUENCE)
    assert learner.metrics.refusals and reason in learner.metrics.refusals[0][1]
    assert kp.format_tree(learner.control.tree, "compact") == before
    assert learner.tick() is kp.RUNNING  # still ticking, still walking
    liar.transport.close()
    honest = agent(net, "k", KNOWER)
    run(net, [honest, learner], 20)
    assert learner.knows(SEQUENCE)
    assert learner.metrics.learned["<c>(TargetSeen,colour=2)"][1] == "k"


def test_teacher_answers_only_what_it_knows_and_one_query_per_cooldown() -> None:
    net = MemoryNetwork()
    k = agent(net, "k", KNOWER, cooldown=50)
    askers = [agent(net, f"a{n}", wait=10) for n in range(3)]
    unknown = agent(net, "u", wait=10)
    unknown.encounter(["TargetSeen(colour=4)"])
    for a in askers:
        a.encounter(SEQUENCE)
    run(net, [k, *askers, unknown], 12)
    assert k.metrics.responses_sent == 1
    taught_by = [a.metrics.learned.get("<c>(TargetSeen,colour=2)", (0, ""))[1] for a in askers]
    assert taught_by.count("k") == 1  # the others learned from the first learner, if at all
    assert not unknown.knows(["TargetSeen(colour=4)"])
    assert unknown.metrics.queries_lost == 1


def test_memory_network_latency_and_loss_are_deterministic() -> None:
    def trial(seed: int) -> tuple[int, int]:
        net = MemoryNetwork(loss=0.5, latency=2, seed=seed)
        agents = [agent(net, "k", KNOWER)] + [agent(net, f"a{n}") for n in range(5)]
        for a in agents[1:]:
            a.encounter(SEQUENCE)
        run(net, agents, 60)
        return net.lost, sum(a.knows(SEQUENCE) for a in agents)

    assert trial(7) == trial(7)
    assert trial(7)[0] > 0


def test_knowledge_persists_and_a_restarted_agent_resumes(tmp_path: Path) -> None:
    path = tmp_path / "kb" / "i.json"
    net = MemoryNetwork()
    k, i = agent(net, "k", KNOWER), agent(net, "i", knowledge_path=path)
    i.encounter(SEQUENCE)
    run(net, [k, i], 4)
    assert i.knows(SEQUENCE) and path.exists()
    saved = KnowledgeBase.load(path)
    assert saved.keys() == ["<c>(TargetSeen,colour=2)"]
    again = agent(MemoryNetwork(), "i", knowledge_path=path)
    assert again.knows(SEQUENCE)
    assert "<k>(new)<sq><c>(TargetSeen,colour=2)" in kp.format_tree(again.control.tree, "compact")
    path.write_text("{not json")
    broken = agent(MemoryNetwork(), "i", knowledge_path=path)
    assert not broken.knows(SEQUENCE) and "cannot resume" in broken.metrics.refusals[0][1]


def _learn_forever(path: str, ready: str) -> None:
    """Child process: learn one colour after another from a teacher, saving each."""
    colours = range(1, 10_000)
    skills = "".join(f"<sq><c>(TargetSeen, colour={c})<a>(Pick, colour={c})<e>" for c in colours)
    net = MemoryNetwork()
    teacher = agent(net, "k", f"<sl><k>(prior){skills}<e><k>(new)<e><a>(Walk)<e>", cooldown=0)
    learner = agent(net, "i", knowledge_path=path, cooldown=0)
    for colour in colours:
        learner.encounter([f"TargetSeen(colour={colour})"])
        while not learner.knows([f"TargetSeen(colour={colour})"]):
            run(net, [teacher, learner], 1)
        if colour == 3:
            Path(ready).write_text("ready")


def saved_items(path: Path) -> int:
    """How many items the saved file holds; it is never half-written, so it always parses."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        return 0
    return len(json.loads(text)["knowledge"])


@pytest.mark.network
def test_knowledge_file_survives_sigkill(tmp_path: Path) -> None:
    path, ready = tmp_path / "i.json", tmp_path / "ready"
    ctx = multiprocessing.get_context("spawn")
    child = ctx.Process(target=_learn_forever, args=(str(path), str(ready)))
    child.start()
    try:
        assert wait_until(lambda: ready.exists() or not child.is_alive(), 60)
        assert ready.exists(), "the child never learned"
        # Kill it while it saves item after item; every file read meanwhile is whole.
        assert wait_until(lambda: saved_items(path) >= 10, 60)
        os.kill(child.pid, signal.SIGKILL)  # type: ignore[arg-type]
    finally:
        child.join(timeout=30)
        if child.is_alive():
            child.kill()
    assert child.exitcode == -signal.SIGKILL
    data = json.loads(path.read_text())  # whole: never a half-written file
    learned = len(data["knowledge"])
    assert learned >= 3
    restarted = agent(MemoryNetwork(), "i", knowledge_path=path)
    assert len(restarted.metrics.learned) == learned
    assert restarted.knows(["TargetSeen(colour=1)"])


@pytest.mark.parametrize(
    "content",
    [
        '{"version":1,"knowledge":[1,2]}',
        '{"version":1,"knowledge":null}',
        '{"version":1,"knowledge":{"a":1}}',
        "[" * 100_000,
        '{"version":1,"knowledge":[{}]}',
    ],
)
def test_a_corrupt_knowledge_file_is_refused_and_the_agent_starts(
    tmp_path: Path, content: str
) -> None:
    path = tmp_path / "kb.json"
    path.write_text(content)
    robot = agent(MemoryNetwork(), "i", knowledge_path=path)
    assert robot.metrics.refused == 1 and "cannot resume" in robot.metrics.refusals[0][1]
    assert robot.tick() is kp.RUNNING


def test_a_failed_save_is_a_refusal_not_a_crash(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("")
    net = MemoryNetwork()
    k, i = agent(net, "k", KNOWER), agent(net, "i", knowledge_path=blocker / "kb.json")
    i.encounter(SEQUENCE)
    run(net, [k, i], 4)
    assert i.knows(SEQUENCE)
    assert any("cannot save" in reason for _, reason in i.metrics.refusals)


def test_teaching_does_not_cut_the_own_wait_short() -> None:
    net = MemoryNetwork()
    a = agent(net, "a", KNOWER, wait=30, cooldown=5)
    b = agent(net, "b", wait=30, cooldown=5)
    a.encounter(["TargetSeen(colour=7)"])  # nobody knows it: a waits its full 30 ticks
    b.encounter(SEQUENCE)  # a teaches b meanwhile
    run(net, [a, b], 10)
    assert b.knows(SEQUENCE)
    assert a.metrics.queries_lost == 0  # still waiting
    run(net, [a, b], 25)
    assert a.metrics.queries_lost == 1


@pytest.mark.parametrize("seed", range(5))
def test_an_item_is_merged_once_whatever_the_duplicates_reordering_and_re_asks(
    tmp_path: Path, seed: int
) -> None:
    """Four teachers answer every query, their answers duplicated and shuffled, and the learner
    asks again and again (it forgets, and re-asks with the same id): each time it learns, the
    item is merged once, its bytes the author's."""
    import random

    from ktbt_proto.exchange.transferlog import TransferLog, read

    rng = random.Random(seed)
    net = MemoryNetwork()
    log = TransferLog(tmp_path / "i.log")
    teachers = [agent(net, f"k{n}", KNOWER, cooldown=0) for n in range(4)]
    learner = agent(net, "i", wait=50, cooldown=1, repeat_every=3, log=log)
    learned = 0
    for _ in range(3):
        learner.encounter(SEQUENCE)
        for _ in range(40):
            net.step()
            for t in rng.sample(teachers, len(teachers)):
                t.tick()
            inbox = learner.transport._inbox  # type: ignore[attr-defined]
            mail = list(inbox) * 2  # every answer twice, in any order
            rng.shuffle(mail)
            inbox.clear()
            inbox.extend(mail)
            learner.tick()
        assert learner.knows(SEQUENCE)
        item = learner.knowledge.lookup("<c>(TargetSeen,colour=2)")
        assert item is not None and kp.format_tree(item.subtree, "compact") == "<a>(Pick,colour=2)"
        learned += 1
        learner.forget(SEQUENCE)
    log.close()
    merged = [e for e in read(tmp_path / "i.log") if isinstance(e, dict) and e["event"] == "merged"]
    assert len(merged) == learned == 3  # once each time, never twice
    assert learner.metrics.forgotten == 3


def test_an_answer_after_the_wait_is_late_not_refused(tmp_path: Path) -> None:
    """A slow honest teacher answers a query whose wait is over: a late answer, logged as
    ``late-answer``, never a refusal; an answer to a query never sent stays one."""
    from ktbt_proto.exchange.transferlog import TransferLog, read

    net = MemoryNetwork()
    log = TransferLog(tmp_path / "i.log")
    learner = agent(net, "i", wait=3, cooldown=50, log=log)
    slow = net.join("k")
    learner.encounter(SEQUENCE)
    run(net, [learner], 8)  # asked, waited, lost
    assert learner.metrics.queries_lost == 1
    (query,) = [m for m in slow.receive() if isinstance(m, Query)]
    slow.send("i", Response(id=query.id, sender="k", sequence=query.sequence, subtree="<a>(Pick)"))
    slow.send("i", Response(id="never", sender="k", sequence=query.sequence, subtree="<a>(Pick)"))
    run(net, [learner], 2)
    log.close()
    assert learner.metrics.late_answers == 1
    assert learner.metrics.refused == 1 and "no open question" in learner.metrics.refusals[0][1]
    events = [e["event"] for e in read(tmp_path / "i.log") if isinstance(e, dict)]
    assert events.count("late-answer") == 1 and events.count("refused") == 1
