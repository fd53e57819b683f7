"""What ``ktbt peer`` does: serve knowledge, ask for it, run a learning agent, route, list.

Every command is a real zenoh peer (or router) with explicit endpoints, and closes its session
on exit, including on SIGINT and SIGTERM. A fleet member (``serve``, ``run``) is a
:class:`PeerSettings`: its name, network settings (with a zenoh id derived from its name, so a
restarted peer is the same peer), security, and what it publishes and overhears; an option
every member takes is one field there.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ktbt_proto.exchange.answers import answers, catalog
from ktbt_proto.exchange.application import ApplicationTimedAgent
from ktbt_proto.exchange.knowledge import KnowledgeBase, with_knowledge
from ktbt_proto.exchange.member import FleetMember
from ktbt_proto.exchange.messages import Query, Response
from ktbt_proto.exchange.overhearing import Overhear, Overhearing, ServerOverhearing
from ktbt_proto.exchange.receiving import Refused, check
from ktbt_proto.exchange.security import Security
from ktbt_proto.exchange.signing import Identity
from ktbt_proto.exchange.trust import refusal
from ktbt_proto.files import write_atomic
from ktbt_proto.formatter import format_tree
from ktbt_proto.items import sequence_key, show_key, show_sequence
from ktbt_proto.registry import Registry
from ktbt_proto.status import Status
from ktbt_proto.transport.zenoh import (
    ZenohCatalogs,
    ZenohSettings,
    ZenohTransport,
    catalogs,
    open_session,
    peers,
    stable_zid,
)
from ktbt_proto.tree import Action, Condition, RunTimer, Tree, Wait, WaitTimer, walk

if TYPE_CHECKING:
    from ktbt_proto.interop.sidecar import LearnedExport

Say = Callable[[str], None]

log = logging.getLogger("ktbt.peer")


@dataclass(frozen=True)
class PeerSettings:
    """A long-running fleet member (``ktbt peer serve``, ``ktbt peer run``): what both take.
    Its zenoh id is derived from ``name`` unless the settings name one (spec/protocol.md
    section 3)."""

    name: str
    settings: ZenohSettings = field(default_factory=ZenohSettings)
    security: Security = field(default_factory=Security)
    publish_answers: bool = False
    overhear: Overhear = Overhear.OFF
    publish_events: bool = False
    """Publish this member's fleet events (``ktbt_proto.exchange.events``, for ``ktbt monitor``)."""
    groot: int | None = None
    """A port to serve Groot2 on (and the next), loopback (spec/groot2.md)."""
    ready: Path | None = None
    """Where to say, once up, that this member is ready (:func:`announce_ready`)."""

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


REST_RATE = 2.0
"""Steps a second, at least, of a ``ktbt peer run`` robot at rest (:class:`Rest`). At rest
nothing it does depends on the rate (its tree's ticks repeat the last, and its member acts only
on what arrived or when its next timed act is due): what a resting peer costs is its wakes,
about 0.2 ms of CPU each on a busy machine. Anything that arrives, or a signal, wakes it at
once."""

STEADY_STEPS = 10
"""Steps at the full rate in which nothing changed before a robot rests, and after each time
something arrived (:class:`Rest`)."""


def quiet(tree: Tree, registry: Registry) -> bool:
    """Whether ``tree`` ticked again on the same blackboard does the same: every leaf pure
    (:attr:`~ktbt_proto.registry.Behaviour.pure`), no timer (``<w>``, ``<wt>``, TT1, TT2
    count ticks or seconds): one of the conditions of a rest (spec/protocol.md section 4.5)."""
    for node, _ in walk(tree.root):
        if isinstance(node, Wait | WaitTimer | RunTimer):
            return False
        if isinstance(node, Condition) and not registry.pure("condition", node.name):
            return False
        if isinstance(node, Action) and not registry.pure("action", node.name):
            return False
    return True


_IMMUTABLE = frozenset((bool, int, float, str, bytes, type(None), Status))
"""The blackboard values :class:`Rest` compares (a tuple may hold a list: not among them)."""


