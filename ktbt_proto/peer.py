"""What ``ktbt peer`` does: serve knowledge, ask for it, run a learning agent, route, list.

Every command is a real zenoh peer (or router) with explicit endpoints, and closes its session
on exit, including on SIGINT and SIGTERM.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field
from pydantic import ValidationError as PydanticError

from .agent import RECEIVE_LIMITS, Agent, Overhear
from .blackboard import Blackboard
from .errors import StringBTError
from .format import format as format_tree
from .knowledge import Knowledge, KnowledgeBase, parse_sequence, sequence_key, show_sequence
from .limits import DEFAULT_LIMITS
from .merge import conditions as parse_conditions
from .messages import Query, Response
from .registry import Registry
from .signing import Identity, SignedItem
from .status import RUNNING, SUCCESS, Status
from .syntax import parse
from .transferlog import TransferLog
from .transport.zenoh import ZenohSettings, ZenohTransport, catalogs, open_session, peers
from .tree import Condition
from .trust import Policy, TrustStore, refusal
from .validate import validate

Colour = Annotated[int, Field(ge=1, le=4)]
"""The demo's colours: 1 to 4. A received skill naming colour 7, -999 or "red" is refused."""


@dataclass(frozen=True)
class Security:
    """A peer's key pair, what it accepts (policy and trust store) and where it logs."""

    identity: Identity | None = None
    policy: Policy = Policy.ANY
    trust: TrustStore | None = None
    log: TransferLog | None = None


Say = Callable[[str], None]


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


def answers(
    knowledge: KnowledgeBase, identity: Identity | None = None
) -> Callable[[str], SignedItem | None]:
    """A server's lookup: every answer formatted (and, with a key pair, signed by this server
    as its author) once, so a query costs one dict lookup."""
    table = {}
    for item in knowledge:
        subtree = format_tree(item.subtree, "compact")
        if item.author is not None:
            table[item.key] = SignedItem(subtree, item.author, item.signature)
        elif identity is not None:
            table[item.key] = identity.sign_item(item.key, subtree)
        else:
            table[item.key] = SignedItem(subtree)
    return table.get


def catalog(
    knowledge: KnowledgeBase, identity: Identity | None = None
) -> Callable[[], list[str | dict[str, Any]]]:
    """What the catalog queryable answers: each sequence with its provenance (a peer with a key
    pair is the author of the items it holds unsigned: it signs them when it answers)."""
    own = identity.public if identity is not None else None

    def entries() -> list[str | dict[str, Any]]:
        out: list[str | dict[str, Any]] = []
        for item in knowledge:
            entry = {
                "sequence": item.key,
                "author": item.author or own,
                "teacher": item.source,
                "received_at": item.received_at,
            }
            out.append({k: v for k, v in entry.items() if v is not None})
        return out

    return entries


class Overhearing:
    """A server that overhears (spec/protocol.md section 4.3): an answer another peer published
    is checked as a robot checks a direct answer (the trust policy, in the transport; the
    receive limits and the structure, here) and added to what the server serves, at once
    (``update``) or, kept in a buffer of ``buffer_size``, when a query first asks for it
    (``buffer``). The subtree is served as received, so its author's signature still holds.
    Lookups run in zenoh callbacks while the main thread hears: one lock guards the tables."""

    def __init__(
        self,
        name: str,
        knowledge: KnowledgeBase,
        served: Callable[[str], SignedItem | None],
        mode: Overhear,
        say: Say,
        buffer_size: int = 16,
    ) -> None:
        self.name, self.knowledge, self.served, self.mode, self.say = (
            name,
            knowledge,
            served,
            mode,
            say,
        )
        self.buffer_size = buffer_size
        self.learned: dict[str, SignedItem] = {}
        self.buffer: dict[str, Response] = {}
        self.refused = 0
        self.lock = threading.Lock()

    def heard(self, message: object) -> None:
        if not isinstance(message, Response) or self.mode == "off":
            return
        with self.lock:
            if message.sequence in self.knowledge or message.sequence in self.buffer:
                return  # known, or the first answer heard is kept
            if self.mode == "update":
                self._learn(message)
            elif len(self.buffer) >= self.buffer_size:
                self._refuse(f"from {message.sender}: overheard answer, buffer full")
            else:
                self.buffer[message.sequence] = message

    def lookup(self, key: str) -> SignedItem | None:
        found = self.served(key)
        if found is not None:
            return found
        with self.lock:
            found = self.learned.get(key)
            kept = self.buffer.pop(key, None) if found is None else None
            return self._learn(kept) if kept is not None else found

    def catalog(self, entries: Callable[[], list[str | dict[str, Any]]]) -> Callable[[], Any]:
        def locked() -> list[str | dict[str, Any]]:
            with self.lock:
                return entries()

        return locked

    def _learn(self, answer: Response) -> SignedItem | None:
        try:
            conds = parse_sequence(answer.sequence, RECEIVE_LIMITS)
            subtree = parse(answer.subtree, limits=RECEIVE_LIMITS).root
            validate(subtree, limits=RECEIVE_LIMITS)
        except StringBTError as err:
            self._refuse(f"from {answer.sender}: {err.code.value} {err.message}")
            return None
        received = datetime.now(UTC).isoformat(timespec="seconds")
        self.knowledge.add(
            Knowledge(conds, subtree, "new", answer.sender, None, answer.author,
                      answer.signature, received)
        )  # fmt: skip
        item = SignedItem(answer.subtree, answer.author, answer.signature)
        self.learned[answer.sequence] = item
        self.say(f"{self.name}: learned {shown(answer.sequence)} from {answer.sender} (overheard)")
        return item

    def _refuse(self, reason: str) -> None:
        self.refused += 1
        logging.getLogger("ktbt.peer").info("%s refused: %s", self.name, reason)


