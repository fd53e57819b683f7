"""What a ROS 2 host does with a message it cannot read (spec/protocol.md section 2.1): it
refuses it, counts it, logs it at WARNING with its reason, and goes on with its tree and
knowledge as they were; then it learns (or relays, or shows) what an honest robot sends.

Each host is a real process in a network namespace of the test's own (``rosns``). A hostile
participant sends it (a) an answer to an open query of its learner whose subtree is
``<sq><c>true.5<e>``, which once made the parser raise an AssertionError and end the process;
(b) an answer whose subtree holds ``ktbt-fault``, whose reading raises when the host is started
with the test hook ``KTBT_FAULT_READING``; and (c) a catalog listing ``<c>true.`` and a sequence
that holds ``ktbt-fault``. The hosts: a ``ktbt ros2 run`` lifecycle node and a robot
``attach``-ed to its user's own node (both meet all three); the ``ktbt ros2 bridge``, which
decodes what each side sends and carries subtrees and catalogs unread, sent them by a ROS
participant and by zenoh peers; and ``ktbt monitor --ros2``, sent an event holding
``ktbt-fault``, a catalog and a tree that do not parse. Each host is checked to be running
after the hostile input and before an honest robot comes; every wait is on a topic, a log line
or the monitor's state, with a deadline.
"""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from ktbt_proto.exchange.refusals import FAULT_MARKER, FAULT_VARIABLE, INTERNAL
from ktbt_proto.files import packaged
from ktbt_proto.items import sequence_digest
from tests.interop.ros2.rosns import KTBT, SEQUENCE, Probe, RosNamespace
from tests.tools.monitor.test_command import Unix, _answers, _state
from tests.zenoh_helpers import endpoint, free_port, wait_until

pytestmark = [pytest.mark.network, pytest.mark.slow, pytest.mark.timeout(300)]

COLOURS = packaged("examples", "knowledge", "colours.sbt")
WANTED = SEQUENCE
"""What the learners ask for (``TargetSeen(colour=2)``), listed in the hostile catalog."""
UNREADABLE = "<sq><c>true.5<e>"
"""A subtree the parser once failed on with an AssertionError: now a refusal, SBT101."""
FAULTY = f"<sq><a>({FAULT_MARKER})<e>"
"""A subtree whose reading raises in a host started with the test hook set."""
LISTED = ["<c>true.", f"<c>({FAULT_MARKER})"]
"""A hostile catalog's entries: one that does not parse, one whose reading raises."""
INJECTED = f"{INTERNAL}: InjectedFault"
"""The reason of a refusal whose reading raised the test hook's exception."""


def faulty(ns: RosNamespace, stage: str, *args: str, name: str) -> subprocess.Popen[str]:
    """``ktbt ARGS`` in the namespace with the test hook set: reading any text that holds
    ``ktbt-fault`` at ``stage`` (``message`` or ``item``) raises inside the process."""
    return ns.start(["env", f"{FAULT_VARIABLE}={stage}", *KTBT, *args], name)


def catalog_raw(peer: str, sequences: list[str]) -> str:
    """A ``Catalog`` naming ``peer`` and listing ``sequences``, serialized (hex), as the
    probe publishes raw bytes."""
    from ktbt_interfaces.msg import Catalog, CatalogEntry
    from rclpy.serialization import serialize_message

    message = Catalog(peer=peer, items=[CatalogEntry(sequence=s) for s in sequences])
    return str(serialize_message(message).hex())


def logged(ns: RosNamespace, name: str, pattern: str, timeout: float = 60) -> str:
    """The first line of a process's log matching the regular expression ``pattern``; fails
    the test at the deadline."""
    found: list[str] = []

    def seen() -> bool:
        found[:] = [line for line in ns.log(name).splitlines() if re.search(pattern, line)]
        return bool(found)

    assert wait_until(seen, timeout), f"{name} never logged {pattern!r}:\n{ns.log(name)[-3000:]}"
    return found[0]


