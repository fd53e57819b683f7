"""``ktbt fleet run``: real ``ktbt peer`` processes, each its own zenoh session on its own
loopback address, every link through the fault layer, a seeded fault schedule, and a record.

The record (``events.jsonl`` in the run's folder, times in seconds since the run began) is what
the checker reads: the plan, every process life (launch, up with what it knew, SIGKILL with what
its save file held), the peers' own exchange events copied from their ``--log`` files, every
fault's window with the counters that prove it happened, memory and file-descriptor samples,
and every save file at the end. Peers are observed only through what they write.

With packet loss (or whenever the machine allows), the run happens inside a network namespace
of its own: the runner starts itself again inside it (``ip netns exec``), and the outer process
deletes the namespace, rules and all, whatever happens (Ctrl-C too). A fleet through routers
then has a namespace more for each router group (its router and the router's clients, started
there with ``ip netns exec``), joined to the others only by the proxies of the routers' links
(netns.socket_in); where namespaces cannot be made, the groups share the machine's loopback,
apart only by their addresses, and the record says why (check: the groups' namespaces).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import random
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any, TextIO

from ktbt_proto.exchange.transferlog import Event
from ktbt_proto.files import TooLarge, packaged, read_bounded, write_atomic
from ktbt_proto.items import item_digest, show_sequence
from ktbt_proto.tools.fleet import netns, watch
from ktbt_proto.tools.fleet.plan import FleetConfig, Host, Plan, make_plan, stream
from ktbt_proto.tools.fleet.proxy import FaultLayer
from ktbt_proto.transport.zenoh import stable_zid

Say = Callable[[str], None]
EXAMPLE_KNOWLEDGE = packaged("examples", "knowledge", "colours.sbt")
COPIED = frozenset(Event) - {Event.QUERY_RECEIVED}
"""The peers' exchange events copied into the record (a query received is counted only)."""
OUTPUTS = (
    "peers",
    "zenoh",
    "events.jsonl",
    "summary.json",
    "result.json",
    "config.json",
    "knowledge.png",
    "monitor.out",
)
"""What a run writes in its folder (and removes there before it starts)."""


def authored_items(path: str | Path) -> dict[str, str]:
    """The teachers' items: sequence key -> the item's digest (``items.item_digest``)."""
    from ktbt_proto.interop.knowledge_file import load_knowledge

    return {item.key: item_digest(item.key, item.subtree) for item in load_knowledge(path)}


def read_saved(path: Path) -> dict[str, str] | str:
    """A save file's items (sequence -> the item's digest, of the subtree as stored), or why it
    cannot be read. Read as data, not through the library, so that damage shows as damage."""
    from ktbt_proto.exchange.knowledge import MAX_FILE

    if not path.exists():
        return {}
    try:
        entries = json.loads(read_bounded(path, MAX_FILE))["knowledge"]
        items = {
            str(e["sequence"]): item_digest(str(e["sequence"]), str(e["subtree"])) for e in entries
        }
    except TooLarge:
        return f"unreadable: larger than {MAX_FILE} bytes"
    except (ValueError, KeyError, TypeError) as exc:
        return f"unreadable: {exc!r}"[:200]
    if len(items) != len(entries):
        twice = Counter(str(e["sequence"]) for e in entries)
        return f"unreadable: items saved twice: {sorted(k for k, n in twice.items() if n > 1)}"[
            :200
        ]
    return items


class Record:
    """``events.jsonl``: one JSON object a line, flushed, with ``t`` relative to the start."""

    def __init__(self, path: Path, t0: float) -> None:
        self.t0 = t0
        self._file: TextIO = open(path, "w", encoding="utf-8")  # noqa: SIM115

    def now(self) -> float:
        return round(time.time() - self.t0, 3)

    def emit(self, kind: str, t: float | None = None, **fields: Any) -> None:
        entry = {"t": self.now() if t is None else round(t, 3), "kind": kind, **fields}
        self._file.write(json.dumps(entry, default=str) + "\n")
        self._file.flush()

    def close(self) -> None:
        self._file.close()


@dataclass
class Life:
    number: int
    proc: subprocess.Popen[bytes]
    out: Path
    started: float
    known: set[str]
    ready: Path
    """Where this life says it is up (``ktbt peer ... --ready``): a JSON object, written whole."""
    up: float | None = None