class Rest:
    """How long a ``ktbt peer run`` robot may wait before its next step (spec/protocol.md
    section 4.5): its ``period`` while its tree may change; at rest, until its member's next
    timed act is due (:meth:`FleetMember.due`: a query's wait over, the backoff's next ask), at
    most ``resting`` seconds. It is at rest when nothing was learned, no memory policy counts
    its ticks, its tree is :func:`quiet`, and its last :data:`STEADY_STEPS` steps left the
    tree's status and the blackboard as they were (a blackboard of plain values: numbers,
    strings, flags). Such a tree's next ticks would do exactly what the last did, and the
    member's step acts only on what arrived and on its timed acts: stepping it less often
    changes nothing the robot does, and what arrives (:attr:`ZenohTransport.stirred`) brings
    it back to its full rate at once (:meth:`stirred`)."""

    def __init__(
        self, robot: ApplicationTimedAgent, fleet: FleetMember, period: float, resting: float
    ) -> None:
        self.robot, self.fleet = robot, fleet
        self.period, self.resting = period, max(period, resting)
        self.steady = 0
        self._tree: Tree | None = None
        self._quiet = False
        self._seen: tuple[Status | None, dict[str, Any]] | None = None

    def stirred(self) -> None:
        """Something arrived: full rate for :data:`STEADY_STEPS` steps at least."""
        self.steady = 0

    def after(self, learned: list[str], now: float) -> float:
        """Seconds to wait before the next step, after the step at ``now`` (the host's
        monotonic clock) that learned ``learned``: :attr:`period` unless at rest."""
        robot, fleet = self.robot, self.fleet
        tree = robot.control.tree
        if tree is not self._tree:  # merged or forgotten: the tree's leaves are others
            self._tree, self._quiet = tree, quiet(tree, robot.registry)
        memory = robot.memory
        board = robot.blackboard
        seen = (fleet.status, dict(board))
        # Only values that cannot change in place are compared: a list a leaf appends to is
        # the same object in the copy, so a blackboard holding one is never taken as steady.
        same = seen == self._seen and all(type(v) in _IMMUTABLE for v in board.values())
        if (
            learned
            or not self._quiet
            or memory.forget_after is not None
            or memory.expire_after is not None
            or not same
        ):
            self.steady = 0
        else:
            self.steady += 1
        self._seen = seen
        if self.steady < STEADY_STEPS:
            return self.period
        return max(0.0, min(self.resting, fleet.due(now) - now))


@contextmanager
def until_signalled(also: Sequence[threading.Event] = ()) -> Iterator[threading.Event]:
    """An event set by SIGINT or SIGTERM, so a long-running command can close cleanly; the
    events in ``also`` (as it holds them when the signal comes) are set too, so that a loop
    waiting on one of them ends at once.

    The events are set by a thread of its own, woken through the signal module's wakeup file
    descriptor, never by the Python signal handler: a handler runs in the main thread between
    any two of its bytecodes, so one that sets an event could wait for that event's lock while
    the main thread it interrupted holds it (inside ``Event.wait``), and the process would
    never end (a second SIGTERM while the first was being handled did so)."""
    stop = threading.Event()
    wanted = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.getsignal(s) for s in wanted}
    read, write = os.pipe()
    os.set_blocking(write, False)

    def watch() -> None:
        while data := os.read(read, 64):  # the signals' numbers; b"": the context ended
            if any(n in wanted for n in data):
                stop.set()
                for event in also:
                    event.set()

    watcher = threading.Thread(target=watch, name="ktbt-signals", daemon=True)
    watcher.start()
    before = signal.set_wakeup_fd(write, warn_on_full_buffer=False)
    for sig in wanted:
        signal.signal(sig, _noted)
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        signal.set_wakeup_fd(before)
        os.close(write)
        watcher.join()
        os.close(read)


def _noted(signum: int, frame: object) -> None:
    """A signal's Python handler while :func:`until_signalled` holds: nothing (its watcher
    acts on the signal); installed so that the signal neither ends nor interrupts the
    process."""


def announce_ready(path: Path | None, peer: str, knows: int | None) -> None:
    """Tell a supervisor (``ktbt fleet run``) that this process is up: one JSON object,
    ``{"peer": NAME, "knows": N}`` (``knows`` null for a router), written whole to ``path``
    once the session is open and, for a member, what it starts knowing is loaded. A supervisor
    reads this, never the human-readable output, which may change."""
    if path is not None:
        write_atomic(path, json.dumps({"peer": peer, "knows": knows}) + "\n")


def wait_for_peers(transport: ZenohTransport, timeout: float) -> dict[str, list[str]]:
    deadline = time.monotonic() + timeout
    found: dict[str, list[str]] = {}
    while time.monotonic() < deadline:
        found = peers(transport, timeout=0.3)
        if found:
            break
        time.sleep(0.05)
    return found


