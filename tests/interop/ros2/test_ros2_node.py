"""Robots on ROS 2 (spec/protocol.md section 11): real ``ktbt ros2 run`` lifecycle nodes on
Fast DDS, each test's processes in a network namespace of their own (``rosns``), every wait a
graph or topic condition with a deadline."""

from __future__ import annotations

import signal
from pathlib import Path
from typing import Any

import pytest

from ktbt_proto.files import packaged
from tests.interop.ros2.rosns import SEQUENCE, SUBTREE, Probe, RosNamespace

pytestmark = [pytest.mark.network, pytest.mark.slow, pytest.mark.timeout(300)]

COLOURS = packaged("examples", "knowledge", "colours.sbt")
SKILL = "AssignCollectionPoint,colour=2"
WANTED = SEQUENCE
SKILL_TREE = SUBTREE


def lifecycle(ns: RosNamespace, node: str, transition: str) -> str:
    done = ns.run("ros2", "lifecycle", node, transition, "--timeout", "60", timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def params_file(tmp: Path) -> Path:
    path = tmp / "fleet.yaml"
    path.write_text(
        f"""\
/**:
  ros__parameters:
    queries_topic: /fleet_a/queries
    answers_topic: /fleet_a/answers
    errors_topic: /fleet_a/errors
    tick_rate: 50.0
    qos_overrides:
      /fleet_a/queries:
        publisher:
          reliability: best_effort
        subscription:
          reliability: best_effort
/teacher/ktbt:
  ros__parameters:
    knowledge: {COLOURS}
    sequences: ["TargetSeen(colour=1)"]
/learner/ktbt:
  ros__parameters:
    sequences: ["TargetSeen(colour=2)"]
    wait_ticks: 100
"""
    )
    return path


def test_a_robot_learns_a_skill_from_another_and_forgets_it_on_request(
    rosns: Any, tmp_path: Path
) -> None:
    ns: RosNamespace = rosns
    fleet = params_file(tmp_path)
    probe = Probe(ns)
    probe.subscribe("/learner/ktbt/tree", "TreeSnapshot", latched=True)
    probe.subscribe("/learner/ktbt/events", "FleetEvent")
    ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/teacher",
            "--params-file", str(fleet), name="teacher")  # fmt: skip
    ns.ktbt("ros2", "run", "--ros-args", "-r", "__ns:=/learner", "--params-file", str(fleet),
            name="learner")  # fmt: skip
    assert "configure done" in lifecycle(ns, "/learner/ktbt", "configure")
    probe.until({"op": "publishers", "topic": "/learner/ktbt/events", "count": 1})
    lifecycle(ns, "/learner/ktbt", "activate")
    assert lifecycle(ns, "/learner/ktbt", "get") == "active"

    # It learns the skill from the teacher: its latched tree holds it, its events the merge.
    snapshot = probe.wait("/learner/ktbt/tree", 90, tree=SKILL)
    assert snapshot["changed"] and snapshot["peer"] == "learner"
    merged = probe.wait("/learner/ktbt/events", 10, event="merged", teacher="teacher")
    assert merged["sequence"] == WANTED and merged["peer"] == "learner"
    assert "learned TargetSeen(colour=2) from teacher" in ns.log("learner")
    listed = ns.run("ros2", "list", "/learner/ktbt", "--until", "TargetSeen(colour=2)")
    assert (listed.returncode, listed.stdout) == (
        0,
        "/learner/ktbt: 1 skill\n  TargetSeen(colour=2)  (teacher teacher)\n",
    )

    # The YAML file's parameters applied: the fleet's topics and their QoS, the rates, what to
    # meet.
    values = probe.until(
        {"op": "params", "node": "/learner/ktbt",
         "names": ["queries_topic", "tick_rate", "wait_ticks", "sequences"]}
    )["values"]  # fmt: skip
    assert values == {
        "queries_topic": "/fleet_a/queries",
        "tick_rate": 50.0,
        "wait_ticks": 100,
        "sequences": ["TargetSeen(colour=2)"],
    }
    queries = probe.until({"op": "publishers", "topic": "/fleet_a/queries", "count": 2})
    assert queries["reliability"] == ["BEST_EFFORT", "BEST_EFFORT"]  # the QoS override applied
    answers = probe.until({"op": "publishers", "topic": "/fleet_a/answers", "count": 2})
    assert answers["reliability"] == ["RELIABLE", "RELIABLE"]
    probe.until({"op": "subscribers", "topic": "/fleet_a/queries", "count": 2})
    assert (
        probe.ask({"op": "subscribers", "topic": "/ktbt/queries", "count": 1}, 0.5)["ok"] is False
    )

    # What it knows, then forgetting it: the tree is taken again, changed, without the item.
    listed = probe.until({"op": "call", "service": "/learner/ktbt/list_knowledge",
                          "type": "ListKnowledge"})["response"]["items"]  # fmt: skip
    assert [(i["sequence"], i["teacher"]) for i in listed] == [(WANTED, "teacher")]
    shown = len(probe.messages("/learner/ktbt/tree"))
    forgot = probe.until({"op": "call", "service": "/learner/ktbt/forget", "type": "Forget",
                          "request": {"sequence": "TargetSeen(colour=2)"}})["response"]  # fmt: skip
    assert forgot == {"success": True, "code": 0, "message": ""}  # Forget.Response.FORGOTTEN
    after = probe.wait("/learner/ktbt/tree", 30, absent={"tree": SKILL}, skip=shown, changed=True)
    assert after["number"] > snapshot["number"]
    probe.wait("/learner/ktbt/events", 10, event="forgotten", sequence=WANTED, reason="asked")
    again = probe.until({"op": "call", "service": "/learner/ktbt/forget", "type": "Forget",
                         "request": {"sequence": "TargetSeen(colour=2)"}})["response"]  # fmt: skip
    assert again == {  # Forget.Response.NOT_KNOWN
        "success": False, "code": 1, "message": "TargetSeen(colour=2) is not known"
    }  # fmt: skip
    for typed, why in (
        ("TargetSeen(colour=", "sequence: 1:19: SBT104 missing ) to close the arguments"),
        ("x" * 4097, "sequence: 4097 characters, more than its bound (4096)"),
    ):
        invalid = probe.until({"op": "call", "service": "/learner/ktbt/forget", "type": "Forget",
                               "request": {"sequence": typed}})["response"]  # fmt: skip
        assert (invalid["success"], invalid["code"]) == (False, 3), invalid  # INVALID
        assert invalid["message"] == why, invalid  # one line

    # Reconfigured while it runs: what it meets and its rate apply at once; what is read at
    # configure, and a bad value, are refused with their reason.
    results = probe.until(
        {"op": "set_params", "node": "/learner/ktbt",
         "values": {"sequences": ["TargetSeen(colour=3)"], "tick_rate": 80.0}}
    )["results"]  # fmt: skip
    assert results == [[True, ""], [True, ""]]
    refused = probe.until(
        {"op": "set_params", "node": "/learner/ktbt",
         "values": {"wait_ticks": 10, "tick_rate": 0.0, "sequences": ["TargetSeen(colour="]}}
    )["results"]  # fmt: skip
    assert refused[0] == [False, "wait_ticks is read at configure: clean up first"]
    assert refused[1] == [False, "tick_rate 0.0: use a number of Hz in (0, 1000]"]
    assert refused[2][0] is False and refused[2][1].startswith(
        "sequences: 'TargetSeen(colour=': SBT"
    )
    probe.wait("/learner/ktbt/tree", 60, skip=shown, tree="AssignCollectionPoint,colour=3")
    forgot_3 = ns.run("ros2", "forget", "/learner/ktbt", "TargetSeen(colour=3)")
    assert (forgot_3.returncode, forgot_3.stdout) == (
        0,
        "/learner/ktbt: forgot TargetSeen(colour=3)\n",
    )
    unknown = ns.run("ros2", "forget", "/learner/ktbt", "TargetSeen(colour=3)")
    assert (unknown.returncode, unknown.stderr) == (
        1,
        "error: /learner/ktbt: TargetSeen(colour=3) is not known\n",
    )


