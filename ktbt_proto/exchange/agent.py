"""The tree-timed agent: ``Parallel(Control, Teach, Learn)`` (the paper's Definition 1).

The three trees are live trees ticked in that order every tick (``spec/protocol.md`` section 4).
The control tree is the robot's own. The teach and learn trees are stringBT too, built from the
behaviours this module registers under ``ktbt.``: the teacher answers what it knows (Algorithm 1)
and then cools down under a TT1 timer; the learner asks once about an unknown sequence and waits
under a TT2 timer (Algorithm 2), merging the first acceptable answer. Teach and learn share one
cool-down flag, as in the paper, so a robot that has just asked or answered does neither for a
while. What it learns and how it checks it is :class:`~ktbt_proto.exchange.core.AgentCore`'s.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from ktbt_proto.blackboard import Blackboard
from ktbt_proto.control import ControlFactory
from ktbt_proto.exchange.core import AgentCore
from ktbt_proto.exchange.memory_policy import MemoryPolicy
from ktbt_proto.exchange.messages import Query, Response
from ktbt_proto.exchange.overhearing import Overhearing
from ktbt_proto.exchange.security import Security
from ktbt_proto.exchange.transferlog import Event
from ktbt_proto.exchange.transport import Transport
from ktbt_proto.items import sequence_key
from ktbt_proto.registry import Registry
from ktbt_proto.runtime import LiveTree
from ktbt_proto.status import FAILURE, RUNNING, SUCCESS, Status
from ktbt_proto.tree import Condition, Node, Tree

__all__ = ["Agent", "Timing"]

MAX_WAITING = 256
"""Queries, and answers to the open query, held between ticks; a newcomer beyond is refused
(the first answer wins, so what came first is what is kept)."""

ENCOUNTERED = "ktbt.encountered"
COOLING_DOWN = "ktbt.coolingDown"
QUERYING = "ktbt.querying"
TEACHING = "ktbt.teaching"

TEACH_TREE = """<sl>
    <sq>
        <c>(ktbt.CoolingDown)
        <tt1>({cooldown})
            <a>(ktbt.EndCoolDown)
        <e>
    <e>
    <sq>
        <c>(ktbt.QueryReceived)
        <a>(ktbt.Respond)
    <e>
<e>
"""

LEARN_TREE = """<msq>
    <c>(!ktbt.CoolingDown)
    <c>(ktbt.UnknownSequence)
    <tt2>({wait})
        <a>(ktbt.QueryAndWait)
    <e>
