"""The zenoh <-> ROS 2 bridge (spec/protocol.md section 11, "Bridge"), with real processes in
one network namespace: a zenoh teacher teaches a ROS learner, and a ROS teacher a zenoh
learner, each learner under the ``trusted`` policy, so the item it takes carries its author's
signature across the bridge; hostile input from each side is refused and counted, and the
bridge goes on. One set of processes serves the module; each test passes alone and in any
order (one that stops the bridge leaves it to :func:`fleets` to start again)."""

from __future__ import annotations

import json
import re
import signal
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from ktbt_proto.exchange.knowledge import KnowledgeBase
from ktbt_proto.exchange.signing import Identity, item_bytes, verify
from tests.interop.ros2.rosns import Probe, RosNamespace
from tests.zenoh_helpers import endpoint, free_port, wait_until


def processes(test: Any) -> Any:
    """The marks of a test of real processes."""
    for mark in (pytest.mark.network, pytest.mark.slow, pytest.mark.timeout(300)):
        test = mark(test)
    return test


GREEN, YELLOW = "TargetSeen(colour=2)", "TargetSeen(colour=3)"
GREEN_KEY, YELLOW_KEY = "<c>(TargetSeen,colour=2)", "<c>(TargetSeen,colour=3)"
YELLOW_SUBTREE = "<sq><a>(PickTreasure)<a>(AssignCollectionPoint,colour=3)<e>"


def knowledge(path: Path, colour: int) -> Path:
    path.write_text(
        f"<k>(prior)<sq><c>(TargetSeen, colour={colour})<a>(PickTreasure)"
        f"<a>(AssignCollectionPoint, colour={colour})<e><e>\n"
    )
    return path


@dataclass
class Fleets:
    ns: RosNamespace
    probe: Probe
    tmp: Path
    teacher_port: int
    zenoh_author: str
    ros_author: str
    bridge: Any
    zenoh_learner: Any


@pytest.fixture(scope="module")
def started(ros2_built: None, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Fleets]:
    tmp = tmp_path_factory.mktemp("bridge")
    ns = RosNamespace(tmp)
    try:
        zt, rt = Identity.generate(), Identity.generate()
        zt.save(tmp / "zt.key")
        rt.save(tmp / "rt.key")
        trust = tmp / "trust.txt"
        trust.write_text(f"{zt.public}\n{rt.public}\n")
        pt, pl = free_port(), free_port()
        probe = Probe(ns)
        # zenoh: a teacher that knows green, signed
        ns.ktbt("peer", "run", "--id", "zt", "--listen", endpoint(pt), "--key",
                str(tmp / "zt.key"), "--knowledge", str(knowledge(tmp / "green.sbt", 2)),
                "--sequence", GREEN, "--duration", "250", name="zt")  # fmt: skip
        # ROS: a teacher that knows yellow, signed; a learner of green under `trusted`
        ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/rt",
                "-p", f"knowledge:={knowledge(tmp / 'yellow.sbt', 3)}",
                "-p", f"key:={tmp / 'rt.key'}", "-p", f"sequences:=[{YELLOW}]",
                name="rt")  # fmt: skip
        ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/rl",
                "-p", f"sequences:=[{GREEN}]", "-p", "policy:=trusted",
                "-p", f"trust:={trust}", name="rl")  # fmt: skip
        bridge = start_bridge(ns, pt)
        # zenoh: a learner of yellow under `trusted`, which ends once it knows it
        learner = ns.ktbt("peer", "run", "--id", "zl", "--listen", endpoint(pl), "--connect",
                          endpoint(pt), "--sequence", YELLOW, "--policy", "trusted",
                          "--trust", str(trust), "--save", str(tmp / "zl.json"),
                          "--exit-when-done", "--duration", "200", name="zl")  # fmt: skip
        yield Fleets(ns, probe, tmp, pt, zt.public, rt.public, bridge, learner)
    finally:
        ns.close()


