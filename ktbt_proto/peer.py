"""What ``ktbt peer`` does: serve knowledge, ask for it, run a learning agent, route, list.

Every command is a real zenoh peer (or router) with explicit endpoints, and closes its session
on exit, including on SIGINT and SIGTERM.
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from .agent import RECEIVE_LIMITS, Agent
from .blackboard import Blackboard
from .errors import StringBTError
from .format import format as format_tree
from .knowledge import KnowledgeBase, sequence_key, show_sequence
from .merge import conditions as parse_conditions
from .messages import Query, Response
from .registry import Registry
from .status import RUNNING, SUCCESS, Status
from .syntax import parse
from .transport.zenoh import ZenohSettings, ZenohTransport, open_session, peers
from .tree import Condition

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
    def target_seen(bb: Blackboard, colour: int) -> bool:
        return bool(bb.get("target") == colour)

    @reg.action("PickTreasure")
    def pick(bb: Blackboard) -> Status:
        bb["Carrying"] = True
        return SUCCESS

    @reg.action("AssignCollectionPoint")
    def assign(bb: Blackboard, colour: int) -> Status:
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
    Items too large to send are refused here, not at every query."""
    kb = KnowledgeBase.from_tree(parse(Path(path).read_bytes()))
    for item in kb:
        if len(format_tree(item.subtree, "compact")) > 60_000:
            raise ValueError(f"{path}: the subtree for {item.key} is too large to send")
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


def answers(knowledge: KnowledgeBase) -> Callable[[str], str | None]:
    """A server's lookup: every answer formatted once, so a query costs one dict lookup."""
    table = {item.key: format_tree(item.subtree, "compact") for item in knowledge}
    return table.get


def serve(name: str, knowledge: KnowledgeBase, settings: ZenohSettings, say: Say) -> int:
    lookup = answers(knowledge)
    with (
        until_signalled() as stop,
        ZenohTransport(name, settings, lookup=lookup, catalog=knowledge.keys),
    ):
        say(f"{name}: serving {len(knowledge)} skills; Ctrl-C to stop")
        for item in knowledge:
            say(f"  {show_sequence(item.conditions)}")
        stop.wait()
    say(f"{name}: stopped")
    return 0


def ask(
    name: str,
    sequence: Sequence[str | Condition],
    settings: ZenohSettings,
    timeout: float,
    say: Say,
    note: Say | None = None,
) -> tuple[int, list[Response]]:
    """Ask once; ``say`` the answers. ``note`` is told, when no answer came, whether nobody was
    reachable or nobody knew: two different problems that look alike otherwise."""
    key = sequence_key(parse_conditions(sequence))
    query = Query(id=Query.new_id(), sender=name, sequence=key)
    with ZenohTransport(name, settings, query_timeout=timeout, serving=False) as transport:
        reachable = wait_for_peers(transport, timeout)
        answers = transport.ask(query, timeout)
    responses = []
    for answer in answers:
        if not isinstance(answer, Response) or answer.id != query.id or answer.sequence != key:
            continue
        try:  # an answer is shown only if it is stringBT a robot would accept
            tree = parse(answer.subtree, limits=RECEIVE_LIMITS)
        except StringBTError as err:
            say(f"# from {answer.sender}: refused, {err.code.value} {err.message}")
            continue
        say(f"# from {answer.sender}")
        say(format_tree(tree).rstrip())
        responses.append(answer)
    if not responses and note is not None:
        if not reachable:
            note(f"no answer: no peer reachable within {timeout:g} s")
        else:
            note(
                f"no answer: {len(reachable)} peer{'s' * (len(reachable) != 1)} reachable, "
                f"none knows {show_sequence(parse_conditions(sequence))}"
            )
    return (0 if responses else 1), responses


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
) -> int:
    """A demo agent: meets each sequence in turn until it knows it (or time runs out), teaching
    what it knows to whoever asks, and prints what it learned."""
    with (
        until_signalled() as stop,
        ZenohTransport(name, settings, query_timeout=wait_ticks / tick_rate) as transport,
    ):
        robot = Agent(
            name,
            control,
            demo_registry(),
            transport,
            wait_ticks=wait_ticks,
            cooldown_ticks=cooldown_ticks,
            knowledge_path=knowledge_path,
        )
        transport.catalog = robot.knowledge.keys
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
            f"lost {m.queries_lost}, refused {len(m.refusals)}, taught {m.responses_sent}"
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
    with ZenohTransport(name, settings, serving=False) as transport:
        found = wait_for_peers(transport, timeout)
    for peer, known in sorted(found.items()):
        say(f"{peer}: {len(known)} skills")
        for key in known:
            say(f"  {shown(key)}")
    if not found:
        say("no peers found")
    return 0 if found else 1
