"""The fleet study (``make soak``): convergence time against fleet size, packet loss, delay, a
half/half silent partition that heals, churn and the links' lease, messages per learned item,
beside the floor of one query round trip measured in each run; every run checked. Writes
``fleet.md`` (the table, with the targets of docs/howto/fleet.md and whether each is met),
``fleet.png`` and ``fleet.json`` into the docs folder."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ktbt_proto.tools.fleet.check import History, read_record
from ktbt_proto.tools.fleet.plan import FleetConfig

Say = Callable[[str], None]

SCENARIOS: list[tuple[str, dict[str, Any], str]] = [
    ("size-5", {"peers": 5}, ""),
    ("size-10", {"peers": 10}, ""),
    ("size-20", {"peers": 20}, ""),
    ("size-40", {"peers": 40}, "within 3 s of the last peer up"),
    ("loss-10", {"peers": 10, "loss": 0.1}, ""),
    ("loss-20", {"peers": 10, "loss": 0.2}, "within 10 s"),
    ("loss-30", {"peers": 10, "loss": 0.3}, ""),
    ("delay-200ms", {"peers": 10, "delay": 0.2}, ""),
    ("partition-30s", {"peers": 10, "partition": 30.0}, "within 2 s after the heal"),
    ("halves-10", {"peers": 10, "partition": 30.0, "partition_kind": "none"}, ""),
    ("churn-20", {"peers": 10, "churn": 0.2, "churn_rounds": 3}, "within 5 s after they are back"),
    ("line-10", {"peers": 10, "topology": "line"}, "within 1 s of the last peer up"),
    ("router-20", {"peers": 20, "topology": "router"}, ""),
    ("member-10", {"peers": 10, "teacher": "run"}, ""),
    ("partition-30s-lease-1s", {"peers": 10, "partition": 30.0, "lease_ms": 1_000}, ""),
    ("partition-30s-lease-10s", {"peers": 10, "partition": 30.0, "lease_ms": 10_000}, ""),
    ("size-20-lease-1s", {"peers": 20, "lease_ms": 1_000}, ""),
    ("geometric-40", {"peers": 40, "topology": "geometric", "radius": 0.2},
     "at most 0.1 s a hop on the longest shortest path"),
    ("size-40-both", {"peers": 40, "dial": "both"}, ""),
    ("router-100", {"peers": 100, "topology": "router", "routers": 5, "settle": 10.0},
     "within 3 s of the last peer up"),
    ("router-100-partition-30s",
     {"peers": 100, "topology": "router", "routers": 5, "partition": 30.0},
     "within 2 s after the heal"),
]  # fmt: skip
"""Teachers are knowledge servers (``ktbt peer serve``) except in ``member-10``, whose teacher
is a fleet member (``ktbt peer run --knowledge``, an agent that teaches one asker per
cool-down); learners are always ``ktbt peer run`` agents that teach onward. The newer peer of
every pair dials the older, except in ``size-40-both``, where both ends dial (what that
costs, beside size-40; last, so that its load does not weigh on the others). Every peer's
lease is ``--lease`` 4000 (the default, LEASE_MS), except in the ``-lease-`` scenarios: the
partition and the healthy 20 at the other leases measured (what the lease buys and costs,
:func:`lease_lines`). ``geometric-40`` is a fleet shaped like a real one: 40 robots placed at
random (seed 7) in a square of side 1 and linked within a radio range of 0.2, a graph whose
longest shortest path from the teacher is several hops (knowledge measured per hop,
check.hops). ``router-100`` is a fleet of 100 peers as zenoh clients spread over 5 routers
(20 each, the routers linked in a chain, every link through the fault layer, each router
group in a network namespace of its own where the machine allows), kept 10 s
after convergence to measure what each process costs with nothing left to learn
(check.idle_cost); ``router-100-partition-30s`` the same fleet with the link between the
router groups r0-r2 and r3-r4 silently cut for 30 s from before the teacher is up
(plan.router_halves); last, as the heaviest."""
FIGURE_RECORDS = ("partition-30s", "churn-20")
"""The scenarios whose records the figure draws (what each peer knew over time)."""
LEASES = (1_000, 4_000, 10_000)
"""The leases measured, in ms: about 1 s, the default and zenoh's own default."""
BEFORE_OPTION_LEASE_MS = 4_000
"""The lease of a scenario recorded before ``--lease`` existed (its config has no
``lease_ms``)."""
LIMITS = {
    "size-40": 3.0, "loss-20": 10.0, "partition-30s": 2.0, "churn-20": 5.0, "line-10": 1.0,
    "router-100": 3.0, "router-100-partition-30s": 2.0,
}  # fmt: skip
IDLE_CPU_MS, IDLE_RSS_MB = 3.0, 50.0
"""The target of one idle peer (nothing left to learn): at most 3 ms of CPU a second and 50 MB
resident."""
HOP_LIMITS = {"geometric-40": 0.1}
"""Seconds a hop on the longest shortest path from the teacher (``per_hop_s``), the target of
the scenarios whose shape is the point."""