def start_bridge(ns: RosNamespace, teacher_port: int) -> Any:
    return ns.ktbt("ros2", "bridge", "--connect", endpoint(teacher_port), name="bridge")


@pytest.fixture
def fleets(started: Fleets) -> Fleets:
    """The module's fleets with their bridge running (a test before may have stopped it)."""
    if started.bridge.poll() is not None:
        started.bridge = start_bridge(started.ns, started.teacher_port)
    return started


def learned(fleets: Fleets) -> str:
    """What the ROS learner knows once it knows green (its ~/list_knowledge service)."""
    done = fleets.ns.run("ros2", "list", "/rl/ktbt", "--until", GREEN, "--timeout", "150",
                         timeout=200)  # fmt: skip
    assert done.returncode == 0, done.stderr + fleets.ns.log("bridge")
    return done.stdout


@pytest.mark.parametrize(
    ("args", "said"),
    [
        ([], "error: --connect: required: the zenoh fleet to bridge (--connect ENDPOINT)"),
        (["--connect", "tcp/127.0.0.1:7447", "--answers-topic", "/ktbt/queries"],
         "error: --queries-topic: the three topics must differ"),
        (["--connect", "tcp/127.0.0.1:7447", "--query-timeout", "0"],
         "error: --query-timeout: 0: use (0, 60] seconds"),
        (["--connect", "tcp/127.0.0.1:7447", "--max-robots", "0"],
         "error: --max-robots: 0: use 1 to 1024"),
        (["--connect", "tcp/127.0.0.1:7447", "--node-name", "a/b"],
         "error: --node-name: 'a/b': use letters, digits and '_' (a ROS node name)"),
        (["--connect", "tcp/127.0.0.1:7447", "--max-per-source", "0"],
         "error: --max-per-source: 0: use 1 to 1024"),
        (["--connect", "tcp/127.0.0.1:7447", "--policy", "trusted"],
         "error: --policy: trusted needs --trust FILE"),
        (["--connect", "tcp/127.0.0.1:7447", "--policy", "signed"],
         "error: --policy: signed: a bridge takes any, or trusted with --trust FILE"),
        (["--connect", "tcp/127.0.0.1:7447", "--policy", "trusted", "--trust", "/no/such.txt"],
         "error: --trust: cannot read trust store /no/such.txt: No such file or directory"),
        (["--connect", "tcp/127.0.0.1:7447", "--bogus"], "error: --bogus: no such option"),
        (["--connect", "tcp/127.0.0.1:7447", "extra"],
         "error: 'extra': unexpected; ROS arguments come after --ros-args"),
    ],
)  # fmt: skip
def test_a_bad_option_is_one_line_and_exit_2(args: list[str], said: str) -> None:
    from typer.testing import CliRunner

    from ktbt_proto.tools.cli.root import app, load_plugins

    load_plugins()
    done = CliRunner().invoke(app, ["ros2", "bridge", *args])
    assert (done.exit_code, done.stderr) == (2, said + "\n")


@processes
def test_a_zenoh_teacher_teaches_a_ros_learner_through_the_bridge(fleets: Fleets) -> None:
    # zt's own signature, believed under trusted: the author is zt's key
    assert learned(fleets) == (
        f"/rl/ktbt: 1 skill\n  {GREEN}  (author {fleets.zenoh_author}, teacher zt)\n"
    )
    assert "rl: learned TargetSeen(colour=2) from zt" in fleets.ns.log("rl")


@processes
def test_a_ros_teacher_teaches_a_zenoh_learner_through_the_bridge(fleets: Fleets) -> None:
    assert fleets.zenoh_learner.wait(timeout=200) == 0, fleets.ns.log("zl")
    assert f"zl: learned {YELLOW} from rt" in fleets.ns.log("zl")
    (item,) = KnowledgeBase.load(fleets.tmp / "zl.json")
    assert (item.key, item.source, item.author) == (YELLOW_KEY, "rt", fleets.ros_author)
    assert item.signature is not None
    assert verify(fleets.ros_author, item.signature, item_bytes(YELLOW_KEY, YELLOW_SUBTREE))


