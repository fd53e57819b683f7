"""What ``ktbt peer`` does: serve knowledge, ask for it, run a learning agent, route, list.

Every command is a real zenoh peer (or router) with explicit endpoints, and closes its session
on exit, including on SIGINT and SIGTERM. A fleet member (``serve``, ``run``) is a
:class:`Member`: its name, network settings (with a zenoh id derived from its name, so a
restarted peer is the same peer), security, and what it publishes and overhears; an option
every member takes is one field there.
"""

from __future__ import annotations

import logging
import random
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field
from pydantic import ValidationError as PydanticError

from ktbt_proto.blackboard import Blackboard
from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.agent import Agent, Timing
from ktbt_proto.exchange.answers import answers, catalog, live_answers
from ktbt_proto.exchange.knowledge import Knowledge, KnowledgeBase, sequence_key, show_sequence
from ktbt_proto.exchange.messages import Query, Response
from ktbt_proto.exchange.overhearing import Ear, Heard, Overhear
from ktbt_proto.exchange.receiving import Refused, check
from ktbt_proto.exchange.security import Security
from ktbt_proto.exchange.signing import Identity, SignedItem
from ktbt_proto.exchange.trust import refusal
from ktbt_proto.formatter import format_tree
from ktbt_proto.interop.sidecar import LearnedExport
from ktbt_proto.limits import DEFAULT_LIMITS
from ktbt_proto.merge import conditions as parse_conditions
from ktbt_proto.merge import merge
from ktbt_proto.registry import Registry
from ktbt_proto.status import RUNNING, SUCCESS, Status
from ktbt_proto.syntax import parse
from ktbt_proto.transport.zenoh import (
    ZenohSettings,
    ZenohTransport,
    catalogs,
    open_session,
    peers,
    stable_zid,
)
from ktbt_proto.tree import Condition, Placeholder, Tree

Colour = Annotated[int, Field(ge=1, le=4)]
"""The demo's colours: 1 to 4. A received skill naming colour 7, -999 or "red" is refused."""


Say = Callable[[str], None]


@dataclass(frozen=True)
class Member:
    """A long-running fleet member (``ktbt peer serve``, ``ktbt peer run``): what both take.
    Its zenoh id is derived from ``name`` unless the settings name one (spec/protocol.md
    section 3)."""

    name: str
    settings: ZenohSettings = field(default_factory=ZenohSettings)
    security: Security = field(default_factory=Security)
    publish_answers: bool = False
    overhear: Overhear = "off"
    publish_events: bool = False
    """Publish this member's fleet events (``ktbt_proto.exchange.events``, for ``ktbt monitor``)."""
    groot: int | None = None
    """A port to serve Groot2 on (and the next), loopback (spec/groot2.md)."""

    def transport(self, **kw: Any) -> ZenohTransport:
        """This member's zenoh peer, with its stable zenoh id."""
        settings = self.settings
        if settings.zid is None:
            settings = replace(settings, zid=stable_zid(self.name))
        return ZenohTransport(
            self.name,
            settings,
            log=self.security.log,
            publish_answers=self.publish_answers,
            overhear=self.overhear != "off",
            publish_events=self.publish_events,
            **kw,
        )


def shown(key: str) -> str:
    """A sequence key as people read and type it (``TargetSeen(colour=2)``); a key that does
    not parse (a hostile peer's catalog) is shown quoted, as it came."""
    try:
        return show_sequence(key)
    except StringBTError:
        return repr(key)


DEMO_CONTROL = """<sl>
    <sq>
        <c>(Carrying)
        <a>(DeliverToZone)
    <e>
    <k>(prior)<e>
    <k>(new)<e>
    <a>(RandomWalk)
<e>
"""
COLOURS = [f"TargetSeen(colour={c})" for c in (1, 2, 3, 4)]