def test_an_inactive_robot_does_not_answer_and_hostile_messages_are_refused(
    rosns: Any, tmp_path: Path
) -> None:
    ns: RosNamespace = rosns
    probe = Probe(ns)
    for topic in ("/teacher/ktbt/events", "/learner/ktbt/events"):
        probe.subscribe(topic, "FleetEvent")
    probe.subscribe("/ktbt/errors", "ErrorReply")
    ns.ktbt("ros2", "run", "--ros-args", "-r", "__ns:=/teacher", "-p", f"knowledge:={COLOURS}",
            name="teacher")  # fmt: skip
    ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/learner",
            "-p", "sequences:=[TargetSeen(colour=2)]", name="learner")  # fmt: skip
    lifecycle(ns, "/teacher/ktbt", "configure")
    assert lifecycle(ns, "/teacher/ktbt", "get") == "inactive"
    probe.until({"op": "publishers", "topic": "/teacher/ktbt/events", "count": 1})

    # The learner asks while the configured, inactive teacher reads the query topic: no answer.
    probe.until({"op": "subscribers", "topic": "/ktbt/queries", "count": 2})
    seen = len(probe.messages("/learner/ktbt/events"))
    for _ in range(2):  # two queries sent after the teacher was on the graph
        probe.wait("/learner/ktbt/events", 60, skip=seen, event="query-sent")
        seen = len(probe.messages("/learner/ktbt/events"))
    kinds = {e["event"] for e in probe.messages("/learner/ktbt/events")}
    assert "answer-received" not in kinds and "merged" not in kinds
    assert probe.messages("/teacher/ktbt/events") == []  # it heard nothing, answered nothing

    # Activated, it answers.
    lifecycle(ns, "/teacher/ktbt", "activate")
    probe.wait("/learner/ktbt/events", 90, event="merged", teacher="teacher")
    probe.wait("/teacher/ktbt/events", 10, event="answer-sent", to="learner")

    # Hostile messages on the query and answer topics: refused, counted, logged at WARNING.
    garbage = "00010000" + "ff" * 60  # a CDR header, then a string claiming 4 GB
    probe.until({"op": "publish", "topic": "/ktbt/queries", "type": "Query", "raw": garbage,
                 "subscribers": 2})  # fmt: skip
    v2 = {"v": 2, "id": "h1", "sender": "probe", "sequence": WANTED}
    probe.until({"op": "publish", "topic": "/ktbt/queries", "type": "Query", "subscribers": 2,
                 "fields": v2})  # fmt: skip
    probe.until({"op": "publish", "topic": "/ktbt/answers", "type": "Answer", "subscribers": 2,
                 "fields": {"v": 1, "id": "h2", "sender": "not a name!", "to": "teacher",
                            "sequence": WANTED, "subtree": "<a>(RandomWalk)"}})  # fmt: skip
    # A field beyond its type's bound (string<=4096 sequence): rclpy publishes it unchecked,
    # the robot refuses it as it reads the bytes, and still answers its sender.
    long = {"v": 1, "id": "h3", "sender": "bounder", "sequence": "x" * 4097}
    probe.until({"op": "publish", "topic": "/ktbt/queries", "type": "Query", "subscribers": 2,
                 "fields": long})  # fmt: skip
    refusals = []
    for reason in (
        "not a Query",
        "query.v: Input should be 1",
        "response.sender: String",
        "(sequence: 4097 characters, more than its bound (4096))",
    ):
        refusals.append(
            probe.wait(
                "/teacher/ktbt/events", 30, event="refused", where="transport", reason=reason
            )
        )
    assert len({r["n"] for r in refusals}) == 4
    # One reply, from the robot whose name comes first (section 11), not one per robot.
    error = probe.wait("/ktbt/errors", 30, to="probe", sender="learner", code="refused")
    assert error["id"] == "0" and error["message"] == "malformed query"
    error = probe.wait("/ktbt/errors", 30, to="bounder", sender="learner", code="refused")
    assert error["id"] == "0" and error["message"] == "malformed query"
    log = ns.log("teacher")
    assert log.count("[WARN]") >= 3 and "teacher refused: on /ktbt/queries" in log
    assert "Traceback" not in log
    # A robot whose files are wrong refuses to configure, with one line, and stays unconfigured.
    missing = tmp_path / "missing.sbt"
    vocabulary = packaged("examples", "sar_vocabulary.toml")
    ns.ktbt("ros2", "run", "--ros-args", "-r", "__ns:=/broken", "-p", f"control:={missing}",
            "-p", f"vocabulary:={vocabulary}", name="broken")  # fmt: skip
    refused = ns.run("ros2", "lifecycle", "/broken/ktbt", "configure", "--timeout", "60")
    assert (refused.returncode, refused.stderr) == (
        1,
        "error: /broken/ktbt refused configure (see its log)\n",
    )
    assert lifecycle(ns, "/broken/ktbt", "get") == "unconfigured"
    assert f"configure failed: control: cannot read {missing}: No such file or directory" in ns.log(
        "broken"
    )
    assert "Traceback" not in ns.log("broken")
    # And the teacher goes on: it still answers what it is asked.
    listed = probe.until({"op": "call", "service": "/teacher/ktbt/list_knowledge",
                          "type": "ListKnowledge"})["response"]["items"]  # fmt: skip
    assert len(listed) == 4


