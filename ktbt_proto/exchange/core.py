"""What every agent is, whoever times it: one robot's knowledge and the one way into it.

An agent (``spec/protocol.md`` section 4) holds a control tree with a placeholder for learned
knowledge, the registry received knowledge is checked against, the knowledge base read off the
tree, its memory policy (section 4.2), its overhearing (section 4.3) and its security settings
(identity, trust policy and store, transfer log: sections 7 and 8). Every answer, direct,
overheard or buffered, takes the one accept pipeline (:meth:`AgentCore.accept`, section 2):
checked, given room, merged, recorded and saved (section 5). Every answer it gives is made by
``ktbt_proto.exchange.answers.answer_to``.

Two drivers time it: the paper's teach and learn trees ticked with the control tree
(``ktbt_proto.exchange.agent.Agent``), or the application's own calls
(``ktbt_proto.exchange.application.ApplicationTimedAgent``, section 4.1). A refusal is counted
and logged at WARNING with its reason; the control tree stays as it was. The network's own errors
are counted apart, never refusals (section 3).
"""

from __future__ import annotations

import logging
import os
from collections import deque
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from pydantic import ValidationError

from ktbt_proto.blackboard import Blackboard
from ktbt_proto.control import ControlFactory, ControlTree
from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.answers import answer_to
from ktbt_proto.exchange.knowledge import (
    MAX_FILE,
    Knowledge,
    KnowledgeBase,
    remove_stale_temporaries,
    salvage,
)
from ktbt_proto.exchange.memory_policy import MemoryPolicy, WhenFull
from ktbt_proto.exchange.messages import Query, Response
from ktbt_proto.exchange.overhearing import Heard, Overhearing
from ktbt_proto.exchange.receiving import RECEIVE_LIMITS, Refused, check_provenance, read_item
from ktbt_proto.exchange.refusals import Throttle, internal_error
from ktbt_proto.exchange.security import Security
from ktbt_proto.exchange.transferlog import Event, TransferLog
from ktbt_proto.exchange.transport import NetworkError, Transport
from ktbt_proto.items import sequence_key
from ktbt_proto.registry import Registry
from ktbt_proto.runtime import LiveTree
from ktbt_proto.tree import Condition, Node, Tree

log = logging.getLogger("ktbt.agent")

__all__ = ["AgentCore", "Metrics"]


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