HOSTILE_ZENOH = """
import json, sys, time, zenoh
conf = zenoh.Config()
conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
conf.insert_json5("scouting/multicast/enabled", "false")
v2 = {"v": 2, "type": "query", "id": "h", "sender": "h", "sequence": "<c>(A)"}
payloads = [b"not json", json.dumps(v2).encode()]
deadline = time.monotonic() + 60
with zenoh.open(conf) as session:
    while payloads and time.monotonic() < deadline:  # until gossip links it to rt's mirror
        for reply in session.get("ktbt/v1/knowledge/rt", payload=payloads[0], timeout=2):
            said = reply.err.payload.to_bytes() if reply.ok is None else b"an answer"
            print(said.decode(errors="replace"), flush=True)
            payloads.pop(0)
            break
"""


FORGER = """
import json, sys, threading, zenoh
conf = zenoh.Config()
conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
conf.insert_json5("listen/endpoints", json.dumps(["tcp/127.0.0.1:0"]))
conf.insert_json5("scouting/multicast/enabled", "false")
forged = json.loads(sys.argv[2])

def answer(query):
    asked = json.loads(query.payload.to_bytes())
    reply = {**forged, "id": asked["id"], "sequence": asked["sequence"]}
    query.reply("ktbt/v1/knowledge/evil", json.dumps(reply).encode())
    print("answered", asked["id"], flush=True)

with zenoh.open(conf) as session:
    token = session.liveliness().declare_token("ktbt/v1/peers/evil")
    queryable = session.declare_queryable("ktbt/v1/knowledge/evil", answer)
    print("up", flush=True)
    threading.Event().wait()  # until the namespace ends it
"""


@processes
def test_a_forgery_is_never_carried_across(fleets: Fleets) -> None:
    """A zenoh peer answers a ROS robot's query with an item whose author's signature is of
    another subtree: the bridge refuses it, and nothing reaches the ROS answer topic."""
    ns, probe = fleets.ns, fleets.probe
    learned(fleets)
    evil = Identity.generate()
    blue = "<c>(TargetSeen,colour=4)"
    other = evil.sign(item_bytes(blue, "<a>(Other)"))  # a signature of another subtree
    forged = {"v": 1, "type": "response", "id": "x", "sender": "evil", "sequence": blue,
              "subtree": "<sq><a>(PickTreasure)<a>(AssignCollectionPoint,colour=4)<e>",
              "author": evil.public, "signature": other}  # fmt: skip
    script = fleets.tmp / "forger.py"
    script.write_text(FORGER)
    ns.start([sys.executable, str(script), endpoint(fleets.teacher_port), json.dumps(forged)],
             "forger")  # fmt: skip
    assert wait_until(lambda: "zenoh peer evil is on ROS" in ns.log("bridge"), 60)
    probe.subscribe("/ktbt/answers", "Answer")
    asked = {"v": 1, "id": "forged-1", "sender": "asker", "sequence": blue}
    refused = "an answer on zenoh from evil: the author's signature does not match the item"
    for n in range(30):  # until gossip links the asker's new mirror to the forger
        asked["id"] = f"forged-{n}"
        probe.until({"op": "publish", "topic": "/ktbt/queries", "type": "Query",
                     "fields": asked, "subscribers": 3})  # fmt: skip
        if wait_until(lambda: refused in ns.log("bridge"), 2):
            break
    assert refused in ns.log("bridge"), ns.log("forger") + ns.log("bridge")
    assert [m for m in probe.messages("/ktbt/answers") if m["sender"] == "evil"] == []


