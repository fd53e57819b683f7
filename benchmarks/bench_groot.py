"""Groot2 status poll round trip: our publisher against BehaviorTree.CPP's own, in the same run.

Run with ``python -m benchmarks.bench_groot`` (or ``python -m benchmarks`` for every module).
Prints a Markdown table and writes the numbers to ``benchmarks/results/groot.json``.

The same port-less tree (11 nodes: a reactive fallback over a collision branch, an empty
knowledge placeholder, a negated-condition branch and a running walk) runs in two processes of
its own, each ticking it at 100 Hz as a robot would:

* ours: a ``LiveTree`` served by ``ktbt_proto.interop.groot2.Groot2Publisher``;
* the anchor: the same tree, as the XML ``ktbt convert`` writes, loaded into BehaviorTree.CPP
  4.8 through ``behaviortreepy`` and served by its own ``Groot2Publisher``.

The client is btview's own: a round trip is one ``MonitorSession.poll()`` (a STATUS request, the
reply and its decoding), exactly what ``btview info`` times for its "status poll" line, here with
``perf_counter_ns`` and without its 20 ms pause between samples. The two publishers are polled
alternately, round by round, after a warm-up; the tree fetch (FULLTREE) is timed the same way.
Target: ours at most 1.5x the anchor.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import multiprocessing
import re
import socket
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

from .timing import Stats, interleaved, machine, markdown_table, write_json

ROUNDS = 2000
TARGET_RATIO = 1.5
TICK_HZ = 100.0
TREE = """<sl>
    <sq><c>(_collisionDetectedF)<a>(CollisionAvoidance)<e>
    <k>(new)<e>
    <sq><c>(!_inZoneF)<a>(WalkToCollection)<e>
    <a>(RandomWalk)
