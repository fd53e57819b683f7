"""The properties of a fleet run, checked over its record as Jepsen's checkers read a history
(``events.jsonl``; docs/howto/fleet.md).

Each property gives a verdict: ``pass``, ``fail`` (with what broke it) or ``skipped`` (with
why: a skipped fault is never a passed one). A fault the scenario asked for passes only when
the record shows it happened: the proxies' counters (bytes held, connections reset, chunks
delayed), the kernel's (packets dropped) and the peers' own events (no answer crossed a
partition, answers came no sooner than the delay allows).
"""

from __future__ import annotations

import json
import statistics
from collections import Counter, defaultdict
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

from ktbt_proto.exchange.transferlog import Event
from ktbt_proto.tools.fleet.plan import distances, neighbours

Outcome = Literal["pass", "fail", "skipped"]
RSS_GROWTH = 0.20
"""Median resident memory of the peers never killed may grow by at most this fraction from
the end of the first churn round to the end of the run."""
RSS_SLACK_KB = 4096
SHOWN_WITHIN = 1.0
"""Seconds within which the monitor must show a merge (the page's target)."""
FD_GROWTH = 16
"""File descriptors of any peer never killed (and of the runner) may grow by at most this."""


@dataclass(frozen=True)
class Verdict:
    name: str
    status: Outcome
    detail: str


def read_record(path: Path) -> list[dict[str, Any]]:
    """The record's events. A last line cut short (the runner was killed while writing it) is
    dropped, and the record then lacks its end; any other line that is not JSON is an error."""
    events = []
    with open(path, encoding="utf-8") as f:
        lines = f.read().split("\n")
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            events.append(json.loads(line))
        except ValueError:
            if number == len(lines):  # no newline after it: torn
                break
            raise ValueError(f"line {number} is not JSON") from None
    return events


class History:
    """A record, indexed for the checks."""

    def __init__(self, events: list[dict[str, Any]]) -> None:
        self.events = events
        run = next((e for e in events if e["kind"] == "run"), None)
        if run is None:
            raise ValueError("not a fleet record: no run event")
        self.config: dict[str, Any] = run["config"]
        self.plan: dict[str, Any] = run["plan"]
        self.items: dict[str, str] = run["items"]
        self.peers = [n["name"] for n in self.plan["nodes"] if n["role"] != "router"]
        self.learners = [n["name"] for n in self.plan["nodes"] if n["role"] == "learner"]

    def of(self, kind: str) -> list[dict[str, Any]]:
        return [e for e in self.events if e["kind"] == kind]

    def one(self, kind: str) -> dict[str, Any] | None:
        found = self.of(kind)
        return found[-1] if found else None

    def lives(self) -> dict[tuple[str, int], dict[str, Any]]:
        """(peer, life) -> its launch event, with ``up`` (time or None) added."""
        out = {(e["peer"], e["life"]): {**e, "up": None} for e in self.of("launch")}
        for e in self.of("up"):
            if (e["peer"], e["life"]) in out:
                out[(e["peer"], e["life"])]["up"] = e["t"]
                out[(e["peer"], e["life"])]["knows"] = e.get("knows")
        return out

    def last_lives(self) -> dict[str, dict[str, Any]]:
        last: dict[str, dict[str, Any]] = {}
        for (peer, number), life in sorted(self.lives().items()):
            if peer in self.peers and (peer not in last or number > last[peer]["life"]):
                last[peer] = life
        return last

    def merges(self) -> dict[tuple[str, int], list[dict[str, Any]]]:
        out: dict[tuple[str, int], list[dict[str, Any]]] = defaultdict(list)
        for e in self.of(Event.MERGED):
            out[(e["peer"], e["life"])].append(e)
        return out

    def changes(self) -> dict[tuple[str, int], list[dict[str, Any]]]:
        """Merges and forgettings of each life, in the record's order."""
        out: dict[tuple[str, int], list[dict[str, Any]]] = defaultdict(list)
        for e in self.events:
            if e["kind"] in (Event.MERGED, Event.FORGOTTEN):
                out[(e["peer"], e["life"])].append(e)
        return out

    def unplanned_exits(self) -> list[str]:
        """Lives that ended other than by the run's own SIGKILL (a churn kill) or its stop at
        the end (SIGTERM, or SIGKILL when that did not end it)."""
        killed = {(e["peer"], e["life"]) for e in self.of("kill")}
        stopping = self.one("stopping")
        if stopping is None:  # a record from before the stop was recorded: its last lives
            last: dict[str, int] = {}
            for e in self.of("exit"):
                last[e["peer"]] = max(last.get(e["peer"], 0), e["life"])
            stopped = set(last.items())
        else:
            stopped = set(stopping.get("lives", {}).items())
        out = []
        for e in self.of("exit"):
            key, code = (e["peer"], e["life"]), e.get("returncode")
            if key in killed and code == -9:
                continue
            if key in stopped and code in (0, -15, -9):
                continue
            out.append(f"{e['peer']} life {e['life']} exited with {code}")
        return out


