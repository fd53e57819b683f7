"""`ktbt monitor` under load: 40 peers, 1,000 fleet events a second for 60 s, watched in a real
headless Chromium, beside a bare zenoh subscriber of the same events in the same run.

Run with ``python -m benchmarks.bench_monitor`` (``--peers``, ``--rate``, ``--seconds``). Prints a
Markdown table and writes ``benchmarks/results/monitor.json``. Needs the ``monitor`` and ``dev``
extras and Debian's ``chromium`` and ``chromium-driver``.

Three processes on loopback: a generator (this module with ``--generate``) holding one zenoh
session with a liveliness token and an ``EventPublisher`` per peer, each peer publishing its
share of the rate (queries, answers, merges and forgets of 20 items, refusals); the monitor
(``ktbt monitor``, a process of its own); and this one, with the browser and the anchor.

* page lag: for each event the page draws, the time from the event's ``t`` (when the peer's
  log recorded it) to the animation frame that drew it, as the page itself measures it
  (``window.ktbtMonitor``), sampled every second;
* the anchor: the same lag at a bare zenoh subscriber in this process (event ``t`` to the
  callback), so the ratio is what the monitor and the page add to the network's own delay;
* the time between two updates the page applies, and the time a frame takes to draw;
* the monitor's resident memory every second, and the page's JavaScript heap.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from benchmarks.timing import RESULTS_DIR, percentile

ROOT = Path(__file__).resolve().parent.parent
ITEMS = [f"<c>(TargetSeen,colour={c % 4 + 1})<c>(Zone,n={c})" for c in range(20)]
KINDS = ("query-sent", "answer-received", "merged", "query-received", "answer-sent", "refused")


def _port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@contextmanager
def _process(*args: str, ready: str | None = None) -> Iterator[subprocess.Popen[str]]:
    proc = subprocess.Popen(
        [sys.executable, *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        if ready is not None:
            assert proc.stdout is not None
            for line in proc.stdout:
                if ready in line:
                    break
            else:
                raise RuntimeError(f"{args[:4]} exited before {ready!r}")
            threading.Thread(target=proc.stdout.read, daemon=True).start()  # keep it drained
        yield proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=15)


def _wait_http(url: str, seconds: float = 20) -> None:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            with urllib.request.urlopen(url, timeout=1):
                return
        except OSError:
            time.sleep(0.1)
    raise RuntimeError(f"{url} never answered")


def _rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def _cpu_s(pid: int) -> float:
    """User and system CPU seconds a process has used."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _ms(t: str) -> float:
    return datetime.fromisoformat(t).timestamp() * 1000


# -- the generator -------------------------------------------------------------------------------