def demo_registry() -> Registry:
    """The search-and-rescue vocabulary of the example knowledge, with stand-in actions."""
    reg = Registry()
    reg.flags("Carrying")

    @reg.condition("TargetSeen")
    def target_seen(bb: Blackboard, colour: Colour) -> bool:
        return bool(bb.get("target") == colour)

    @reg.action("PickTreasure")
    def pick(bb: Blackboard) -> Status:
        bb["Carrying"] = True
        return SUCCESS

    @reg.action("AssignCollectionPoint")
    def assign(bb: Blackboard, colour: Colour) -> Status:
        bb["zone"] = colour
        return SUCCESS

    @reg.action("DeliverToZone")
    def deliver(bb: Blackboard) -> Status:
        bb["Carrying"] = False
        bb["delivered"] = bb.get("delivered", 0) + 1
        return SUCCESS

    @reg.action("RandomWalk")
    def walk(bb: Blackboard) -> Status:
        return RUNNING

    return reg


@contextmanager
def until_signalled() -> Iterator[threading.Event]:
    """An event set by SIGINT or SIGTERM, so a long-running command can close cleanly."""
    stop = threading.Event()
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    for sig in previous:
        signal.signal(sig, lambda *_: stop.set())
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def load_knowledge(path: str | Path) -> KnowledgeBase:
    """A knowledge file: stringBT whose ``<k>(...)`` placeholders hold the items to serve.
    At most one byte past the size limit is read (``/dev/zero`` is refused, not read until
    memory runs out). Items too large to send, signed and all, are refused here, not at every
    query."""
    with open(path, "rb") as f:
        data = f.read(DEFAULT_LIMITS.max_size + 1)
    kb = KnowledgeBase.from_tree(parse(data))
    for item in kb:
        subtree = format_tree(item.subtree, "compact")
        try:  # the largest a reply can be: longest id and name, both signatures
            Response(
                id="i" * 64,
                sender="s" * 64,
                sequence=item.key,
                subtree=subtree,
                author="A" * 43,
                signature="A" * 86,
                key="A" * 43,
                hop="A" * 86,
            )
        except PydanticError:
            raise ValueError(f"{path}: the subtree for {item.key} is too large to send") from None
    if not len(kb):
        raise ValueError(
            f"{path}: no knowledge items (inside a <k>(...): <sq>, the conditions, the actions)"
        )
    return kb


def wait_for_peers(transport: ZenohTransport, timeout: float) -> dict[str, list[str]]:
    deadline = time.monotonic() + timeout
    found: dict[str, list[str]] = {}
    while time.monotonic() < deadline:
        found = peers(transport, timeout=0.3)
        if found:
            break
        time.sleep(0.05)
    return found


class Overhearing:
    """A server that overhears (spec/protocol.md section 4.3), through the one :class:`Ear`
    and the one set of receive checks (``ktbt_proto.exchange.receiving``; the trust policy also
    runs in
    the transport): an answer another peer published is added to what the server serves, at
    once (``update``) or, kept in the buffer, when a query first asks for it (``buffer``). The
    subtree is served as received, so its author's signature still holds. Lookups run in zenoh
    callbacks while the main thread hears: one lock guards the tables."""

    def __init__(
        self,
        name: str,
        knowledge: KnowledgeBase,
        served: Callable[[str], SignedItem | None],
        mode: Overhear,
        say: Say,
        buffer_size: int = 16,
    ) -> None:
        self.name, self.knowledge, self.served, self.say = name, knowledge, served, say
        self.ear = Ear(mode, buffer_size)
        self.learned: dict[str, SignedItem] = {}
        self.refused = 0
        self.lock = threading.Lock()

    def heard(self, message: object) -> None:
        if not isinstance(message, Response):
            return
        with self.lock:
            heard = self.ear.hear(message, message.sequence in self.knowledge, self._learn)
        if heard is Heard.FULL:
            self._refuse(f"from {message.sender}: overheard answer, buffer full")

    def lookup(self, key: str) -> SignedItem | None:
        found = self.served(key)
        if found is not None:
            return found
        with self.lock:
            found = self.learned.get(key)
            if found is not None:
                return found
            kept = self.ear.take(key)
            return self.learned.get(key) if kept is not None and self._learn(kept) else None

    def catalog(self, entries: Callable[[], list[str | dict[str, Any]]]) -> Callable[[], Any]:
        def locked() -> list[str | dict[str, Any]]:
            with self.lock:
                return entries()

        return locked

    def _learn(self, answer: Response) -> bool:
        try:
            conds, subtree = check(answer, answer.sequence)
        except Refused as refused:
            self._refuse(refused.reason)
            return False
        received = datetime.now(UTC).isoformat(timespec="seconds")
        self.knowledge.add(
            Knowledge(conds, subtree, "new", answer.sender, None, answer.author,
                      answer.signature, received)
        )  # fmt: skip
        self.learned[answer.sequence] = SignedItem(answer.subtree, answer.author, answer.signature)
        self.say(f"{self.name}: learned {shown(answer.sequence)} from {answer.sender} (overheard)")
        return True

    def _refuse(self, reason: str) -> None:
        self.refused += 1
        logging.getLogger("ktbt.peer").info("%s refused: %s", self.name, reason)