@contextmanager
def alive(ns: RosNamespace, **hosts: subprocess.Popen[str]) -> Iterator[None]:
    """Should a wait in the block fail, the test fails naming the host (by its log's name)
    that ended, with its log: a hostile message that ends its host is what is tested. After
    the block, every host is checked to be running."""

    def running() -> None:
        for name, proc in hosts.items():
            assert proc.poll() is None, f"{name} ended ({proc.returncode}):\n{ns.log(name)[-3000:]}"

    try:
        yield
    except AssertionError:
        running()
        raise
    running()


def refused_then_learned(
    ns: RosNamespace, probe: Probe, host: subprocess.Popen[str], robot: str, events: str
) -> None:
    """The learner ``robot`` (the process ``host``, started with ``KTBT_FAULT_READING=item``
    and told no sequences, its events on ``events``) asks for what a hostile catalog lists; two
    answers it cannot read come to that query, then the catalog lists two entries it cannot
    read. Each answer is refused (its event, its WARNING line), the catalog's entries too (a
    WARNING line), and it keeps running; then an honest ``ktbt ros2 run`` teacher comes, and
    it learns from it."""

    def catalog(sequences: list[str]) -> None:
        """The hostile catalog, latched, on a topic of a node of the fleet (the probe reads
        the query topic); each one published replaces the one before."""
        probe.until({"op": "publish", "topic": "/hostile/catalog", "type": "Catalog",
                     "raw": catalog_raw("hostile", sequences), "latched": True,
                     "subscribers": 1}, 60)  # fmt: skip

    with alive(ns, **{robot: host}):
        catalog([WANTED])
        asked = probe.wait("/ktbt/queries", 60, sender=robot, sequence=WANTED)
        # (a) and (b): answers to the open query, each from a sender of its own (one answer
        # per sender and sequence is taken to the agent).
        hostile = [("hostile", UNREADABLE, "SBT101 "), ("hostile2", FAULTY, INJECTED)]
        refusals = []
        for sender, subtree, reason in hostile:
            answer = {"v": 1, "id": asked["id"], "sender": sender, "to": robot,
                      "sequence": WANTED, "subtree": subtree}  # fmt: skip
            probe.until({"op": "publish", "topic": "/ktbt/answers", "type": "Answer",
                         "fields": answer, "subscribers": 1})  # fmt: skip
            refusals.append(
                probe.wait(events, 30, event="refused", reason=f"from {sender}: {reason}")
            )
        assert refusals[1]["reason"] == f"from hostile2: {INJECTED}", refusals
        for refused in refusals:
            logged(ns, robot, re.escape(f"{robot} refused knowledge: {refused['reason']}"))
        # (c) The catalog, changed: an entry that does not parse, one whose reading raises.
        catalog([*LISTED, WANTED])
        logged(
            ns, robot, re.escape(f"{robot} refused knowledge: the catalog of hostile: {INJECTED}")
        )
    assert host.poll() is None, ns.log(robot)[-3000:]  # running, and it learned nothing
    assert "merged" not in {e["event"] for e in probe.messages(events)}

    ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/teacher",
            "-p", f"knowledge:={COLOURS}", name="teacher")  # fmt: skip
    merged = probe.wait(events, 90, event="merged", teacher="teacher", sequence=WANTED)
    assert merged["peer"] == robot


def stopped(ns: RosNamespace, proc: subprocess.Popen[str], name: str, counted: str) -> int:
    """Stop a host by its pid (SIGTERM): it ends with 0 and no traceback; the number its last
    line matching ``counted`` (a regular expression with one group) says it refused."""
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=30) == 0, ns.log(name)[-3000:]
    log = ns.log(name)
    assert "Traceback" not in log and "AssertionError" not in log, log[-3000:]
    said = [m for line in log.splitlines() if (m := re.search(counted, line))]
    assert said, log[-3000:]
    return int(said[-1].group(1))


