"""A KT-BT agent: ``Parallel(Control, Teach, Learn)`` (the paper's Definition 1).

The three trees are live trees ticked in that order every tick. The control tree is the
robot's own. The teach and learn trees are stringBT too, built from the behaviours this module
registers under ``ktbt.``: the teacher answers what it knows (Algorithm 1) and then cools down
under a TT1 timer; the learner asks once about an unknown sequence and waits under a TT2 timer
(Algorithm 2), merging the first acceptable answer. Teach and learn share one cool-down flag, as
in the paper, so a robot that has just asked or answered does neither for a while.

Whatever a peer sends is checked before it can touch the control tree: its signatures under
the agent's trust policy, size, depth and number limits, parsing, validation against the robot's
own registry (names, argument types and ranges), and that it answers the sequence asked. A
refusal is counted and logged with its reason, and the control tree stays as it was. Every
exchange is written to the transfer log when one is given (``spec/protocol.md`` section 8).
"""

from __future__ import annotations

import logging
import os
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from pydantic import ValidationError

from ktbt_proto.blackboard import Blackboard
from ktbt_proto.control import ControlFactory, ControlTree
from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.knowledge import (
    MAX_FILE,
    Knowledge,
    KnowledgeBase,
    remove_stale_temporaries,
    salvage,
    sequence_key,
)
from ktbt_proto.exchange.memory import MemoryPolicy
from ktbt_proto.exchange.messages import Query, Response
from ktbt_proto.exchange.overhearing import Ear, Heard, Overhear
from ktbt_proto.exchange.receiving import RECEIVE_LIMITS, Refused, read, vet
from ktbt_proto.exchange.signing import Identity
from ktbt_proto.exchange.transferlog import TransferLog
from ktbt_proto.exchange.transport import NetworkError, Transport
from ktbt_proto.exchange.trust import Policy, TrustStore, refusal
from ktbt_proto.formatter import format_tree
from ktbt_proto.limits import Limits
from ktbt_proto.merge import conditions as parse_conditions
from ktbt_proto.registry import Registry
from ktbt_proto.runtime import LiveTree
from ktbt_proto.status import FAILURE, RUNNING, SUCCESS, Status
from ktbt_proto.tree import Condition, Node, Tree

log = logging.getLogger("ktbt.agent")

__all__ = ["RECEIVE_LIMITS", "Agent", "Metrics", "Overhear"]
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


@dataclass
class Metrics:
    """What an experiment reads off an agent."""

    queries_sent: int = 0
    queries_received: int = 0
    responses_sent: int = 0
    responses_received: int = 0
    queries_lost: int = 0
    refused: int = 0
    refusals: deque[tuple[int, str]] = field(default_factory=lambda: deque(maxlen=256))
    """The latest refusals (tick, reason); ``refused`` counts them all."""
    learned: dict[str, tuple[int, str]] = field(default_factory=dict)
    """Sequence key -> (tick it was learned, who taught it), for what it holds now."""
    forgotten: int = 0
    """Learned items forgotten: idle, expired, evicted or on request (section 4.2)."""
    learned_direct: int = 0
    """Items learned from an answer to this agent's own query."""
    learned_buffered: int = 0
    """Items learned from an overheard answer kept in the buffer, when needed (section 4.3)."""
    learned_passive: int = 0
    """Items learned from an overheard answer as soon as it was heard (section 4.3)."""
    overheard: int = 0
    """Answers to others' queries received (section 4.3)."""
    overheard_refused: int = 0
    """Of those, refused: a check failed, or the buffer was full (also counted in ``refused``)."""
    late_answers: int = 0
    """Answers to one of this agent's own recent queries that came after the first acceptable
    answer or after the wait: honest, too late, discarded; not refusals (section 2)."""
    network_errors: int = 0
    """The network's own errors about this agent's queries (a get that timed out): not
    refusals, since no peer sent them (spec/protocol.md section 3)."""