def measured(summary: dict[str, Any]) -> float | None:
    """The scenario's convergence: after the heal, after the last restart, or after the last
    peer is up."""
    if summary["name"] == "churn-20":
        value = summary.get("churn_convergence_s")
    else:
        value = summary.get("convergence_s")
    return None if value is None else float(value)


def dial_rate(retry_ms: int, seconds: float = 3.0) -> float:
    """Connection attempts a second one zenoh peer makes to a dead endpoint with ``--retry
    retry_ms``: a loopback listener that closes every connection at once counts them (what
    the retry period costs, spec/protocol.md section 3)."""
    import socket
    import threading
    import time

    from ktbt_proto.transport.zenoh import ZenohSettings, open_session

    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(0.2)
    port = server.getsockname()[1]
    count, stop = [0], threading.Event()

    def accept() -> None:
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                continue
            count[0] += 1
            conn.close()

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    session = open_session(ZenohSettings(connect=[f"tcp/127.0.0.1:{port}"], retry_ms=retry_ms))
    try:
        began, first = time.monotonic(), count[0]
        time.sleep(seconds)
        rate = (count[0] - first) / (time.monotonic() - began)
    finally:
        session.close()  # type: ignore[no-untyped-call]
        stop.set()
        thread.join()
        server.close()
    return round(rate, 2)


def keep_alive_rates(leases: tuple[int, ...] = LEASES, seconds: float = 10.0) -> dict[int, float]:
    """Writes a second on an idle link at each lease, both ways together: two zenoh sessions
    with nothing declared, linked through a loopback relay that counts each read, all leases
    side by side (what the lease costs, spec/protocol.md section 3: one keep-alive from each
    end every lease / KEEP_ALIVE ms, each a few bytes)."""
    import socket
    import threading
    import time

    from ktbt_proto.transport.zenoh import ZenohSettings, open_session

    stop = threading.Event()
    counts = {lease: [0] for lease in leases}
    sessions: list[Any] = []
    sockets: list[socket.socket] = []

    def pump(src: socket.socket, dst: socket.socket, count: list[int]) -> None:
        with contextlib.suppress(OSError):
            while not stop.is_set() and (data := src.recv(65536)):
                count[0] += 1
                dst.sendall(data)

    def relay(server: socket.socket, port: int, count: list[int]) -> None:
        with contextlib.suppress(OSError):
            conn, _ = server.accept()
            up = socket.create_connection(("127.0.0.1", port))
            sockets.extend([conn, up])
            for a, b in ((conn, up), (up, conn)):
                threading.Thread(target=pump, args=(a, b, count), daemon=True).start()

    try:
        for lease in leases:
            with socket.socket() as probe:
                probe.bind(("127.0.0.1", 0))
                port = probe.getsockname()[1]
            listen = ZenohSettings(listen=[f"tcp/127.0.0.1:{port}"], lease_ms=lease)
            sessions.append(open_session(listen))
            server = socket.create_server(("127.0.0.1", 0))
            sockets.append(server)
            threading.Thread(target=relay, args=(server, port, counts[lease]), daemon=True).start()
            dial = f"tcp/127.0.0.1:{server.getsockname()[1]}"
            sessions.append(open_session(ZenohSettings(connect=[dial], lease_ms=lease)))
        time.sleep(1.0)  # past the handshake
        first = {lease: count[0] for lease, count in counts.items()}
        began = time.monotonic()
        time.sleep(seconds)
        took = time.monotonic() - began
        return {lease: round((counts[lease][0] - first[lease]) / took, 2) for lease in leases}
    finally:
        stop.set()
        for sock in sockets:  # the relays first: a session closes at once on a closed link
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
            sock.close()
        for session in sessions:
            session.close()