def test_a_ros2_run_learner_refuses_what_it_cannot_read_and_learns_after(
    rosns: Any,
) -> None:
    """``ktbt ros2 run``: each answer refused is an event on ``~/events`` and a WARNING line,
    the catalog's entry a WARNING line; the summary it logs when stopped counts all three."""
    ns: RosNamespace = rosns
    probe = Probe(ns)
    probe.subscribe("/learner/ktbt/events", "FleetEvent")
    probe.subscribe("/ktbt/queries", "Query")
    learner = faulty(ns, "item", "ros2", "run", "--autostart", "--ros-args", "-r",
                     "__ns:=/learner", "-p", "wait_ticks:=1000", name="learner")  # fmt: skip
    probe.until({"op": "publishers", "topic": "/learner/ktbt/events", "count": 1}, 60)
    refused_then_learned(ns, probe, learner, "learner", "/learner/ktbt/events")
    # The entry that does not parse is skipped, never asked (an INFO line: the node logs the
    # library's INFO; a user's node shows what its own logging configuration shows).
    logged(ns, "learner", re.escape(f"not asking for '{LISTED[0]}', listed by hostile"))
    refused = stopped(ns, learner, "learner", r"queries sent .*, refused (\d+),")
    assert refused == 3  # the two answers and the catalog's entry


USER_NODE = """
import signal, threading
import py_trees, rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions
from ktbt_proto.interop.ros2.embed import attach
from ktbt_proto.tools.demo import demo_registry

rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
node = rclpy.create_node("user")
root = py_trees.composites.Selector("Robot", memory=False, children=[
    py_trees.composites.Selector("k:new", memory=False),
    py_trees.behaviours.Running("Patrol"),
])
tree = py_trees.trees.BehaviourTree(root)
robot = attach(node, tree, demo_registry(), wait=10.0)
node.create_timer(0.1, tree.tick)
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *_: stop.set())
executor = SingleThreadedExecutor()
executor.add_node(node)
while not stop.is_set():
    executor.spin_once(timeout_sec=0.1)
print(f"user: stopped, refused {robot.agent.metrics.refused + robot.transport.refused}",
      flush=True)
robot.close()
"""
"""A user's own node, as a ROS 2 user writes one (and as ``examples/ros2/dock_robot.py``
does): a py_trees tree ticked by its own timer, KT-BT attached (told no sequences: it meets
what the fleet's catalogs list), spun until SIGTERM; an exception raised by any callback
comes out of ``spin_once`` and ends the process."""


def test_an_attached_robot_refuses_what_it_cannot_read_and_learns_after(
    rosns: Any, tmp_path: Path
) -> None:
    """A robot ``attach``-ed to its user's node: each refusal is an event on ``~/ktbt/events``
    and a WARNING line, and its user's spin goes on."""
    ns: RosNamespace = rosns
    script = tmp_path / "user_node.py"
    script.write_text(USER_NODE)
    probe = Probe(ns)
    probe.subscribe("/user/ktbt/events", "FleetEvent")
    probe.subscribe("/ktbt/queries", "Query")
    user = ns.start(["env", f"{FAULT_VARIABLE}=item", sys.executable, str(script)], "user")
    probe.until({"op": "publishers", "topic": "/user/ktbt/events", "count": 1}, 60)
    refused_then_learned(ns, probe, user, "user", "/user/ktbt/events")
    refused = stopped(ns, user, "user", r"user: stopped, refused (\d+)")
    assert refused == 3  # the two answers and the catalog entry (the agent counts all three)


EVIL_PEERS = """
import json, sys, threading
from ktbt_proto.transport.zenoh import ZenohSettings, ZenohTransport

peers, listed = json.loads(sys.argv[1]), json.loads(sys.argv[2])
for name, listen, subtree in peers:  # each answers every sequence asked with its subtree
    ZenohTransport(name, ZenohSettings(listen=[listen]), lookup=lambda key, s=subtree: s,
                   catalog=lambda: [{"sequence": s} for s in listed])
print("up", flush=True)
threading.Event().wait()  # until the namespace ends it
"""
"""Hostile zenoh peers (ktbt_proto's own transport, loopback, no multicast scouting): each
answers whatever it is asked with the subtree it is given, and lists ``listed``."""


