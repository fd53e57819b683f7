"""The tests' ROS participant (run by ``rosns.Probe`` inside a test's network namespace): one
JSON request a line on stdin, one JSON answer a line on stdout. Everything waited on has the
request's deadline (``timeout``) and is polled on observable conditions, never slept for.

Requests (``op``): ``ping``; ``sub`` (topic, type: ``Query`` or ``rcl_interfaces/msg/Log``,
latched); ``wait`` (topic, match): the first
message received on the topic (past the first ``skip``) whose fields match (and hold none of
``absent``); ``messages`` (topic); ``publishers`` and ``subscribers`` (topic, count): wait
until the topic has that many (``named``: and each one's node is known), with the publishers'
nodes, types, reliability and durability; ``graph`` (topics, services: names; ``absent``: true
to wait until none is there): the graph API's topic and service names with their types, once
all of them are there; ``publish`` (topic, type, fields or ``raw`` hex bytes,
subscribers: wait for that many first; ``latched``: its publisher latched; answered with the
simulated time, ``sim``); ``call`` (service,
type, request); ``params`` (node, names): a node's parameter values; ``set_params`` (node,
values): set them, each one's result; ``clock`` (start, speed): publish ``/clock`` from
``start`` seconds at ``speed`` times real time (a step of 0.1 simulated seconds at a time),
from then on; ``matched`` (topic, count): wait until the probe's publisher on the topic has
that many subscriptions, and the simulated time then (``sim``).

:func:`echo` renders received messages as ``ros2 topic echo`` prints them (YAML, ``---`` after
each), for the tutorial's captured output: the ``ros2`` command line has no wheel.
"""

from __future__ import annotations

import importlib
import json
import sys
import threading
import time
from typing import Any

import rclpy
from ktbt_interfaces import msg as ktbt_msg
from ktbt_interfaces import srv as ktbt_srv
from lifecycle_msgs.srv import GetState
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import try_shutdown

SERVICES: dict[str, Any] = {
    "Forget": ktbt_srv.Forget,
    "ListKnowledge": ktbt_srv.ListKnowledge,
    "GetParameters": GetParameters,
    "GetState": GetState,
}


def plain(value: Any) -> Any:
    """A ROS message as JSON-ready values."""
    if hasattr(value, "get_fields_and_field_types"):
        return {name: plain(getattr(value, name)) for name in value.get_fields_and_field_types()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    if isinstance(value, bytes | bytearray):
        return value.hex()
    return value


def echo(messages: list[dict[str, Any]]) -> str:
    """Messages as ``ros2 topic echo`` prints them: each as block YAML in field order (what
    ros2cli's ``message_to_yaml`` does), then ``---``."""
    import yaml  # type: ignore[import-untyped]

    return "".join(
        yaml.safe_dump(m, sort_keys=False, default_flow_style=False, allow_unicode=True,
                       width=10_000) + "---\n"
        for m in messages
    )  # fmt: skip


def message_type(name: str) -> Any:
    """A ``ktbt_interfaces`` message type by its name (``Query``), or any other by its full
    name (``rcl_interfaces/msg/Log``, what ``/rosout`` carries)."""
    if "/" not in name:
        return getattr(ktbt_msg, name)
    package, kind, type_name = name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), type_name)


def matches(message: dict[str, Any], match: dict[str, Any]) -> bool:
    for key, want in match.items():
        got = message.get(key)
        if isinstance(want, str) and isinstance(got, str):
            if want not in got:
                return False
        elif got != want:
            return False
    return True