class Agent:
    """One robot's KT-BT trees, bound to a transport.

    ``control``: the robot's control tree (with a ``<k>(new)`` placeholder for learned
    knowledge), or a backend's factory (``spec/protocol.md`` section 4.4); ``registry``: its
    conditions and actions, against which received knowledge is checked. The application tells
    the agent what it faces with :meth:`encounter`.
    """

    def __init__(
        self,
        name: str,
        control: Tree | Node | str | ControlFactory,
        registry: Registry,
        transport: Transport,
        *,
        blackboard: Blackboard | None = None,
        wait_ticks: int = 1000,
        cooldown_ticks: int = 1000,
        knowledge_path: str | Path | None = None,
        slot: str = "new",
        receive_limits: Limits = RECEIVE_LIMITS,
        teach_if: Callable[[Query], bool] | None = None,
        repeat_every: int = 0,
        identity: Identity | None = None,
        policy: Policy = Policy.ANY,
        trust: TrustStore | None = None,
        log: TransferLog | None = None,
        memory: MemoryPolicy | None = None,
        overhear: Overhear = "off",
        buffer_size: int = 16,
    ) -> None:
        self.name = name
        self.ear = Ear(overhear, buffer_size)
        """What to do with answers addressed to others, and the buffer (section 4.3)."""
        self.last_answer: Response | None = None
        """The last answer this agent sent (what a listener nearby may overhear)."""
        self.memory = memory or MemoryPolicy()
        """How much this robot may hold and for how long (section 4.2)."""
        self._active = 0
        """The last tick at which something was learned (the idle rule's clock)."""
        self.identity = identity
        """This robot's key pair: it signs the items it authors and every answer it sends."""
        self.policy = policy
        self.trust = trust
        """Which answers are accepted, by their signatures (``ktbt_proto.exchange.trust``)."""
        self.log = log
        if hasattr(transport, "screen"):
            # A transport that keeps one answer per peer (zenoh) checks signatures first, so a
            # forgery on a peer's key does not take that peer's place.
            transport.screen = lambda r: refusal(r, self.policy, self.trust)
        self.repeat_every = repeat_every
        """While waiting, broadcast the open query again every this many ticks (0: once), so
        that peers who come into range during the wait hear it, as a radio beacon would."""
        self.teach_if = teach_if
        """The application's own teaching rule, asked before answering a query it could answer
        (the search-and-rescue robots do not teach while carrying a target)."""
        self.transport = transport
        self.slot = slot
        self.receive_limits = receive_limits
        self.knowledge_path = Path(knowledge_path) if knowledge_path is not None else None
        self.metrics = Metrics()
        self.blackboard = Blackboard() if blackboard is None else blackboard
        self.now = 0
        if isinstance(control, ControlTree):
            raise TypeError(
                f"Agent takes its control tree as stringBT or as a backend's factory such as "
                f"py_trees_control(tree), not a built {type(control).__name__}: the agent builds "
                "it around its own registry, blackboard and clock (spec/protocol.md section 4.4)"
            )
        self.control: ControlTree = (
            control(registry, self.blackboard, self._clock)
            if callable(control)
            else LiveTree(control, registry, self.blackboard, ticks=self._clock)
        )
        # A backend may know more than ``registry`` (a py_trees tree's own behaviours).
        self.registry: Registry = getattr(self.control, "registry", registry)
        self.knowledge = KnowledgeBase.from_tree(self.control.tree)
        self.wait_ticks = wait_ticks
        self.cooldown_ticks = cooldown_ticks
        self._cooling_since: int | None = None
        self._asking: _QueryAndWait | None = None
        self._queries: deque[Query] = deque()
        self._responses: deque[Response] = deque()
        self._open: Query | None = None
        self._answered = False
        self._closed: dict[str, None] = {}
        """The ids of this agent's latest closed queries (insertion-ordered, bounded)."""
        self._heard: dict[str, Query] = {}
        if self.knowledge_path is not None and self.knowledge_path.exists():
            self._resume(self.knowledge_path)
        own = self._library()
        self.teach = LiveTree(
            TEACH_TREE.format(cooldown=cooldown_ticks), own, self.blackboard, ticks=self._clock
        )
        self.learn = LiveTree(
            LEARN_TREE.format(wait=wait_ticks), own, self.blackboard, ticks=self._clock
        )

    def _clock(self) -> int:
        """The agent's clock: every timer of its three trees measures against ``now``."""
        return self.now

    # -- what the application calls -----------------------------------------------------------

    def encounter(self, sequence: Iterable[Condition | str] | None) -> None:
        """The condition sequence the robot faces now (None: nothing in particular)."""
        self.blackboard[ENCOUNTERED] = (
            None if sequence is None else sequence_key(parse_conditions(sequence))
        )

    def knows(self, sequence: Iterable[Condition | str] | str) -> bool:
        key = sequence if isinstance(sequence, str) else sequence_key(parse_conditions(sequence))
        return key in self.knowledge

    def next_due(self) -> int | None:
        """The first tick at which ticking this agent could change something if nothing new
        arrives and the control tree's inputs stay as they are: messages to handle, a wait or
        cool-down ending, a query to repeat. None: nothing pending at all. A caller that ticks
        the agent then (and whenever a message arrives) sees exactly what ticking it every
        tick would give, because every timer reads the agent's clock. Timers inside the control
        tree are not counted: skipping ticks suits a control tree without them (the
        simulator's has none)."""
        now = self.now
        if self._queries or self._responses:
            return now + 1
        due: int | None = None
        asking = self._asking
        if asking is not None and asking.query is not None:
            start = asking.asked_at
            due = start + max(self.wait_ticks - 1, 0)  # TT2's last tick
            if self.repeat_every:
                beacon = start + ((now - start) // self.repeat_every + 1) * self.repeat_every
                due = min(due, beacon)
        since = self._cooling_since
        if since is not None and self.blackboard.get(COOLING_DOWN):
            # TT1 starts on the tick after the flag was set and runs its child N ticks later.
            end = since + 1 if now <= since else since + 1 + self.cooldown_ticks
            due = end if due is None else min(due, end)
        return max(due, now + 1) if due is not None else None

    def _cool_down(self, bb: Blackboard) -> None:
        """Start (or keep) the shared cool-down. Queries still waiting are dropped: a robot
        in cool-down does not listen, and their askers will have stopped waiting by its end."""
        if not bb.get(COOLING_DOWN):
            self._cooling_since = self.now
        bb[COOLING_DOWN] = True
        self._queries.clear()

    def tick(self, *, control: bool = True, now: int | None = None) -> Status | None:
        """One tick: read the transport, then tick Control, Teach and Learn.

        ``control=False`` leaves the control tree out of this tick: only for a caller that knows
        the control tree's inputs have not changed and its behaviours keep no state, so that
        ticking it again would change nothing. ``now`` sets the agent's clock (the tick number
        its metrics are stamped with) when the caller keeps its own.
        """
        self.now = self.now + 1 if now is None else now
        for message in self.transport.receive():
            if isinstance(message, NetworkError):
                self._network_error(message)
            elif isinstance(message, Query):
                self._received(message)
                if self.blackboard.get(COOLING_DOWN):  # a cooling robot does not listen
                    continue
                if len(self._queries) >= MAX_WAITING:
                    self.refuse(f"query {message.id} from {message.sender}: too many waiting")
                else:
                    self._queries.append(message)
            elif isinstance(message, Response):
                asking = self._asking
                if asking is None or asking.query is None or asking.query.id != message.id:
                    self._not_mine(message)
                elif len(self._responses) >= MAX_WAITING:
                    self.refuse(f"from {message.sender}: too many answers waiting")
                else:
                    self._responses.append(message)
        status = self.control.tick() if control else None
        self.teach.tick()
        self.learn.tick()
        self.tend_memory()
        return status

    @property
    def overhear(self) -> Overhear:
        return self.ear.mode

    def _network_error(self, error: NetworkError) -> None:
        """The network's own error about a query of ours: counted apart, logged as its own
        event, never a refusal (spec/protocol.md section 3)."""
        self.metrics.network_errors += 1
        log.debug("%s: network error on query %s: %s", self.name, error.id, error.reason)
        self._record("network-error", id=error.id, reason=error.reason)

    def _received(self, query: Query) -> None:
        self.metrics.queries_received += 1
        self._record("query-received", sender=query.sender, id=query.id, sequence=query.sequence)

    # -- application-timed teaching and learning (spec/protocol.md section 4.1) ---------------

    HEARD_LIMIT = 1024
    """Open queries an application-timed agent remembers, one per asker (oldest dropped)."""

    def ask(self, sequence: Iterable[Condition | str] | str) -> Query:
        """Broadcast a query now, outside the learn tree, for an application that owns the
        wait and cool-down itself (the simulator's release timing). The query stays open until
        :meth:`close_query`; :meth:`receive` merges the first acceptable answer to it."""
        if self._open is not None:
            self.close_query()
        key = sequence if isinstance(sequence, str) else sequence_key(parse_conditions(sequence))
        query = Query(id=Query.new_id(), sender=self.name, sequence=key)
        self._open, self._answered = query, False
        self.transport.broadcast(query)
        self.metrics.queries_sent += 1
        return query

    @property
    def open_query(self) -> Query | None:
        """The query :meth:`ask` sent and not yet closed (answered or not)."""
        return self._open

    def announce(self, to: str) -> None:
        """Send the open, unanswered query again to one peer (one that just came into range),
        so that it stays answerable for the asker's whole wait."""
        if self._open is not None and not self._answered:
            self.transport.send(to, self._open)

    def close_query(self) -> None:
        """The asker's wait is over: a query nobody answered counts as lost, and answers to it
        that arrive later are late answers (section 2)."""
        if self._open is not None:
            if not self._answered:
                self.metrics.queries_lost += 1
            self._closed_query(self._open.id)
        self._open = None

    RECENT_QUERIES = 256
    """Closed queries whose late answers are told apart from refusals (oldest forgotten)."""

    def _closed_query(self, id: str) -> None:
        closed = self._closed
        closed[id] = None
        if len(closed) > self.RECENT_QUERIES:
            del closed[next(iter(closed))]

    def _late(self, response: Response) -> None:
        """An answer to one of this agent's own queries, after it was answered or closed:
        discarded, counted apart, never a refusal (spec/protocol.md section 2)."""
        self.metrics.late_answers += 1
        log.debug("%s: late answer from %s to query %s", self.name, response.sender, response.id)
        self._record("late-answer", sender=response.sender, id=response.id)

    def heard(self, sender: str) -> Query | None:
        """The latest query received from ``sender`` by :meth:`receive`, if any."""
        return self._heard.get(sender)

    def answer(self, query: Query) -> bool:
        """Answer ``query`` (one this agent heard) if its sequence is known, signed as the tree's
        answers are; True if sent. Whom to answer and when is the caller's rule."""
        item = self.knowledge.lookup(query.sequence)
        if item is None:
            return False
        subtree = format_tree(item.subtree, "compact")
        author, signature = item.author, item.signature
        if author is None and self.identity is not None:  # its own knowledge: it is the author
            signed = self.identity.sign_item(query.sequence, subtree)
            author, signature = signed.author, signed.signature
        try:
            response = Response(
                id=query.id,
                sender=self.name,
                sequence=query.sequence,
                subtree=subtree,
                author=author,
                signature=signature,
            )
            if self.identity is not None:
                response = self.identity.sign_reply(response)
        except ValidationError as exc:  # too large to send: no peer could accept it
            reason = exc.errors()[0].get("msg", "invalid")
            self.refuse(f"cannot answer {query.sequence[:80]} to {query.sender}: {reason}")
            return False
        self.transport.send(query.sender, response)
        self.last_answer = response
        self.metrics.responses_sent += 1
        self._record(
            "answer-sent", to=query.sender, id=query.id, sequence=query.sequence, author=author
        )
        return True

    def receive(self) -> int:
        """Read the transport without ticking any tree: queries are remembered by asker (for
        :meth:`heard`); an answer to the open query is checked and merged (section 2), any
        other answer refused. Returns how many answers it accepted."""
        learned = 0
        heard = self._heard
        for message in self.transport.receive():
            if isinstance(message, NetworkError):
                self._network_error(message)
            elif isinstance(message, Query):
                self._received(message)
                heard.pop(message.sender, None)
                heard[message.sender] = message
                if len(heard) > self.HEARD_LIMIT:
                    del heard[next(iter(heard))]
            elif isinstance(message, Response):
                asked = self._open
                if asked is None or self._answered or asked.id != message.id:
                    learned += self._not_mine(message)
                    continue
                self.metrics.responses_received += 1
                new = asked.sequence not in self.knowledge
                if self.accept(message, asked):
                    self._answered = True
                    self.metrics.learned_direct += new
                    learned += 1
        return learned

    # -- overhearing (spec/protocol.md section 4.3) -------------------------------------------

    def _not_mine(self, response: Response) -> int:
        """An answer to somebody else's query (or to none): refused unless this agent
        overhears; then learned at once (``update``) or kept for later (``buffer``), after the
        same checks as a direct answer. Returns how many items were learned."""
        heard = self.ear.hear(response, response.sequence in self.knowledge, self._overheard)
        if heard is Heard.OFF:
            mine = self._open is not None and self._open.id == response.id
            if mine or response.id in self._closed:
                self._late(response)
            else:
                self.refuse(f"from {response.sender}: an answer to no open question")
            return 0
        self.metrics.overheard += 1
        if heard is Heard.FULL:
            self.metrics.overheard_refused += 1
            self.refuse(f"from {response.sender}: overheard answer, buffer full")
        elif heard is Heard.LEARNED:
            self.metrics.learned_passive += 1
            return 1
        return 0

    def _overheard(self, response: Response) -> bool:
        asked = Query(id=response.id, sender=self.name, sequence=response.sequence)
        if self.accept(response, asked):
            return True
        self.metrics.overheard_refused += 1
        return False

    @property
    def buffered(self) -> list[str]:
        """The sequences of the overheard answers kept for later, in the order heard."""
        return self.ear.buffered

    def learn_buffered(self, sequence: Iterable[Condition | str] | str) -> bool:
        """Learn ``sequence`` from an overheard answer kept in the buffer, without asking; True
        if it was there and passed the checks (the entry is used up either way)."""
        key = sequence if isinstance(sequence, str) else sequence_key(parse_conditions(sequence))
        response = self.ear.take(key)
        if response is None or key in self.knowledge:
            return False
        if self._overheard(response):
            self.metrics.learned_buffered += 1
            return True
        return False

    # -- memory (spec/protocol.md section 4.2) ------------------------------------------------

    def _held(self) -> int:
        if self.memory.count_innate:
            return len(self.knowledge)
        return sum(1 for item in self.knowledge if item.source is not None)

    def _learned_items(self) -> list[Knowledge]:
        return [item for item in self.knowledge if item.source is not None]

    def _last_use(self, item: Knowledge) -> int:
        """The last tick the item was used, or learned if it has not been used since."""
        used = self.control.last_used(item.segment, item.conditions)
        learned = self.metrics.learned.get(item.key, (0, ""))[0]
        return max(learned, used if used is not None else -1)

    def _make_room(self) -> bool:
        """Whether one more item fits, evicting the least recently used learned item if the
        policy says so."""
        capacity = self.memory.capacity
        if capacity is None or self._held() < capacity:
            return True
        if self.memory.when_full != "evict":
            return False
        learned = self._learned_items()
        if not learned:
            return False
        oldest = min(learned, key=self._last_use)
        self.forget(oldest.key, reason="evicted")
        return self._held() < capacity

    def tend_memory(self) -> int:
        """Apply the policy's forgetting at tick ``now``: everything learned after
        ``forget_after`` idle ticks, each item after ``expire_after`` ticks unused. ``tick``
        calls it; an application-timed owner calls it itself. Returns how many were forgotten."""
        policy = self.memory
        if policy.forget_after is None and policy.expire_after is None:
            return 0
        learned = self._learned_items()
        if not learned:
            return 0
        now = self.now
        uses = {item.key: self._last_use(item) for item in learned}
        if policy.forget_after is not None:
            active = max(self._active, *uses.values())
            if now - active >= policy.forget_after:
                return self.forget_learned(reason="idle")
        forgotten = 0
        if policy.expire_after is not None:
            for item in learned:
                if now - uses[item.key] >= policy.expire_after:
                    forgotten += self.forget(item.key, reason="expired")
        return forgotten

    def forget(self, sequence: Iterable[Condition | str] | str, *, reason: str = "asked") -> bool:
        """Forget a learned item: from the running tree at the next tick boundary at which it is
        not running (``LiveTree.forget``), from the knowledge base and from the saved file.
        Innate knowledge is never forgotten. True if the item was learned and is now gone."""
        key = sequence if isinstance(sequence, str) else sequence_key(parse_conditions(sequence))
        item = self.knowledge.lookup(key)
        if item is None or item.source is None:
            return False
        self.control.forget(item.segment, item.conditions)
        self.knowledge.remove(key)
        self.metrics.learned.pop(key, None)
        self.metrics.forgotten += 1
        self._record("forgotten", sequence=key, reason=reason)
        if self.knowledge_path is not None:
            try:
                self._persisted().save(self.knowledge_path)
            except OSError as exc:
                self.refuse(f"cannot save knowledge to {self.knowledge_path}: {exc}")
        return True

    def forget_learned(self, *, reason: str = "asked") -> int:
        """Forget everything learned at once (the release's ephemeral rule); innate knowledge
        stays. Returns how many items were forgotten."""
        return sum(self.forget(item.key, reason=reason) for item in self._learned_items())

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
        known = self.knowledge.lookup(query.sequence) is not None
        if known and self.teach_if is not None and not self.teach_if(query):
            return FAILURE
        if not self.answer(query):
            return FAILURE
        self._cool_down(bb)  # one query per cool-down: the others' askers will time out
        bb[TEACHING] = True
        return SUCCESS

    # -- learning -------------------------------------------------------------------------------

    def _record(self, event: str, **fields: object) -> None:
        if self.log is not None:
            self.log.record(event, peer=self.name, tick=self.now, **fields)

    def refuse(self, reason: str) -> None:
        self.metrics.refused += 1
        self.metrics.refusals.append((self.now, reason))
        log.info("%s refused knowledge: %s", self.name, reason)
        self._record("refused", reason=reason)

    def accept(self, response: Response, asked: Query) -> bool:
        """The receive pipeline (spec/protocol.md section 2), the one every answer goes through,
        direct, overheard or buffered: log it, check it (``ktbt_proto.exchange.receiving``), make
        room
        under the memory policy, merge it, record and save it. True if the item is known now
        (learned, or known already); a refusal is counted and logged with its reason."""
        self._record(
            "answer-received",
            sender=response.sender,
            id=response.id,
            sequence=response.sequence,
            author=response.author,
        )
        try:
            vet(response, asked.sequence, self.policy, self.trust)
            if asked.sequence in self.knowledge:  # known already (perhaps innate): nothing to do
                return True
            conds, subtree = read(response, self.receive_limits, self.registry)
            if not self._make_room():
                raise Refused(f"from {response.sender}: memory full ({self.memory.capacity} items)")
            changed = self.control.merge(subtree, self.slot, when=conds)
        except Refused as refused:
            self.refuse(refused.reason)
            return False
        except StringBTError as err:
            self.refuse(f"from {response.sender}: {err.code.value} {err.message}")
            return False
        if changed:
            received = datetime.now(UTC).isoformat(timespec="seconds")
            self._learned(
                Knowledge(
                    conds,
                    subtree,
                    self.slot,
                    response.sender,
                    self.now,
                    author=response.author,
                    signature=response.signature,
                    received_at=received,
                )
            )
        return True

    def _learned(self, item: Knowledge) -> None:
        self._active = self.now
        self.knowledge.add(item)
        self.metrics.learned[item.key] = (self.now, item.source or "")
        self._record("merged", sequence=item.key, teacher=item.source, author=item.author)
        if self.knowledge_path is not None:
            try:
                self._persisted().save(self.knowledge_path)
            except OSError as exc:  # the robot keeps what it learned in memory and goes on
                self.refuse(f"cannot save knowledge to {self.knowledge_path}: {exc}")

    def _persisted(self) -> KnowledgeBase:
        return KnowledgeBase(k for k in self.knowledge if k.source is not None)

    def _resume(self, path: Path) -> None:
        """Merge what a previous run learned. A damaged file is refused with its reason, the
        items it still holds whole are kept, and it is moved aside (``FILE.damaged-TIME``)
        before anything is saved, so it is never overwritten; a file that cannot be read at
        all is left alone and nothing is saved over it. Temporary files a killed save left
        behind are removed."""
        for tmp in remove_stale_temporaries(path):
            log.info("%s removed %s, left by an interrupted save", self.name, tmp)
        try:
            saved = list(KnowledgeBase.load(path, self.receive_limits))
        except OSError as exc:
            self.refuse(f"cannot resume from {path}: {exc}; nothing will be saved over it")
            self.knowledge_path = None
            return
        except (ValueError, StringBTError) as exc:
            try:
                with open(path, "rb") as f:
                    text = f.read(MAX_FILE).decode("utf-8", "replace")
            except OSError:
                text = ""
            saved = salvage(text, self.receive_limits)
            try:
                if not path.is_file() or path.is_symlink():
                    raise OSError(0, "not a regular file")
                aside = _set_aside(path)
                where = f"moved to {aside.name}"
            except OSError as err:
                self.knowledge_path = None
                where = f"cannot be moved aside ({err.strerror}); nothing will be saved over it"
            self.refuse(
                f"cannot resume from {path}: {str(exc).splitlines()[0]}; "
                f"kept {len(saved)} whole items, the file {where}"
            )
        for item in saved:
            try:
                self.control.merge(item.subtree, item.segment, when=item.conditions)
            except StringBTError as err:
                self.refuse(f"saved knowledge {item.key}: {err.code.value} {err.message}")
                continue
            self.knowledge.add(item)
            self.metrics.learned[item.key] = (0, item.source or "")


def _set_aside(path: Path) -> Path:
    """Move a damaged file to ``FILE.damaged-TIME`` (``-2``, ``-3``... if that name is taken):
    linked under the new name first, which never replaces a file, then unlinked, so no aside
    file, and nothing in the damaged one, is ever overwritten (spec/protocol.md section 5)."""
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S")
    for n in range(1, 1000):
        aside = path.with_name(f"{path.name}.damaged-{stamp}" + (f"-{n}" if n > 1 else ""))
        try:
            os.link(path, aside)
        except FileExistsError:
            continue
        path.unlink()
        return aside
    raise OSError(0, "too many damaged files set aside")


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
            agent._record("query-sent", id=self.query.id, sequence=key)
            self.bb[QUERYING] = True
            self.asked_at = agent.now
            return RUNNING
        while agent._responses:  # only answers to this query are let in (``Agent.tick``)
            response = agent._responses.popleft()
            agent.metrics.responses_received += 1
            new = self.query.sequence not in agent.knowledge
            if agent.accept(response, self.query):
                agent.metrics.learned_direct += new
                self._finish()
                return SUCCESS
        waited = agent.now - self.asked_at
        if agent.repeat_every and waited > 0 and waited % agent.repeat_every == 0:
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