def check(events: list[dict[str, Any]]) -> list[Verdict]:
    h = History(events)
    return [
        _completed(h),
        _convergence(h),
        _no_duplicates(h),
        _saved_files(h),
        _kills_lose_nothing(h),
        *_faults(h),
        _rounds(h),
        _bounded(h),
        *_monitor(h),
        *_groups(h),
    ]


def _completed(h: History) -> Verdict:
    aborted = h.of("aborted")
    if aborted:
        return Verdict("completed", "fail", "; ".join(str(e.get("reason")) for e in aborted))
    if h.one("end") is None:
        return Verdict("completed", "fail", "the record stops before the run's end")
    return Verdict("completed", "pass", "the schedule ran to its end")


def convergence_time(h: History, among: set[str] | None = None) -> float | None:
    """When the last peer (in its last life; of ``among``, if given) knew every item, or None
    if one never did."""
    merges = h.changes()
    latest = 0.0
    for peer, life in h.last_lives().items():
        if among is not None and peer not in among:
            continue
        if life["up"] is None:
            return None
        known = set(life.get("known", []))
        when = life["up"]
        for m in sorted(merges.get((peer, life["life"]), []), key=lambda e: e["t"]):
            if m["kind"] == Event.FORGOTTEN:
                known.discard(m["sequence"])
            elif m["sequence"] in h.items and m["sequence"] not in known:
                known.add(m["sequence"])
                when = max(when, m["t"])
        if not set(h.items) <= known:
            return None
        latest = max(latest, when)
    return latest


def reference_time(h: History) -> float:
    ref = h.one("reference")
    return float(ref["at"]) if ref is not None else 0.0


def _convergence(h: History) -> Verdict:
    done, ref, bound = convergence_time(h), reference_time(h), float(h.config["bound"])
    if done is None:
        missing = []
        merges = h.merges()
        for peer, life in h.last_lives().items():
            known = set(life.get("known", [])) | {
                m["sequence"] for m in merges.get((peer, life["life"]), [])
            }
            if not set(h.items) <= known:
                missing.append(f"{peer} ({len(known & set(h.items))}/{len(h.items)})")
        return Verdict("convergence", "fail", "never knew every item: " + ", ".join(missing))
    dead = h.unplanned_exits()
    if dead:
        return Verdict("convergence", "fail", "peers died: " + "; ".join(dead[:5]))
    short = []
    for e in h.of("final"):
        if e["peer"] in h.learners and isinstance(e["saved"], dict):
            lacks = set(h.items) - set(e["saved"])
            if lacks:
                short.append(f"{e['peer']} saved {len(h.items) - len(lacks)}/{len(h.items)}")
    if short:
        return Verdict("convergence", "fail", "save files short: " + ", ".join(short[:5]))
    took = max(0.0, done - ref)
    status: Outcome = "pass" if took <= bound else "fail"
    return Verdict("convergence", status, f"{took:.2f} s after the reference (bound {bound:g} s)")


def _no_duplicates(h: History) -> Verdict:
    lives, dups = h.lives(), []
    for (peer, number), merged in h.merges().items():
        known = set(lives.get((peer, number), {}).get("known", []))
        for m in sorted(merged, key=lambda e: e["t"]):
            if m["sequence"] in known:
                dups.append(f"{peer} life {number}: {m['sequence']} at {m['t']:.2f} s")
            known.add(m["sequence"])
    if dups:
        return Verdict("no duplicate merge", "fail", "; ".join(dups[:5]))
    total = len(h.of(Event.MERGED))
    return Verdict("no duplicate merge", "pass", f"{total} merges, each once per peer life")


def _saved_files(h: History) -> Verdict:
    finals, bad = h.of("final"), []
    if not finals:
        return Verdict("saved files", "fail", "no save file was read at the end")
    for e in finals:
        saved = e["saved"]
        if isinstance(saved, str):
            bad.append(f"{e['peer']}: {saved}")
            continue
        for sequence, dig in saved.items():
            if sequence not in h.items:
                bad.append(f"{e['peer']}: foreign item {sequence}")
            elif dig != h.items[sequence]:
                bad.append(f"{e['peer']}: {sequence} differs from its author's")
    if bad:
        return Verdict("saved files", "fail", "; ".join(bad[:5]))
    items = sum(len(e["saved"]) for e in finals)
    return Verdict(
        "saved files", "pass", f"{len(finals)} files, {items} items, every digest its author's"
    )