<e>
"""
# A memory sequence: the guards decide whether to start asking; once asked, the robot waits its
# full time, even if it teaches meanwhile (which sets the shared cool-down flag).


@dataclass(frozen=True)
class Timing:
    """The teach and learn trees' timing (section 4), in ticks of the agent's clock.
    ``wait``: W, how long a query waits for an answer (TT2); ``cooldown``: N, how long the
    robot neither asks nor teaches after a wait or an answer (TT1); 1,000 each, as in the
    authors' release. ``repeat_every``: while waiting, broadcast the open query again every
    this many ticks (0: once), so that peers who come into range during the wait hear it, as a
    radio beacon would."""

    wait: int = 1000
    cooldown: int = 1000
    repeat_every: int = 0

    def __post_init__(self) -> None:
        for name in ("wait", "cooldown", "repeat_every"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise ValueError(f"{name} must be a whole number of ticks, at least 0")


class Agent(AgentCore):
    """One robot's KT-BT trees, bound to a transport (section 4): every :meth:`tick` reads the
    transport, then ticks Control, Teach and Learn. The application tells the agent what it
    faces with :meth:`encounter`. ``timing``: the teach and learn trees' timers; the other
    settings are :class:`~ktbt_proto.exchange.core.AgentCore`'s.
    """

    def __init__(
        self,
        name: str,
        control: Tree | Node | str | ControlFactory,
        registry: Registry,
        transport: Transport,
        *,
        timing: Timing = Timing(),
        blackboard: Blackboard | None = None,
        security: Security = Security(),  # noqa: B008
        memory: MemoryPolicy = MemoryPolicy(),  # noqa: B008
        ear: Overhearing | None = None,
        knowledge_path: str | Path | None = None,
        slot: str = "new",
    ) -> None:
        super().__init__(
            name,
            control,
            registry,
            transport,
            blackboard=blackboard,
            security=security,
            memory=memory,
            ear=ear,
            knowledge_path=knowledge_path,
            slot=slot,
        )
        self.timing = timing
        self._asking: _QueryAndWait | None = None
        self._queries: deque[Query] = deque()
        self._responses: deque[Response] = deque()
        own = self._library()
        self.teach = LiveTree(
            TEACH_TREE.format(cooldown=timing.cooldown), own, self.blackboard, ticks=self._clock
        )
        self.learn = LiveTree(
            LEARN_TREE.format(wait=timing.wait), own, self.blackboard, ticks=self._clock
        )

    @property
    def open_query(self) -> Query | None:
        """The query the learn tree is waiting on (TT2), if any: a fleet member sends it again
        to a neighbour that appears (section 4.5)."""
        return self._asking.query if self._asking is not None else None

    def encounter(self, sequence: Iterable[Condition | str] | None) -> None:
        """The condition sequence the robot faces now (None: nothing in particular)."""
        self.blackboard[ENCOUNTERED] = None if sequence is None else sequence_key(sequence)

    def tick(self) -> Status:
        """One tick of the agent's clock: read the transport, then tick Control, Teach and
        Learn, then apply the memory policy (sections 4 and 4.2). Returns the control tree's
        status."""
        self.now += 1
        self._read()
        status = self.control.tick()
        self.teach.tick()
        self.learn.tick()
        self.tend_memory()
        return status

    def _query(self, query: Query) -> None:
        """A query waits for the teach tree, unless the robot cools down (it does not listen)
        or too many wait already (refused)."""
        if self.blackboard.get(COOLING_DOWN):
            return
        if len(self._queries) >= MAX_WAITING:
            self.refuse(f"query {query.id} from {query.sender}: too many waiting")
        else:
            self._queries.append(query)

    def _response(self, response: Response) -> int:
        """An answer to the open query waits for the learn tree; any other is not ours."""
        asking = self._asking
        if asking is None or asking.query is None or asking.query.id != response.id:
            return self._not_mine(response)
        if len(self._responses) >= MAX_WAITING:
            self.refuse(f"from {response.sender}: too many answers waiting")
        else:
            self._responses.append(response)
        return 0

    def _cool_down(self, bb: Blackboard) -> None:
        """Start (or keep) the shared cool-down. Queries still waiting are dropped: a robot
        in cool-down does not listen, and their askers will have stopped waiting by its end."""
        bb[COOLING_DOWN] = True
        self._queries.clear()

    # -- the library behaviours of the teach and learn trees ----------------------------------

    def _library(self) -> Registry:
        own = Registry()
        bb = self.blackboard
        own.add_condition("ktbt.CoolingDown", lambda _bb: bool(bb.get(COOLING_DOWN)))
        own.add_condition("ktbt.QueryReceived", lambda _bb: bool(self._queries))
        own.add_condition("ktbt.UnknownSequence", self._unknown)
        own.add_action("ktbt.EndCoolDown", self._end_cooldown)
        own.add_action("ktbt.Respond", self._respond)
        agent = self

        class QueryAndWait(_QueryAndWait):
            def __init__(self, bb: Blackboard) -> None:
                super().__init__(bb, agent)

        own.add_action("ktbt.QueryAndWait", QueryAndWait)
        return own

    def _unknown(self, bb: Blackboard) -> bool:
        key = bb.get(ENCOUNTERED)
        return bool(key) and key not in self.knowledge

    def _end_cooldown(self, bb: Blackboard) -> Status:
        bb[COOLING_DOWN] = False
        bb[TEACHING] = False
        return SUCCESS

    def _respond(self, bb: Blackboard) -> Status:
        """Algorithm 1: take one query; answer it if the sequence is known."""
        query = self._queries.popleft()
        if not self.answer(query):
            return FAILURE
        self._cool_down(bb)  # one query per cool-down: the others' askers will time out
        bb[TEACHING] = True
        return SUCCESS


class _QueryAndWait:
    """Algorithm 2 as a stateful action: ask once, then wait for the first acceptable answer.

    Its TT2 parent halts it when the wait is over: the query is then lost."""

    def __init__(self, bb: Blackboard, agent: Agent) -> None:
        self.bb = bb
        self.agent = agent
        self.query: Query | None = None
        self.asked_at = 0
        agent._asking = self

    def tick(self) -> Status:
        agent = self.agent
        if self.query is None:
            key = self.bb.get(ENCOUNTERED)
            if not key:
                return FAILURE
            if agent.learn_buffered(key):  # overheard earlier: no query, no wait
                return SUCCESS
            self.query = Query(id=Query.new_id(), sender=agent.name, sequence=key)
            agent.transport.broadcast(self.query)
            agent.metrics.queries_sent += 1
            agent._record(Event.QUERY_SENT, id=self.query.id, sequence=key)
            self.bb[QUERYING] = True
            self.asked_at = agent.now
            return RUNNING
        while agent._responses:  # only answers to this query are let in (``Agent._response``)
            response = agent._responses.popleft()
            agent.metrics.responses_received += 1
            new = self.query.sequence not in agent.knowledge
            if agent.accept(response, self.query):
                agent.metrics.learned_direct += new
                self._finish()
                return SUCCESS
        waited = agent.now - self.asked_at
        every = agent.timing.repeat_every
        if every and waited > 0 and waited % every == 0:
            agent.transport.broadcast(self.query)
        return RUNNING

    def halt(self) -> None:
        self.agent.metrics.queries_lost += 1
        self._finish()

    def _finish(self) -> None:
        agent = self.agent
        while agent._responses:  # more answers to the finished query: nobody asks now
            agent._late(agent._responses.popleft())
        if self.query is not None:
            agent._closed_query(self.query.id)
        self.query = None
        self.bb[QUERYING] = False
        self.agent._cool_down(self.bb)