def test_the_bridge_refuses_what_it_cannot_read_from_either_side_and_relays_after(
    rosns: Any, tmp_path: Path
) -> None:
    """``ktbt ros2 bridge`` started with ``KTBT_FAULT_READING=message``: a ROS answer it
    cannot decode, and a zenoh reply it cannot decode (to a ROS learner's query it relayed),
    are refused, logged and counted in its summary; the unreadable subtree it relays to the
    ROS learner, which refuses it; hostile catalogs from both sides are carried, not read. It
    keeps running, and relays an honest zenoh teacher's answer to the ROS learner after."""
    ns: RosNamespace = rosns
    evil, evil2, honest = free_port(), free_port(), free_port()
    probe = Probe(ns)
    probe.subscribe("/rl/ktbt/events", "FleetEvent")
    probe.subscribe("/ktbt/queries", "Query")  # one of the fleet: the bridge reads its catalog
    script = tmp_path / "evil_peers.py"
    script.write_text(EVIL_PEERS)
    peers = [["evil", endpoint(evil), UNREADABLE], ["evil2", endpoint(evil2), FAULTY]]
    ns.start([sys.executable, str(script), json.dumps(peers), json.dumps(LISTED)], "evil")
    bridge = faulty(ns, "message", "ros2", "bridge", "--connect", endpoint(evil), "--connect",
                    endpoint(evil2), "--connect", endpoint(honest), name="bridge")  # fmt: skip
    learner = ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/rl",
                      "-p", "sequences:=[TargetSeen(colour=2)]", name="rl")  # fmt: skip
    with alive(ns, bridge=bridge, rl=learner):
        logged(ns, "bridge", "bridging zenoh")
        # ROS's side: an answer whose fields hold the marker (refused, unread), one with the
        # unreadable subtree (to no question the bridge relayed), a catalog of both kinds.
        for n, subtree in enumerate((FAULTY, UNREADABLE)):
            answer = {"v": 1, "id": f"h{n}", "sender": "hostile", "to": "evil",
                      "sequence": WANTED, "subtree": subtree}  # fmt: skip
            probe.until({"op": "publish", "topic": "/ktbt/answers", "type": "Answer",
                         "fields": answer, "subscribers": 2}, 60)  # fmt: skip
        logged(ns, "bridge", re.escape(f"bridge.ktbt_bridge refused: on /ktbt/answers: {INJECTED}"))
        probe.until({"op": "publish", "topic": "/hostile/catalog", "type": "Catalog",
                     "raw": catalog_raw("hostile", LISTED), "latched": True,
                     "subscribers": 1}, 60)  # fmt: skip
        logged(ns, "bridge", "ROS robot hostile is on zenoh")
        # Zenoh's side: the ROS learner's query, relayed, answered by both hostile peers: the
        # reply holding the marker is refused by the learner's mirror in the bridge, the
        # other relayed, and refused by the learner.
        logged(ns, "bridge", "zenoh peer evil2 is on ROS")
        shown = "/ktbt_bridge/zenoh/evil2/catalog"  # the zenoh peer's catalog, as carried
        probe.subscribe(shown, "Catalog", latched=True)

        def carried() -> bool:
            listed = [[i["sequence"] for i in m["items"]] for m in probe.messages(shown)]
            return LISTED in listed

        assert wait_until(carried, 30), probe.messages(shown)
        logged(ns, "bridge", rf"rl refused: a reply to \S+: {re.escape(INJECTED)}")
        probe.wait("/rl/ktbt/events", 60, event="refused", reason="from evil: SBT101 ")
    assert bridge.poll() is None, ns.log("bridge")[-3000:]
    assert learner.poll() is None, ns.log("rl")[-3000:]
    assert "merged" not in {e["event"] for e in probe.messages("/rl/ktbt/events")}

    # An honest zenoh teacher comes: the bridge relays its answer, and the learner learns.
    ns.ktbt("peer", "serve", "--id", "zt", "--knowledge", str(COLOURS),
            "--listen", endpoint(honest), name="zt")  # fmt: skip
    merged = probe.wait("/rl/ktbt/events", 90, event="merged", teacher="zt")
    assert merged["sequence"] == WANTED
    refused = stopped(ns, bridge, "bridge", r"relayed queries .*; refused (\d+);")
    assert refused >= 2
    summary = logged(ns, "bridge", "relayed queries")
    assert re.search(r"answers [1-9]\d* to ROS", summary), summary