class ProbeNode:
    def __init__(self) -> None:
        self.node = rclpy.create_node("ktbt_probe")
        self.lock = threading.Lock()
        self.received: dict[str, list[dict[str, Any]]] = {}
        self.subs: dict[str, Any] = {}
        self.pubs: dict[str, Any] = {}
        self.sim = 0.0
        """The simulated time last published on ``/clock`` (op ``clock``)."""

    def qos(self, latched: bool) -> QoSProfile:
        return QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=1 if latched else 100,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
        )

    def handle(self, req: dict[str, Any]) -> dict[str, Any]:
        op, timeout = req["op"], float(req.get("timeout", 30))
        deadline = time.monotonic() + timeout
        if op == "ping":
            return {"ok": True}
        if op == "sub":
            topic = req["topic"]
            self.received.setdefault(topic, [])

            def keep(message: Any, topic: str = topic) -> None:
                with self.lock:
                    self.received[topic].append(plain(message))

            self.subs[topic] = self.node.create_subscription(
                message_type(req["type"]), topic, keep, self.qos(bool(req.get("latched")))
            )
            return {"ok": True}
        if op in ("wait", "messages"):
            topic = req["topic"]
            while True:
                with self.lock:
                    seen = list(self.received.get(topic, []))
                if op == "messages":
                    return {"ok": True, "messages": seen}
                for message in seen[int(req.get("skip", 0)) :]:
                    absent = req.get("absent", {})
                    if matches(message, req["match"]) and not any(
                        str(v) in str(message.get(k)) for k, v in absent.items()
                    ):
                        return {"ok": True, "msg": message}
                if time.monotonic() > deadline:
                    return {"ok": False, "error": "timeout", "last": seen[-5:]}
                time.sleep(0.02)
        if op == "publishers":  # with each one's node, type and QoS
            named = bool(req.get("named"))  # and each one's node known (discovered later)
            while len(infos := self.node.get_publishers_info_by_topic(req["topic"])) < req[
                "count"
            ] or (named and any(i.node_name == "_NODE_NAME_UNKNOWN_" for i in infos)):
                if time.monotonic() > deadline:
                    return {"ok": False, "error": "timeout"}
                time.sleep(0.02)
            return {
                "ok": True,
                "reliability": [i.qos_profile.reliability.name for i in infos],
                "durability": [i.qos_profile.durability.name for i in infos],
                "nodes": [f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos],
                "types": [i.topic_type for i in infos],
            }
        if op == "graph":  # what a third node sees through the graph API
            want = set(req.get("topics", [])) | set(req.get("services", []))
            while True:
                topics = dict(self.node.get_topic_names_and_types())
                services = dict(self.node.get_service_names_and_types())
                there = want & (topics.keys() | services.keys())
                if (not there) if req.get("absent") else there == want:
                    return {"ok": True, "topics": topics, "services": services}
                if time.monotonic() > deadline:
                    return {"ok": False, "error": "timeout", "missing": sorted(want - there)}
                time.sleep(0.05)
        if op == "subscribers":  # wait until the topic has that many subscriptions
            while len(self.node.get_subscriptions_info_by_topic(req["topic"])) < req["count"]:
                if time.monotonic() > deadline:
                    return {"ok": False, "error": "timeout"}
                time.sleep(0.02)
            return {"ok": True}
        if op == "clock":
            threading.Thread(
                target=self.clock, args=(float(req["start"]), float(req["speed"])), daemon=True
            ).start()
            return {"ok": True}
        if op == "matched":
            pub = self.pubs[req["topic"]]
            while pub.get_subscription_count() < req["count"]:
                if time.monotonic() > deadline:
                    return {"ok": False, "error": "timeout"}
                time.sleep(0.005)
            return {"ok": True, "sim": self.sim}
        if op == "publish":
            topic = req["topic"]
            msg_type = getattr(ktbt_msg, req["type"])
            pub = self.pubs.get(topic)
            if pub is None:
                pub = self.pubs[topic] = self.node.create_publisher(
                    msg_type, topic, self.qos(bool(req.get("latched")))
                )
            while pub.get_subscription_count() < req.get("subscribers", 1):
                if time.monotonic() > deadline:
                    return {"ok": False, "error": "no subscriber"}
                time.sleep(0.02)
            if "raw" in req:
                pub.publish(bytes.fromhex(req["raw"]))
            else:
                fields = dict(req["fields"])
                if req["type"] == "Catalog":  # its entries as messages
                    fields["items"] = [ktbt_msg.CatalogEntry(**e) for e in fields.get("items", [])]
                pub.publish(msg_type(**fields))
            return {"ok": True, "sim": self.sim}
        if op == "call":
            srv_type = SERVICES[req["type"]]
            client = self.node.create_client(srv_type, req["service"])
            try:
                if not client.wait_for_service(timeout_sec=timeout):
                    return {"ok": False, "error": "no service"}
                request = srv_type.Request(**req.get("request", {}))
                future = client.call_async(request)
                done = threading.Event()
                future.add_done_callback(lambda _: done.set())
                if not done.wait(max(0.0, deadline - time.monotonic())):
                    return {"ok": False, "error": "no answer"}
                return {"ok": True, "response": plain(future.result())}
            finally:
                self.node.destroy_client(client)
        if op == "set_params":  # each result: (successful, reason)
            srv = SetParameters
            client = self.node.create_client(srv, f"{req['node']}/set_parameters")
            try:
                if not client.wait_for_service(timeout_sec=timeout):
                    return {"ok": False, "error": "no service"}
                params = [
                    Parameter(k, value=v).to_parameter_msg() for k, v in req["values"].items()
                ]
                future = client.call_async(srv.Request(parameters=params))
                done = threading.Event()
                future.add_done_callback(lambda _: done.set())
                if not done.wait(max(0.0, deadline - time.monotonic())):
                    return {"ok": False, "error": "no answer"}
                results = future.result().results
                return {"ok": True, "results": [[r.successful, r.reason] for r in results]}
            finally:
                self.node.destroy_client(client)
        if op == "params":
            names = req["names"]
            answer = self.handle(
                {
                    "op": "call",
                    "service": f"{req['node']}/get_parameters",
                    "type": "GetParameters",
                    "request": {"names": names},
                    "timeout": timeout,
                }
            )
            if not answer["ok"]:
                return answer
            values = {}
            for name, value in zip(names, answer["response"]["values"], strict=True):
                kind = value["type"]
                field = {1: "bool_value", 2: "integer_value", 3: "double_value",
                         4: "string_value", 9: "string_array_value"}.get(kind)  # fmt: skip
                values[name] = value[field] if field else None
            return {"ok": True, "values": values}
        return {"ok": False, "error": f"unknown op {op!r}"}

    def clock(self, start: float, speed: float, step: float = 0.1) -> None:
        """``/clock`` from ``start``, ``step`` simulated seconds every ``step / speed`` real
        ones (each step taken against the real clock, so a late one does not slow it)."""
        from rosgraph_msgs.msg import Clock

        pub = self.node.create_publisher(Clock, "/clock", 10)
        began, n = time.monotonic(), 0
        while True:
            self.sim = start + n * step
            whole = int(self.sim)
            msg = Clock()
            msg.clock.sec, msg.clock.nanosec = whole, round((self.sim - whole) * 1e9)
            pub.publish(msg)
            n += 1
            time.sleep(max(0.0, began + n * step / speed - time.monotonic()))


def main() -> None:
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)  # SIGTERM ends it at once
    probe = ProbeNode()
    executor = SingleThreadedExecutor()
    executor.add_node(probe.node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        for line in sys.stdin:
            try:
                answer = probe.handle(json.loads(line))
            except Exception as exc:  # report it to the test, which fails with it
                answer = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
            sys.stdout.write(json.dumps(answer) + "\n")
            sys.stdout.flush()
    finally:
        executor.shutdown()
        probe.node.destroy_node()
        try_shutdown()


if __name__ == "__main__":
    main()
