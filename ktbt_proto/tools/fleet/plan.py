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

Besides a mesh, a line and routers, a fleet can be shaped like a real one (networkx, the
``fleet`` extra): a random geometric graph (robots linked when within a radio range of each
other, as the simulator's communication range links them, spec/simulator.md), a grid, or an
edge list from a file. Such a graph that is not connected is refused, never run.
"""

from __future__ import annotations

import math
import random
import re
from collections import defaultdict
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

from ktbt_proto.files import TooLarge, read_bounded

Topology = Literal["mesh", "line", "router", "geometric", "grid", "edges"]
TOPOLOGIES: tuple[Topology, ...] = ("mesh", "line", "router", "geometric", "grid", "edges")
GRAPHS = ("geometric", "grid", "edges")
"""The topologies built with networkx."""
INSTALL = "--topology geometric, grid and edges need networkx: pip install 'ktbt[fleet]'"
MAX_EDGES_FILE = 1 << 20
"""The largest edge-list file read, in bytes."""
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
    radius: float = 0.0
    """The radio range of ``--topology geometric``: peers placed uniformly at random (seeded)
    in a square of side 1 are linked when within it of each other."""
    edges: str = ""
    """The edge-list file of ``--topology edges`` (networkx's format: a pair of peer indices
    a line, ``#`` comments, anything after the pair ignored)."""

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
        if self.partition and self.topology == "router" and self.router_count < 2:
            raise PlanError("--partition with --topology router needs --routers 2 or more")
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
        if (self.topology == "geometric") != bool(self.radius):
            raise PlanError("--topology geometric needs --radius R, and --radius needs it")
        if not (math.isfinite(self.radius) and self.radius >= 0):
            raise PlanError("--radius is a distance in a square of side 1, above 0")
        if (self.topology == "edges") != bool(self.edges):
            raise PlanError("--topology edges needs --edges FILE, and --edges needs it")
        if self.topology in GRAPHS:
            peer_pairs(self)  # a graph that is not connected, or a bad file, is refused here

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
    """0 or 1 for every peer (teachers in half 0), and every router through routers (its group
    of clients with it); empty without a partition."""
    victims: list[list[str]] = field(default_factory=list)
    """The learners killed in each churn round."""
    positions: dict[str, list[float]] = field(default_factory=dict)
    """Where each peer is in ``--topology geometric`` (x, y in the unit square)."""
    group: dict[str, int] = field(default_factory=dict)
    """With ``--topology router``: each router's group (its index) and each peer's (its
    router's); the runner puts every group in a network namespace of its own where the machine
    allows, joined to the others only through the proxies of the routers' links."""

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
            "positions": self.positions,
            "group": self.group,
        }


def _address(prefix: int, k: int) -> str:
    return f"127.{prefix}.{k // 250}.{k % 250 + 1}"


def stream(seed: int, decision: str) -> random.Random:
    """The seeded random stream of one decision of a run."""
    return random.Random(f"{seed}/{decision}")


def positions(config: FleetConfig) -> dict[int, tuple[float, float]]:
    """Each peer's place in the unit square for ``--topology geometric``, drawn from the seed's
    own stream (the same seed, the same places, whatever networkx draws)."""
    rng = stream(config.seed, "positions")
    return {k: (rng.random(), rng.random()) for k in range(config.peers)}


def _networkx() -> Any:
    try:
        import networkx
    except ImportError:
        raise PlanError(INSTALL) from None
    return networkx


def read_edges(path: str, peers: int) -> list[tuple[int, int]]:
    """The links of an edge-list file (networkx's format, read line by line so that an error
    names its line): pairs of peer indices, each from 0 to ``peers - 1``."""
    nx = _networkx()
    try:
        text = read_bounded(path, MAX_EDGES_FILE).decode("utf-8")
    except TooLarge:
        raise PlanError(f"--edges {path}: larger than {MAX_EDGES_FILE} bytes") from None
    except OSError as exc:
        raise PlanError(f"--edges {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise PlanError(f"--edges {path}: not UTF-8 text") from None
    out: list[tuple[int, int]] = []
    for number, line in enumerate(text.splitlines(), 1):
        where = f"--edges {path}:{number}"
        if len(line.split("#", 1)[0].split()) == 1:
            raise PlanError(f"{where}: one peer, not a pair: {line.strip()!r}")
        try:
            pairs = list(nx.parse_edgelist([line], nodetype=int, data=False).edges)
        except TypeError:
            raise PlanError(f"{where}: not a pair of peer indices: {line.strip()!r}") from None
        for a, b in pairs:
            for k in (a, b):
                if not 0 <= k < peers:
                    raise PlanError(
                        f"{where}: peer {k} is not one of the {peers} peers (0 to {peers - 1}):"
                        " change the file or --peers"
                    )
            if a == b:
                raise PlanError(f"{where}: peer {a} linked to itself")
            out.append((a, b))
    return out


def peer_pairs(config: FleetConfig) -> list[tuple[int, int]]:
    """The peer links of ``config`` as (newer, older) index pairs, in a fixed order: every pair
    in a mesh, neighbours in a line, and the edges of a geometric graph, a grid (as square as
    the peers allow, filled row by row) or an edge-list file, built with networkx; none for
    routers. A graph that is not connected is refused (PlanError)."""
    n = config.peers
    if config.topology == "mesh":
        return [(i, j) for i in range(n) for j in range(i)]
    if config.topology == "line":
        return [(i, i - 1) for i in range(1, n)]
    if config.topology not in GRAPHS:
        return []
    nx = _networkx()
    graph = nx.Graph()
    graph.add_nodes_from(range(n))
    if config.topology == "geometric":
        placed = nx.random_geometric_graph(n, config.radius, pos=positions(config))
        graph.add_edges_from(placed.edges)
        what = (
            f"the geometric graph of {n} peers within radius {config.radius:g} (seed {config.seed})"
        )
        fix = "raise --radius or change --seed"
    elif config.topology == "grid":
        cols = math.ceil(math.sqrt(n))
        grid = nx.grid_2d_graph(math.ceil(n / cols), cols)
        graph.add_edges_from(
            (r * cols + c, s * cols + d) for (r, c), (s, d) in grid.edges
            if r * cols + c < n and s * cols + d < n
        )  # fmt: skip
        what, fix = f"the grid of {n} peers", "change --peers"  # never: a grid is connected
    else:
        graph.add_edges_from(read_edges(config.edges, n))
        what = f"the graph of --edges {config.edges}"
        fix = f"link every peer, 0 to {n - 1}, or change --peers"
    if not nx.is_connected(graph):
        parts = sorted(nx.connected_components(graph), key=len, reverse=True)
        alone = sorted(parts[1], key=int)[:5]
        raise PlanError(
            f"{what} is not connected ({len(parts)} parts; peers {', '.join(map(str, alone))}"
            f" cannot reach peer {min(parts[0])}): {fix}"
        )
    return sorted((max(a, b), min(a, b)) for a, b in graph.edges)


def neighbours(plan: dict[str, Any]) -> dict[str, set[str]]:
    """Each peer's neighbours in a plan (its JSON form, as a record holds it): the peers it is
    linked to directly or through routers only. A router relays and learns nothing, so a hop
    of knowledge is from one peer to the next."""
    roles = {n["name"]: n["role"] for n in plan["nodes"]}
    near: dict[str, set[str]] = defaultdict(set)
    for link in plan["links"]:
        near[link["dialer"]].add(link["listener"])
        near[link["listener"]].add(link["dialer"])
    out: dict[str, set[str]] = {}
    for peer in (name for name, role in roles.items() if role != "router"):
        found: set[str] = set()
        seen: set[str] = set()
        stack = [peer]
        while stack:
            for other in near[stack.pop()]:
                if roles.get(other) == "router":
                    if other not in seen:
                        seen.add(other)
                        stack.append(other)
                elif other != peer:
                    found.add(other)
        out[peer] = found
    return out


def distances(plan: dict[str, Any]) -> dict[str, int]:
    """Each peer's hops from the nearest teacher (breadth first over :func:`neighbours`): the
    graph's shortest paths, along which knowledge spreads at best. A peer no teacher reaches
    is left out."""
    near = neighbours(plan)
    hops = {n["name"]: 0 for n in plan["nodes"] if n["role"] == "teacher"}
    frontier = list(hops)
    while frontier:
        following = []
        for peer in frontier:
            for other in sorted(near.get(peer, ())):
                if other not in hops:
                    hops[other] = hops[peer] + 1
                    following.append(other)
        frontier = following
    return hops


def router_halves(plan: Plan) -> dict[str, int]:
    """The halves of a fleet through routers: its chain of routers cut in the middle (one
    link between router groups crosses), each peer in its router's half, half 0 the one with
    the first teacher's router. Every router and peer is named, so that the crossing links
    are exactly the routers' link across the cut."""
    routers, peers = plan.routers, plan.peers
    own = {p.name: plan.group[p.name] for p in peers}
    cut = (len(routers) + 1) // 2  # routers below it on one side
    teacher = next(p for p in peers if p.role == "teacher")
    near = own[teacher.name] < cut

    def side(r: int) -> int:
        return 0 if (r < cut) == near else 1

    return {**{r.name: side(r.index) for r in routers}, **{p: side(r) for p, r in own.items()}}


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

    if config.topology == "router":
        routers = plan.routers
        for r in range(1, len(routers)):
            link(routers[r], routers[r - 1])
        for i, p in enumerate(peers):
            link(p, routers[i % len(routers)])
            plan.group[p.name] = i % len(routers)
        plan.group.update({r.name: r.index for r in routers})
    else:
        for newer, older in peer_pairs(config):  # the newer (higher) peer dials
            link(peers[newer], peers[older])
            if config.dial == "both":
                link(peers[older], peers[newer])
    if config.topology == "geometric":
        plan.positions = {
            peers[k].name: [round(x, 4), round(y, 4)] for k, (x, y) in positions(config).items()
        }
    if config.partition and config.topology == "router":
        plan.half = router_halves(plan)
    elif config.partition:
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