THIEF = """
import json, sys, time, zenoh
conf = zenoh.Config()
conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
conf.insert_json5("scouting/multicast/enabled", "false")
deadline = time.monotonic() + 60
with zenoh.open(conf) as session:
    n = 0
    while time.monotonic() < deadline:  # until gossip links it to rt's mirror
        n += 1
        asked = {"v": 1, "type": "query", "id": f"dup-{n}", "sequence": sys.argv[2]}
        gets = {  # the asker's query, then at once the thief's: its id, in the thief's name
            who: session.get("ktbt/v1/knowledge/rt", timeout=5,
                             payload=json.dumps({**asked, "sender": who}).encode())
            for who in ("honest", "thief")
        }
        got = {who: [json.loads(r.ok.payload.to_bytes()) for r in replies if r.ok is not None]
               for who, replies in gets.items()}
        if any(got.values()):
            print(json.dumps(got), flush=True)
            break
        time.sleep(0.2)
"""


@processes
def test_a_zenoh_peer_repeating_an_askers_id_does_not_take_its_answer(fleets: Fleets) -> None:
    """Two zenoh queries with one id, the asker's and a thief's in its own name, both relayed
    to ROS before the ROS teacher answers: each answer goes back to the asker it is addressed
    to, so the asker gets the teacher's answer, and the thief only its own."""
    ns = fleets.ns
    learned(fleets)  # everything is up
    script = fleets.tmp / "thief.py"
    script.write_text(THIEF)
    ns.start([sys.executable, str(script), endpoint(fleets.teacher_port), YELLOW_KEY], "thief")
    thief = ns.processes[-1]
    assert thief.wait(timeout=90) == 0, ns.log("thief")
    got = json.loads(ns.log("thief").splitlines()[-1])
    (answer,) = got["honest"]
    assert (answer["sender"], answer["sequence"]) == ("rt", YELLOW_KEY), got
    assert answer["id"].startswith("dup-") and answer["subtree"] == YELLOW_SUBTREE, got
    assert [a["id"] for a in got["thief"]] in ([], [answer["id"]]), got  # its own, if any


@processes
def test_hostile_input_from_either_side_is_refused_and_counted(fleets: Fleets) -> None:
    from ktbt_interfaces.msg import Catalog, CatalogEntry
    from rclpy.serialization import serialize_message

    ns, probe = fleets.ns, fleets.probe
    learned(fleets)  # everything is up, and the learners learn (counted below)
    assert fleets.zenoh_learner.wait(timeout=200) == 0, ns.log("zl")
    # ROS: bytes that are no Query, a query of another version, a catalog naming no robot, and
    # one larger than 1 MiB serialized (refused unread).
    garbage = "00010000" + "ff" * 60  # a CDR header, then a string claiming 4 GB
    probe.until({"op": "publish", "topic": "/ktbt/queries", "type": "Query", "raw": garbage,
                 "subscribers": 3})  # fmt: skip
    probe.subscribe("/ktbt/queries", "Query")  # one of the fleet: its catalogs are read
    v2 = {"v": 2, "id": "h1", "sender": "probe", "sequence": GREEN_KEY}
    probe.until({"op": "publish", "topic": "/ktbt/queries", "type": "Query", "subscribers": 3,
                 "fields": v2})  # fmt: skip
    probe.until({"op": "publish", "topic": "/evil/catalog", "type": "Catalog",
                 "fields": {"peer": "not a name!"}, "subscribers": 1,
                 "latched": True})  # fmt: skip
    big = Catalog(peer="big", items=[CatalogEntry(sequence="<c>(A)" + " " * 1100)] * 1024)
    probe.until({"op": "publish", "topic": "/big/catalog", "type": "Catalog", "subscribers": 1,
                 "latched": True, "raw": serialize_message(big).hex()})  # fmt: skip
    assert wait_until(lambda: "catalog on /big/catalog" in ns.log("bridge"), 30)
    # zenoh: a query that is not JSON and one of another version, to the ROS teacher's mirror.
    script = fleets.tmp / "hostile.py"
    script.write_text(HOSTILE_ZENOH)
    ns.start([sys.executable, str(script), endpoint(fleets.teacher_port)], "hostile")
    hostile = ns.processes[-1]
    assert hostile.wait(timeout=60) == 0, ns.log("hostile")
    said = ns.log("hostile")
    assert said.count('"code":"refused"') == 2, said
    # The bridge refused each, logged it, and goes on; stopped, it says how many it refused.
    fleets.bridge.send_signal(signal.SIGTERM)
    assert fleets.bridge.wait(timeout=30) == 0
    log = ns.log("bridge")
    assert "Traceback" not in log
    assert "on /ktbt/queries: not a Query" in log and "query.v: Input should be 1" in log
    assert "a catalog on /evil/catalog names no robot" in log
    assert "refused: catalog on /big/catalog: 11" in log and "more than 1048576" in log
    assert log.count("rt refused: a query:") == 2
    summary = [line for line in log.splitlines() if "relayed queries" in line][-1]
    counted = re.search(r"answers (\d+) to ROS, (\d+) to zenoh; refused (\d+);", summary)
    assert counted is not None, summary
    to_ros, to_zenoh, refused = map(int, counted.groups())
    assert refused >= 6, summary  # 2 from ROS's topics, 2 catalogs, 2 from zenoh (and others')
    assert to_ros >= 1 and to_zenoh >= 1, summary  # what the learners learned, at least