def _kills_lose_nothing(h: History) -> Verdict:
    kills = h.of("kill")
    if not kills:
        return Verdict("kill -9 loses nothing saved", "skipped", "no peer was killed")
    lives, merges, lost = h.lives(), h.merges(), []
    finals = {e["peer"]: e["saved"] for e in h.of("final")}
    for k in kills:
        saved = k["saved"]
        if isinstance(saved, str):
            lost.append(f"{k['peer']}: save file after the kill {saved}")
            continue
        after = lives.get((k["peer"], k["life"] + 1))
        if after is None:
            lost.append(f"{k['peer']}: never restarted after its kill")
            continue
        if after.get("knows") is not None and after["knows"] < len(saved):
            lost.append(f"{k['peer']}: restarted knowing {after['knows']} of {len(saved)} saved")
        again = {m["sequence"] for m in merges.get((k["peer"], k["life"] + 1), [])} & set(saved)
        if again:
            lost.append(f"{k['peer']}: learned again what it had saved: {sorted(again)}")
        final = finals.get(k["peer"])
        if isinstance(final, dict) and not set(saved) <= set(final):
            lost.append(f"{k['peer']}: its last save lacks {sorted(set(saved) - set(final))}")
    if lost:
        return Verdict("kill -9 loses nothing saved", "fail", "; ".join(lost[:5]))
    held = sum(len(k["saved"]) for k in kills)
    if held == 0:
        return Verdict(
            "kill -9 loses nothing saved", "skipped", f"{len(kills)} kills, nothing saved yet"
        )
    return Verdict(
        "kill -9 loses nothing saved", "pass", f"{len(kills)} kills, {held} saved items all kept"
    )


def knows_at(h: History, peer: str, t: float) -> set[str]:
    """What ``peer`` knew at ``t``, from its own timestamps: the life up at ``t`` (none if it
    was down), what that life started with, and its merges and forgettings until ``t``."""
    lives = h.lives()
    ended = {(e["peer"], e["life"]): e["t"] for e in h.of("kill")}
    current = None
    for (name, number), life in sorted(lives.items()):
        up = life["up"]
        if name == peer and up is not None and up <= t < ended.get((name, number), float("inf")):
            current = life
    if current is None:
        return set()
    known = set(current.get("known", []))
    for e in h.changes().get((peer, current["life"]), []):
        if e["t"] <= t:
            if e["kind"] == Event.FORGOTTEN:
                known.discard(e["sequence"])
            else:
                known.add(e["sequence"])
    return known & set(h.items)


def round_times(h: History) -> list[float | None]:
    """Each churn round's convergence, counted from the victims' return (the round's end) to
    the first moment every peer knew every item, before the next round began; None for a
    round that never converged."""
    starts = sorted(
        e["t"] for e in h.of("fault") if e["fault"] == "churn" and e["phase"] == "start"
    )
    ends = sorted(e["t"] for e in h.of("fault") if e["fault"] == "churn" and e["phase"] == "end")
    last = h.events[-1]["t"] if h.events else 0.0
    moments = sorted(
        {
            e["t"]
            for e in h.events
            if e["kind"] in (Event.MERGED, "up", Event.FORGOTTEN) and "t" in e
        }
    )
    out: list[float | None] = []
    for i, end in enumerate(ends):
        until = starts[i + 1] if i + 1 < len(starts) else max(last, end)
        took = None
        for t in [end, *(m for m in moments if end < m <= until)]:
            if all(knows_at(h, p, t) >= set(h.items) for p in h.peers):
                took = round(t - end, 3)
                break
        out.append(took)
    return out


def _rounds(h: History) -> Verdict:
    times, bound = round_times(h), float(h.config["bound"])
    if not times:
        return Verdict("churn rounds converge", "skipped", "no churn round ended")
    late = [
        f"round {i}: {'never' if t is None else f'{t:.2f} s'}"
        for i, t in enumerate(times, 1)
        if t is None or t > bound
    ]
    shown = ", ".join("never" if t is None else f"{t:.2f}" for t in times)
    if late:
        return Verdict("churn rounds converge", "fail", f"bound {bound:g} s: " + "; ".join(late))
    return Verdict("churn rounds converge", "pass", f"{len(times)} rounds: {shown} s")