def idle_alone(seconds: float = 10.0, settle: float = 5.0) -> dict[str, dict[str, float]]:
    """What one process costs idle and alone, as the study's machine runs it: a ``ktbt peer
    run --demo`` with nothing to learn (no sequence to meet, no neighbour) and a ``ktbt peer
    router`` with no client, side by side on loopback, each measured over ``seconds`` once
    ``settle`` seconds after it is up: CPU time (ms a second) and resident memory (MB), from
    /proc (runner.usage). The target of one idle peer: 3 ms a second, 50 MB."""
    import socket
    import subprocess
    import sys
    import tempfile
    import time

    from ktbt_proto.tools.fleet.runner import usage

    def port() -> int:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            found: int = s.getsockname()[1]
            return found

    peer = ["ktbt_proto", "peer"]
    commands = {
        "peer": [*peer, "run", "--demo", "--listen", f"tcp/127.0.0.1:{port()}", "--duration",
                 str(int(settle + seconds + 60)), "--no-multicast"],
        "router": [*peer, "router", "--listen", f"tcp/127.0.0.1:{port()}"],
    }  # fmt: skip
    procs: dict[str, subprocess.Popen[bytes]] = {}
    out: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory(prefix="ktbt-idle-") as folder:
        try:
            for name, args in commands.items():
                ready = Path(folder) / f"{name}.ready"
                procs[name] = subprocess.Popen(
                    [sys.executable, "-m", *args, "--ready", str(ready)],
                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                    stdin=subprocess.DEVNULL,
                )  # fmt: skip
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and not all(
                (Path(folder) / f"{n}.ready").exists() for n in commands
            ):
                if any(p.poll() is not None for p in procs.values()):
                    return {}
                time.sleep(0.1)
            time.sleep(settle)
            first = {n: usage(p.pid) for n, p in procs.items()}
            began = time.monotonic()
            time.sleep(seconds)
            last = {n: usage(p.pid) for n, p in procs.items()}
            took = time.monotonic() - began
            for name in commands:
                a, b = first[name], last[name]
                if a is not None and b is not None:
                    out[name] = {
                        "cpu_ms_per_s": round((b[2] - a[2]) / took, 2),
                        "rss_mb": round(b[0] / 1024, 1),
                    }
        finally:
            for p in procs.values():
                if p.poll() is None:
                    p.terminate()
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
    return out