OUTSIDER = """
import pathlib, sys, rclpy
from ktbt_interfaces.msg import Catalog, Query
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
rclpy.init()
node = rclpy.create_node("outsider")
latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
node.create_publisher(Catalog, "/outsider/catalog", latched).publish(Catalog(peer="outsider"))
node.create_subscription(Query, "/other/queries", lambda m: None, 10)  # another fleet's
go = pathlib.Path(sys.argv[1])
while not go.exists():  # until the test lets it join the bridge's fleet
    rclpy.spin_once(node, timeout_sec=0.05)
node.create_subscription(Query, "/ktbt/queries", lambda m: None, 10)
print("joined", flush=True)
while True:
    rclpy.spin_once(node, timeout_sec=0.5)
"""


@processes
def test_the_bridge_reads_its_own_fleet_and_logs_to_rosout(fleets: Fleets) -> None:
    """A catalog published by a node of another fleet (one reading other topics) is not
    mirrored; once that node reads the bridge's query topic, it is. The bridge says so through
    its node's logger: the lines reach /rosout."""
    ns, probe = fleets.ns, fleets.probe
    learned(fleets)  # everything is up
    probe.subscribe("/rosout", "rcl_interfaces/msg/Log")
    probe.subscribe("/ktbt/queries", "Query")  # the probe is one of the bridge's fleet
    script, go = fleets.tmp / "outsider.py", fleets.tmp / "outsider.go"
    script.write_text(OUTSIDER)
    ns.start([sys.executable, str(script), str(go)], "outsider")
    probe.until({"op": "publishers", "topic": "/outsider/catalog", "count": 1, "named": True})
    probe.until({"op": "publish", "topic": "/mate/catalog", "type": "Catalog",
                 "fields": {"peer": "mate"}, "subscribers": 1, "latched": True})  # fmt: skip
    line = probe.wait("/rosout", name="ktbt_bridge", msg="ROS robot mate is on zenoh", timeout=60)
    assert line["level"] == 20  # INFO, from the bridge's node
    assert "outsider" not in ns.log("bridge")
    go.touch()
    probe.wait("/rosout", name="ktbt_bridge", msg="ROS robot outsider is on zenoh", timeout=60)