class AgentCore:
    """One robot's knowledge, bound to a transport; a driver (:class:`Agent` or
    :class:`ApplicationTimedAgent`) decides when it asks and answers (section 4).

    ``control``: the robot's control tree as stringBT (with a ``<k>(new)`` placeholder for
    learned knowledge), or a backend's factory (section 4.4); ``registry``: its conditions and
    actions, against which received knowledge is checked (section 2). ``blackboard``: the
    control tree's (a new one if None). ``security``: its key pair, trust policy and store, and
    transfer log (sections 7 and 8). ``memory``: how much it may hold and for how long (section
    4.2). ``ear``: what it does with answers to others' queries (section 4.3; None: refuses
    them). ``knowledge_path``: where what it learns is saved, and resumed from (section 5).
    ``slot``: the placeholder learned knowledge goes into.
    """

    RECENT_QUERIES = 256
    """Closed queries whose late answers are told apart from refusals (oldest forgotten)."""

    def __init__(
        self,
        name: str,
        control: Tree | Node | str | ControlFactory,
        registry: Registry,
        transport: Transport,
        *,
        blackboard: Blackboard | None = None,
        security: Security = Security(),  # noqa: B008 (frozen: one default is safe to share)
        memory: MemoryPolicy = MemoryPolicy(),  # noqa: B008 (frozen too)
        ear: Overhearing | None = None,
        knowledge_path: str | Path | None = None,
        slot: str = "new",
    ) -> None:
        self.name = name
        self.transport = transport
        self.registry = registry
        self.security = security
        self.memory = memory
        self.ear = ear or Overhearing()
        self.slot = slot
        self.knowledge_path = Path(knowledge_path) if knowledge_path is not None else None
        self.metrics = Metrics()
        self._warn = Throttle(log.warning)  # a flood of refusals is a few lines and a count
        self.blackboard = Blackboard() if blackboard is None else blackboard
        self.now = 0
        """The agent's clock, in ticks: every timer of its trees reads it, and its metrics and
        log records are stamped with it."""
        self.last_answer: Response | None = None
        """The last answer this agent sent (what a listener nearby may overhear)."""
        self._active = 0
        """The last tick at which something was learned (the idle rule's clock)."""
        self._closed: dict[str, None] = {}
        """The ids of this agent's latest closed queries (insertion-ordered, bounded)."""
        self._saves_held = 0
        """How many :meth:`saving_once` blocks are open: a save inside one waits for its end."""
        self._unsaved = False
        """Whether a save waits for the end of the outermost :meth:`saving_once` block."""
        if isinstance(control, ControlTree):
            raise TypeError(
                f"Agent takes its control tree as stringBT or as a backend's factory such as "
                f"py_trees_control(tree), not a built {type(control).__name__}: the agent builds "
                "it around its own registry, blackboard and clock (spec/protocol.md section 4.4)"
            )
        if not callable(control) and not isinstance(control, str | Tree | Node):
            kind = type(control)
            hint = (
                "pass py_trees_control(tree, behaviours={...}) from ktbt_proto"
                if kind.__module__.split(".")[0] == "py_trees"
                else "pass stringBT text, a Tree, or a backend's factory"
            )
            raise TypeError(f"Agent cannot run a {kind.__name__} as its control tree: {hint}")
        self.control: ControlTree = (
            control(registry, self.blackboard, self._clock)
            if callable(control)
            else LiveTree(control, registry, self.blackboard, ticks=self._clock)
        )
        # A backend may know more than ``registry`` (a py_trees tree's own behaviours).
        self.registry = self.control.registry
        self.knowledge = KnowledgeBase.from_tree(self.control.tree)
        if self.knowledge_path is not None and self.knowledge_path.exists():
            self._resume(self.knowledge_path)
        # A network transport serves what the agent knows, and checks signatures before an
        # answer takes its sender's one place (spec/protocol.md sections 3 and 4.5).
        transport.attach(self)

    def _clock(self) -> int:
        """The agent's clock: every timer of its trees measures against ``now``."""
        return self.now

    @property
    def log(self) -> TransferLog | None:
        """The transfer log (``security.log``), section 8."""
        return self.security.log

    def knows(self, sequence: Iterable[Condition | str] | str) -> bool:
        return sequence_key(sequence) in self.knowledge

    # -- reading the transport (each driver says what becomes of a query and an answer) -------

    def _read(self) -> int:
        """Drain the transport once: the network's errors are counted apart, each query and
        answer handed to the driver. Returns how many answers were accepted."""
        accepted = 0
        with self.saving_once():  # the answers read together: one save (section 5)
            for message in self.transport.receive():
                if isinstance(message, NetworkError):
                    self._network_error(message)
                elif isinstance(message, Query):
                    self.metrics.queries_received += 1
                    self._record(
                        Event.QUERY_RECEIVED,
                        sender=message.sender,
                        id=message.id,
                        sequence=message.sequence,
                    )
                    self._query(message)
                elif isinstance(message, Response):
                    accepted += self._response(message)
        return accepted

    def _query(self, query: Query) -> None:
        raise NotImplementedError

    def _response(self, response: Response) -> int:
        raise NotImplementedError

    def _network_error(self, error: NetworkError) -> None:
        """The network's own error about a query of ours: counted apart, logged as its own
        event, never a refusal (spec/protocol.md section 3)."""
        self.metrics.network_errors += 1
        log.debug("%s: network error on query %s: %s", self.name, error.id, error.reason)
        self._record(Event.NETWORK_ERROR, id=error.id, reason=error.reason)

    # -- answering ------------------------------------------------------------------------------

    def answer(self, query: Query) -> bool:
        """Answer ``query`` (one this agent heard): one response for each of its sequences that
        is known (section 1), made by ``answer_to`` (section 2, signed as section 7 says); True
        if one was sent. Whom to answer and when is the driver's rule (section 4 or 4.1)."""
        sent = False
        for sequence in query.sequences:
            item = self.knowledge.lookup(sequence)
            if item is None:
                continue
            try:
                response = answer_to(query, self.name, item, self.security.identity, sequence)
            except ValidationError as exc:  # too large to send: no peer could accept it
                reason = exc.errors()[0].get("msg", "invalid")
                self.refuse(f"cannot answer {sequence[:80]} to {query.sender}: {reason}")
                continue
            self.transport.send(query.sender, response)
            self.last_answer = response
            self.metrics.responses_sent += 1
            self._record(
                Event.ANSWER_SENT,
                to=query.sender,
                id=query.id,
                sequence=sequence,
                author=response.author,
            )
            sent = True
        return sent

    # -- queries of its own, closed, and their late answers (section 2) ------------------------

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
        self._record(Event.LATE_ANSWER, sender=response.sender, id=response.id)

    # -- overhearing (spec/protocol.md section 4.3) -------------------------------------------

    def _not_mine(self, response: Response, mine: bool = False) -> int:
        """An answer to somebody else's query (or to none; ``mine``: to this agent's open query,
        answered already): refused unless this agent overhears; then learned at once
        (``update``) or kept for later (``buffer``), after the same checks as a direct answer.
        Returns how many items were learned."""
        heard = self.ear.hear(response, response.sequence in self.knowledge, self._overheard)
        if heard is Heard.OFF:
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
        key = sequence_key(sequence)
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
        if self.memory.when_full != WhenFull.EVICT:
            return False
        learned = self._learned_items()
        if not learned:
            return False
        oldest = min(learned, key=self._last_use)
        self.forget(oldest.key, reason="evicted")
        return self._held() < capacity

    def tend_memory(self) -> int:
        """Apply the policy's forgetting at tick ``now``: everything learned after
        ``forget_after`` idle ticks, each item after ``expire_after`` ticks unused. ``Agent.tick``
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
        key = sequence_key(sequence)
        item = self.knowledge.lookup(key)
        if item is None or item.source is None:
            return False
        self.control.forget(item.segment, item.conditions)
        self.knowledge.remove(key)
        self.metrics.learned.pop(key, None)
        self.metrics.forgotten += 1
        self._record(Event.FORGOTTEN, sequence=key, reason=reason)
        self._save()
        return True

    def forget_learned(self, *, reason: str = "asked") -> int:
        """Forget everything learned at once (the release's ephemeral rule); innate knowledge
        stays. Returns how many items were forgotten."""
        return sum(self.forget(item.key, reason=reason) for item in self._learned_items())

    # -- the accept pipeline (spec/protocol.md section 2) --------------------------------------

    def _record(self, event: Event, **fields: object) -> None:
        if self.security.log is not None:
            self.security.log.record(event, peer=self.name, tick=self.now, **fields)

    def refuse(self, reason: str) -> None:
        """Count a refusal, keep its reason (the latest 256), log it at WARNING (visible by
        default: a robot that learns nothing says why) and record it (section 2)."""
        self.metrics.refused += 1
        self.metrics.refusals.append((self.now, reason))
        self._warn(f"{self.name} refused knowledge: {reason}")
        self._record(Event.REFUSED, reason=reason)

    def accept(self, response: Response, asked: Query) -> bool:
        """The receive pipeline (spec/protocol.md section 2), the one every answer goes through,
        direct, overheard or buffered: log it, check it (``ktbt_proto.exchange.receiving``), make
        room under the memory policy, merge it, record and save it. True if the item is known
        now (learned, or known already); a refusal is counted and logged with its reason."""
        self._record(
            Event.ANSWER_RECEIVED,
            sender=response.sender,
            id=response.id,
            sequence=response.sequence,
            author=response.author,
        )
        # The answer is to one of the sequences asked (a query may name several: section 1).
        wanted = response.sequence if response.sequence in asked.sequences else asked.sequence
        try:
            check_provenance(response, wanted, self.security.policy, self.security.trust)
            if wanted in self.knowledge:  # known already (perhaps innate): nothing to do
                return True
            # The merge checks the item against the vocabulary (the control tree's contract),
            # so it is checked here only when a learned item would be evicted to make room
            # for it: a bad item never takes a good one's place.
            full = self.memory.capacity is not None and self._held() >= self.memory.capacity
            conds, subtree = read_item(response, RECEIVE_LIMITS, self.registry if full else None)
            if not self._make_room():
                raise Refused(f"from {response.sender}: memory full ({self.memory.capacity} items)")
            changed = self.control.merge(subtree, self.slot, when=conds)
        except Refused as refused:
            self.refuse(refused.reason)
            return False
        except StringBTError as err:
            self.refuse(f"from {response.sender}: {err.code.value} {err.message}")
            return False
        except Exception as exc:  # a check or merge that raised: refused, the tree as it was
            self.refuse(f"from {response.sender}: {internal_error(exc)}")
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
        self._record(Event.MERGED, sequence=item.key, teacher=item.source, author=item.author)
        self._save()

    # -- persistence (spec/protocol.md section 5) ---------------------------------------------

    @contextmanager
    def saving_once(self) -> Iterator[None]:
        """Hold the saves of what is learned or forgotten inside the block, and save once at
        its end if anything changed (section 5): the answers one read of the transport merges
        are one write, and a fleet member announces what it merged before that write, so a
        neighbour asks while it is made (section 4.5). Blocks nest; the outermost saves."""
        self._saves_held += 1
        try:
            yield
        finally:
            self._saves_held -= 1
            if not self._saves_held and self._unsaved:
                self._save()

    def _save(self) -> None:
        """Save what was learned; a robot that cannot keeps it in memory and goes on. Inside
        :meth:`saving_once`, at the end of the block."""
        if self.knowledge_path is None:
            return
        if self._saves_held:
            self._unsaved = True
            return
        self._unsaved = False
        try:
            KnowledgeBase(k for k in self.knowledge if k.source is not None).save(
                self.knowledge_path
            )
        except OSError as exc:
            self.refuse(f"cannot save knowledge to {self.knowledge_path}: {exc}")

    def _resume(self, path: Path) -> None:
        """Merge what a previous run learned. A damaged file is refused with its reason, the
        items it still holds whole are kept, and it is moved aside (``FILE.damaged-TIME``)
        before anything is saved, so it is never overwritten; a file that cannot be read at
        all is left alone and nothing is saved over it. Temporary files a killed save left
        behind are removed."""
        for tmp in remove_stale_temporaries(path):
            log.info("%s removed %s, left by an interrupted save", self.name, tmp)
        try:
            saved = list(KnowledgeBase.load(path, RECEIVE_LIMITS))
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
            saved = salvage(text, RECEIVE_LIMITS)
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
