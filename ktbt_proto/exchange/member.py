"""The fleet member: one robot that learns and teaches while it runs (``spec/protocol.md``
section 4.5), the one loop every host runs.

A host says only *when*: ``ktbt peer run`` calls :meth:`FleetMember.step` from a sleep loop, the
ROS 2 lifecycle node from its timer, an embedded robot (``attach``) from a timer on its user's
node. One step reads what arrived (answers are checked and merged, section 2), reports what was
learned, brings the export up to date, notes the peers that appeared, reads the fleet's
catalogs when there may be something new in them (a learner told no sequences), works out what
is still to learn, asks as section 4.5 says (:class:`Learner`), ticks the control tree (unless
its host ticks it) and tends memory (section 4.2). Answers are given at once by the transport,
inside its callback, from what the agent knows at that moment.

What the loop needs of a network is declared: :class:`Appearing` (the peers that appeared since
it last asked) and :class:`Catalogs` (what the fleet's catalogs list, when they may have
changed), implemented by the zenoh and ROS 2 transports alike; and, where the network carries
them, :class:`Relay` (announcements of what a peer just learned, so that a neighbour that lacks
it asks at once, section 4.5: zenoh's announcements, ROS 2's republished catalogs).
"""

from __future__ import annotations

import logging
import math
import random
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.application import ApplicationTimedAgent
from ktbt_proto.exchange.backoff import Backoff
from ktbt_proto.exchange.knowledge import KnowledgeBase
from ktbt_proto.exchange.messages import MAX_MORE, Query
from ktbt_proto.exchange.refusals import Throttle, fault, internal_error
from ktbt_proto.items import parse_sequence, sequence_key, show_key
from ktbt_proto.registry import Registry
from ktbt_proto.status import Status
from ktbt_proto.tree import SequenceNode
from ktbt_proto.validate import find_problems

__all__ = [
    "CATALOG_PERIOD",
    "NEWCOMERS_AT_ONCE",
    "NEWCOMERS_KEPT",
    "RELAY_AT_ONCE",
    "RELAY_GRACE",
    "RELAY_HOLD",
    "Appearing",
    "Catalogs",
    "FleetMember",
    "Learner",
    "ListedSequences",
    "Relay",
    "Replies",
]

log = logging.getLogger("ktbt.member")

NEWCOMERS_AT_ONCE = 1
"""Peers that appeared a member sends its query at once, at most, counting those it sent it
within :data:`RELAY_GRACE` whose answer may still be on its way (section 4.5): when a partition
heals, tens of peers appear in the same half second, each knowing all it lacks, and asking each
would bring as many answers to every item. The others wait their turn (:data:`NEWCOMERS_KEPT`
of them), or its next broadcast, which reaches them all."""

NEWCOMERS_KEPT = 256
"""Peers that appeared kept waiting their turn to be asked, at most (the newest kept)."""

CATALOG_PERIOD = 2.0
"""Seconds between two readings of the fleet's catalogs by a learner told no sequences
(besides one whenever a peer appears): peers learn, so their catalogs grow (section 4.5)."""

RELAY_HOLD = 2.0
"""Seconds during which a member, having asked an announcer at once for a sequence, asks no
announcer at once for it again, whoever announces it (section 4.5): a hundred peers that
learned it together cost one ask, and a flood of announcements, or a lie, one ask a hold."""

RELAY_GRACE = 1.0
"""Seconds after a member sent its open query to another peer (or to all) during which an
announcer is not asked yet (section 4.5): that peer's answer may be on its way, as when a
teacher that joined a fleet answers its learners one after the other and the first to learn
announce. The announcement waits, and is taken once no answer can be on its way: the second
is over, or (a network that tells, :class:`Replies`) every peer the query reached has finished
with it, as one that knew nothing has at once."""

RELAY_AT_ONCE = 8
"""Announcers asked at once in one step at most (section 4.5); those beyond wait for the
member's next ask."""