def _faults(h: History) -> list[Verdict]:
    cfg, out = h.config, []
    starts = {e["fault"]: e for e in h.of("fault") if e["phase"] == "start"}
    ends = {e["fault"]: e for e in h.of("fault") if e["phase"] == "end"}
    skipped = {e["fault"]: e["reason"] for e in h.of("skipped")}
    if cfg["loss"]:
        ev = ends.get("loss", {}).get("evidence", {})
        if "loss" in skipped:
            out.append(Verdict("fault: loss", "skipped", skipped["loss"]))
        elif ev.get("dropped", 0) > 0:
            out.append(Verdict("fault: loss", "pass", f"{ev['dropped']} packets dropped"))
        else:
            out.append(Verdict("fault: loss", "fail", "no packet was dropped"))
    if cfg["delay"]:
        ev = ends.get("delay", {}).get("evidence", {})
        fastest = _fastest_answer(h)
        floor = 2 * float(cfg["delay"])
        if not ev.get("delayed_chunks"):
            out.append(Verdict("fault: delay", "fail", "no chunk was delayed"))
        elif fastest is not None and fastest < floor * 0.9:
            out.append(
                Verdict("fault: delay", "fail", f"an answer came in {fastest:.3f} s < {floor:g} s")
            )
        else:
            shown = "no answer timed" if fastest is None else f"fastest answer {fastest:.3f} s"
            out.append(
                Verdict("fault: delay", "pass", f"{ev['delayed_chunks']} chunks delayed; {shown}")
            )
    if cfg["partition"] and cfg["partition_kind"] != "none":
        out.append(_partition(h, starts, ends))
    if cfg["churn"]:
        kills = [k for k in h.of("kill") if k.get("returncode") == -9]
        expected = sum(len(v) for v in h.plan["victims"])
        if len(kills) == expected and expected:
            out.append(Verdict("fault: churn", "pass", f"{len(kills)} peers killed by SIGKILL"))
        else:
            out.append(
                Verdict("fault: churn", "fail", f"{len(kills)} of {expected} kills happened")
            )
    if not out:
        out.append(Verdict("faults", "skipped", "none scheduled (a baseline)"))
    return out


def _fastest_answer(h: History) -> float | None:
    """The quickest answer after its query, timed from the first sending of that query that
    could have reached the answer's sender: the broadcast, or the query sent to it alone
    (``to``), whichever came first. An open query is sent again to a peer that appears, which
    may have heard the broadcast already: its answer to the broadcast is not a quick answer to
    the second sending."""
    sent: dict[tuple[str, Any, Any], float] = {}
    for e in h.of(Event.QUERY_SENT):
        sent.setdefault((e["peer"], e.get("id"), e.get("to")), e["t"])
    times = []
    for e in h.of(Event.ANSWER_RECEIVED):
        key = (e["peer"], e.get("id"))
        sendings = [sent.get((*key, e.get("sender"))), sent.get((*key, None))]
        began = min((t for t in sendings if t is not None), default=None)
        if began is not None:
            times.append(e["t"] - began)
    return min(times) if times else None


STAGES = (
    ("start", "link"),
    ("link", "session"),
    ("session", "seen"),
    ("seen", "query"),
    ("query", "answer"),
    ("answer", "merge"),
)
"""The stages of one transfer's timeline (docs/results/fleet.md), in the order they happen
when the teacher comes last: its process start, the link between the two up (zenoh dials while
it opens the session), its session up (open returned; its liveliness is declared then), the
learner seeing that liveliness, the query that was answered sent, the answer received, the
merge. A stage whose end came before its start (a link that came up after the session) is left
out of that transfer's stages; the next stage holds the time."""


def timelines(h: History) -> list[dict[str, Any]]:
    """For every item a learner merged, the marks of its timeline (seconds since the run
    began; None where the record has no such mark): ``start`` (the teacher's process launch),
    ``session`` (its session up), ``link`` (the latest link between the two up, by the proxy,
    before the liveliness was seen), ``seen`` (the learner saw the teacher's liveliness),
    ``query`` (the query that was answered sent, to the teacher alone or to all), ``answer``,
    ``merge``; and ``knew``, when the teacher knew the item (a learner teaching onward)."""
    by_peer: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for e in h.events:
        if "peer" in e:
            by_peer[e["peer"]].append(e)
    links = h.of("link-up")
    teachers = {n["name"] for n in h.plan["nodes"] if n["role"] == "teacher"}

    def last(events: list[dict[str, Any]], until: float, **match: Any) -> dict[str, Any] | None:
        found = None
        for e in events:
            if e["t"] > until:
                break
            if all(e.get(k) == v for k, v in match.items()):
                found = e
        return found

    out = []
    for m in h.of(Event.MERGED):
        learner, teacher, t = m["peer"], m.get("teacher"), m["t"]
        if teacher is None or m["sequence"] not in h.items:
            continue
        mine, theirs = by_peer[learner], by_peer.get(teacher, [])
        marks: dict[str, Any] = {"learner": learner, "teacher": teacher, "merge": t}
        answer = last(mine, t, kind=Event.ANSWER_RECEIVED, sender=teacher,
                      sequence=m["sequence"])  # fmt: skip
        marks["answer"] = answer["t"] if answer else None
        query = None
        if answer is not None:
            query = last(mine, answer["t"], kind=Event.QUERY_SENT, id=answer.get("id"), to=teacher)
            query = query or last(mine, answer["t"], kind=Event.QUERY_SENT, id=answer.get("id"))
        marks["query"] = query["t"] if query else None
        launch = last(theirs, t, kind="launch")
        start = launch["t"] if launch else None
        marks["start"] = start
        session = next(
            (e for e in theirs if e["kind"] == Event.SESSION_UP and start is not None
             and e["t"] >= start - 0.05 and e["t"] <= t),
            None,
        )  # fmt: skip
        marks["session"] = session["t"] if session else None
        seen = last(mine, marks["query"] or t, kind=Event.PEER_SEEN, sender=teacher)
        marks["seen"] = seen["t"] if seen else None
        link = None
        for e in links:
            if e["t"] > (marks["seen"] or t):
                break
            if {e["dialer"], e["listener"]} == {learner, teacher}:
                link = e
        marks["link"] = link["t"] if link else None
        if teacher in teachers:
            marks["knew"] = start
        else:
            knew = last(theirs, t, kind=Event.MERGED, sequence=m["sequence"])
            marks["knew"] = knew["t"] if knew else start
        out.append(marks)
    return out