@dataclass
class PeerProcess:
    """A peer or router process and what the run has seen of it."""

    node: Host
    folder: Path
    lives: list[Life] = field(default_factory=list)
    log_offset: int = 0
    counts: Counter[str] = field(default_factory=Counter)

    @property
    def log(self) -> Path:
        return self.folder / f"{self.node.name}.log"

    @property
    def save(self) -> Path:
        return self.folder / f"{self.node.name}.json"

    @property
    def life(self) -> Life | None:
        return self.lives[-1] if self.lives else None

    @property
    def running(self) -> bool:
        return self.life is not None and self.life.proc.poll() is None

    @property
    def up(self) -> bool:
        return self.running and self.life is not None and self.life.up is not None


class FleetRun:
    """Runs one scenario (inside whatever network namespace the caller chose)."""

    def __init__(
        self,
        config: FleetConfig,
        out: Path,
        say: Say,
        live: bool,
        loss_note: str | None,
        groups: tuple[str, ...] = (),
        apart_note: str | None = None,
    ) -> None:
        self.config, self.out, self.say, self.live = config, out, say, live
        self.loss_note = loss_note
        """None when the loss rule is in place; otherwise why loss is skipped."""
        self.groups, self.apart_note = groups, apart_note
        """The network namespace of each router group (by the group's index), or none and why
        (``apart_note``)."""
        self.t0 = time.time()
        self.items = authored_items(config.knowledge or EXAMPLE_KNOWLEDGE)
        self.plan: Plan = make_plan(config, _port())
        self.members = {n.name: PeerProcess(n, out / "peers") for n in self.plan.nodes}
        self.spaces = {name: groups[g] for name, g in self.plan.group.items()} if groups else {}
        """Each fleet member's network namespace, if not the runner's."""
        self.layer = FaultLayer(
            self.plan.links, self.plan.port, config.delay, self._linked, self._dialled_held,
            spaces=self.spaces,
        )  # fmt: skip
        self.record = Record(out / "events.jsonl", self.t0)
        self.pause = stream(config.seed, "churn-pauses")
        self.teacher_program = "run" if config.teacher == "run" else "serve"
        self.faults_open: dict[str, dict[str, Any]] = {}
        self.last_sample = 0.0
        self.sampling = True
        self.bad = 0
        """Lines of the peers' logs that were not log entries (skipped)."""
        self.converged: float | None = None
        self.reference = 0.0

    # -- processes ----------------------------------------------------------------------------

    def _zenoh_config(self, node: Host) -> Path:
        path = self.out / "zenoh" / f"{node.name}.json5"
        # Only what the peers' own settings (ZenohSettings: mode, endpoints, retry, lease,
        # multicast off) do not give: no gossip (the fleet's links are the only paths) and, for
        # routers too, the stable zenoh id (a restarted peer is the same peer).
        conf: dict[str, Any] = {
            "scouting": {"gossip": {"enabled": False}},
            "id": stable_zid(node.name),
        }
        path.write_text(json.dumps(conf, indent=1))
        return path

    def _command(self, member: PeerProcess, ready: Path) -> list[str]:
        node, port = member.node, self.plan.port
        connect = [f"tcp/{link.proxy}:{port}" for link in self.plan.dials(node.name)]
        conf = ["--config", str(self._zenoh_config(node)), "--ready", str(ready)]
        conf += ["--retry", str(self.config.retry_ms), "--lease", str(self.config.lease_ms)]
        python = [sys.executable, "-m", "ktbt_proto", "peer"]
        if node.role == "router":
            args = [*python, "router", "--listen", f"tcp/{node.address}:{port}", *conf]
            if self.config.watch:
                args += ["--listen", watch.endpoint(self.config.watch, node.name)]
            return args + [a for c in connect for a in ("--connect", c)]
        endpoints = [a for c in connect for a in ("--connect", c)]
        if self.config.topology == "router":
            endpoints += ["--mode", "client"]
        else:
            endpoints += ["--listen", f"tcp/{node.address}:{port}"]
        if self.config.watch:  # the monitor's own link: a unix socket, outside the fault layer
            if self.config.topology != "router":
                endpoints += ["--listen", watch.endpoint(self.config.watch, node.name)]
            endpoints += ["--publish-events"]
        common = ["--id", node.name, "--log", str(member.log), *conf, *endpoints]
        knowledge = str(self.config.knowledge or EXAMPLE_KNOWLEDGE)
        robot = ["--vocabulary", self.config.vocabulary] if self.config.vocabulary else []
        if node.role == "teacher" and self.teacher_program == "serve":
            return [*python, "serve", "--knowledge", knowledge, *robot, *common]
        if self.config.control:
            robot += ["--control", self.config.control]
        args = [*python, "run", *common, *(robot or ["--demo"])]
        args += ["--save", str(member.save), "--duration", "31536000"]
        if node.role == "teacher":
            args += ["--knowledge", knowledge]
        else:  # the learners meet the knowledge file's sequences, and stop at nothing else
            args += [a for key in self.items for a in ("--sequence", show_sequence(key))]
        return args

    def launch(self, member: PeerProcess) -> None:
        number = len(member.lives) + 1
        out = member.folder / f"{member.node.name}.out.{number}"
        ready = member.folder / f"{member.node.name}.ready.{number}"
        ready.unlink(missing_ok=True)
        if member.node.role == "teacher":
            known = set(self.items)
        elif member.node.role == "learner":
            saved = read_saved(member.save)
            known = set(saved) if isinstance(saved, dict) else set()
        else:
            known = set()
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        command = self._command(member, ready)
        space = self.spaces.get(member.node.name)
        if space is not None:  # ip execs the command: the pid is the peer's
            command = ["ip", "netns", "exec", space, *command]
        with open(out, "wb") as sink:
            proc = subprocess.Popen(
                command, stdout=sink, stderr=subprocess.STDOUT, env=env,
                stdin=subprocess.DEVNULL, start_new_session=True,
            )  # fmt: skip
        member.lives.append(Life(number, proc, out, self.record.now(), known, ready))
        self.record.emit(
            "launch",
            peer=member.node.name,
            role=member.node.role,
            life=number,
            pid=proc.pid,
            known=sorted(known),
        )

    def kill(self, member: PeerProcess) -> None:
        """SIGKILL, as a crash: nothing is flushed or closed."""
        life = member.life
        if life is None or life.proc.poll() is not None:
            return
        os.kill(life.proc.pid, signal.SIGKILL)
        life.proc.wait()
        self._tail(member)
        saved = read_saved(member.save)
        self.record.emit(
            "kill", peer=member.node.name, life=life.number, pid=life.proc.pid,
            returncode=life.proc.returncode, saved=saved,
        )  # fmt: skip

    async def stop_all(self) -> None:
        """SIGTERM to every process, SIGKILL to those still up after a few seconds (a zenoh
        close can block under faults); each by its pid."""
        running = [m for m in self.members.values() if m.running]
        self.record.emit(
            "stopping", lives={m.node.name: m.life.number for m in running if m.life is not None}
        )
        procs = [m.life.proc for m in running if m.life is not None]
        for proc in procs:
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + 6
        while time.monotonic() < deadline and any(proc.poll() is None for proc in procs):
            await asyncio.sleep(0.1)
        for proc in procs:
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    proc.kill()
            proc.wait()

    # -- observation --------------------------------------------------------------------------

    def _tail(self, member: PeerProcess) -> None:
        life = member.life
        if life is not None and life.up is None and life.ready.exists():
            try:
                knows = json.loads(life.ready.read_bytes())["knows"]
            except (OSError, ValueError, TypeError, KeyError):
                knows = None  # up all the same: the file is there
            try:  # when the process wrote it, not when this loop looked
                life.up = round(min(life.ready.stat().st_mtime - self.t0, self.record.now()), 3)
            except OSError:
                life.up = self.record.now()
            self.record.emit(
                "up", t=life.up, peer=member.node.name, life=life.number,
                knows=knows if isinstance(knows, int) else None,
                netns=netns.of_process(life.proc.pid),
            )  # fmt: skip
        if member.node.role == "router" or not member.log.exists():
            return
        with open(member.log, "rb") as f:
            f.seek(member.log_offset)
            data = f.read()
        end = data.rfind(b"\n") + 1
        member.log_offset += end
        for raw in data[:end].splitlines():
            try:
                entry = json.loads(raw)
                event = entry.get("event")
                t = datetime.fromisoformat(entry["t"]).timestamp() - self.t0
            except (ValueError, TypeError, KeyError, AttributeError):
                self.bad += 1  # a line that is not a log entry: counted, never fatal
                continue
            if not isinstance(event, str):
                self.bad += 1
                continue
            member.counts[event] += 1
            if event not in COPIED:
                continue
            fields = {
                k: entry.get(k)
                for k in ("sequence", "more", "sender", "to", "id", "teacher", "where")
            }
            if event == "refused":
                fields["reason"] = str(entry.get("reason", ""))[:200]
            life = member.life
            if event == "merged" and life is not None and entry.get("sequence"):
                life.known.add(str(entry["sequence"]))
            if event == "forgotten" and life is not None and entry.get("sequence"):
                life.known.discard(str(entry["sequence"]))
            self.record.emit(
                event, t=t, peer=member.node.name, life=life.number if life else 0,
                **{k: v for k, v in fields.items() if v is not None},
            )  # fmt: skip

    def _linked(self, link: Any) -> None:
        """A connection of ``link`` reached its listener (the proxy says so): the link is up,
        a mark of the timelines (check.timelines)."""
        self.record.emit("link-up", link=link.index, dialer=link.dialer, listener=link.listener)

    def _dialled_held(self, link: Any) -> None:
        """A connection of ``link`` was accepted while the link is held: its dialer gave the
        silent link up and dialled again (how long that takes is the lease's work)."""
        self.record.emit("dialled-held", link=link.index)

    def knows(self, member: PeerProcess) -> set[str]:
        life = member.life
        return set() if life is None else life.known & set(self.items)

    def all_know(self) -> bool:
        peers = [m for m in self.members.values() if m.node.role != "router"]
        return all(m.up and self.knows(m) >= set(self.items) for m in peers)

    def _sample(self) -> None:
        for m in self.members.values():
            if m.running and m.life is not None:
                used = usage(m.life.proc.pid)
                if used is not None:
                    self.record.emit(
                        "sample", peer=m.node.name, life=m.life.number, rss_kb=used[0],
                        fds=used[1], cpu_ms=used[2],
                    )  # fmt: skip
        used = usage(os.getpid())
        if used is not None:
            self.record.emit(
                "sample", peer="runner", life=1, rss_kb=used[0], fds=used[1], cpu_ms=used[2]
            )

    def record_groups(self) -> None:
        """Which network namespace each router group has (the inode that names it, against
        which every member's own is held when it is up), and the runner's; or why the groups
        share one."""
        if not self.groups:
            note = self.apart_note or "the run has no network namespace"
            self.record.emit("groups", skipped=note)
            self.say(f"{self.config.name}: router groups share one loopback: {note}")
            return
        spaces = {
            str(g): {"name": name, "inode": netns.of_name(name)}
            for g, name in enumerate(self.groups)
        }
        self.record.emit("groups", namespaces=spaces, runner=netns.of_process(os.getpid()))

    async def observe(self, stop: asyncio.Event) -> None:
        live = None
        if self.live:
            from rich.live import Live

            live = Live(self.table(), refresh_per_second=2, transient=False)
            live.start()
        try:
            while not stop.is_set():
                for m in self.members.values():
                    self._tail(m)
                if self.converged is None and self.all_know():
                    self.converged = self.record.now()
                if self.sampling and time.monotonic() - self.last_sample > 2.0:
                    self.last_sample = time.monotonic()
                    self._sample()
                if live is not None:
                    live.update(self.table())
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), 0.2)
        finally:
            for m in self.members.values():
                self._tail(m)
            if live is not None:
                live.update(self.table())
                live.stop()

    def table(self) -> Any:
        from rich.table import Table

        faults = ", ".join(self.faults_open) or "none"
        table = Table(title=f"{self.config.name}: t={self.record.now():.1f}s, faults: {faults}")
        for column in ("peer", "state", "knows", "learned", "taught", "refused", "asked"):
            table.add_column(column)
        for m in self.members.values():
            state = "up" if m.up else ("starting" if m.running else "down")
            life = f" (life {len(m.lives)})" if len(m.lives) > 1 else ""
            knows = "" if m.node.role == "router" else f"{len(self.knows(m))}/{len(self.items)}"
            table.add_row(
                f"{m.node.name} {m.node.role}", state + life, knows, str(m.counts["merged"]),
                str(m.counts["answer-sent"]), str(m.counts["refused"]),
                str(m.counts["query-sent"]),
            )  # fmt: skip
        return table

    # -- the schedule -------------------------------------------------------------------------

    async def wait_up(self, names: list[str], limit: float) -> bool:
        deadline = time.monotonic() + limit
        while time.monotonic() < deadline:
            if all(self.members[n].up for n in names):
                return True
            dead = [n for n in names if not self.members[n].running]
            if dead:
                self.say(f"{self.config.name}: {', '.join(dead)} exited before coming up")
                return False
            await asyncio.sleep(0.1)
        return False

    def fault(self, name: str, phase: str, **fields: Any) -> None:
        if phase == "start":
            self.faults_open[name] = fields
        else:
            self.faults_open.pop(name, None)
        self.record.emit("fault", fault=name, phase=phase, **fields)
        self.say(f"{self.config.name}: t={self.record.now():.1f}s {name} {phase}")

    def _link_counters(self, links: list[int]) -> dict[str, int]:
        total: Counter[str] = Counter()
        counters = self.layer.counters()
        for i in links:
            total.update(counters[i])
        return dict(total)

    async def schedule(self) -> str | None:
        """Run the scenario; returns why it could not run to its end, or None.

        The learners come up first, then (with a partition, once it has begun on links already
        up) the teachers: the last peer up is a teacher, and convergence is the time its
        knowledge takes to reach every peer."""
        cfg, plan = self.config, self.plan
        teachers = [n.name for n in plan.peers if n.role == "teacher"]
        learners = [n.name for n in plan.peers if n.role == "learner"]
        if cfg.delay:
            self.fault("delay", "start", seconds=cfg.delay, links=[li.index for li in plan.links])
        for r in plan.routers:
            self.launch(self.members[r.name])
        if plan.routers and not await self.wait_up([r.name for r in plan.routers], 60):
            return "the routers did not come up"
        for name in learners:
            self.launch(self.members[name])
        if not await self.wait_up(learners, cfg.up_limit):
            down = [n for n in learners if not self.members[n].up]
            return f"not up within {cfg.up_limit:g} s: {', '.join(down)}"
        self.record.emit("learners-up")
        crossing = [link.index for link in plan.crossing()]
        cut = f"partition-{cfg.partition_kind}"
        injected = bool(cfg.partition) and cfg.partition_kind != "none"
        started = time.monotonic()
        if cfg.partition:
            await asyncio.sleep(1.0)  # the links between the halves are up
            started = time.monotonic()
        if injected:
            self.layer.apply(plan.crossing(), "held" if cfg.partition_kind == "silent" else "cut")
            self.fault(cut, "start", links=crossing, half=plan.half)
        for name in teachers:
            self.launch(self.members[name])
        if not await self.wait_up(teachers, cfg.up_limit):
            return "the teachers did not come up"
        up = [self.members[n].life for n in teachers]
        self.reference = max((life.up or 0.0) for life in up if life is not None)
        self.record.emit("all-up", t=self.reference)
        if injected:
            await asyncio.sleep(max(0.0, cfg.partition - (time.monotonic() - started)))
            evidence = self._link_counters(crossing)
            self.layer.apply(plan.crossing(), "open")
            self.fault(cut, "end", evidence=evidence)
            self.reference = self.record.now()
        for number, victims in enumerate(plan.victims, 1):
            # The first round strikes while the victims are still learning (what they saved
            # must come back, the rest be learned); later ones after the fleet has converged.
            await asyncio.sleep((0.1 if number == 1 else 0.5) + 0.5 * self.pause.random())
            self.fault("churn", "start", round=number, peers=victims)
            if number == 1:
                await self._kill_while_learning(victims, cfg.bound)
            for v in victims:
                self.kill(self.members[v])
            await asyncio.sleep(cfg.churn_down)
            for v in victims:
                self.launch(self.members[v])
            if not await self.wait_up(victims, cfg.up_limit):
                return f"churn round {number}: the restarted peers did not come up"
            self.fault("churn", "end", round=number, peers=victims)
            self.reference = self.record.now()
            if number < len(plan.victims):  # they learn again and run a while: a round
                if await self.until(self.all_know, cfg.bound):
                    self.record.emit("round-converged", round=number)
                await asyncio.sleep(1.0)
        self.record.emit("reference", at=self.reference)
        if self.converged is not None and self.converged < self.reference:
            self.converged = None
        await self.until(self.all_know, cfg.bound)
        self.converged = self.record.now() if self.all_know() else None
        self.record.emit("converged", at=self.converged)
        if plan.victims and self.converged is not None:
            self.record.emit("round-converged", round=len(plan.victims))
        self._sample()  # the settle window opens: nothing is left to learn (check.idle_cost)
        self.last_sample = time.monotonic()
        await asyncio.sleep(cfg.settle)
        if cfg.watch:
            await self.watched()
        self._sample()  # the last samples, before the probe opens a session here
        self.sampling = False  # the probe's session (its threads and sockets) is not the run's
        return None

    async def watched(self, limit: float = 10.0) -> None:
        """Record what the monitor shows (``/api/state`` on its unix socket), with when it was
        asked and when it answered: every peer and what it knows, once that agrees with what
        the peers' logs say or at ``limit`` seconds; the checker holds the two against each
        other."""
        began = time.monotonic()
        while True:
            asked = self.record.now()
            view = await asyncio.to_thread(watch.view, self.config.watch)
            agreed = view is not None and all(
                set(view["knows"].get(m.node.name, ())) == self.knows(m)
                and view["status"].get(m.node.name) == "present"
                for m in self.members.values()
                if m.node.role != "router"
            )
            if agreed or time.monotonic() - began > limit:
                break
            await asyncio.sleep(0.2)
        found = view or {"error": "the monitor did not answer on its socket (see monitor.out)"}
        self.record.emit("monitor", asked=asked, waited=round(time.monotonic() - began, 3), **found)

    async def _kill_while_learning(self, victims: list[str], limit: float) -> None:
        """Kill each victim once it has merged some items but not all (its log says so), so that
        the kill has something saved to lose; those never in that state die at the limit."""
        left, deadline = list(victims), time.monotonic() + limit
        while left and time.monotonic() < deadline:
            for v in list(left):
                if 0 < len(self.knows(self.members[v])) < len(self.items):
                    self.kill(self.members[v])
                    left.remove(v)
            await asyncio.sleep(0.02)

    async def until(self, done: Callable[[], bool], limit: float) -> bool:
        deadline = time.monotonic() + limit
        while not done():
            if time.monotonic() > deadline:
                return False
            await asyncio.sleep(0.05)
        return True

    async def floor(self) -> dict[str, Any]:
        """One query round trip to a teacher on a direct link (no proxy, no loss, no delay):
        the floor beside which convergence times are read; and one through a proxied link (its
        delay, loss and all) to the peer behind it, which knows every item by then."""
        teacher = next(n for n in self.plan.peers if n.role == "teacher")
        sequence = next(iter(self.items))
        self.record.emit("probing")  # the probe's own link is not one of the fleet's redials
        if self.config.topology == "router":
            direct = {"skipped": "teachers are clients of routers: no direct link to probe"}
        else:
            direct = await asyncio.to_thread(
                _probe, teacher.name, f"tcp/{teacher.address}:{self.plan.port}", sequence
            )
        roles = {n.name: n.role for n in self.plan.peers}
        link = next((li for li in self.plan.links if li.listener in roles), None)
        if link is None:
            proxied: dict[str, Any] = {"skipped": "no link listens on a peer"}
        else:
            endpoint = f"tcp/{link.proxy}:{self.plan.port}"
            proxied = await asyncio.to_thread(_probe, link.listener, endpoint, sequence)
            proxied["link"] = link.index
        return {**direct, "proxied": proxied}

    async def _finish(self, stop: asyncio.Event, watcher: asyncio.Task[None]) -> None:
        """The fault windows' ends, the last log lines and the save files, before the stop."""
        cfg = self.config
        try:
            if cfg.delay:
                self.fault("delay", "end", evidence=self._link_counters(list(self.layer.proxies)))
            if cfg.loss and self.loss_note is None:
                dropped = sum(netns.dropped(n) or 0 for n in (None, *self.groups))
                self.fault("loss", "end", evidence={"dropped": dropped})
        finally:
            stop.set()
            try:
                await watcher
            except Exception as exc:  # recorded: the run fails on it
                self.record.emit("aborted", reason=f"the observer crashed: {exc!r}"[:300])
        for m in self.members.values():
            if m.node.role == "learner" or self.teacher_program == "run":
                saved = read_saved(m.save) if m.node.role != "router" else {}
                self.record.emit("final", peer=m.node.name, saved=saved)

    async def run(self) -> dict[str, Any]:
        cfg = self.config
        (self.out / "peers").mkdir(parents=True, exist_ok=True)
        (self.out / "zenoh").mkdir(parents=True, exist_ok=True)
        self.record.emit(
            "run", config=cfg.to_json(), plan=self.plan.to_json(), items=self.items, t0=self.t0,
            teacher_program=self.teacher_program, netns=os.environ.get("KTBT_FLEET_NETNS"),
        )  # fmt: skip
        if self.plan.group:
            self.record_groups()
        if cfg.loss:
            if self.loss_note is None:
                self.fault("loss", "start", fraction=cfg.loss)
            else:
                self.record.emit("skipped", fault="loss", reason=self.loss_note)
                self.say(f"{cfg.name}: loss skipped: {self.loss_note}")
        await self.layer.start()
        stop = asyncio.Event()
        watcher = asyncio.create_task(self.observe(stop))
        problem: str | None = None
        probe: dict[str, Any] = {}
        try:
            try:
                problem = await self.schedule()
                if problem is None:
                    probe = await self.floor()
                    self.record.emit("floor", **probe)
            except asyncio.CancelledError:  # Ctrl-C or SIGTERM: clean up, record why
                problem = "interrupted"
            except Exception as exc:  # a crash is a failed run, never a passed one
                problem = f"crashed: {exc!r}"[:300]
        finally:
            # The processes are stopped first and whatever fails after: nothing outlives the run.
            try:
                await asyncio.shield(self._finish(stop, watcher))
            finally:
                await asyncio.shield(self.stop_all())
                try:
                    for m in self.members.values():
                        for life in m.lives:
                            self.record.emit(
                                "exit", peer=m.node.name, life=life.number,
                                returncode=life.proc.returncode,
                            )  # fmt: skip
                    self.record.emit("counters", links=self.layer.counters(), bad_lines=self.bad)
                    await asyncio.shield(self.layer.close())
                finally:
                    if problem is not None:
                        self.record.emit("aborted", reason=problem)
                    self.record.emit("end")
                    self.record.close()
        return {"problem": problem, "floor": probe}