Catalog = dict[str, list[dict[str, str]]]
"""The fleet's catalogs as read: peer name -> its entries (``{"sequence": ..., ...}``)."""


class Appearing(Protocol):
    """A network that tells which peers appeared (a zenoh liveliness token, a ROS 2 query
    subscription matched): a newcomer is asked at once (section 4.5)."""

    def appeared(self) -> list[str]:
        """The peers that appeared since the last call, oldest first."""
        ...


class Catalogs(Protocol):
    """The fleet's catalogs, as a network carries them (zenoh's catalog queryables, ROS 2's
    latched ``~/catalog`` topics)."""

    def changed(self, now: float, appeared: bool) -> Catalog | None:
        """What the catalogs list, when they may have changed since the last call (a peer
        ``appeared``, :data:`CATALOG_PERIOD` passed, a catalog was republished); else None."""
        ...


class Relay(Protocol):
    """A network that carries announcements of what a peer just learned (section 3: zenoh's
    ``ktbt/v1/learned/<peer>``; section 11: a ROS 2 robot's latched catalog, republished after
    a merge), so that a neighbour that lacks it asks the announcer at once instead of at its
    next timed ask (section 4.5)."""

    def learned(self, keys: list[str]) -> None:
        """Announce the sequence keys this member just learned, in one announcement."""
        ...

    def news(self, now: float) -> list[tuple[str, tuple[str, ...]]]:
        """The announcements heard since the last call (``now``: the host's clock, as
        :meth:`Catalogs.changed`'s): (announcer, sequences), oldest first."""
        ...


@runtime_checkable
class Replies(Protocol):
    """A network that tells whether an answer to a query it sent may still come (zenoh: the
    get has not ended, :meth:`ZenohTransport.awaiting`), so that an announcement waits for such
    an answer only while one can come (:data:`RELAY_GRACE`, section 4.5)."""

    def awaiting(self, id: str, to: str) -> bool:
        """Whether an answer to query ``id`` sent to peer ``to`` ("": to all) may still come."""
        ...


class ListedSequences:
    """The sequences a learner told none meets (section 4.5): those its fleet's catalogs list,
    that its vocabulary can execute, in the order found. A sequence its vocabulary cannot
    execute is skipped (never asked, so never refused) with one INFO line. An entry whose
    reading raises anything else is refused: counted in :attr:`refused`, logged at WARNING,
    skipped from then on (section 2.1)."""

    def __init__(
        self,
        name: str,
        registry: Registry,
        say: Callable[[str], None],
        refuse: Callable[[str], None] | None = None,
    ) -> None:
        self.name, self.registry, self.say = name, registry, say
        self.found: list[str] = []
        self.skipped: set[str] = set()
        self.refused = 0
        self._warn = Throttle(log.warning)
        self._refuse = refuse
        """Who else is told of a refusal (a member's agent, which counts and records it)."""

    def read(self, listed: Catalog) -> list[str]:
        """Take in the catalogs read (peer -> entries); the sequences new to this learner."""
        new = []
        for peer, entries in sorted(listed.items()):
            for entry in entries:
                given = entry.get("sequence", "")
                if given in self.skipped:
                    continue
                try:
                    fault("item", given)
                    conds = parse_sequence(given)
                    problems = find_problems(SequenceNode(conds), self.registry)
                except StringBTError as err:
                    problems = [err]
                    conds = ()
                except Exception as exc:
                    self.skipped.add(given)
                    self.refused += 1
                    reason = f"the catalog of {peer[:64]}: {internal_error(exc)}"
                    if self._refuse is not None:
                        self._refuse(reason)
                    else:
                        self._warn(f"{self.name} refused: {reason}")
                    continue
                key = sequence_key(conds) if not problems else given
                if key in self.found or key in self.skipped:
                    continue
                if problems:
                    self.skipped.add(given)
                    log.info(
                        "%s: not asking for %s, listed by %s: its vocabulary cannot execute it "
                        "(%s %s)",
                        self.name, show_key(given), peer[:64], problems[0].code,
                        problems[0].message,
                    )  # fmt: skip
                    continue
                self.found.append(key)
                new.append(key)
                self.say(f"{self.name}: will meet {show_key(key)} (listed by {peer[:64]})")
        return new