def test_hostile_answers_to_an_open_query_are_refused_and_the_signed_skill_learned(
    rosns: Any, tmp_path: Path
) -> None:
    """Signed knowledge over ROS (section 7): the learner under the `trusted` policy, its query
    open, is sent answers in the teacher's name: unsigned, with a signature that does not
    verify, signed by an author it does not trust, one over the size limit and bytes that are
    no Answer. Each is refused, counted and logged at WARNING with its reason, and its latched
    tree stays the one it showed; then it learns the teacher's signed item, the author's key
    with it."""
    from ktbt_proto.exchange.messages import Response
    from ktbt_proto.exchange.signing import Identity

    ns: RosNamespace = rosns
    key = tmp_path / "teacher.key"
    public = Identity.generate().save(key).read_text().strip()
    teacher_id, stranger = Identity.load(key), Identity.generate()
    trust = tmp_path / "trust"
    trust.write_text(f"{public}\n")
    probe = Probe(ns)
    probe.subscribe("/learner/ktbt/events", "FleetEvent")
    probe.subscribe("/learner/ktbt/tree", "TreeSnapshot", latched=True)
    ns.ktbt("ros2", "run", "--ros-args", "-r", "__ns:=/teacher", "-p", f"knowledge:={COLOURS}",
            "-p", f"key:={key}", name="teacher")  # fmt: skip
    learner = ns.ktbt(
        "ros2",
        "run",
        "--autostart",
        "--ros-args",
        "-r",
        "__ns:=/learner",
        "-p",
        "sequences:=[TargetSeen(colour=2)]",
        "-p",
        "policy:=trusted",
        "-p",
        f"trust:={trust}",
        "-p",
        "wait_ticks:=600",
        name="learner",
    )  # fmt: skip (a query open 6 s)
    lifecycle(ns, "/teacher/ktbt", "configure")  # present, not answering yet
    asked = probe.wait("/learner/ktbt/events", 60, event="query-sent")
    before = probe.wait("/learner/ktbt/tree", 30)
    answer = {"v": 1, "id": asked["id"], "sender": "teacher", "to": "learner",
              "sequence": WANTED, "subtree": SKILL_TREE}  # fmt: skip
    other = teacher_id.sign_item("<c>(TargetSeen,colour=3)", SKILL_TREE)
    item = stranger.sign_item(WANTED, SKILL_TREE)
    untrusted = stranger.sign_reply(
        Response(id=asked["id"], sender="teacher", sequence=WANTED, subtree=SKILL_TREE,
                 author=item.author, signature=item.signature)
    )  # fmt: skip
    hostile: list[tuple[dict[str, Any], str]] = [
        ({"fields": answer}, "from teacher: the item is not signed by its author"),
        (
            {"fields": answer | {"author": public, "signature": other.signature}},
            "from teacher: the author's signature does not match the item",
        ),
        (
            {
                "fields": answer
                | {k: untrusted.model_dump()[k] for k in ("author", "signature", "key", "hop")}
            },
            f"from teacher: author {stranger.public} is not in the trust store",
        ),
        (
            {"fields": answer | {"subtree": "<sq>" + "<a>(PickTreasure)" * 5000 + "<e>"}},
            "on /ktbt/answers: ",  # then its size: "N bytes, more than the limit"
        ),
        ({"raw": "00010000" + "ff" * 60}, "on /ktbt/answers: not a Answer"),
    ]
    refusals = []
    for message, reason in hostile:
        probe.until({"op": "publish", "topic": "/ktbt/answers", "type": "Answer",
                     "subscribers": 2, **message})  # fmt: skip
        refusals.append(
            probe.wait("/learner/ktbt/events", 30, event="refused", where="transport",
                       reason=reason)
        )  # fmt: skip
    assert refusals[3]["reason"].endswith("bytes, more than the limit")
    assert len({r["n"] for r in refusals}) == len(hostile)
    warned = [line for line in ns.log("learner").splitlines() if "[WARN]" in line]
    for refused in refusals:
        assert any(f"learner refused: {refused['reason']}" in line for line in warned), warned
    assert probe.messages("/learner/ktbt/tree") == [before]  # the tree as it was
    assert "merged" not in {e["event"] for e in probe.messages("/learner/ktbt/events")}

    lifecycle(ns, "/teacher/ktbt", "activate")
    merged = probe.wait("/learner/ktbt/events", 90, event="merged", teacher="teacher")
    assert merged["author"] == public and merged["sequence"] == WANTED
    probe.wait("/learner/ktbt/tree", 30, tree=SKILL, changed=True)
    learner.send_signal(signal.SIGTERM)  # stopped, it says what it refused
    assert learner.wait(timeout=30) == 0
    summary = [line for line in ns.log("learner").splitlines() if "queries sent" in line]
    assert "refused 5," in summary[-1], summary
    assert "Traceback" not in ns.log("learner")