def load_average() -> float | None:
    """The machine's load average over the last minute (``/proc/loadavg``), read before each
    run: on a shared machine, what else was running shows in every number."""
    try:
        return float(Path("/proc/loadavg").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None


def study(out: Path, docs: Path, say: Say, only: list[str] | None = None) -> list[dict[str, Any]]:
    """Run the scenarios (``only`` those named) and write fleet.md, fleet.json and fleet.png.
    With ``only``, the summaries of the scenarios not run are kept from the previous
    fleet.json, so that one scenario can be run again without running them all; the figure is
    drawn again only if the records it draws are in ``out``."""
    from ktbt_proto.tools.fleet.runner import run

    previous: dict[str, Any] = {}
    with contextlib.suppress(OSError, ValueError, TypeError, KeyError):
        previous = {s["name"]: s for s in json.loads((docs / "fleet.json").read_text())}
    ran: dict[str, dict[str, Any]] = {}
    for name, params, _ in SCENARIOS:
        if only and name not in only:
            continue
        load = load_average()
        say(f"--- {name} (load average {load})")
        config = FleetConfig(name=name, seed=7, bound=60.0, **{"teacher": "serve", **params})
        summary = run(config, out / name, say)
        summary["load_before"] = load
        before = previous.get(name, {}).get("messages_per_item_before")
        summary["messages_per_item_before"] = (
            before if before is not None else previous.get(name, {}).get("messages_per_item")
        )
        ran[name] = summary
        for v in summary["verdicts"]:
            if v["status"] == "fail":
                say(f"  FAIL {v['name']}: {v['detail']}")
        say(f"  convergence {measured(summary)} s, floor {summary.get('floor_s')} s")
    rates = {ms: dial_rate(ms) for ms in (250, 1000)}
    say(f"connection attempts a second to a dead endpoint: {rates}")
    keep_alives = keep_alive_rates()
    say(f"writes a second on an idle link, by lease (ms): {keep_alives}")
    alone = idle_alone()
    say(f"one idle process alone: {alone}")
    kept = {} if not only else previous
    summaries = [ran.get(n) or kept[n] for n, _, _ in SCENARIOS if n in ran or n in kept]
    for s in summaries:
        s.pop("dial_rates", None)
        s.pop("keep_alive_rates", None)
        s.pop("idle_alone", None)
    if summaries:
        summaries[0]["dial_rates"] = rates
        summaries[0]["keep_alive_rates"] = keep_alives
        summaries[0]["idle_alone"] = {**alone, "load_before": load_average()}
    docs.mkdir(parents=True, exist_ok=True)
    (docs / "fleet.json").write_text(json.dumps(summaries, indent=1, default=str))
    (docs / "fleet.md").write_text("\n".join(table(summaries)) + "\n")
    drawn = [n for n in FIGURE_RECORDS if any(s["name"] == n for s in summaries)]
    missing = [n for n in drawn if not (out / n / "events.jsonl").exists()]
    if missing:
        say(f"fleet.png kept as it was: no record of {', '.join(missing)} in {out}")
        return [ran[n] for n in ran]
    try:
        figure(out, summaries, docs / "fleet.png")
    except ImportError as exc:
        say(str(exc))
    return [ran[n] for n in ran]


def _ms(value: Any) -> str:
    return "-" if value is None else f"{float(value) * 1000:.1f}"


def table(summaries: list[dict[str, Any]]) -> list[str]:
    targets = {name: target for name, _, target in SCENARIOS}
    by_name = {s["name"]: s for s in summaries}
    lines = [
        "# Fleet study",
        "",
        "Real `ktbt peer` processes on loopback, one zenoh session each, every link through the",
        "fault layer (`ktbt fleet study`, `make soak`); one teacher holds the four colour skills",
        "(a `ktbt peer serve`, except in member-10, where it is a `ktbt peer run --knowledge`),",
        "every other peer learns them and teaches onward. The learners start first, the teacher",
        "last. Convergence is the time until every live peer knows every item, counted from the",
        "last peer up (the teacher), the heal of the partition, or the return of the peers",
        "killed in a churn round (the slowest of three rounds; the first strikes while they",
        "learn). The floor is one query round trip to the teacher on a direct link (no proxy),",
        "measured in the same run; the linked floor, one through a proxied link (its delay and",
        "loss included) to the learner behind it, an agent that answers from its tick loop",
        "(none in router-20 and router-100, whose links end at routers). Every run must converge",
        "within 60 s (the bound) to pass. Messages per item count every query sent (to all or",
        "to one peer), every answer sent and every announcement of what a peer learned (one",
        "put, however many neighbours hear it), over the items merged. The newer peer of every",
        "pair dials the older (both",
        "ends dial in size-40-both). geometric-40 is shaped like a real fleet: 40 robots",
        "placed at random (seed 7) in a square of side 1, linked when within 0.2 of each other",
        "(a radio range). Each scenario ran once, on a 2-core machine shared",
        "with other work (the load average of the minute before each run is in the table):",
        "read the numbers as orders of magnitude.",
        "",
        "| scenario | peers | topology | convergence (s) | target | met | floor (ms) "
        "| linked floor (ms) | convergence / floor | messages per item "
        "| honest answers refused (late) | late answers, counted apart | checks (pass/fail/skip) "
        "| load before |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    lines = _scenario_rows(lines, summaries, targets)
    lines += _targets(summaries)
    lines += _hop_table(summaries)
    lines += _stage_table(summaries)
    lines += _messages_table(summaries)
    lines += _idle_table(summaries)
    lines += _dial_lines(summaries)
    lines += lease_lines(summaries)
    return _closing(lines, summaries, by_name)


def _scenario_rows(
    lines: list[str], summaries: list[dict[str, Any]], targets: dict[str, str]
) -> list[str]:
    for s in summaries:
        conv, floor = measured(s), s.get("floor_s")
        met = {True: "yes", False: "no", None: ""}[meets(s)]
        ratio = "-" if conv is None or not floor else f"{conv / float(floor):,.0f}"
        counts = [sum(v["status"] == k for v in s["verdicts"]) for k in ("pass", "fail", "skipped")]
        lines.append(
            f"| {s['name']} | {s['config']['peers']} | {s['config']['topology']} "
            f"| {'-' if conv is None else f'{conv:.2f}'} | {targets.get(s['name']) or '-'} "
            f"| {met or '-'} | {_ms(floor)} | {_ms(s.get('floor_proxied_s'))} | {ratio} "
            f"| {s.get('messages_per_item') or '-'} "
            f"| {s.get('honest_answers_refused', '-')} ({s.get('late_answers_refused', '-')}) "
            f"| {s.get('late_answers', '-')} | {'/'.join(map(str, counts))} "
            f"| {s.get('load_before') if s.get('load_before') is not None else '-'} |"
        )
    return lines


def meets(summary: dict[str, Any]) -> bool | None:
    """Whether a scenario met its target (:data:`LIMITS` on convergence, :data:`HOP_LIMITS` on
    the time a hop); None for one without a target."""
    name = summary["name"]
    if name in HOP_LIMITS:
        hop = summary.get("per_hop_s")
        return hop is not None and float(hop) <= HOP_LIMITS[name]
    if name in LIMITS:
        conv = measured(summary)
        return conv is not None and conv <= LIMITS[name]
    return None


def _targets(summaries: list[dict[str, Any]]) -> list[str]:
    """Each target, met or missed by how much, and for a missed one the stage of the timeline
    that holds the most time (its median) in the transfers merged after the scenario's
    reference time (the last peer up, the heal...), or in all of them if none was (issue 27:
    say where the time goes)."""
    from ktbt_proto.tools.fleet.check import STAGES

    targets = {name: target for name, _, target in SCENARIOS}
    lines = ["", "Targets:", ""]
    for s in summaries:
        limit = LIMITS.get(s["name"])
        load = s.get("load_before")
        shown = "" if load is None else f", load average {load} before the run"
        if s["name"] in HOP_LIMITS:
            lines.append(f"- {s['name']} ({targets.get(s['name'])}): {_hop_verdict(s)}{shown}.")
            continue
        if limit is None:
            continue
        conv = measured(s)
        stages = s.get("stages_after_reference") or s.get("stages") or {}
        names = [f"{a}-{b}" for a, b in STAGES if f"{a}-{b}" in stages]
        held = max(names, key=lambda n: stages[n]["median"], default=None)
        where = (
            ""
            if held is None
            else f"; the longest stage, {held.replace('-', ' → ')}, median"
            f" {stages[held]['median']:.2f} s, worst {stages[held]['worst']:.2f} s"
        )
        if conv is None:
            verdict = "did not converge within the bound"
        elif conv <= limit:
            verdict, where = f"met: {conv:.2f} s", ""
        else:
            verdict = f"missed by {conv - limit:.2f} s ({conv:.2f} s)"
        lines.append(f"- {s['name']} ({targets.get(s['name'])}): {verdict}{where}{shown}.")
    return lines if len(lines) > 3 else []


def _hop_verdict(summary: dict[str, Any]) -> str:
    hop, limit = summary.get("per_hop_s"), HOP_LIMITS[summary["name"]]
    if hop is None:
        return "not every peer on the longest shortest path learned every item"
    far = f"{summary.get('eccentricity')} hops, the slowest item {float(hop):.3f} s a hop"
    if float(hop) <= limit:
        return f"met: {far}"
    return f"missed by {float(hop) - limit:.3f} s a hop ({far})"


def _hop_table(summaries: list[dict[str, Any]]) -> list[str]:
    """Hop by hop (check.hops): for every scenario whose record gave them, the longest shortest
    path from the teacher, the deepest who-taught-whom tree, and per item the seconds after
    the reference at which the last peer that far knew it, over that distance."""
    rows = []
    for s in summaries:
        items = s.get("hops")
        if not items:
            continue
        per_item = " / ".join(
            "-" if i["per_hop_s"] is None
            else f"{i['last_at_eccentricity_s']:.2f} ({i['per_hop_s']:.3f})"
            for i in items
        )  # fmt: skip
        detours = sum(int(i.get("detours") or 0) for i in items)
        load = s.get("load_before")
        rows.append(
            f"| {s['name']} | {s['config']['topology']} | {s.get('eccentricity', '-')} "
            f"| {s.get('tree_depth') if s.get('tree_depth') is not None else '-'} "
            f"| {per_item} | {detours} | {'-' if load is None else load} |"
        )
    if not rows:
        return []
    return [
        "",
        "Hop by hop: the longest shortest path from the teacher in the fleet's graph (hops"
        " between peers; a router is no hop), the deepest who-taught-whom tree of an item (from"
        " the learners' merges, each naming its teacher), and per item the seconds after the"
        " reference at which the last peer that far knew it (in brackets, over the distance:"
        " the time a hop); detours are learners taught along a longer path than their shortest.",
        "",
        "| scenario | topology | longest shortest path (hops) | deepest tree | last peer that far"
        " knew each item, s (s a hop) | detours | load before |",
        "| --- | --- | --- | --- | --- | --- | --- |",
        *rows,
    ]


def _stage_table(summaries: list[dict[str, Any]]) -> list[str]:
    """Where the time goes: median and worst of each stage of the transfers' timelines."""
    from ktbt_proto.tools.fleet.check import STAGES

    names = [f"{a}-{b}" for a, b in STAGES]
    lines = [
        "",
        "Where the time goes: every learned item's timeline (check.timelines), from its"
        " teacher's process start to the merge, each stage's median / worst in ms over the"
        " scenario's transfers (a link that came up after the teacher's session is counted in"
        " session-seen).",
        "",
        "| scenario | transfers | " + " | ".join(n.replace("-", " → ") for n in names) + " |",
        "| --- | --- | " + " | ".join("---" for _ in names) + " |",
    ]
    for s in summaries:
        stages = s.get("stages") or {}
        count = max((v.get("count", 0) for v in stages.values()), default=0)
        cells = [
            f"{stages[n]['median'] * 1000:.0f} / {stages[n]['worst'] * 1000:.0f}"
            if n in stages
            else "-"
            for n in names
        ]
        lines.append(f"| {s['name']} | {count} | " + " | ".join(cells) + " |")
    return lines


def _messages_table(summaries: list[dict[str, Any]]) -> list[str]:
    rows = [
        f"| {s['name']} | {s.get('messages_per_item') or '-'} "
        f"| {s.get('messages_per_item_before') or '-'} |"
        for s in summaries
    ]
    return [
        "",
        "Messages per learned item (queries sent, to all or to one peer, answers sent and"
        " announcements of what was learned, over items merged), against the previous study"
        " of the same scenario (one query a sequence, asked again on a timer; announcements"
        " were not counted before):",
        "",
        "| scenario | messages per item | before |",
        "| --- | --- | --- |",
        *rows,
    ]


def _idle_table(summaries: list[dict[str, Any]]) -> list[str]:
    """What a process costs with nothing left to learn (check.idle_cost), by role, for the
    scenarios whose settle window was long enough to measure it (5 s or more: the CPU time is
    counted in ticks of 10 ms), beside the target of one idle peer."""
    alone: dict[str, Any] = next((s["idle_alone"] for s in summaries if s.get("idle_alone")), {})
    lines = []
    if alone.get("peer"):
        peer, router = alone["peer"], alone.get("router") or {}
        ok = peer["cpu_ms_per_s"] <= IDLE_CPU_MS and peer["rss_mb"] <= IDLE_RSS_MB
        lines = [
            "",
            f"One idle peer alone (a `ktbt peer run --demo` with nothing to learn and no"
            f" neighbour, measured over 10 s in the same study, load average"
            f" {alone.get('load_before', '-')} at the end): {peer['cpu_ms_per_s']:.1f} ms of CPU"
            f" a second and {peer['rss_mb']:.1f} MB RSS, against a target of {IDLE_CPU_MS:g} ms"
            f" and {IDLE_RSS_MB:g} MB: {'met' if ok else 'missed'}; a `ktbt peer router` with"
            f" no client beside it: {router.get('cpu_ms_per_s', '-')} ms a second and"
            f" {router.get('rss_mb', '-')} MB.",
        ]
    rows = []
    for s in summaries:
        idle = s.get("idle") or {}
        if float(idle.get("window_s") or 0) < 5.0:
            continue
        load = s.get("load_before")
        for role, cpu in idle["cpu_ms_per_s"].items():
            rss = idle["rss_mb"][role]
            met = "-"
            if role == "learner":
                ok = cpu["median"] <= IDLE_CPU_MS and rss["median"] <= IDLE_RSS_MB
                met = "yes" if ok else "no"
            rows.append(
                f"| {s['name']} | {role} | {cpu['median']:.1f} / {cpu['worst']:.1f} "
                f"| {rss['median']:.0f} / {rss['worst']:.0f} | {met} | {idle['window_s']:.1f} "
                f"| {'-' if load is None else load} |"
            )
    if not rows:
        return lines
    return [
        *lines,
        "",
        "What a process costs with nothing left to learn: from convergence to the end of the"
        " run, each process's CPU time (user and system, /proc) over the window, in ms a"
        " second, and its resident memory (RSS) at the end, the median / worst over the"
        f" processes of each role; target for an idle learner (a `ktbt peer run`): at most"
        f" {IDLE_CPU_MS:g} ms a second and {IDLE_RSS_MB:g} MB (both medians).",
        "",
        "| scenario | role | CPU (ms a second) | RSS (MB) | target met | window (s)"
        " | load before |",
        "| --- | --- | --- | --- | --- | --- | --- |",
        *rows,
    ]


def _dial_lines(summaries: list[dict[str, Any]]) -> list[str]:
    rates = next((s["dial_rates"] for s in summaries if s.get("dial_rates")), None)
    if not rates:
        return []
    shown = ", ".join(f"{rate} a second at --retry {ms}" for ms, rate in rates.items())
    return [
        "",
        f"What the retry period costs: one peer dialling an endpoint that stays dead made"
        f" {shown} (measured in the same run); every peer dials every dead neighbour so.",
    ]


def lease_of(summary: dict[str, Any]) -> int:
    """The lease every peer of a scenario had, in ms."""
    return int(summary["config"].get("lease_ms", BEFORE_OPTION_LEASE_MS))


def lease_lines(summaries: list[dict[str, Any]]) -> list[str]:
    """What the lease buys and costs, one row a lease measured: the writes a second on an idle
    link (keep-alives), how long a link that went silent was kept (check.given_up), the
    partition's heal (convergence after it) and the delay its dead
    links caused the half with the teacher (against halves-10, the same halves with no dead
    link), and the healthy links a fleet of 20 without faults gave up and dialled again."""
    found: dict[str, float] = next(
        (s["keep_alive_rates"] for s in summaries if s.get("keep_alive_rates")), {}
    )
    rates: dict[int, float] = {int(ms): rate for ms, rate in found.items()}  # JSON: str keys
    base = next((s for s in summaries if s["name"] == "halves-10"), None)
    half = None if base is None else base.get("teacher_half_s")
    rows = []
    for lease in sorted(set(rates) | {lease_of(s) for s in summaries}):
        cut = [s for s in summaries if s["name"].startswith("partition-30s") and
               lease_of(s) == lease]  # fmt: skip
        calm = [s for s in summaries if s["name"].startswith("size-20") and lease_of(s) == lease]
        if not (cut or calm) and lease not in rates:
            continue
        heal = measured(cut[0]) if cut else None
        kept = cut[0].get("silent_link_given_up_s") if cut else None
        mine = cut[0].get("teacher_half_s") if cut else None
        delay = "-" if mine is None or half is None else f"{float(mine) - float(half):+.2f}"
        redials = "-"
        if calm and calm[0].get("links_redialled") is not None:
            redials = (
                f"{calm[0]['links_redialled']} of {calm[0].get('links_up')} ({calm[0]['name']})"
            )
        loads = "/".join(
            "-" if s.get("load_before") is None else str(s["load_before"]) for s in cut + calm
        )
        rows.append(
            f"| {lease / 1000:g} s | {rates.get(lease, '-')} "
            f"| {'-' if kept is None else f'{kept:.2f}'} "
            f"| {'-' if heal is None else f'{heal:.2f}'} | {delay} | {redials} | {loads or '-'} |"
        )
    if not rows:
        return []
    return [
        "",
        "What the lease buys and costs (every peer's `--lease`; 4 keep-alives a lease): writes"
        " a second on an idle link, both ends together (two sessions linked through a relay"
        " that counts each read, measured in the same run; each a keep-alive of a few bytes);"
        " in the 30 s silent partition, how long a dialer kept a link that went silent before"
        " it dialled again (the median over the links that crossed it), the convergence after"
        " the heal, and the delay its dead links caused the"
        " half with the teacher (against halves-10); the links of 20 peers without faults"
        " closed and dialled again before the end (a healthy link given up); the load average"
        " before those runs.",
        "",
        "| lease | writes a second on an idle link | silent link given up after (s)"
        " | partition-30s: convergence after the heal (s) | dead links' delay (s)"
        " | healthy links dialled again | load before |",
        "| --- | --- | --- | --- | --- | --- | --- |",
        *rows,
    ]


def _closing(
    lines: list[str], summaries: list[dict[str, Any]], by_name: dict[str, dict[str, Any]]
) -> list[str]:
    dup = sum(
        1 for s in summaries for v in s["verdicts"]
        if v["name"] == "no duplicate merge" and v["status"] == "fail"
    )  # fmt: skip
    lost = sum(
        1 for s in summaries for v in s["verdicts"]
        if v["name"] == "kill -9 loses nothing saved" and v["status"] == "fail"
    )  # fmt: skip
    bad = sum(
        1 for s in summaries for v in s["verdicts"]
        if v["name"] == "saved files" and v["status"] == "fail"
    )  # fmt: skip
    part, base = by_name.get("partition-30s"), by_name.get("halves-10")
    if part and base and part.get("teacher_half_s") is not None and base.get("teacher_half_s"):
        a, b = float(part["teacher_half_s"]), float(base["teacher_half_s"])
        lines += [
            "",
            f"The half with the teacher learned everything in {a:.2f} s with every link to the"
            f" other half silently dead, against {b:.2f} s with the same halves and no dead link:"
            f" the dead links delayed it by {a - b:+.2f} s (target: at most 0.1 s).",
        ]
    honest = sum(int(s.get("honest_answers_refused") or 0) for s in summaries)
    late = sum(int(s.get("late_answers_refused") or 0) for s in summaries)
    lines += [
        "",
        f"Every fleet peer is honest, so every refusal of what one sent turned a good answer"
        f" away: {honest} over the study, {late} of them answers that arrived after their"
        f' question had closed ("an answer to no open question"). The peers count them as'
        f" refusals; they are not faults of the network or of a peer.",
    ]
    lines += [
        "",
        f"Over the whole study: {dup} runs with a duplicate merge, {lost} with a lost saved item,"
        f" {bad} with a corrupted or foreign saved item.",
        "",
        "Checks that failed, and faults that were skipped (a check that does not apply, such",
        "as a kill in a run without churn, is skipped and not listed):",
        "",
    ]
    others = [
        f"- {s['name']}: {v['status']} {v['name']}: {v['detail']}"
        for s in summaries
        for v in s["verdicts"]
        if v["status"] == "fail" or (v["status"] == "skipped" and v["name"].startswith("fault:"))
    ]
    lines += others or ["- none"]
    return lines


def figure(out: Path, summaries: list[dict[str, Any]], path: Path) -> None:
    from ktbt_proto.tools.fleet.figure import draw, pyplot

    plt = pyplot()
    by = {s["name"]: s for s in summaries}
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    sizes = [by[n] for n in ("size-5", "size-10", "size-20", "size-40") if n in by]
    ax = axes[0][0]
    ax.plot([s["config"]["peers"] for s in sizes], [measured(s) for s in sizes], "o-")
    ax.axhline(3.0, color="grey", ls=":", lw=0.8, label="target at 40 peers")
    ax.set_xlabel("peers (mesh, no faults)")
    ax.set_ylabel("convergence after the last peer up (s)")
    ax.legend(fontsize=7)
    losses = [by[n] for n in ("size-10", "loss-10", "loss-20", "loss-30") if n in by]
    ax = axes[0][1]
    ax.plot(
        [100 * s["config"]["loss"] for s in losses], [measured(s) for s in losses], "o-", c="C1"
    )
    ax.set_xlabel("packet loss on every link (%), 10 peers")
    ax.set_ylabel("convergence (s)")
    for ax, name in zip((axes[1][0], axes[1][1]), FIGURE_RECORDS, strict=True):
        if name in by:
            draw(ax, History(read_record(out / name / "events.jsonl")), name)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