@dataclass
class Learner:
    """When a fleet member asks (section 4.5): driven by events, not by a timer. It asks for
    every sequence it lacks in one query (section 1) as soon as it lacks one; a peer that
    appears (its liveliness, section 3) is sent the open query at once, and the query stays
    open a whole ``wait`` from then; a query closes when every sequence it names is answered,
    or when its wait is over. With no query open, the peers that appear are asked at once, each
    alone (those present before were asked already). Of the peers that appear, it asks
    :data:`NEWCOMERS_AT_ONCE` at a time, counting those asked within :data:`RELAY_GRACE` whose
    answer may be on its way: when a partition heals, tens of peers that know all it lacks
    appear together, and one answer an item is enough. The others wait their turn, the newest
    first (those that appeared together in an order drawn at random), until it knows what it
    lacks or broadcasts; only a peer that just appeared stretches the query's wait, so a queue
    of them does not keep it open, and a peer that waited its turn holds back no announcer
    (:meth:`awaited`). After a query nobody answered, it holds back ``cooldown``
    seconds and then the ``backoff``'s hold; after one answered (in part), it asks at once for
    what is left. The announcers of what it lacks (``relayed``, section 4.5) are asked each
    alone, as newcomers are, except that they stretch an open query's wait once at most, so
    that no stream of announcements keeps a query open for ever."""

    robot: ApplicationTimedAgent
    backoff: Backoff
    wait: float
    cooldown: float
    opened: float = 0.0
    stretched: str = ""
    """The id of the last query an announcer was asked in (its wait stretched once)."""
    sent: dict[str, float] = field(default_factory=dict)
    """Where the open query went and when: a peer's name, or "" for a broadcast."""
    waiting: list[str] = field(default_factory=list)
    """Peers that appeared and were not asked yet, the next to ask last."""
    tried: dict[str, float] = field(default_factory=dict)
    """Peers that waited their turn, sent the open query, and when: they take a newcomer's
    place, but an announcer is not held back for them (:meth:`awaited`), since nothing says
    they know anything."""
    _rng: random.Random = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # Seeded with the member's name: a fleet spreads its asks over the peers that appeared
        # together, and a run with the same names draws the same.
        self._rng = random.Random(f"ktbt-newcomers:{self.robot.name}")

    def awaited(self, now: float, announcer: str) -> bool:
        """Whether an answer to the open query may be on its way from a peer other than
        ``announcer``: sent it, or broadcast, within :data:`RELAY_GRACE`, and, on a network
        that tells (:class:`Replies`), not finished with by every peer it reached."""
        query = self.robot.open_query
        if query is None:
            return False
        network = self.robot.transport
        told = network.awaiting if isinstance(network, Replies) else None
        return any(
            p != announcer and now - t < RELAY_GRACE and (told is None or told(query.id, p))
            for p, t in self.sent.items()
        )

    def newcomers(self, now: float, appeared: list[str]) -> list[str]:
        """The peers that appeared to send the query to now (section 4.5): as many as
        :data:`NEWCOMERS_AT_ONCE` leaves room for beside the peers sent the open query, still
        unanswered, within :data:`RELAY_GRACE` (a broadcast reached none of the newcomers),
        taken from those waiting, the newest first; those that appeared together are put in
        an order drawn at random. With no query open, only a peer that just appeared is asked
        (a new query); the others wait for the open query, or for the broadcast."""
        fresh = list(dict.fromkeys(appeared))
        self._rng.shuffle(fresh)
        just = set(fresh)
        self.waiting = [*(p for p in self.waiting if p not in just), *fresh][-NEWCOMERS_KEPT:]
        busy = 0
        if self.robot.unanswered:
            asked = [*self.sent.items(), *self.tried.items()]
            busy = sum(1 for p, t in asked if p and now - t < RELAY_GRACE)
        room = max(0, NEWCOMERS_AT_ONCE - busy)
        pool = self.waiting
        if self.robot.open_query is None:
            pool = [p for p in self.waiting if p in just]
        chosen = pool[len(pool) - room :] if room else []
        self.waiting = [p for p in self.waiting if p not in chosen]
        return chosen

    def due(self, now: float, missing: Sequence[str]) -> float:
        """When its next step may ask or close a query though nothing arrived (section 4.5,
        the host's clock): the open query's wait ends (at once when it is all answered), a
        peer that waited its turn finds room (an ask's :data:`RELAY_GRACE` is over), or, with
        no query open and something ``missing``, the backoff lets it ask. ``math.inf``: never,
        until something arrives."""
        if self.robot.open_query is None:
            return self.backoff.until if missing else math.inf
        if not self.robot.unanswered:
            return now
        due = self.opened + self.wait
        if self.waiting:
            asked = (*self.sent.items(), *self.tried.items())
            due = min([due, *(t + RELAY_GRACE for p, t in asked if p and now - t < RELAY_GRACE)])
        return due

    def _ask(self, now: float, missing: list[str], to: Sequence[str] = ()) -> Query:
        query = self.robot.ask(missing[0], *missing[1 : 1 + MAX_MORE], to=to)
        self.sent = {peer: now for peer in to} if to else {"": now}
        self.tried = {}
        if not to:
            self.waiting.clear()  # the broadcast reached them
        self.opened = now
        return query

    def _announce(self, now: float, peers: Iterable[str]) -> None:
        for peer in peers:
            self.robot.announce(peer)
            self.sent[peer] = now

    def step(
        self, now: float, missing: list[str], appeared: list[str], relayed: Sequence[str] = ()
    ) -> None:
        robot = self.robot
        if robot.buffered:  # overheard and kept (section 4.3): learned without asking
            for key in [k for k in missing if k in robot.buffered]:
                robot.learn_buffered(key)
            missing = [k for k in missing if k not in robot.knowledge]
        query = robot.open_query
        if query is not None and (not robot.unanswered or now - self.opened >= self.wait):
            answered = len(robot.unanswered) < len(query.sequences)
            robot.close_query()
            if answered:
                self.backoff.reset(now)
            else:
                self.backoff.lost(now + self.cooldown)
        if robot.open_query is None and not missing:
            self.waiting.clear()  # nothing to ask them
        asking = robot.open_query is not None or bool(missing)
        chosen = self.newcomers(now, appeared) if asking else []
        if chosen and robot.open_query is not None:  # newcomers hear the open query at once
            self._announce(now, [p for p in chosen if p in appeared])
            for peer in [p for p in chosen if p not in appeared]:  # waited their turn
                robot.announce(peer)
                self.tried[peer] = now
            if any(p in appeared for p in chosen):  # a queue of them does not keep it open
                self.opened = now
        elif chosen:  # each alone: the others were asked already
            self._ask(now, missing, chosen)
            self.backoff.reset(now)
        relayed = [p for p in relayed if p not in chosen]
        if relayed and missing:  # announcers of what it lacks (section 4.5), each alone
            query = robot.open_query
            if query is None:
                query = self._ask(now, missing, relayed)
                self.backoff.reset(now)
            else:
                self._announce(now, relayed)
                if self.stretched != query.id:
                    self.opened = now
            self.stretched = query.id
            self.waiting = [p for p in self.waiting if p not in relayed]
        if missing and robot.open_query is None and self.backoff.ready(now):
            self._ask(now, missing)