INVENTOR = """
import sys, rclpy
from ktbt_interfaces.msg import Answer, Catalog, CatalogEntry, FleetEvent, Query
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from ktbt_proto.exchange.events import EventPublisher
from ktbt_proto.exchange.signing import Identity
from ktbt_proto.interop.ros2.showing import event_msg

rclpy.init()
node = rclpy.create_node("inventor")
latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
reliable = QoSProfile(depth=64, reliability=ReliabilityPolicy.RELIABLE)
answers = node.create_publisher(Answer, "/ktbt/answers", reliable)


def answer(query):  # every real asker answered in the claimed name, unsigned
    if not query.sender.startswith("asker"):
        answers.publish(Answer(v=1, id=query.id, sender=sys.argv[1], sequence=query.sequence,
                               subtree="<sq><a>(PickTreasure)<e>", to=query.sender))


node.create_subscription(Query, "/ktbt/queries", answer, reliable)  # one of the fleet
green = [CatalogEntry(sequence="<c>(TargetSeen,colour=2)")]
for i in range(64):  # 64 invented robots, each with a catalog
    pub = node.create_publisher(Catalog, f"/fake{i}/catalog", latched)
    pub.publish(Catalog(peer=f"fake{i}", items=green))
queries = node.create_publisher(Query, "/ktbt/queries", reliable)
events = node.create_publisher(FleetEvent, "/fake0/events", reliable)
signed = []  # an event signed by a key of no trust store, claiming a trusted robot's name
EventPublisher(sys.argv[1], signed.append, Identity.generate())(
    {"t": "2026-12-06T21:00:00.000+00:00", "event": "session-up"})
n = 0

def flood():  # 100 queries a second, in 64 invented names, and two events
    global n
    n += 1
    queries.publish(Query(v=1, id=f"q{n}", sender=f"asker{n % 64}",
                          sequence="<c>(TargetSeen,colour=2)"))
    events.publish(event_msg(signed[0]))
    events.publish(FleetEvent(v=1, peer="fake0", event="session-up", t="x", key="k", sig="s"))

node.create_timer(0.01, flood)
print("up", flush=True)
rclpy.spin(node)  # until the namespace ends it
"""


def inventor(ns: RosNamespace, tmp: Path, claims: str) -> None:
    """A hostile rclpy process: 64 invented robots' catalogs, queries in 64 invented names,
    events claiming ``claims`` signed by a key of its own, or not signed right, and an
    unsigned answer in the name ``claims`` to every query of a real asker."""
    script = tmp / "inventor.py"
    script.write_text(INVENTOR)
    ns.start([sys.executable, str(script), claims], "inventor")
    wait_until(lambda: "up" in ns.log("inventor").splitlines(), 60)
    assert "up" in ns.log("inventor").splitlines(), ns.log("inventor")


def present(ns: RosNamespace, port: int, *names: str) -> str:
    """Who is present on the zenoh fleet at ``port`` (``ktbt peer list``), asked again until
    ``names`` are there (zenoh's gossip links the lister to each mirror in its time)."""
    shown = ""

    def listed() -> bool:
        nonlocal shown
        done = ns.run("peer", "list", "--connect", endpoint(port), "--timeout", "3", timeout=60)
        assert done.returncode == 0, done.stderr
        shown = done.stdout
        return set(names) <= set(re.findall(r"^(\S+):", shown, re.MULTILINE))

    assert wait_until(listed, 90), shown
    return shown


@processes
def test_one_source_inventing_names_leaves_room_for_an_honest_robot(
    rosns: RosNamespace, tmp_path: Path
) -> None:
    """Under ``any``, one process inventing 64 robots (catalogs, and queries in 64 names) takes
    its share of the bridge's places and no more: an honest robot that comes later is
    mirrored, and zenoh sees it."""
    ns, port = rosns, free_port()
    inventor(ns, tmp_path, "nobody")
    bridge = ns.ktbt("ros2", "bridge", "--listen", endpoint(port), "--max-robots", "6",
                     "--max-per-source", "2", name="bridge")  # fmt: skip
    assert wait_until(lambda: "the query topic named 2 robots already" in ns.log("bridge"), 90)
    # of its 64 catalogs, 2 are read
    assert wait_until(lambda: "publishes 2 followed already" in ns.log("bridge"), 60)
    ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/honest",
            "-p", f"knowledge:={knowledge(tmp_path / 'yellow.sbt', 3)}",
            "-p", f"sequences:=[{YELLOW}]", name="honest")  # fmt: skip
    assert wait_until(lambda: "ROS robot honest is on zenoh" in ns.log("bridge"), 120), ns.log(
        "bridge"
    )
    shown = present(ns, port, "honest")
    assert sum(f"fake{i}:" in shown for i in range(64)) <= 2, shown
    bridge.send_signal(signal.SIGTERM)
    assert bridge.wait(timeout=30) == 0
    assert "Traceback" not in ns.log("bridge")
    assert "policy any: every participant of ROS domain" in ns.log("bridge")