def test_ctrl_c_takes_the_shutdown_transition_and_a_malformed_query_gets_no_reply_to_no_one(
    rosns: Any,
) -> None:
    """A robot ended by SIGINT goes through the lifecycle's shutdown transition (its summary
    logged, its files closed) and exits 0; a query whose sender cannot be read is refused
    and counted with no error reply, as no one could read it (section 11)."""
    from tests.interop.ros2.rosns import wait_for_line

    ns: RosNamespace = rosns
    probe = Probe(ns)
    probe.subscribe("/ktbt/errors", "ErrorReply")
    robot = ns.ktbt("ros2", "run", "--autostart", "--ros-args", "-r", "__ns:=/r1", name="r1")
    wait_for_line(ns, "r1", "r1: active", 60)
    garbage = "00" * 12  # not a Query: no sender to be read from it
    probe.until({"op": "publish", "topic": "/ktbt/queries", "type": "Query", "raw": garbage})
    wait_for_line(ns, "r1", "r1 refused: on /ktbt/queries", 60)
    robot.send_signal(signal.SIGINT)
    assert robot.wait(timeout=60) == 0, ns.log("r1")
    log = ns.log("r1")
    assert "shutting down from active" in log and "r1: queries sent" in log
    assert probe.messages("/ktbt/errors") == []