def usage(pid: int) -> tuple[int, int, float] | None:
    """A process's resident memory (kB), open descriptors and CPU time so far (user and
    system, ms), from ``/proc``: the CPU time of two samples over the time between them is
    what the process costs a second (check.idle_cost, study.idle_alone)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
        fds = len(os.listdir(f"/proc/{pid}/fd"))
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    found = re.search(r"VmRSS:\s+(\d+)", status)
    fields = stat.rsplit(")", 1)[-1].split()  # after the command name, which may hold spaces
    try:
        ticks = int(fields[11]) + int(fields[12])  # utime and stime (fields 14 and 15)
    except (IndexError, ValueError):
        return None
    cpu_ms = ticks * 1000.0 / os.sysconf("SC_CLK_TCK")
    return (int(found.group(1)) if found else 0), fds, cpu_ms


def _port() -> int:
    """A port free on 127.0.0.1, used on every fleet address (each its own address)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def _probe(teacher: str, endpoint: str, sequence: str, rounds: int = 20) -> dict[str, Any]:
    from ktbt_proto.exchange.messages import Query, encode
    from ktbt_proto.transport.zenoh import PREFIX, ZenohSettings, open_session

    session = open_session(ZenohSettings(connect=[endpoint]))
    times: list[float] = []
    try:
        deadline = time.monotonic() + 10
        key = f"{PREFIX}/knowledge/{teacher}"
        while len(times) < rounds and time.monotonic() < deadline:
            query = Query(id=Query.new_id(), sender="fleet-probe", sequence=sequence)
            began = time.perf_counter()
            for reply in session.get(key, payload=encode(query), timeout=2.0):
                if reply.ok is not None:
                    times.append(time.perf_counter() - began)
                    break
    finally:
        session.close()  # type: ignore[no-untyped-call]
    if not times:
        return {"skipped": "the teacher did not answer the probe"}
    times.sort()
    return {"rounds": len(times), "median_s": times[len(times) // 2], "min_s": times[0]}


def run_inside(
    config: FleetConfig,
    out: Path,
    say: Say,
    live: bool,
    loss_note: str | None,
    groups: tuple[str, ...] = (),
    apart_note: str | None = None,
) -> Any:
    """One scenario here; SIGINT and SIGTERM stop its schedule, and everything it started is
    still stopped and recorded."""

    async def main() -> dict[str, Any]:
        fleet = FleetRun(config, out, say, live, loss_note, groups, apart_note)
        task = asyncio.current_task()
        if task is None:  # asyncio.run always runs main() as a task
            raise RuntimeError("run_inside's main() is not running as a task")
        loop = asyncio.get_running_loop()
        stopping: list[int] = []

        def interrupt(sig: int) -> None:
            # The first signal stops the schedule; later ones would land in the cleanup and
            # leave peers behind, so they are only counted.
            stopping.append(sig)
            if len(stopping) == 1:
                task.cancel()

        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, interrupt, sig)
        return await fleet.run()

    return asyncio.run(main())


def run(
    config: FleetConfig, out: Path, say: Say, live: bool = False, monitor: str | None = None
) -> dict[str, Any]:
    """Run one scenario and check it; inside a namespace of its own where the machine allows
    (needed for loss; through routers, a namespace more for each router group), else on the
    machine's loopback with loss skipped and the router groups apart only by their
    addresses. With ``monitor``
    (HOST:PORT), ``ktbt monitor`` watches the fleet from this machine's loopback for the
    whole run. Returns the summary (also written to ``summary.json``)."""
    from ktbt_proto.tools.fleet.check import check_record

    out.mkdir(parents=True, exist_ok=True)
    for old in OUTPUTS:  # a previous run's files, never anything else
        target = out / old
        if target.is_dir():
            shutil.rmtree(target)
        elif target.exists():
            target.unlink()
    why = netns.unavailable(need_nft=bool(config.loss))
    ended: list[str] = []
    previous = signal.signal(signal.SIGTERM, _interrupt)  # as Ctrl-C: everything is stopped
    try:
        with contextlib.ExitStack() as stack:
            if monitor is not None:
                watching = stack.enter_context(watch.watching(config, monitor, out, say))
                config, ended = watching.config, watching.ended
            if why is None:
                result = _in_namespace(config, out, live)
            else:
                note = why if config.loss else None
                result = run_inside(config, out, say, live, note, apart_note=why)
    finally:
        signal.signal(signal.SIGTERM, previous)
    summary = check_record(out)
    summary["aborted"] = result.get("problem") or (ended[0] if ended else None)
    summary["passed"] = summary["passed"] and summary["aborted"] is None
    write_atomic(out / "summary.json", json.dumps(summary, indent=1, default=str))
    return summary


def _in_namespace(config: FleetConfig, out: Path, live: bool) -> dict[str, Any]:
    name = f"ktbt-fleet-{os.getpid()}-{random.randrange(1 << 20):x}"
    groups = [f"{name}-g{g}" for g in range(config.router_count)]
    made: list[str] = []
    proc: subprocess.Popen[bytes] | None = None
    try:
        for space in [name, *groups]:
            netns.create(space)
            made.append(space)
        note = None
        if config.loss:
            try:
                for space in made:
                    netns.add_loss(space, config.loss)
            except OSError as exc:
                note = str(exc)
        spec = {"config": config.to_json(), "loss": note, "groups": groups}
        write_atomic(out / "config.json", json.dumps(spec))
        proc = subprocess.Popen(
            ["ip", "netns", "exec", name, sys.executable, "-m", "ktbt_proto.tools.fleet.runner",
             str(out), "--live" if live else "--quiet"],
            env={**os.environ, "KTBT_FLEET_NETNS": name},
            start_new_session=True,  # it hears exactly one signal: the one sent here
        )  # fmt: skip
        previous = signal.signal(signal.SIGTERM, _interrupt)
        try:
            proc.wait()
        except KeyboardInterrupt:  # tell the inner runner once; later signals are ignored
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(signal.SIGINT)
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=60)
        finally:
            signal.signal(signal.SIGTERM, previous)
        result_file = out / "result.json"
        if result_file.exists():
            result: dict[str, Any] = json.loads(result_file.read_text())
            return result
        return {"problem": f"the runner in the namespace exited with {proc.returncode}"}
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        for space in reversed(made):
            netns.delete(space)


def _interrupt(*_: object) -> None:
    raise KeyboardInterrupt


def main() -> None:
    """Inside the namespace: ``python -m ktbt_proto.tools.fleet.runner OUT [--live]``."""
    out = Path(sys.argv[1])
    spec = json.loads((out / "config.json").read_text())
    config = FleetConfig(**spec["config"])
    live = "--live" in sys.argv[2:]

    def say(text: str) -> None:
        if not live:
            print(text, flush=True)

    result = run_inside(config, out, say, live, spec["loss"], tuple(spec.get("groups", ())))
    write_atomic(out / "result.json", json.dumps(result, default=str))


if __name__ == "__main__":
    main()