def serve(member: Member, knowledge: KnowledgeBase, say: Say) -> int:
    """Serve ``knowledge`` until stopped, answering inside zenoh's callback; publishing and
    overhearing as the member says (section 4.3); with the member's ``groot``, the knowledge
    is shown to Groot2 (spec/groot2.md)."""
    security = member.security
    ear = Overhearing(
        member.name, knowledge, answers(knowledge, security.identity), member.overhear, say
    )
    policy = security.policy
    name = member.name
    groot = member.groot
    with (
        until_signalled() as stop,
        ExitStack() as stack,
        member.transport(
            lookup=ear.lookup,
            catalog=ear.catalog(catalog(knowledge, security.identity)),
            identity=security.identity,
            screen=lambda r: refusal(r, policy, security.trust),
            tree=lambda: format_tree(knowledge.tree(), "compact"),
        ) as transport,
    ):
        say(f"{name}: serving {len(knowledge)} skills; Ctrl-C to stop")
        if groot is not None:
            from ktbt_proto.interop.groot2 import Groot2Publisher, knowledge_tree

            stack.enter_context(Groot2Publisher(knowledge_tree(knowledge), groot))
            say(f"{name}: Groot2 on port {groot} (btview snapshot -p {groot})")
        if security.identity is not None:
            say(f"  signed as {security.identity.public}")
        for item in knowledge:
            say(f"  {show_sequence(item.conditions)}")
        if member.overhear == "off":
            stop.wait()
        while not stop.wait(0.05):
            for message in transport.receive():
                ear.heard(message)
    say(f"{name}: stopped; refused {transport.refused + ear.refused} messages")
    return 0


def ask(
    name: str,
    sequence: Sequence[str | Condition],
    settings: ZenohSettings,
    timeout: float,
    say: Say,
    note: Say | None = None,
    security: Security | None = None,
) -> tuple[int, list[Response]]:
    """Ask the fleet and print each acceptable answer the moment it arrives, with its
    provenance; an answer the policy or the receive limits refuse is shown as refused.
    ``note`` is told, when no answer came, whether nobody was reachable or nobody knew: two
    different problems that look alike otherwise."""
    security = security or Security()
    key = sequence_key(parse_conditions(sequence))
    query = Query(id=Query.new_id(), sender=name, sequence=key)
    responses: list[Response] = []

    def show(answer: Response) -> None:
        if answer.id != query.id:
            return
        try:  # shown only if it passes a robot's receive checks (numbers too)
            _, subtree = check(answer, key, security.policy, security.trust)
        except Refused as refused:
            say(f"# refused {refused.reason}")
            return
        say(f"# from {answer.sender}{provenance(answer)}")
        say(format_tree(subtree).rstrip())
        responses.append(answer)

    with ZenohTransport(
        name,
        settings,
        query_timeout=timeout,
        serving=False,
        log=security.log,
        # Checked before a reply takes its key's place: a forgery cannot shut the genuine out.
        screen=lambda r: refusal(r, security.policy, security.trust),
    ) as transport:
        reachable = wait_for_peers(transport, timeout)
        transport.ask(query, timeout, on_answer=show)
    if not responses and note is not None:
        if not reachable:
            note(f"no answer: no peer reachable within {timeout:g} s")
        else:
            note(
                f"no answer: {len(reachable)} peer{'s' * (len(reachable) != 1)} reachable, "
                f"none knows {show_sequence(parse_conditions(sequence))}"
            )
    return (0 if responses else 1), responses


