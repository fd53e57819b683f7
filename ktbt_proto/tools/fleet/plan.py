"""What a fleet run is: its peers, their loopback addresses, the links between them and the
seeded choices of its fault schedule (which half each peer is in, who is killed in which churn
round). Pure data, so that the same seed gives the same fleet and the same faults.

Learners come first, teachers last (``p0``..., then ``t``...). Addresses: peer ``k`` listens on
``127.1.x.y``, router ``r`` on ``127.3.0.(r+1)``, and link ``l``'s proxy on ``127.2.x.y`` (all
of 127.0.0.0/8 is local). With ``dial="one"`` (the default) the newer peer of a pair dials
the older (peer ``i`` dials ``j < i``; peers start in that order, so a newcomer connects out
at once to the peers it knows, spec/protocol.md section 3, and a restarted peer is dialled
again within its neighbours' retry period). With ``dial="both"`` both ends of a peer link
dial each other, each through a proxy of its own: twice the links and proxies, and at 40
peers a storm of links opened, closed and dialled again that holds the fleet for tens of
seconds (docs/results/fleet.md, size-40-both).
"""

from __future__ import annotations

import math
import random
import re
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

Topology = Literal["mesh", "line", "router"]
TOPOLOGIES: tuple[Topology, ...] = ("mesh", "line", "router")
Dial = Literal["one", "both"]
"""Who dials a peer link: the newer (higher) peer only, or both ends."""
PartitionKind = Literal["silent", "reset", "none"]
"""``none``: the same halves and schedule, nothing held or cut (a baseline for the half
with the teacher)."""
TeacherProgram = Literal["run", "serve"]
"""What a teacher runs: ``ktbt peer run --knowledge`` or ``ktbt peer serve``."""


class PlanError(ValueError):
    """A fleet that cannot be run as asked (too few peers, a partition without halves...)."""


def seconds(text: str) -> float:
    """``200ms``, ``30s``, ``1.5`` (seconds) or ``2m`` as seconds."""
    found = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*(ms|s|m)?\s*", text)
    if found is None:
        raise PlanError(f"not a duration: {text!r} (e.g. 200ms, 30s, 2m)")
    value, unit = float(found.group(1)), found.group(2) or "s"
    return value * {"ms": 0.001, "s": 1.0, "m": 60.0}[unit]