def serve(
    member: PeerSettings, knowledge: KnowledgeBase, say: Say, registry: Registry | None = None
) -> int:
    """Serve ``knowledge`` until stopped, answering inside zenoh's callback; publishing and
    overhearing as the member says (section 4.3), an overheard answer served only if it passes
    the checks a learner runs (the member's trust policy and store, the receive limits and
    ``registry``, the server's vocabulary, if it has one); with the member's ``groot``, the
    knowledge is shown to Groot2 (spec/groot2.md)."""
    security = member.security
    ear = ServerOverhearing(
        member.name,
        knowledge,
        answers(knowledge, security.identity),
        member.overhear,
        lambda a: say(f"{member.name}: learned {show_key(a.sequence)} from {a.sender} (overheard)"),
        security=security,
        registry=registry,
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
        ear.log = transport.log  # with --publish-events, the transport made one
        say(f"{name}: serving {len(knowledge)} skills; Ctrl-C to stop")
        announce_ready(member.ready, name, len(knowledge))
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
    registry: Registry | None = None,
) -> tuple[int, list[Response]]:
    """Ask the fleet and print each acceptable answer the moment it arrives, with its
    provenance; an answer the policy or the receive limits refuse is shown as refused, and so
    is one the asker's ``registry`` (if given) could not execute (section 2).
    ``note`` is told, when no answer came, whether nobody was reachable or nobody knew: two
    different problems that look alike otherwise."""
    security = security or Security()
    key = sequence_key(sequence)
    query = Query(id=Query.new_id(), sender=name, sequence=key)
    responses: list[Response] = []

    def show(answer: Response) -> None:
        if answer.id != query.id:
            return
        try:  # shown only if it passes a robot's receive checks (numbers too)
            _, subtree = check(answer, key, security.policy, security.trust, registry=registry)
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
                f"none knows {show_sequence(key)}"
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
    member: PeerSettings,
    sequences: Sequence[str] | None,
    say: Say,
    *,
    control: str,
    registry: Registry,
    slot: str = "new",
    knowledge: KnowledgeBase | None = None,
    tick_rate: float = 100.0,
    wait_ticks: int = 200,
    cooldown_ticks: int = 50,
    duration: float = 30.0,
    knowledge_path: str | None = None,
    exit_when_done: bool = False,
    export_learned: str | LearnedExport | None = None,
    rest_rate: float = REST_RATE,
) -> int:
    """A fleet member that learns and teaches, running ``control`` with ``registry`` and
    learning into the placeholder ``slot``: it starts with ``knowledge`` (if any) and what
    ``knowledge_path`` saved, meets each sequence in turn until it knows it (or time runs out),
    asking again with a bounded backoff while it is missing, and at once when a new peer
    appears; it teaches what it knows to whoever asks, and prints what it learned. With
    ``sequences`` None, the sequences it meets are those its fleet's catalogs list and its
    vocabulary can execute (:class:`ListedSequences`), the catalogs read again whenever a peer
    appears and every ``CATALOG_PERIOD`` seconds (section 4.5); ``exit_when_done`` then stops
    once it knows every one found, and it has found one. Refusals are logged (to stderr and, with a
    transfer log, there) and the summary counts all of them, transport ones too; the
    network's own errors are counted apart. ``export_learned``: a folder (or an export made
    already) to mirror learned items into as BT.CPP documents (spec/stringbt.md section
    12.1); the member's ``groot``: serve the control tree to Groot2 (spec/groot2.md). At rest
    (:class:`Rest`: a tree whose ticks change nothing) it sleeps until its member's next timed
    act, ``1 / rest_rate`` seconds at most, instead of stepping at ``tick_rate``, and steps at
    once when anything arrives."""
    security = member.security
    name = member.name
    wait, cooldown = wait_ticks / tick_rate, cooldown_ticks / tick_rate
    woken: list[threading.Event] = []
    with (
        until_signalled(woken) as stop,
        ExitStack() as stack,
        member.transport(query_timeout=wait, identity=security.identity) as transport,
    ):
        woken.append(transport.stirred)  # a signal ends a rest at once
        robot = ApplicationTimedAgent(
            name,
            with_knowledge(control, knowledge, slot),
            registry,
            transport,
            knowledge_path=knowledge_path,
            # with --publish-events, the transport has a log even without --log
            security=replace(security, log=transport.log),
            ear=Overhearing(member.overhear),
            slot=slot,
        )
        # The agent attached itself to the transport (ZenohTransport.attach): it answers every
        # query it can at once from what it knows, as `peer serve` does, and serves its
        # catalog and tree (section 4.5).
        if member.groot is not None:
            from ktbt_proto.interop.groot2 import Groot2Publisher

            stack.enter_context(Groot2Publisher(robot, member.groot, stop=stop))
            say(f"{name}: Groot2 on port {member.groot} (btview snapshot -p {member.groot})")
        export = export_learned
        if isinstance(export, str):
            from ktbt_proto.interop.sidecar import LearnedExport

            export = LearnedExport(export)
        for _, reason in robot.metrics.refusals:  # a damaged --save file, say
            say(f"{name}: refused: {reason}")
        wait_for_peers(transport, 3.0)
        deadline = time.monotonic() + duration
        fleet = FleetMember(
            robot,
            transport,
            ZenohCatalogs(transport),
            None if sequences is None else [sequence_key([s]) for s in sequences],
            wait,
            cooldown,
            say,
            export,
            relay=transport,  # what it learns is announced, and asked for at once (section 4.5)
        )
        if fleet.listed is None:
            say(f"{name}: knows {len(robot.knowledge)}, will meet {len(fleet.todo)} sequences")
        else:
            say(f"{name}: knows {len(robot.knowledge)}, will meet what its peers list")
        announce_ready(member.ready, name, len(robot.knowledge))
        period = 1.0 / tick_rate
        rest, stirred = Rest(robot, fleet, period, 1.0 / rest_rate), transport.stirred
        while not stop.is_set() and (now := time.monotonic()) < deadline:
            robot.now += 1
            if stirred.is_set():  # arrived since the last step, at rest or not
                rest.stirred()
                stirred.clear()
            learned = fleet.step(now)
            if exit_when_done and fleet.done:
                break
            sleep = rest.after(learned, time.monotonic())  # the step took time too
            if sleep > period:  # at rest: until its next timed act, or anything arrives
                stirred.wait(min(sleep, deadline - time.monotonic()))
            else:
                stop.wait(period)
        m = robot.metrics
        say(
            f"{name}: queries sent {m.queries_sent}, answers {m.responses_received}, "
            f"lost {m.queries_lost}, refused {fleet.refused + transport.refused}, "
            f"taught {m.responses_sent + transport.answered}, late answers {m.late_answers}, "
            f"network errors {m.network_errors}"
        )
        for item in robot.knowledge:
            say(f"  knows {show_sequence(item.conditions)}")
        met = fleet.listed.found if fleet.listed is not None else list(sequences or ())
        return 0 if all(robot.knows([s]) for s in met) else 1