def provenance(answer: Response) -> str:
    """`` (author KEY, sent with key KEY)`` for what an answer says of its origin."""
    words = []
    if answer.author is not None:
        words.append(f"author {answer.author}")
    if answer.key is not None:
        words.append(f"sent with key {answer.key}")
    return f" ({', '.join(words)})" if words else ""


BACKOFF_FIRST = 0.25
"""Seconds a learner holds back after its first unanswered query, doubling with each one."""
BACKOFF_MOST = 2.0
"""The longest it holds back: knowledge that is missing is asked for again at least this often
(after the wait and the cool-down)."""


@dataclass
class Backoff:
    """When a learner may ask next (spec/protocol.md section 4.5): at once at first, then
    after each query nobody answered, ``first`` seconds later, doubling up to ``most``; at
    once again when it learns something or a new peer appears.

    Each hold is stretched by up to ``jitter`` of itself, drawn from a generator seeded with
    ``seed`` (the member's name): a fleet whose queries were lost together does not ask again
    in step, and a run with the same names draws the same holds."""

    first: float = BACKOFF_FIRST
    most: float = BACKOFF_MOST
    hold: float = 0.0
    until: float = 0.0
    seed: str = ""
    jitter: float = 0.5
    _rng: random.Random = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self._rng = random.Random(f"ktbt-backoff:{self.seed}")

    def lost(self, now: float) -> None:
        self.hold = self.first if self.hold == 0 else min(self.hold * 2, self.most)
        self.until = now + self.hold * (1 + self.jitter * self._rng.random())

    def reset(self, now: float) -> None:
        self.hold, self.until = 0.0, now

    def ready(self, now: float) -> bool:
        return now >= self.until


def with_knowledge(control: str | Tree, knowledge: KnowledgeBase | None) -> str | Tree:
    """The control tree with ``knowledge``'s items in their placeholders (``prior`` when the
    tree has no placeholder of an item's name): what the agent starts knowing, and teaches."""
    if knowledge is None or not len(knowledge):
        return control
    tree = parse(control) if isinstance(control, str) else control
    names = {n.name for n, _ in tree.walk() if isinstance(n, Placeholder)}
    for item in knowledge:
        slot = item.segment if item.segment in names else "prior"
        tree = merge(tree, item.subtree, slot, when=item.conditions)
    return tree