def generate(port: int, peers: int, rate: float, seconds: float, signed: bool = False) -> int:
    """Listen on ``port`` and publish ``rate`` events a second, spread over ``peers`` peers
    (each signing its events with a key pair of its own if ``signed``)."""
    from ktbt_proto.exchange.events import EventPublisher
    from ktbt_proto.exchange.signing import Identity
    from ktbt_proto.transport.zenoh import ZenohSettings, open_session

    session = open_session(ZenohSettings(listen=[f"tcp/127.0.0.1:{port}"]))
    names = [f"robot{i:02d}" for i in range(peers)]
    tokens = [session.liveliness().declare_token(f"ktbt/v1/peers/{n}") for n in names]
    publishers = [
        EventPublisher.on_session(session, n, identity=Identity.generate() if signed else None)
        for n in names
    ]
    print("generating", flush=True)
    time.sleep(3.0)  # the monitor connects and subscribes
    sent, start = 0, time.monotonic()
    knows: dict[tuple[int, int], bool] = {}
    while time.monotonic() - start < seconds:
        due = int((time.monotonic() - start) * rate)
        while sent < due:
            p, step = sent % peers, sent // peers
            item = (step // len(KINDS) + p) % len(ITEMS)
            kind = KINDS[step % len(KINDS)]
            if kind == "merged" and knows.get((p, item)):
                kind, knows[(p, item)] = "forgotten", False
            elif kind == "merged":
                knows[(p, item)] = True
            entry: dict[str, Any] = {
                "t": datetime.now(UTC).isoformat(timespec="milliseconds"),
                "event": kind,
                "peer": names[p],
                "sequence": ITEMS[item],
                "id": f"q{step}",
                "sender": names[(p + 1) % peers],
                "teacher": names[(p + 1) % peers],
            }
            if kind == "refused":
                entry["reason"] = "SBT310 colour=7 out of range"
            publishers[p][0](entry)
            sent += 1
        time.sleep(0.002)
    print(f"sent {sent} dropped {sum(pub.dropped for pub, _ in publishers)}", flush=True)
    for _, zpub in publishers:
        zpub.undeclare()
    for token in tokens:
        token.undeclare()  # type: ignore[no-untyped-call]
    session.close()  # type: ignore[no-untyped-call]
    return 0


# -- the measurement -----------------------------------------------------------------------------


def bench(peers: int, rate: float, seconds: float, signed: bool = False) -> dict[str, Any]:
    from ktbt_proto.exchange.events import decode_event
    from ktbt_proto.transport.zenoh import ZenohSettings, open_session
    from tests.browser import chromium, unavailable

    why = unavailable()
    if why is not None:
        raise SystemExit(f"bench_monitor: no browser: {why}")
    fleet, http = _port(), _port()
    anchor: list[float] = []
    page_lags: list[float] = []
    gaps: list[float] = []
    frames: list[float] = []
    rss: list[int] = []
    heap: list[int] = []
    with ExitStack() as stack:
        generator = stack.enter_context(
            _process("-m", "benchmarks.bench_monitor", "--generate", str(fleet),
                     "--peers", str(peers), "--rate", str(rate), "--seconds", str(seconds),
                     *(["--signed"] if signed else []), ready="generating")
        )  # fmt: skip
        monitor = stack.enter_context(
            _process("-m", "ktbt_proto", "monitor", "--connect", f"tcp/127.0.0.1:{fleet}",
                     "--http", f"127.0.0.1:{http}", ready="localhost only")
        )  # fmt: skip
        session = open_session(ZenohSettings(connect=[f"tcp/127.0.0.1:{fleet}"]))
        stack.callback(session.close)

        def heard(sample: Any) -> None:
            event = decode_event(sample.payload.to_bytes())
            anchor.append(time.time() * 1000 - _ms(event.t))

        subscriber = session.declare_subscriber("ktbt/v1/events/*", heard)
        stack.callback(subscriber.undeclare)
        url = f"http://127.0.0.1:{http}/"
        _wait_http(url)
        driver = stack.enter_context(chromium())
        driver.get(url)
        start = time.monotonic()
        load = [os.getloadavg()[0]]
        cpu = [_cpu_s(monitor.pid)]
        seen_batches = 0
        while generator.poll() is None and time.monotonic() - start < seconds + 30:
            time.sleep(1.0)
            probe = driver.execute_script(
                "const p = window.ktbtMonitor;"
                "const out = {lags: p.lags.slice(), gaps: p.batchGaps.slice(),"
                "  frames: p.frameTimes.slice(), batches: p.batches,"
                "  heap: performance.memory ? performance.memory.usedJSHeapSize : 0};"
                "p.lags.length = 0; p.batchGaps.length = 0; p.frameTimes.length = 0;"
                "return out;"
            )
            page_lags.extend(probe["lags"])
            gaps.extend(probe["gaps"])
            frames.extend(probe["frames"])
            seen_batches = probe["batches"]
            rss.append(_rss_kb(monitor.pid))
            heap.append(int(probe["heap"]))
        load.append(os.getloadavg()[0])
        cpu.append(_cpu_s(monitor.pid))
        elapsed = time.monotonic() - start
        stats = driver.execute_script(
            "return [document.getElementById('stat-events').textContent,"
            " document.getElementById('stat-dropped').textContent,"
            " document.querySelectorAll('#matrix tbody tr').length]"
        )
    settle = len(rss) // 6  # the first tenth-ish of the run: start-up
    return {
        "peers": peers,
        "signed": signed,
        "items": len(ITEMS),
        "rate": rate,
        "seconds": seconds,
        "events_shown": int(stats[0]),
        "dropped_at_monitor": int(stats[1]),
        "rows": int(stats[2]),
        "batches": seen_batches,
        "page_lag_ms": _summary(page_lags),
        "anchor_lag_ms": _summary(anchor),
        "update_gap_ms": _summary(gaps),
        "frame_ms": _summary(frames),
        "load_average": [round(x, 1) for x in load],
        "monitor_cpu_percent": round(100 * (cpu[1] - cpu[0]) / elapsed, 1),
        "monitor_rss_mb_by_quarter": [
            round(rss[len(rss) * q // 4 - 1] / 1024, 1) for q in (1, 2, 3, 4)
        ]
        if len(rss) >= 4
        else [],
        "monitor_rss_mb": {
            "after_start": round(rss[settle] / 1024, 1) if rss else 0,
            "end": round(rss[-1] / 1024, 1) if rss else 0,
            "max": round(max(rss) / 1024, 1) if rss else 0,
        },
        "page_heap_mb": {
            "after_start": round(heap[settle] / 2**20, 1) if heap else 0,
            "end": round(heap[-1] / 2**20, 1) if heap else 0,
            "max": round(max(heap) / 2**20, 1) if heap else 0,
        },
    }


def _summary(samples: Sequence[float]) -> dict[str, float]:
    if not samples:
        return {"n": 0}
    ordered = sorted(round(s * 1000) for s in samples)  # in µs: percentile takes integers
    return {
        "n": len(ordered),
        "p50": round(percentile(ordered, 0.5) / 1000, 1),
        "p99": round(percentile(ordered, 0.99) / 1000, 1),
        "max": round(ordered[-1] / 1000, 1),
    }


def report(r: dict[str, Any]) -> str:
    lag, raw = r["page_lag_ms"], r["anchor_lag_ms"]
    ratio = lag["p50"] / raw["p50"] if raw.get("p50") else float("nan")
    rows = [
        f"`ktbt monitor`: {r['peers']} peers, {r['rate']:,.0f} events/s for {r['seconds']:.0f} s,"
        f" headless Chromium; {r['events_shown']:,} events taken, {r['dropped_at_monitor']}"
        f" dropped, {r['rows']} peers drawn, {r['batches']:,} updates",
        "",
        "| measure | p50 | p99 | max | anchor (bare zenoh subscriber), p50 |",
        "| --- | ---: | ---: | ---: | ---: |",
        f"| page lag: event recorded -> drawn | {lag['p50']} ms | {lag['p99']} ms |"
        f" {lag['max']} ms | {raw['p50']} ms ({ratio:.0f}x; target <= 1 s behind) |",
        f"| time between updates | {r['update_gap_ms']['p50']} ms |"
        f" {r['update_gap_ms']['p99']} ms | {r['update_gap_ms']['max']} ms | |",
        f"| frame time (drawing a batch) | {r['frame_ms']['p50']} ms | {r['frame_ms']['p99']} ms |"
        f" {r['frame_ms']['max']} ms | |",
        "",
        f"monitor memory (RSS): {r['monitor_rss_mb']['after_start']} MB after start-up,"
        f" {r['monitor_rss_mb']['end']} MB at the end, {r['monitor_rss_mb']['max']} MB at most;"
        f" page heap {r['page_heap_mb']['after_start']} -> {r['page_heap_mb']['end']} MB"
        f" (max {r['page_heap_mb']['max']} MB); RSS by quarter of the run:"
        f" {', '.join(str(x) for x in r['monitor_rss_mb_by_quarter'])} MB; monitor CPU"
        f" {r['monitor_cpu_percent']} % of a core; machine load {r['load_average'][0]} at the"
        f" start, {r['load_average'][1]} at the end (2 cores)",
    ]
    return "\n".join(rows)


def publish_cost(rounds: int) -> dict[str, Any]:
    """``bench_transfer``'s path (ask, check, merge, tick) between a teacher and a learner that
    publish no events (the anchor), publish them unsigned, and publish them signed (every
    event of both logs: query and answer sent and received), round by round in turn."""
    import gc

    import ktbt_proto as kp
    from benchmarks import bench_transfer as bt
    from benchmarks.timing import gc_paused
    from ktbt_proto.exchange.signing import Identity
    from ktbt_proto.interop.knowledge_file import load_knowledge
    from ktbt_proto.tools.demo import DEMO_CONTROL, demo_registry
    from ktbt_proto.transport.zenoh import ZenohTransport, peers

    kb = load_knowledge(bt.KNOWLEDGE_PATH)
    control, registry = kp.parse(DEMO_CONTROL), demo_registry()
    modes = ("none", "unsigned", "signed")
    samples: dict[str, list[int]] = {mode: [] for mode in modes}
    with ExitStack() as stack:
        pairs: dict[str, ZenohTransport] = {}
        for mode in modes:
            pt, pl = bt.free_port(), bt.free_port()
            publish = mode != "none"
            key = Identity.generate() if mode == "signed" else None
            stack.enter_context(
                ZenohTransport(bt.TEACHER, bt.settings(pt), lookup=bt.serve_lookup(kb),
                               catalog=kb.keys, publish_events=publish, identity=key)
            )  # fmt: skip
            learner = stack.enter_context(
                ZenohTransport(
                    bt.LEARNER, bt.settings(pl, pt), publish_events=publish, identity=key
                )
            )

            def sees(asker: ZenohTransport = learner) -> bool:
                return bt.TEACHER in peers(asker, 0.3)

            bt._wait(sees, "no teacher")
            pairs[mode] = learner
        with gc_paused():
            for r in range(bt.WARMUP + rounds):
                if r and r % 100 == 0:
                    gc.collect()
                for mode in modes[r % 3 :] + modes[: r % 3]:
                    fresh = bt.fresh_learner(control, registry, bt.COLOURS[r % len(bt.COLOURS)])
                    elapsed, ok = bt.transfer(pairs[mode], fresh, [[] for _ in bt.PHASES])
                    if not ok:
                        raise AssertionError(f"{mode}: round {r} did not complete")
                    if r >= bt.WARMUP:
                        samples[mode].append(elapsed)
    result: dict[str, Any] = {"rounds": rounds, **{m: bt._us(s) for m, s in samples.items()}}
    result["ratio"] = {
        m: round(result[m]["median"] / result["none"]["median"], 2) for m in ("unsigned", "signed")
    }
    return result


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0] if __doc__ else None)
    parser.add_argument("--peers", type=int, default=40)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--generate", type=int, metavar="PORT", help=argparse.SUPPRESS)
    parser.add_argument("--signed", action="store_true", help="The peers sign their events.")
    parser.add_argument(
        "--publish-cost", type=int, metavar="ROUNDS", help="Time transfers with and without events."
    )
    args = parser.parse_args(argv)
    if args.generate:
        return generate(args.generate, args.peers, args.rate, args.seconds, args.signed)
    if args.publish_cost:
        cost = publish_cost(args.publish_cost)
        RESULTS_DIR.mkdir(exist_ok=True)
        (RESULTS_DIR / "monitor_publish_cost.json").write_text(json.dumps(cost, indent=2) + "\n")
        print(json.dumps(cost, indent=2))
        return 0
    result = bench(args.peers, args.rate, args.seconds, args.signed)
    RESULTS_DIR.mkdir(exist_ok=True)
    (RESULTS_DIR / ("monitor_signed.json" if args.signed else "monitor.json")).write_text(
        json.dumps(result, indent=2) + "\n"
    )
    print(report(result))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