def serve(
    name: str,
    knowledge: KnowledgeBase,
    settings: ZenohSettings,
    say: Say,
    security: Security | None = None,
    publish_answers: bool = False,
    overhear: Overhear = "off",
    groot: int | None = None,
) -> int:
    """Serve ``knowledge`` until stopped; ``publish_answers`` and ``overhear``: section 4.3;
    ``groot``: show the knowledge to Groot2 on that port (spec/groot2.md)."""
    security = security or Security()
    ear = Overhearing(name, knowledge, answers(knowledge, security.identity), overhear, say)
    policy = security.policy
    with (
        until_signalled() as stop,
        ExitStack() as stack,
        ZenohTransport(
            name,
            settings,
            lookup=ear.lookup,
            catalog=ear.catalog(catalog(knowledge, security.identity)),
            identity=security.identity,
            log=security.log,
            publish_answers=publish_answers,
            overhear=overhear != "off",
            screen=lambda r: refusal(r, policy, security.trust),
        ) as transport,
    ):
        say(f"{name}: serving {len(knowledge)} skills; Ctrl-C to stop")
        if groot is not None:
            from .groot2 import Groot2Publisher, knowledge_tree

            stack.enter_context(Groot2Publisher(knowledge_tree(knowledge), groot))
            say(f"{name}: Groot2 on port {groot} (btview snapshot -p {groot})")
        if security.identity is not None:
            say(f"  signed as {security.identity.public}")
        for item in knowledge:
            say(f"  {show_sequence(item.conditions)}")
        if overhear == "off":
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
        if answer.id != query.id or answer.sequence != key:
            return
        why = refusal(answer, security.policy, security.trust)
        try:  # shown only if it is stringBT within a robot's receive limits (numbers too)
            tree = parse(answer.subtree, limits=RECEIVE_LIMITS)
            validate(tree, limits=RECEIVE_LIMITS)
        except StringBTError as err:
            why = why or f"{err.code.value} {err.message}"
        if why is not None:
            say(f"# from {answer.sender}: refused, {why}")
            return
        say(f"# from {answer.sender}{provenance(answer)}")
        say(format_tree(tree).rstrip())
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


def run_agent(
    name: str,
    settings: ZenohSettings,
    sequences: Sequence[str],
    say: Say,
    *,
    control: str = DEMO_CONTROL,
    tick_rate: float = 100.0,
    wait_ticks: int = 200,
    cooldown_ticks: int = 50,
    duration: float = 30.0,
    knowledge_path: str | None = None,
    exit_when_done: bool = False,
    security: Security | None = None,
    publish_answers: bool = False,
    overhear: Overhear = "off",
    groot: int | None = None,
) -> int:
    """A demo agent: meets each sequence in turn until it knows it (or time runs out), teaching
    what it knows to whoever asks, and prints what it learned. Refusals are logged (to stderr
    and, with a transfer log, there) and the summary counts all of them, transport ones too.
    ``publish_answers`` and ``overhear``: spec/protocol.md section 4.3; ``groot``: serve the
    control tree to Groot2 on that port (spec/groot2.md)."""
    security = security or Security()
    with (
        until_signalled() as stop,
        ExitStack() as stack,
        ZenohTransport(
            name,
            settings,
            query_timeout=wait_ticks / tick_rate,
            log=security.log,
            publish_answers=publish_answers,
            overhear=overhear != "off",
        ) as transport,
    ):
        robot = Agent(
            name,
            control,
            demo_registry(),
            transport,
            wait_ticks=wait_ticks,
            cooldown_ticks=cooldown_ticks,
            knowledge_path=knowledge_path,
            identity=security.identity,
            policy=security.policy,
            trust=security.trust,
            log=security.log,
            overhear=overhear,
        )
        transport.catalog = catalog(robot.knowledge, security.identity)
        if groot is not None:
            from .groot2 import Groot2Publisher

            stack.enter_context(Groot2Publisher(robot, groot))
            say(f"{name}: Groot2 on port {groot} (btview snapshot -p {groot})")
        for _, reason in robot.metrics.refusals:  # a damaged --save file, say
            say(f"{name}: refused: {reason}")
        wait_for_peers(transport, 3.0)
        deadline = time.monotonic() + duration
        todo = list(sequences)
        period = 1.0 / tick_rate
        say(f"{name}: knows {len(robot.knowledge)}, will meet {len(todo)} sequences")
        announced = set(robot.metrics.learned)
        while not stop.is_set() and time.monotonic() < deadline:
            while todo and robot.knows([todo[0]]):
                todo.pop(0)
            if not todo and exit_when_done:
                break
            robot.encounter([todo[0]] if todo else None)
            robot.tick()
            for key in robot.metrics.learned.keys() - announced:
                tick, source = robot.metrics.learned[key]
                say(f"{name}: learned {shown(key)} from {source} at tick {tick}")
                announced.add(key)
            stop.wait(period)
        m = robot.metrics
        say(
            f"{name}: queries sent {m.queries_sent}, answers {m.responses_received}, "
            f"lost {m.queries_lost}, refused {m.refused + transport.refused}, "
            f"taught {m.responses_sent}"
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