<e>
"""


def _free_port() -> int:
    """A port p of loopback with p + 1 free too (REP and PUB)."""
    while True:
        with socket.socket() as a:
            a.bind(("127.0.0.1", 0))
            port = int(a.getsockname()[1])
            with socket.socket() as b:
                try:
                    b.bind(("127.0.0.1", port + 1))
                except OSError:
                    continue
            return port


def _ours(port: int) -> Callable[[], object]:
    import ktbt_proto as kp
    from ktbt_proto.interop.groot2 import Groot2Publisher

    reg = kp.Registry()
    reg.add_condition("_collisionDetectedF", lambda bb: False)
    reg.add_condition("_inZoneF", lambda bb: True)
    for name in ("CollisionAvoidance", "WalkToCollection"):
        reg.add_action(name, lambda bb: kp.SUCCESS)
    reg.add_action("RandomWalk", lambda bb: kp.RUNNING)
    live = kp.LiveTree(TREE, reg)
    live.tick()
    publisher = Groot2Publisher(live, port)
    return lambda: (live.tick(), publisher)


def _btcpp(port: int) -> Callable[[], object]:
    import behaviortreepy as bt

    import ktbt_proto as kp
    from ktbt_proto.interop.btcpp import to_xml

    s = bt.NodeStatus
    factory = bt.BehaviorTreeFactory()
    factory.register_simple_condition("_collisionDetectedF", lambda n: s.FAILURE)
    factory.register_simple_condition("_inZoneF", lambda n: s.SUCCESS)
    for name in ("CollisionAvoidance", "WalkToCollection"):
        factory.register_simple_action(name, lambda n: s.SUCCESS)
    factory.register_simple_stateful_action("RandomWalk", lambda n: s.RUNNING, lambda n: s.RUNNING)
    # Leaves by element name, as BT.CPP writes them (it refuses <Condition ID=...> in reactive
    # sequences); a no-op once the export writes that form.
    xml = re.sub(r'<(Condition|Action) ID="([^"]+)"', r"<\2", to_xml(kp.parse(TREE)))
    tree = factory.create_tree_from_text(xml)
    tree.tick_once()
    publisher = bt.Groot2Publisher(tree, port)
    return lambda: (tree.tick_once(), publisher)


def ticks(rounds: int) -> dict[str, Stats]:
    """One tick of the same tree three ways, interleaved: unprobed (the anchor), served by a
    publisher (its probe writes the status bytes), and served while recording transitions."""
    import struct

    import zmq

    import ktbt_proto as kp
    from ktbt_proto.interop.groot2 import Groot2Publisher

    def tree() -> kp.LiveTree:
        reg = kp.Registry()
        flip = [False]

        def collision(bb: object) -> bool:  # alternates, so bytes change and get recorded
            flip[0] = not flip[0]
            return flip[0]

        reg.add_condition("_collisionDetectedF", collision)
        reg.add_condition("_inZoneF", lambda bb: True)
        for name in ("CollisionAvoidance", "WalkToCollection"):
            reg.add_action(name, lambda bb: kp.SUCCESS)
        reg.add_action("RandomWalk", lambda bb: kp.RUNNING)
        return kp.LiveTree(TREE, reg)

    plain, served, recorded = tree(), tree(), tree()
    context = zmq.Context()
    publishers = []
    try:
        for live, record in ((served, False), (recorded, True)):
            port = _free_port()
            publishers.append(Groot2Publisher(live, port))
            live.tick()
            if record:
                req = context.socket(zmq.REQ)
                req.setsockopt(zmq.RCVTIMEO, 5000)
                req.connect(f"tcp://127.0.0.1:{port}")
                req.send_multipart([struct.pack("<BBI", 2, ord("r"), 1), b"start"])
                req.recv_multipart()
                req.close(linger=0)
            live.tick()
        return interleaved(
            {"unprobed": plain.tick, "served": served.tick, "recording": recorded.tick},
            rounds=rounds * 10,
            warmup=200,
        )
    finally:
        for publisher in publishers:
            publisher.close()
        context.destroy(linger=0)


def serve(kind: str, port: int, ready: Any, stop: Any) -> None:
    """A robot: the tree ticking at TICK_HZ, served by one publisher, until ``stop`` is set."""
    tick = (_ours if kind == "ours" else _btcpp)(port)
    ready.set()
    while not stop.wait(1.0 / TICK_HZ):
        tick()


def run(rounds: int) -> dict[str, Any]:
    from btview.client import Groot2Client
    from btview.session import MonitorSession

    spawn = multiprocessing.get_context("spawn")
    stop = spawn.Event()
    robots, sessions = {}, {}
    try:
        for kind in ("ours", "btcpp"):
            port, ready = _free_port(), spawn.Event()
            robots[kind] = spawn.Process(target=serve, args=(kind, port, ready, stop))
            robots[kind].start()
            if not ready.wait(60):
                raise RuntimeError(f"the {kind} publisher did not start")
            sessions[kind] = MonitorSession(Groot2Client("127.0.0.1", port, timeout_ms=5000))
            deadline = time.monotonic() + 30
            while not sessions[kind].refresh_tree():
                if time.monotonic() > deadline:
                    raise RuntimeError(f"no tree from the {kind} publisher")
                time.sleep(0.05)
        for kind, session in sessions.items():
            if not session.poll() or session.tree is None:
                raise RuntimeError(f"{kind}: {session.last_error}")
        nodes = {kind: session.tree.size for kind, session in sessions.items() if session.tree}
        if nodes["ours"] != nodes["btcpp"]:
            raise RuntimeError(f"the two publishers serve different trees: {nodes}")

        def poll(kind: str) -> Callable[[], object]:
            session = sessions[kind]

            def one() -> None:
                if not session.poll():
                    raise RuntimeError(f"{kind}: {session.last_error}")

            return one

        def fetch(kind: str) -> Callable[[], object]:
            session = sessions[kind]

            def one() -> None:
                if not session.refresh_tree():
                    raise RuntimeError(f"{kind}: {session.last_error}")

            return one

        polls = interleaved({k: poll(k) for k in sessions}, rounds=rounds, warmup=50)
        fetches = interleaved({k: fetch(k) for k in sessions}, rounds=max(rounds // 10, 20))
    finally:
        stop.set()
        for session in sessions.values():
            session.close()
        for robot in robots.values():
            robot.join(30)
            if robot.is_alive():
                robot.terminate()
                robot.join(10)

    def row(stats: dict[str, Stats]) -> dict[str, Any]:
        return {
            **{
                kind: {"median_us": round(st.median_us, 1), "p90_us": round(st.p90_us, 1)}
                for kind, st in stats.items()
            },
            "ratio": round(stats["ours"].median_ns / stats["btcpp"].median_ns, 2),
        }

    tick = ticks(rounds)
    return {
        "tick": {
            **{k: {"median_us": round(st.median_us, 2)} for k, st in tick.items()},
            "served_ratio": round(tick["served"].median_ns / tick["unprobed"].median_ns, 2),
            "recording_ratio": round(tick["recording"].median_ns / tick["unprobed"].median_ns, 2),
        },
        "machine": machine(),
        "behaviortreepy": importlib.metadata.version("behaviortreepy"),
        "btview": importlib.metadata.version("btview"),
        "nodes": nodes["ours"],
        "rounds": rounds,
        "status_poll": row(polls),
        "tree_fetch": row(fetches),
        "target_ratio": TARGET_RATIO,
    }


def report(result: dict[str, Any]) -> str:
    rows = []
    for name, key in (("status poll (btview info)", "status_poll"), ("tree fetch", "tree_fetch")):
        r = result[key]
        rows.append(
            [
                name,
                f"{r['ours']['median_us']} us (p90 {r['ours']['p90_us']})",
                f"{r['btcpp']['median_us']} us (p90 {r['btcpp']['p90_us']})",
                f"{r['ratio']}x",
            ]
        )
    table = markdown_table(["round trip", "ours", "BehaviorTree.CPP", "ratio"], rows)
    t = result["tick"]
    ticking = (
        f"One tick of the same tree: unprobed {t['unprobed']['median_us']} us, served "
        f"{t['served']['median_us']} us ({t['served_ratio']}x), recording "
        f"{t['recording']['median_us']} us ({t['recording_ratio']}x)."
    )
    verdict = "meets" if result["status_poll"]["ratio"] <= TARGET_RATIO else "MISSES"
    return (
        f"## Groot2 publisher, {result['nodes']}-node tree ({result['machine']}, "
        f"behaviortreepy {result['behaviortreepy']}, btview {result['btview']})\n\n{table}\n\n"
        f"Status poll {verdict} the target (at most {TARGET_RATIO}x BehaviorTree.CPP's).\n\n"
        f"{ticking}"
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_groot")
    parser.add_argument("--rounds", type=int, default=ROUNDS, help="status polls of each")
    parser.add_argument("--no-json", action="store_true", help="do not write results/groot.json")
    args = parser.parse_args(argv)
    try:
        import behaviortreepy  # noqa: F401
        import btview  # noqa: F401
        import zmq  # noqa: F401
    except ImportError as err:
        print(f"bench_groot: skipped ({err.name} missing): pip install -e '.[dev]'")
        return 0
    result = run(args.rounds)
    print(report(result))
    if not args.no_json:
        path = write_json("groot", result)
        print(f"\nWrote {path.relative_to(path.parents[2])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