def router(settings: ZenohSettings, say: Say, ready: Path | None = None) -> int:
    """A zenoh router on ``settings``' endpoints until stopped (spec/protocol.md section 3)."""
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
            announce_ready(ready, "router", None)
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
            say(f"  {show_key(entry['sequence'])}" + (f"  ({', '.join(origin)})" if origin else ""))
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


def fleet_keys(folder: Path, names: Sequence[str], say: Say) -> int:
    """A fleet's keys in one go (spec/protocol.md section 7): ``FOLDER/NAME.key`` (private)
    and ``.pub`` for each robot, and ``FOLDER/trust.txt``, the trust store naming them all,
    which every robot of the fleet is given with the ``trusted`` policy. Nothing is written
    over an existing file: a name whose key exists already is refused before any is made."""
    taken = [n for n in names if (folder / f"{n}.key").exists()]
    store = folder / "trust.txt"
    if taken or store.exists():
        raise FileExistsError(
            f"{folder}: {', '.join(f'{n}.key' for n in taken) or 'trust.txt'} exists; "
            "keys are never overwritten"
        )
    lines = []
    for name in names:
        identity = Identity.generate()
        identity.save(folder / f"{name}.key")
        lines.append(f"{name} {identity.public}")
    write_atomic(store, "\n".join(lines) + "\n")
    say(f"wrote {len(names)} key pairs and {store}: give each robot its key and the store")
    return 0


def configure_logging() -> None:
    """Refusals and other exchange events to stderr, so an operator sees them."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s", force=False)