class Synced(Protocol):
    """What follows the robot's knowledge (the BehaviorTree.CPP export of what it learned)."""

    def sync(self, knowledge: KnowledgeBase) -> object: ...


@dataclass
class FleetMember:
    """One robot of a fleet (section 4.5), run by its host one :meth:`step` at a time.

    ``agent``: the robot (its knowledge, control tree and metrics), built on a transport that
    answers at once; ``network``: the peers that appeared; ``catalogs``: the fleet's catalogs,
    read only when ``sequences`` is None (then it meets what they list and its vocabulary can
    execute, :class:`ListedSequences`); ``sequences``: the sequence keys to meet. ``wait``:
    seconds a query stays open; ``cooldown``: seconds held back after a query nobody answered.
    ``say``: where a learned item and a newly listed sequence are reported (the host's log).
    ``export``: kept in step with what it knows. ``ticks_control``: whether a step ticks the
    control tree (an embedded robot's tree is ticked by its user)."""

    agent: ApplicationTimedAgent
    network: Appearing
    catalogs: Catalogs | None
    sequences: Iterable[str] | None
    wait: float
    cooldown: float
    say: Callable[[str], None]
    export: Synced | None = None
    ticks_control: bool = True
    relay: Relay | None = None
    """Where what it learns is announced and its neighbours' announcements are heard (section
    4.5); None: it learns what a neighbour learned at its next timed ask."""
    todo: list[str] = field(init=False)
    """The sequence keys still to learn."""
    listed: ListedSequences | None = field(init=False)
    learner: Learner = field(init=False)
    status: Status | None = field(init=False, default=None)
    """What the control tree's last tick returned (None before the first, or when its host
    ticks it)."""

    def __post_init__(self) -> None:
        name = self.agent.name
        self.todo = [] if self.sequences is None else list(self.sequences)
        self.listed = (
            ListedSequences(name, self.agent.registry, self.say, self.agent.refuse)
            if self.sequences is None
            else None
        )
        self.learner = Learner(self.agent, Backoff(seed=name), self.wait, self.cooldown)
        self._reported = set(self.agent.metrics.learned)
        self._last = -math.inf
        self._held: dict[str, float] = {}
        """Sequence -> when an announcer of it was asked at once (:data:`RELAY_HOLD`)."""
        self._waiting: dict[str, tuple[str, ...]] = {}
        """Announcements kept while an answer may be on its way (:data:`RELAY_GRACE`)."""
        if self.export is not None:  # what a resumed save file holds already
            self.export.sync(self.agent.knowledge)

    @property
    def name(self) -> str:
        return self.agent.name

    @property
    def done(self) -> bool:
        """Nothing left to learn, and (told no sequences) something was listed and learned."""
        return not self.todo and (self.listed is None or bool(self.listed.found))

    def due(self, now: float) -> float:
        """When its next step may act though nothing arrived (section 4.5, the host's clock):
        the learner's next timed ask or close (:meth:`Learner.due`), or an announcement kept
        while an answer may be on its way is taken (:data:`RELAY_GRACE` over); ``math.inf``
        when settled (nothing to learn, no query open, no announcement waiting). Anything that
        arrives may bring it sooner: a host that sleeps until then wakes for what arrives
        (``ktbt peer run``'s rest). The catalogs' period is not in it: a host sleeps a bounded
        time (``REST_RATE``), so a reading may come that much late."""
        due = self.learner.due(now, self.todo)
        if self._waiting:
            if self.agent.open_query is None:  # closed since: nothing to wait for
                return now
            sent = self.learner.sent.values()
            due = min([due, *(t + RELAY_GRACE for t in sent if now - t < RELAY_GRACE)])
        return due

    @property
    def refused(self) -> int:
        """Refusals of the agent, the catalogs' it read included (its transport counts its
        own)."""
        return self.agent.metrics.refused

    def timing(self, wait: float, cooldown: float) -> None:
        """A new wait and cool-down (a host whose tick rate changed)."""
        self.wait = self.learner.wait = wait
        self.cooldown = self.learner.cooldown = cooldown

    def meet(self, keys: Iterable[str]) -> None:
        """Meet these sequence keys too (told, no longer reading the catalogs for them)."""
        self.todo += [k for k in keys if k not in self.todo]

    def tell(self, keys: Iterable[str]) -> None:
        """Meet exactly these sequence keys from now on; the catalogs are no longer read."""
        self.todo, self.listed = list(keys), None

    def step(self, now: float, *, tick: bool = True) -> list[str]:
        """Section 4.5's loop, once; ``now`` in seconds of the host's clock (monotonic for
        ``ktbt peer run``, the node's for a ROS robot: sim time under ``use_sim_time``), the
        same at every step: every wait, cool-down, backoff and catalog period is on it. A
        clock that goes back (a simulation reset) ends the hold: it may ask at once, and an
        open query stays open a whole wait from then. ``tick`` False: a step between two ticks
        (a host that steps when an answer arrives or it is told what to meet, section 11),
        which neither ticks the control tree nor tends memory, both counted in ticks. Returns
        the keys learned in this step."""
        agent = self.agent
        if now < self._last:
            self.learner.backoff.reset(now)
            self.learner.opened = now
            self._held.clear()  # held from a time that is now to come
        self._last = now
        with agent.saving_once():  # announced before it is saved: one write less a hop
            agent.receive()
            learned = [k for k in agent.metrics.learned if k not in self._reported]
            if learned and self.relay is not None:
                self.relay.learned(learned)
        for key in learned:
            at, source = agent.metrics.learned[key]
            self.say(f"{agent.name}: learned {show_key(key)} from {source} at tick {at}")
            self._reported.add(key)
        if self.export is not None:
            self.export.sync(agent.knowledge)
        appeared = self.network.appeared()
        heard = self.relay.news(now) if self.relay is not None else []
        if self.listed is not None and self.catalogs is not None:
            found = self.catalogs.changed(now, bool(appeared))
            if found is not None:
                self.todo += self.listed.read(found)
        if self.listed is not None and heard:  # told none: what its vocabulary can execute
            told: Catalog = {}
            for peer, sequences in heard:
                told.setdefault(peer, []).extend({"sequence": s} for s in sequences)
            self.todo += self.listed.read(told)
        self.todo = [key for key in self.todo if key not in agent.knowledge]
        self.learner.step(now, self.todo, appeared, self._worth_asking(now, heard))
        if tick:
            if self.ticks_control:
                self.status = agent.control.tick()
            agent.tend_memory()
        return learned

    def _worth_asking(self, now: float, heard: list[tuple[str, tuple[str, ...]]]) -> list[str]:
        """The announcers to ask at once (section 4.5), the first heard first: each announced a
        sequence this member lacks for which no announcer was asked at once in the last
        :data:`RELAY_HOLD` seconds (those sequences are then held, whoever else announces
        them); :data:`RELAY_AT_ONCE` of them at most. While an answer to the open query may be
        on its way from another peer (:data:`RELAY_GRACE`), an announcement waits (those of 256
        announcers at most)."""
        held = self._held
        for key in [k for k, when in held.items() if now - when >= RELAY_HOLD]:
            del held[key]
        lacking, worth = set(self.todo), list[str]()
        news, self._waiting = self._waiting, {}
        for peer, sequences in heard:
            news[peer] = tuple(dict.fromkeys((*news.get(peer, ()), *sequences)))[-1 - MAX_MORE :]
        for peer, sequences in news.items():
            fresh = [s for s in sequences if s in lacking and s not in held]
            if not fresh or len(worth) >= RELAY_AT_ONCE:
                continue
            if self.learner.awaited(now, peer):
                if len(self._waiting) < 256:
                    self._waiting[peer] = tuple(fresh)
                continue
            held.update((s, now) for s in fresh)
            worth.append(peer)
        return worth

    def forgot(self, key: str) -> None:
        """``key`` was forgotten on request: reported again when it is learned again."""
        self._reported.discard(key)
