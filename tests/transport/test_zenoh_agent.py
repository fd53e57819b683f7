"""A robot built by hand in Python is a fleet member like ``ktbt peer run`` (spec/protocol.md
sections 3 and 4.5): an ``Agent`` on a ``ZenohTransport`` serves its catalog, answers from what
it knows at that moment, and says why it refuses, at WARNING. The door-opening robot
(``tests/door_robot.py``), whose vocabulary is not the search-and-rescue one, learns its skill
over zenoh on loopback and runs it; real ``ktbt peer`` processes see it."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

import ktbt_proto as kp
from ktbt_proto.exchange.agent import Agent, Timing
from ktbt_proto.exchange.messages import Query, Response, decode
from ktbt_proto.items import sequence_key
from ktbt_proto.tools.vocabulary import write_vocabulary
from ktbt_proto.transport.zenoh import ZenohTransport
from tests.door_robot import (
    MEMORY,
    SEQUENCE,
    VOCABULARY,
    door_blackboard,
    door_registry,
)
from tests.zenoh_helpers import endpoint, free_port, ktbt_run, see, settings, wait_until

pytestmark = pytest.mark.network  # zenoh sessions on loopback

CONTROL = "<sl><k>(new)<e><e>"
"""The door robot's control tree: nothing but a placeholder for what it learns."""
SHOWN = 'DoorClosed, HandleSeen(side="left")'
"""How ``ktbt peer list`` shows the door skill's sequence."""
SEQUENCE_KEY = sequence_key(SEQUENCE)


def vocabulary_registry(folder: Path) -> kp.Registry:
    """The door robot's registry as a hand-built robot makes it: loaded from its vocabulary
    file, its Python behaviours bound to the names the file declares."""
    path = folder / "door.toml"
    path.write_text(VOCABULARY)
    reg = door_registry(kp.load_vocabulary(path))
    assert write_vocabulary(reg) == VOCABULARY  # the behaviours agree with the file
    return reg


def test_a_hand_built_agent_learns_runs_and_is_listed_with_what_it_knows(tmp_path: Path) -> None:
    """The teacher is never ticked: it answers from its live knowledge inside zenoh's callback,
    as a fleet member does. The learner runs the learned skill with its own behaviours, and
    ``ktbt peer list`` shows both robots with the skill, ``ktbt peer ask`` gets it from the
    learner, which learned it a moment ago."""
    pt, pl = free_port(), free_port()
    reg = vocabulary_registry(tmp_path)
    with (
        ZenohTransport("teacher", settings(pt)) as tt,
        ZenohTransport("door", settings(pl, pt)) as tl,
    ):
        Agent("teacher", f"<sl><k>(new){MEMORY}<e><e>", door_registry(), tt)
        bb = door_blackboard()
        robot = Agent("door", CONTROL, reg, tl, timing=Timing(wait=500), blackboard=bb)
        see(tl, "teacher")
        robot.encounter(SEQUENCE)
        assert wait_until(lambda: robot.tick() is None or robot.knows(SEQUENCE), 20), (
            robot.metrics.refusals
        )
        assert robot.metrics.learned['<c>(DoorClosed)<c>(HandleSeen,side="left")'][1] == "teacher"
        assert tt.answered == 1 and robot.metrics.refused == 0
        for _ in range(3):
            robot.tick()
        assert bb["log"] == ["grasp", "turn 30/60", "turn 60/60", "push"]

        lines: list[str] = []

        def both_listed() -> bool:  # `peer list` prints who answered its first round
            listed = ktbt_run("peer", "list", "--connect", endpoint(pl), "--connect",
                              endpoint(pt), "--timeout", "5")  # fmt: skip
            assert listed.returncode == 0, listed.stderr
            lines[:] = listed.stdout.splitlines()
            return {"door: 1 skills", "teacher: 1 skills"} <= set(lines)

        assert wait_until(both_listed, 60), lines
        for name in ("door", "teacher"):
            at = lines.index(f"{name}: 1 skills")
            assert lines[at + 1].strip().startswith(SHOWN), lines
        assert "(author" not in lines[lines.index("door: 1 skills") + 1]  # unsigned
        assert "teacher teacher" in lines[lines.index("door: 1 skills") + 1]

        asked = ktbt_run("peer", "ask", "--sequence", SHOWN, "--connect", endpoint(pl),
                         "--timeout", "3")  # fmt: skip
        assert asked.returncode == 0, asked.stderr
        assert "# from door" in asked.stdout and "<a>(TurnHandle, degrees=60)" in asked.stdout
        assert tl.answered >= 1