def run_agent(
    member: Member,
    sequences: Sequence[str],
    say: Say,
    *,
    control: str = DEMO_CONTROL,
    knowledge: KnowledgeBase | None = None,
    tick_rate: float = 100.0,
    wait_ticks: int = 200,
    cooldown_ticks: int = 50,
    duration: float = 30.0,
    knowledge_path: str | None = None,
    exit_when_done: bool = False,
    export_learned: str | None = None,
) -> int:
    """A fleet member that learns and teaches: it starts with ``knowledge`` (if any) and what
    ``knowledge_path`` saved, meets each sequence in turn until it knows it (or time runs out),
    asking again with a bounded backoff while it is missing, and at once when a new peer
    appears; it teaches what it knows to whoever asks, and prints what it learned. Refusals are
    logged (to stderr and, with a transfer log, there) and the summary counts all of them,
    transport ones too; the network's own errors are counted apart. ``export_learned``: a
    folder to mirror learned items into as BT.CPP documents (spec/stringbt.md section 12.1);
    the member's ``groot``: serve the control tree to Groot2 (spec/groot2.md)."""
    security = member.security
    name = member.name
    with (
        until_signalled() as stop,
        ExitStack() as stack,
        member.transport(
            query_timeout=wait_ticks / tick_rate, identity=security.identity
        ) as transport,
    ):
        robot = Agent(
            name,
            with_knowledge(control, knowledge),
            demo_registry(),
            transport,
            timing=Timing(wait=wait_ticks, cooldown=cooldown_ticks),
            knowledge_path=knowledge_path,
            # with --publish-events, the transport has a log even without --log
            security=replace(security, log=transport.log),
            ear=Ear(member.overhear),
        )
        transport.catalog = catalog(robot.knowledge, security.identity)
        # Every query it can answer is answered at once from what it knows, as `peer serve`
        # does, not one asker per cool-down through the teach tree (section 4.5).
        transport.lookup = live_answers(lambda: robot.knowledge, security.identity)
        # The tree as of the last merge: a Tree is never changed in place, only replaced.
        transport.tree = lambda: format_tree(robot.control.tree, "compact")
        if member.groot is not None:
            from ktbt_proto.interop.groot2 import Groot2Publisher

            stack.enter_context(Groot2Publisher(robot, member.groot, stop=stop))
            say(f"{name}: Groot2 on port {member.groot} (btview snapshot -p {member.groot})")
        export = LearnedExport(export_learned) if export_learned is not None else None
        if export is not None:  # what a resumed --save file holds already
            export.sync(robot.knowledge)
        for _, reason in robot.metrics.refusals:  # a damaged --save file, say
            say(f"{name}: refused: {reason}")
        wait_for_peers(transport, 3.0)
        deadline = time.monotonic() + duration
        todo = list(sequences)
        period = 1.0 / tick_rate
        say(f"{name}: knows {len(robot.knowledge)}, will meet {len(todo)} sequences")
        announced = set(robot.metrics.learned)
        backoff = Backoff(seed=name)
        lost, joined = robot.metrics.queries_lost, transport.joined
        while not stop.is_set() and time.monotonic() < deadline:
            now = time.monotonic()
            while todo and robot.knows([todo[0]]):
                todo.pop(0)
            if not todo and exit_when_done:
                break
            if transport.joined != joined:  # a new neighbour: it may know
                joined = transport.joined
                backoff.reset(now)
            if robot.metrics.queries_lost != lost:
                lost = robot.metrics.queries_lost
                backoff.lost(now)
            robot.encounter([todo[0]] if todo and backoff.ready(now) else None)
            robot.tick()
            if export is not None:
                export.sync(robot.knowledge)
            for key in robot.metrics.learned.keys() - announced:
                tick, source = robot.metrics.learned[key]
                say(f"{name}: learned {shown(key)} from {source} at tick {tick}")
                announced.add(key)
                backoff.reset(now)
            stop.wait(period)
        m = robot.metrics
        say(
            f"{name}: queries sent {m.queries_sent}, answers {m.responses_received}, "
            f"lost {m.queries_lost}, refused {m.refused + transport.refused}, "
            f"taught {m.responses_sent + transport.answered}, late answers {m.late_answers}, "
            f"network errors {m.network_errors}"
        )
        for item in robot.knowledge:
            say(f"  knows {show_sequence(item.conditions)}")
        return 0 if all(robot.knows([s]) for s in sequences) else 1


def router(settings: ZenohSettings, say: Say) -> int:
    routed = ZenohSettings(
        listen=settings.listen,
        connect=settings.connect,
        config=settings.config,
        mode="router",
        multicast_scouting=settings.multicast_scouting,
    )
    with until_signalled() as stop:
        session = open_session(routed)
        try:
            say(f"router listening on {', '.join(settings.listen) or 'the configured endpoints'}")
            stop.wait()
        finally:
            session.close()  # type: ignore[no-untyped-call]
    return 0


def list_peers(name: str, settings: ZenohSettings, timeout: float, say: Say) -> int:
    """Who is present and what each knows, with each item's author and teacher."""
    with ZenohTransport(name, settings, serving=False) as transport:
        found = wait_for_peers(transport, timeout)
        detail = catalogs(transport, timeout=min(timeout, 1.0)) if found else {}
    for peer, known in sorted(found.items()):
        say(f"{peer}: {len(known)} skills")
        entries = detail.get(peer) or [{"sequence": key} for key in known]
        for entry in entries:
            origin = [f"{k} {entry[k]}" for k in ("author", "teacher", "received_at") if k in entry]
            say(f"  {shown(entry['sequence'])}" + (f"  ({', '.join(origin)})" if origin else ""))
    if not found:
        say("no peers found")
    return 0 if found else 1


def keygen(path: Path, name: str, say: Say) -> int:
    """Write a new key pair (``PATH`` private, ``PATH.pub`` public) and print the trust-store
    line for it."""
    identity = Identity.generate()
    public = identity.save(path)
    say(f"wrote {path} (private, keep it) and {public}")
    say(f"{name} {identity.public}")
    return 0


def configure_logging() -> None:
    """Refusals and other exchange events to stderr, so an operator sees them."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s", force=False)