def stage_times(lines: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Median and worst of each stage over ``lines`` (seconds; a stage whose marks a line
    lacks, or that ran backwards, such as a teacher seen before it knew the item, is left out
    for that line)."""
    out: dict[str, dict[str, float]] = {}
    for a, b in STAGES:
        spans = sorted(
            line[b] - line[a]
            for line in lines
            if line.get(a) is not None and line.get(b) is not None and line[b] >= line[a]
        )
        if spans:
            out[f"{a}-{b}"] = {
                "median": round(statistics.median(spans), 4),
                "worst": round(spans[-1], 4),
                "count": len(spans),
            }
    return out


def _learned_at(life: dict[str, Any], changes: list[dict[str, Any]], sequence: str) -> float | None:
    """When a peer's ``life`` (its last) came to know ``sequence`` for good: its up if it
    started knowing it, else its merge after which it was not forgotten; None if it did not."""
    if life["up"] is None:
        return None
    when: float | None = life["up"] if sequence in life.get("known", []) else None
    for e in sorted(changes, key=lambda e: e["t"]):
        if e.get("sequence") != sequence:
            continue
        if e["kind"] == Event.FORGOTTEN:
            when = None
        elif when is None:
            when = max(e["t"], life["up"])
    return when


def hops(h: History) -> list[dict[str, Any]]:
    """Hop by hop, per item: who taught whom (``tree``: each peer's teacher of the item, from
    its last life's merge), the tree's ``depth`` (the most hops from a teacher along it; a hop
    whose teacher's own learning the record lacks ends the count there), the graph's
    ``eccentricity`` (the longest shortest path from the teachers, plan.distances), the time
    after the reference at which the last peer that far knew the item
    (``last_at_eccentricity_s``) and that time over the distance (``per_hop_s``: what one hop
    took on the longest shortest path). ``detours`` counts the peers that learned along a
    longer path than their shortest, ``off_graph`` the hops between peers not linked (a
    transport that routes through peers)."""
    dist = distances(h.plan)
    near = neighbours(h.plan)
    teachers = {n["name"] for n in h.plan["nodes"] if n["role"] == "teacher"}
    merges = sorted(
        (e for e in h.of(Event.MERGED) if e.get("teacher") is not None), key=lambda e: e["t"]
    )
    ref = reference_time(h)
    ecc = max(dist.values(), default=0)
    lives, changes = h.last_lives(), h.changes()
    last = {peer: life["life"] for peer, life in lives.items()}
    out = []
    for sequence in h.items:
        tree: dict[str, str] = {}
        depths: dict[str, int | None] = {}
        # Each peer's hops from a teacher at its latest merge of the item so far (merges in
        # time order: a teacher's own merge comes before what it teaches).
        latest: dict[str, int | None] = {}
        for e in (e for e in merges if e["sequence"] == sequence):
            teacher = e["teacher"]
            up = 0 if teacher in teachers else latest.get(teacher)
            latest[e["peer"]] = None if up is None else up + 1
            if last.get(e["peer"]) == e["life"]:
                tree[e["peer"]] = teacher
                depths[e["peer"]] = latest[e["peer"]]
        known = [d for d in depths.values() if d is not None]
        farthest = [
            _learned_at(lives[p], changes.get((p, last[p]), []), sequence) if p in lives else None
            for p, d in dist.items()
            if d == ecc and ecc
        ]
        at = None
        if farthest and None not in farthest:
            at = round(max(0.0, max(t for t in farthest if t is not None) - ref), 3)
        out.append({
            "item": sequence,
            "tree": tree,
            "depth": max(known, default=None),
            "eccentricity": ecc,
            "last_at_eccentricity_s": at,
            "per_hop_s": None if at is None or not ecc else round(at / ecc, 4),
            "detours": sum(1 for p, d in depths.items() if d is not None and d > dist.get(p, d)),
            "off_graph": sum(1 for p, t in tree.items() if t not in near.get(p, ())),
        })  # fmt: skip
    return out


def _partition(h: History, starts: dict[str, Any], ends: dict[str, Any]) -> Verdict:
    name = f"partition-{h.config['partition_kind']}"
    start, end = starts.get(name), ends.get(name)
    if start is None or end is None:
        return Verdict(f"fault: {name}", "fail", "the partition never started or never healed")
    ev = end.get("evidence", {})
    if name == "partition-silent":
        injected = ev.get("chunks_held", 0) + ev.get("connections_held", 0)
        held, waiting = ev.get("chunks_held", 0), ev.get("connections_held", 0)
        what = f"{held} chunks and {waiting} connections held"
    else:
        injected = ev.get("resets", 0) + ev.get("refused", 0)
        what = f"{ev.get('resets', 0)} connections reset, {ev.get('refused', 0)} refused"
    if not injected:
        return Verdict(f"fault: {name}", "fail", "nothing was held or cut on the crossing links")
    half = start.get("half", {})
    leaks = [
        f"{e['peer']} heard {e['sender']} at {e['t']:.2f} s"
        for e in h.of(Event.ANSWER_RECEIVED)
        if start["t"] < e["t"] < end["t"] - 0.5
        and e.get("sender") in half
        and half.get(e["peer"]) != half.get(e["sender"])
    ]
    if leaks:
        return Verdict(f"fault: {name}", "fail", "answers crossed it: " + "; ".join(leaks[:3]))
    return Verdict(f"fault: {name}", "pass", f"{what}; no answer crossed it")


def _bounded(h: History) -> Verdict:
    rounds = [e for e in h.of("fault") if e["fault"] == "churn" and e["phase"] == "start"]
    if len(rounds) < 2:
        return Verdict("memory and descriptors bounded", "skipped", "needs two churn rounds")
    killed = {k["peer"] for k in h.of("kill")}
    first = rounds[1]["t"]  # after the first round: every peer up and settled once
    before: dict[str, dict[str, Any]] = {}
    after: dict[str, dict[str, Any]] = {}
    for s in h.of("sample"):
        if s["peer"] in killed:
            continue
        if s["t"] <= first:
            before[s["peer"]] = s
        else:
            after[s["peer"]] = s
    both = sorted(set(before) & set(after))
    if not both:
        return Verdict("memory and descriptors bounded", "skipped", "no samples across rounds")
    peers = [p for p in both if p != "runner"]
    growth = [
        (after[p]["rss_kb"] - before[p]["rss_kb"] - RSS_SLACK_KB) / before[p]["rss_kb"]
        for p in peers
    ]
    median = statistics.median(growth) if growth else 0.0
    fds = {p: after[p]["fds"] - before[p]["fds"] for p in both}
    worst = max(fds, key=lambda p: fds[p])
    detail = (
        f"{len(rounds)} rounds: median RSS growth {max(median, 0.0) * 100:.1f} % "
        f"(bound {RSS_GROWTH * 100:g} %), most descriptors gained {fds[worst]} ({worst})"
    )
    ok = median <= RSS_GROWTH and fds[worst] <= FD_GROWTH
    return Verdict("memory and descriptors bounded", "pass" if ok else "fail", detail)


def _monitor(h: History) -> list[Verdict]:
    """With ``--monitor``: the monitor, asked at the end, showed every peer present and what
    the peers' own logs say each knew at some time between :data:`SHOWN_WITHIN` seconds
    before it was asked and when it answered (a merge reaches the page within that). No
    verdict for a run watched by no monitor; skipped for one that did not reach its end."""
    if not h.config.get("watch"):
        return []
    name = "the monitor shows what the peers know"
    seen = h.one("monitor")
    if seen is None and h.of("aborted"):
        return [Verdict(name, "skipped", "the run did not reach its end")]
    if seen is None or "knows" not in seen:
        why = "no view of the monitor recorded" if seen is None else seen.get("error")
        return [Verdict(name, "fail", str(why))]
    since, until = seen.get("asked", seen["t"]) - SHOWN_WITHIN, seen["t"]
    wrong = []
    for peer in h.peers:
        if peer not in seen["knows"]:
            wrong.append(f"{peer} not shown")
            continue
        if seen["status"].get(peer) != "present":
            wrong.append(f"{peer} shown {seen['status'].get(peer)}, not present")
        shown = set(seen["knows"][peer])
        moments = [since, until] + [
            e["t"] for e in h.events
            if e["kind"] in (Event.MERGED, Event.FORGOTTEN, "up", "kill")
            and e.get("peer") == peer
            and since <= e["t"] <= until
        ]  # fmt: skip
        if not any(shown == knows_at(h, peer, t) for t in moments):
            known = knows_at(h, peer, until)
            extra, missing = sorted(shown - known), sorted(known - shown)
            wrong.append(f"{peer}: shown but not known {extra}, known but not shown {missing}")
    if wrong:
        return [Verdict(name, "fail", "; ".join(wrong)[:500])]
    detail = (
        f"{len(h.peers)} peers present and what each knows, {seen['waited']:g} s after the "
        f"settle; {seen['events']} events, dropped {seen['drops'] or 'none'}"
    )
    return [Verdict(name, "pass", detail)]


def _groups(h: History) -> list[Verdict]:
    """Through routers: every router group lived in a network namespace of its own, apart from
    the others and from the runner's (each member's namespace, read from ``/proc`` when it came
    up, is its group's), and every link between groups carried bytes through its proxy, the
    only path between them. Skipped, with why, where namespaces could not be made; no verdict
    for a fleet without routers (or a record from before groups had namespaces)."""
    seen = h.one("groups")
    group: dict[str, int] = h.plan.get("group") or {}
    if seen is None or not group:
        return []
    name = "router groups in namespaces of their own"
    if "skipped" in seen:
        return [Verdict(name, "skipped", str(seen["skipped"]))]
    inode = {int(g): space.get("inode") for g, space in seen["namespaces"].items()}
    wrong = []
    if None in inode.values() or len(set(inode.values()) | {seen.get("runner")}) != len(inode) + 1:
        wrong.append(f"the groups' namespaces are not apart: {inode}, runner {seen.get('runner')}")
    members: Counter[int] = Counter()
    for e in h.of("up"):
        g = group.get(e["peer"])
        if g is None:
            continue
        if e.get("netns") != inode.get(g):
            wrong.append(f"{e['peer']} life {e['life']} was not in group {g}'s namespace")
        else:
            members[g] += 1
    between = [li for li in h.plan["links"] if group[li["dialer"]] != group[li["listener"]]]
    counted = (h.one("counters") or {}).get("links", {})
    carried = {li["index"]: counted.get(str(li["index"]), {}).get("bytes", 0) for li in between}
    wrong += [f"the link between groups {i} carried nothing" for i, b in carried.items() if not b]
    if wrong:
        return [Verdict(name, "fail", "; ".join(wrong)[:500])]
    shown = ", ".join(f"{members[g]}" for g in sorted(inode))
    detail = (
        f"{len(inode)} groups, each in a namespace of its own (processes up there: {shown});"
        f" {len(between)} links between them carried {sum(carried.values())} bytes"
    )
    return [Verdict(name, "pass", detail)]


def honest_refusals(h: History) -> dict[str, int]:
    """Refusals of what a fleet peer sent. Every fleet peer is honest, so each one is an honest
    answer turned away; most are answers arriving after the question was closed (another
    neighbour answered first), which a peer refuses as "an answer to no open question"."""
    peers = set(h.peers)
    honest = [
        e for e in h.of(Event.REFUSED)
        if str(e.get("reason", "")).removeprefix("from ").split(":", 1)[0] in peers
    ]  # fmt: skip
    late = [e for e in honest if "an answer to no open question" in str(e.get("reason", ""))]
    return {
        "honest_answers_refused": len(honest),
        "late_answers_refused": len(late),
        "late_answers": len(h.of(Event.LATE_ANSWER)),
    }


def redials(h: History) -> dict[str, int]:
    """How many of the fleet's links came up (``links_up``) and how many times one came up
    again after its first (``links_redialled``: a link closed, by a fault, a kill or its lease,
    and dialled again), before the floor's probe opened a link of its own. In a fleet without
    faults every redial is a healthy link given up: what a lease too short for the load costs
    (spec/protocol.md section 3)."""
    probing = h.one("probing")
    until = float("inf") if probing is None else probing["t"]
    ups = Counter(e["link"] for e in h.of("link-up") if e["t"] < until)
    return {"links_up": len(ups), "links_redialled": sum(ups.values()) - len(ups)}


def given_up(h: History) -> float | None:
    """How long a link that went silent was kept: from the start of a silent partition to the
    first connection its dialer made again through the held link (the lease, plus up to one
    retry period), the median over the links that crossed it; None without such a
    partition or redial (spec/protocol.md section 3)."""
    start = next(
        (e for e in h.of("fault") if e["fault"] == "partition-silent" and e["phase"] == "start"),
        None,
    )
    if start is None:
        return None
    first: dict[int, float] = {}
    for e in h.of("dialled-held"):
        if e["t"] >= start["t"]:
            first.setdefault(e["link"], e["t"] - start["t"])
    return round(statistics.median(first.values()), 3) if first else None


def idle_cost(h: History) -> dict[str, Any]:
    """What a peer costs when nothing is left to learn: from the samples of the settle window
    (from convergence to the end; the runner samples every process every 2 s), each process's
    CPU time over the window's length (ms a second) and its last resident memory (MB), the
    median and the worst by role (learner, teacher, router). Empty when the fleet did not
    converge or a process has fewer than two samples in the window (a record from before CPU
    time was sampled)."""
    done = h.one("converged")
    if done is None or done.get("at") is None:
        return {}
    roles = {n["name"]: n["role"] for n in h.plan["nodes"]}
    window: dict[tuple[str, int], list[dict[str, Any]]] = defaultdict(list)
    for s in h.of("sample"):
        if s["t"] >= done["t"] and s["peer"] in roles and "cpu_ms" in s:
            window[(s["peer"], s["life"])].append(s)
    cpu: dict[str, list[float]] = defaultdict(list)
    rss: dict[str, list[float]] = defaultdict(list)
    spans = []
    for (peer, _), samples in window.items():
        first, last = samples[0], samples[-1]
        if last["t"] - first["t"] < 1.0:
            continue
        spans.append(last["t"] - first["t"])
        cpu[roles[peer]].append((last["cpu_ms"] - first["cpu_ms"]) / (last["t"] - first["t"]))
        rss[roles[peer]].append(last["rss_kb"] / 1024)
    if not spans:
        return {}

    def spread(values: list[float]) -> dict[str, float]:
        return {"median": round(statistics.median(values), 2), "worst": round(max(values), 2)}

    return {
        "window_s": round(min(spans), 2),
        "cpu_ms_per_s": {role: spread(v) for role, v in sorted(cpu.items())},
        "rss_mb": {role: spread(v) for role, v in sorted(rss.items())},
    }


MESSAGES = (Event.QUERY_SENT, Event.ANSWER_SENT, Event.ANNOUNCED)
"""What a run's messages are (``messages_per_item``): every query sent (to all, or to one peer),
every answer sent and every announcement of what a peer learned (one put, however many
neighbours hear it; spec/protocol.md section 4.5)."""


def metrics(h: History) -> dict[str, Any]:
    """The numbers of a run: convergence after the reference, messages per learned item..."""
    done, ref = convergence_time(h), reference_time(h)
    counted = [e for e in h.events if e["kind"] in MESSAGES]
    messages = len([e for e in counted if e.get("to") != "fleet-probe"])
    merged = len(h.of(Event.MERGED))
    up = h.one("all-up")
    half = {p for p, side in h.plan["half"].items() if side == 0}
    teacher_half = convergence_time(h, half) if half and up is not None else None
    floor = h.one("floor") or {}
    rounds = round_times(h)
    lines = timelines(h)
    after = [line for line in lines if line["merge"] >= ref]
    per_item = hops(h)
    per_hop = [i["per_hop_s"] for i in per_item]
    depths = [i["depth"] for i in per_item if i["depth"] is not None]
    return {
        "hops": per_item,
        "eccentricity": max((i["eccentricity"] for i in per_item), default=None),
        "tree_depth": max(depths, default=None),
        "per_hop_s": None if not per_hop or None in per_hop else max(per_hop),
        "stages": stage_times(lines),
        "stages_after_reference": stage_times(after),
        "convergence_s": None if done is None else round(max(0.0, done - ref), 3),
        "all_up_s": None if up is None else up["t"],
        "reference_s": ref,
        "teacher_half_s": None
        if teacher_half is None or up is None
        else round(max(0.0, teacher_half - up["t"]), 3),
        "churn_convergence_s": None
        if not rounds or None in rounds
        else round(max(r for r in rounds if r is not None), 3),
        "messages": messages,
        "learned": merged,
        "messages_per_item": round(messages / merged, 2) if merged else None,
        "floor_s": floor.get("median_s"),
        "floor_proxied_s": (floor.get("proxied") or {}).get("median_s"),
        "refused": len(h.of(Event.REFUSED)),
        **honest_refusals(h),
        **redials(h),
        "silent_link_given_up_s": given_up(h),
        "error_replies": len(h.of(Event.ERROR_RECEIVED)),
        "network_errors": len(h.of(Event.NETWORK_ERROR)),
        "idle": idle_cost(h),
    }


def check_record(folder: Path) -> dict[str, Any]:
    """Check a run's record; the summary the runner writes to ``summary.json``."""
    events = read_record(folder / "events.jsonl")
    h = History(events)
    verdicts = check(events)
    return {
        "name": h.config["name"],
        "config": h.config,
        "faults": [v.name for v in verdicts if v.name.startswith("fault")],
        "verdicts": [asdict(v) for v in verdicts],
        "passed": all(v.status != "fail" for v in verdicts),
        **metrics(h),
    }