def test_a_transport_without_answer_at_once_leaves_queries_to_the_teach_tree() -> None:
    """``answer_at_once=False``: the catalog is still served, but a query waits for the
    agent's teach tree (spec section 3), which answers on its tick."""
    pt, pl = free_port(), free_port()
    with (
        ZenohTransport("teacher", settings(pt), answer_at_once=False) as tt,
        ZenohTransport("door", settings(pl, pt)) as tl,
    ):
        teacher = Agent("teacher", f"<sl><k>(new){MEMORY}<e><e>", door_registry(), tt)
        assert tt.lookup is None and tt.catalog is not None
        robot = Agent("door", CONTROL, door_registry(), tl, timing=Timing(wait=500))
        see(tl, "teacher")
        robot.encounter(SEQUENCE)

        def learned() -> bool:
            teacher.tick()
            robot.tick()
            return robot.knows(SEQUENCE)

        assert wait_until(learned, 20), robot.metrics.refusals
        assert (tt.answered, teacher.metrics.responses_sent) == (0, 1)


def test_a_query_that_came_before_the_agent_attached_is_answered_when_it_does() -> None:
    """A peer's liveliness is up once its session is open, and whoever sees it appear asks at
    once (spec section 4.5): a query that arrives before the agent is built on the transport
    is answered from what the agent knows as soon as it attaches, not left to the asker's next
    timed ask. Answered there, it is taken out of the agent's inbox: its tick does not
    answer it a second time."""
    pt, pa = free_port(), free_port()
    with (
        ZenohTransport("teacher", settings(pt)) as tt,
        ZenohTransport("asker", settings(pa, pt), query_timeout=30.0) as ta,
    ):
        seen: set[str] = set()

        def asker_seen() -> bool:
            seen.update(tt.appeared())
            return "asker" in seen

        assert wait_until(asker_seen)
        see(ta, "teacher")
        tt.stirred.clear()
        query = Query(id=Query.new_id(), sender="asker", sequence=SEQUENCE_KEY)
        ta.broadcast(query)
        assert tt.stirred.wait(15)  # it came, and waits in the inbox
        teacher = Agent("teacher", f"<sl><k>(new){MEMORY}<e><e>", door_registry(), tt)
        answers: list[object] = []

        def read() -> bool:
            answers.extend(ta.receive())
            return bool(answers)

        assert wait_until(read)
        teacher.tick()  # the agent reads its inbox
        assert [(a.sender, a.id, a.sequence) for a in answers if isinstance(a, Response)] == [
            ("teacher", query.id, SEQUENCE_KEY)
        ]
        assert (tt.answered, tt.refused, teacher.metrics.responses_sent) == (1, 0, 0)


def test_what_a_transport_was_given_is_kept_when_an_agent_attaches() -> None:
    with ZenohTransport("t", settings(free_port()), catalog=lambda: ["mine"]) as t:
        agent = Agent("t", f"<sl><k>(new){MEMORY}<e><e>", door_registry(), t)
        assert t.catalog is not None and t.catalog() == ["mine"]
        assert t.lookup is not None and t.lookup(agent.knowledge.keys()[0]) is not None


def test_refusals_over_zenoh_are_warnings_that_say_why(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A query that is not one, sent to a robot's queryable, is refused by its transport; an
    answer naming an action the learner does not have is refused by its agent: both at WARNING,
    visible by default, each with its reason."""
    pt, pl, px = free_port(), free_port(), free_port()
    caplog.set_level(logging.WARNING)
    with (
        ZenohTransport("teacher", settings(pt)) as tt,
        ZenohTransport("door", settings(pl, pt)) as tl,
        ZenohTransport("x", settings(px, pl), serving=False) as other,
    ):
        skill = MEMORY.replace("<a>(Push)", "<a>(Kick)")  # the door robot has no Kick
        wide = kp.Registry()
        wide.flags("DoorClosed", "HandleSeen")
        for name in ("GraspHandle", "TurnHandle", "Kick"):
            wide.declare("action", name, more_arguments=True)
        wide.declare("condition", "HandleSeen", more_arguments=True)
        Agent("teacher", f"<sl><k>(new){skill}<e><e>", wide, tt)
        robot = Agent("door", CONTROL, door_registry(), tl, timing=Timing(wait=500))
        see(tl, "teacher")
        robot.encounter(SEQUENCE)
        assert wait_until(lambda: robot.tick() is None or robot.metrics.refused > 0, 20)
        assert not robot.knows(SEQUENCE)
        see(other, "door")
        replies = list(other.session.get("ktbt/v1/knowledge/door", payload=b"not json", timeout=5))
        assert [decode(r.err.payload.to_bytes()).type for r in replies if r.err] == ["error"]
        assert all(r.err is not None for r in replies)
        assert wait_until(lambda: tl.refused == 1)
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    agent = [r.getMessage() for r in warnings if r.name == "ktbt.agent"]
    transport = [r.getMessage() for r in warnings if r.name == "ktbt.zenoh"]
    assert any("door refused knowledge: from teacher: SBT306" in m and "Kick" in m for m in agent)
    assert any(m.startswith("door refused: a query: ") for m in transport), transport