@processes
def test_under_trusted_only_proven_names_cross(rosns: RosNamespace, tmp_path: Path) -> None:
    """A bridge on ``trusted`` mirrors a ROS robot once an event or answer of it is signed by
    the key its trust store gives the name: a ROS teacher teaches a zenoh learner, and a ROS
    learner that knows nothing (proven by the events of its queries) learns from a zenoh
    teacher; a process inventing 64 robots, an event claiming the teacher's name with another
    key, and answers in the teacher's name not signed by its key, get nothing across. At
    ``--log-level warn`` the bridge's INFO lines are not logged, its refusals are."""
    ns, tmp = rosns, tmp_path
    keys = tmp / "keys"
    made = ns.run("peer", "keys", str(keys), "zt", "rt", "rl")
    assert made.returncode == 0, made.stderr
    trust = keys / "trust.txt"
    pt, pl = free_port(), free_port()
    inventor(ns, tmp, "rt")
    ns.ktbt("peer", "run", "--id", "zt", "--listen", endpoint(pt), "--key", str(keys / "zt.key"),
            "--knowledge", str(knowledge(tmp / "green.sbt", 2)), "--sequence", GREEN,
            "--duration", "250", name="zt")  # fmt: skip
    ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/rt",
            "-p", f"knowledge:={knowledge(tmp / 'yellow.sbt', 3)}",
            "-p", f"key:={keys / 'rt.key'}", "-p", f"sequences:=[{YELLOW}]",
            name="rt")  # fmt: skip
    ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/rl",
            "-p", f"sequences:=[{GREEN}]", "-p", "policy:=trusted", "-p", f"trust:={trust}",
            "-p", f"key:={keys / 'rl.key'}", name="rl")  # fmt: skip
    bridge = ns.ktbt("ros2", "bridge", "--connect", endpoint(pt), "--policy", "trusted",
                     "--trust", str(trust), "--max-robots", "4", "--max-per-source", "2",
                     "--ros-args", "--log-level", "warn", name="bridge")  # fmt: skip
    zl = ns.ktbt("peer", "run", "--id", "zl", "--listen", endpoint(pl), "--connect",
                 endpoint(pt), "--sequence", YELLOW, "--policy", "trusted", "--trust",
                 str(trust), "--exit-when-done", "--duration", "200", name="zl")  # fmt: skip
    assert zl.wait(timeout=220) == 0, ns.log("zl") + ns.log("bridge")
    assert f"zl: learned {YELLOW} from rt" in ns.log("zl")
    done = ns.run("ros2", "list", "/rl/ktbt", "--until", GREEN, "--timeout", "150", timeout=200)
    assert done.returncode == 0, done.stderr + ns.log("bridge")
    shown = present(ns, pt, "rt", "rl")
    assert not any(f"fake{i}" in shown or f"asker{i}" in shown for i in range(64)), shown
    bridge.send_signal(signal.SIGTERM)
    assert bridge.wait(timeout=30) == 0
    log = ns.log("bridge")
    assert "Traceback" not in log
    assert "a ROS robot named fake" in log and "its name is not proven" in log
    assert "an event on /fake0/events: " in log  # the one not signed right
    assert "an answer on ROS from rt: the reply is not signed by the key" in log
    assert "is on zenoh" not in log and "proved its name" not in log  # INFO: below warn
    assert "policy any" not in log