def tree_of(uds: Path, peer: str) -> None:
    """Ask the monitor for a peer's tree (as its page does when the peer is selected)."""
    connection = Unix(uds)
    try:
        connection.request("GET", f"/api/tree/{peer}")
        assert connection.getresponse().status == 200
    finally:
        connection.close()


def test_the_monitor_counts_what_it_cannot_read_and_shows_an_honest_robot(
    rosns: Any, tmp_path: Path
) -> None:
    """``ktbt monitor --ros2`` started with ``KTBT_FAULT_READING=message``: an event on a
    robot's ``~/events`` whose fields hold the marker, a catalog listing what does not parse
    and a tree that does not parse are each dropped as malformed with their reason; it keeps
    running, and shows an honest robot that comes after."""
    ns: RosNamespace = rosns
    uds = tmp_path / "http.sock"
    monitor = faulty(ns, "message", "monitor", "--ros2", "--http", "127.0.0.1:8470",
                     "--uds", str(uds), name="monitor")  # fmt: skip
    probe = Probe(ns)
    assert wait_until(lambda: _answers(uds), 60), ns.log("monitor")

    def malformed() -> list[str]:
        """The reasons of what the monitor dropped as malformed (the latest it keeps)."""
        stats: Any = _state(uds)["stats"]
        return list(stats["reasons"].get("malformed", []))

    def dropped(*reasons: str) -> bool:
        seen = malformed()
        return all(any(reason in r for r in seen) for reason in reasons)

    def tree_refused() -> bool:
        tree_of(uds, "hostile")  # read when asked for, as the page asks
        return dropped("tree of hostile: ")

    with alive(ns, monitor=monitor):
        event = {"v": 1, "n": 0, "peer": "hostile", "t": "2026-12-01T21:00:00+00:00",
                 "event": "refused", "reason": FAULT_MARKER, "tick": -1}  # fmt: skip
        probe.until({"op": "publish", "topic": "/hostile/ktbt/events", "type": "FleetEvent",
                     "fields": event, "subscribers": 1}, 60)  # fmt: skip
        probe.until({"op": "publish", "topic": "/hostile/ktbt/catalog", "type": "Catalog",
                     "raw": catalog_raw("hostile", LISTED), "latched": True,
                     "subscribers": 1}, 60)  # fmt: skip
        probe.until({"op": "publish", "topic": "/hostile/ktbt/tree", "type": "TreeSnapshot",
                     "fields": {"peer": "hostile", "changed": True, "number": 1,
                                "tree": UNREADABLE}, "latched": True,
                     "subscribers": 1}, 60)  # fmt: skip
        assert wait_until(lambda: dropped(INJECTED, "catalog of hostile: "), 60), malformed()
        assert wait_until(tree_refused, 60), malformed()
        reasons = malformed()
        assert INJECTED in reasons, reasons  # the event, its reason no more than the type
        assert any(r.startswith("catalog of hostile: ") and "SBT101" in r for r in reasons), reasons
        assert any(r.startswith("tree of hostile: ") and "SBT101" in r for r in reasons), reasons

    assert monitor.poll() is None, ns.log("monitor")[-3000:]

    ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/teacher",
            "-p", f"knowledge:={COLOURS}", name="teacher")  # fmt: skip
    item = sequence_digest(WANTED)

    def shown() -> bool:
        peers: Any = _state(uds)["peers"]
        return any(
            p["peer"] == "teacher" and p["status"] == "present" and p["knows"].get(item)
            == "known" for p in peers
        )  # fmt: skip

    assert wait_until(shown, 90), _state(uds)["peers"]
    state: Any = _state(uds)
    assert state["drops"]["malformed"] >= 3, state["drops"]
    assert monitor.poll() is None and "Traceback" not in ns.log("monitor")