@dataclass(frozen=True)
class FleetConfig:
    """One scenario. ``loss`` is a fraction of packets dropped on every link in each direction
    (nftables); ``delay`` is one-way, added in each direction of every link (the proxy);
    ``partition`` the length of a half/half partition of links already up (0: none); ``churn``
    the fraction of learners killed with SIGKILL and restarted in each of ``churn_rounds``."""

    peers: int = 10
    teachers: int = 1
    topology: Topology = "mesh"
    routers: int = 0
    """Routers for ``--topology router`` (0: one for every 20 peers)."""
    loss: float = 0.0
    delay: float = 0.0
    partition: float = 0.0
    partition_kind: PartitionKind = "silent"
    churn: float = 0.0
    churn_rounds: int = 1
    churn_down: float = 2.0
    seed: int = 7
    bound: float = 30.0
    """Convergence must come within this many seconds of the reference time."""
    settle: float = 1.0
    """Seconds watched after convergence, for late duplicates."""
    up_timeout: float = 0.0
    """Seconds for every peer to come up (0: 30 + 1.5 a peer)."""
    knowledge: str = ""
    """The teachers' knowledge file (empty: the example colour skills); the learners meet its
    sequences."""
    vocabulary: str = ""
    """Every peer's ``--vocabulary`` (empty: the search-and-rescue demo robot)."""
    control: str = ""
    """Every peer's ``--control`` tree (empty: the demo robot's, or, with a vocabulary, a
    learner that runs only what it knows)."""
    teacher: TeacherProgram = "run"
    """``run``: teachers are fleet members (``ktbt peer run --knowledge``: an agent, which
    teaches one asker per cool-down); ``serve``: knowledge servers (``ktbt peer serve``, which
    answer every query at once)."""
    name: str = "fleet"
    dial: Dial = "one"
    """``one``: the newer (higher) peer of a link dials; ``both``: both ends dial each other."""
    retry_ms: int = 250
    """Every peer's ``--retry``: the period at which it dials a dead endpoint again."""
    lease_ms: int = 4_000
    """Every peer's ``--lease``: how long a link may carry nothing before it is closed (and
    dialled again), in ms (spec/protocol.md section 3)."""
    watch: str = ""
    """The folder of the monitor's unix sockets (``--monitor``): every peer also listens there
    and publishes its fleet events; empty: no monitor."""

    def __post_init__(self) -> None:
        if self.peers < 2 or self.peers > 200:
            raise PlanError("--peers must be between 2 and 200")
        if not 1 <= self.teachers < self.peers:
            raise PlanError("--teachers must be at least 1 and fewer than --peers")
        if self.topology not in TOPOLOGIES:
            raise PlanError(f"--topology must be one of {', '.join(TOPOLOGIES)}")
        if not 0 <= self.loss < 1:
            raise PlanError("--loss is a fraction: at least 0, below 1")
        if not 0 <= self.churn <= 1:
            raise PlanError("--churn is a fraction of the learners, 0 to 1")
        durations = (self.delay, self.partition, self.churn_down, self.settle, self.bound)
        if not all(math.isfinite(d) and d >= 0 for d in durations):
            raise PlanError("durations are not negative, and finite")
        if self.partition and self.topology == "router":
            raise PlanError("--partition needs --topology mesh or line (halves of peer links)")
        if self.teacher not in ("run", "serve"):
            raise PlanError("--teacher must be run or serve")
        if self.dial not in ("one", "both"):
            raise PlanError("--dial must be one or both")
        if not 10 <= self.retry_ms <= 600_000:
            raise PlanError("--retry is a period from 10 ms to 600 s")
        if not 500 <= self.lease_ms <= 600_000:
            raise PlanError("--lease is from 500 ms to 600 s")
        if self.partition_kind not in ("silent", "reset", "none"):
            raise PlanError("--partition-kind must be silent, reset or none")

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @property
    def router_count(self) -> int:
        if self.topology != "router":
            return 0
        return self.routers or max(1, self.peers // 20)

    @property
    def up_limit(self) -> float:
        return self.up_timeout or 30.0 + 1.5 * self.peers

    @property
    def faults(self) -> list[str]:
        """The faults this scenario injects, by name."""
        out = []
        if self.loss:
            out.append("loss")
        if self.delay:
            out.append("delay")
        if self.partition and self.partition_kind != "none":
            out.append(f"partition-{self.partition_kind}")
        if self.churn:
            out.append("churn")
        return out


@dataclass(frozen=True)
class Host:
    """A peer or a router: its name, role and the address it listens on."""

    name: str
    role: Literal["teacher", "learner", "router"]
    address: str
    index: int


@dataclass(frozen=True)
class Link:
    """One dialled connection: ``dialer`` connects to the proxy on ``proxy``, which connects on
    to ``listener`` from the dialer's own address (so kernel rules can tell links apart)."""

    index: int
    dialer: str
    listener: str
    proxy: str
    target: str
    bind: str


@dataclass
class Plan:
    config: FleetConfig
    port: int
    nodes: list[Host] = field(default_factory=list)
    links: list[Link] = field(default_factory=list)
    half: dict[str, int] = field(default_factory=dict)
    """0 or 1 for every peer (teachers in half 0); empty without a partition."""
    victims: list[list[str]] = field(default_factory=list)
    """The learners killed in each churn round."""

    @property
    def peers(self) -> list[Host]:
        return [n for n in self.nodes if n.role != "router"]

    @property
    def routers(self) -> list[Host]:
        return [n for n in self.nodes if n.role == "router"]

    def node(self, name: str) -> Host:
        return next(n for n in self.nodes if n.name == name)

    def dials(self, name: str) -> list[Link]:
        return [link for link in self.links if link.dialer == name]

    def crossing(self) -> list[Link]:
        """The links between the two halves."""
        return [
            link
            for link in self.links
            if self.half.get(link.dialer, -1) != self.half.get(link.listener, -1)
        ]

    def to_json(self) -> dict[str, Any]:
        return {
            "port": self.port,
            "nodes": [asdict(n) for n in self.nodes],
            "links": [asdict(link) for link in self.links],
            "half": self.half,
            "victims": self.victims,
        }


def _address(prefix: int, k: int) -> str:
    return f"127.{prefix}.{k // 250}.{k % 250 + 1}"


def stream(seed: int, decision: str) -> random.Random:
    """The seeded random stream of one decision of a run."""
    return random.Random(f"{seed}/{decision}")


def make_plan(config: FleetConfig, port: int) -> Plan:
    """Peers, links and the seeded schedule choices of ``config``: each decision draws from a
    stream of its own, so that adding churn does not move the partition's halves."""
    plan = Plan(config, port)
    width = len(str(config.peers - 1))
    first_teacher = config.peers - config.teachers
    for k in range(config.peers):  # teachers last: they start last and dial every neighbour
        role: Literal["teacher", "learner"] = "learner" if k < first_teacher else "teacher"
        name = f"{'t' if role == 'teacher' else 'p'}{k:0{width}d}"
        plan.nodes.append(Host(name, role, _address(1, k), k))
    for r in range(config.router_count):
        plan.nodes.append(Host(f"r{r}", "router", f"127.3.0.{r + 1}", r))
    peers = plan.peers

    def link(dialer: Host, listener: Host) -> None:
        index = len(plan.links)
        plan.links.append(
            Link(index, dialer.name, listener.name, _address(2, index), listener.address,
                 dialer.address)
        )  # fmt: skip

    both = config.dial == "both"
    if config.topology == "mesh":
        for i, a in enumerate(peers):
            for b in peers[:i]:
                link(a, b)
                if both:
                    link(b, a)
    elif config.topology == "line":
        for i in range(1, len(peers)):
            link(peers[i], peers[i - 1])
            if both:
                link(peers[i - 1], peers[i])
    else:
        routers = plan.routers
        for r in range(1, len(routers)):
            link(routers[r], routers[r - 1])
        for i, p in enumerate(peers):
            link(p, routers[i % len(routers)])
    if config.partition:
        learners = [p.name for p in peers if p.role == "learner"]
        size_a = (len(peers) + 1) // 2 - config.teachers
        if size_a < 0 or len(learners) - max(size_a, 0) < 1:
            raise PlanError("a partition needs at least one learner in the half with no teacher")
        if config.topology == "line":  # halves of a line are its two ends (teachers last)
            chosen = set(learners[len(learners) - max(size_a, 0) :])
        else:
            chosen = set(stream(config.seed, "halves").sample(learners, max(size_a, 0)))
        for p in peers:
            plan.half[p.name] = 0 if p.role == "teacher" or p.name in chosen else 1
    if config.churn:
        learners = [p.name for p in peers if p.role == "learner"]
        count = max(1, round(config.churn * len(learners)))
        plan.victims = [
            sorted(stream(config.seed, f"victims-{r}").sample(learners, count))
            for r in range(config.churn_rounds)
        ]
    return plan
