"""The fault layer's kernel half: a network namespace of the run's own (an isolated loopback,
so its rules touch nothing else on the machine) and packet loss in it with nftables
(``numgen random mod 100 < P drop``, counted). Loss applies between the proxies and the peers
they connect to (both ends in 127.1.0.0/16), in both directions of every link.

A fleet through routers has one namespace more for each router group (its router and the
router's clients), each an isolated loopback of its own: the groups are joined only by the
proxies of the routers' links, each a listening socket in the dialer's namespace and an
onward one in the listener's (:func:`socket_in`), so the fault layer is the only path between
groups and a cut between them is a real one.

Where the machine does not allow it (not root, no ``ip``, no ``nft``) :func:`unavailable` says
why, and the run reports loss as skipped."""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import shutil
import signal
import socket
import subprocess

TABLE = "ktbt_fleet"
CLONE_NEWNET = 0x40000000


def _run(*args: str, stdin: str | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(list(args), input=stdin, capture_output=True, text=True, timeout=20)


def unavailable(need_nft: bool) -> str | None:
    """Why a namespace (with nftables, if ``need_nft``) cannot be made here; None if it can."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    if shutil.which("ip") is None:
        return "no `ip` command (apt-get install -y iproute2)"
    if need_nft and shutil.which("nft") is None:
        return "no `nft` command (apt-get install -y nftables)"
    return None


def create(name: str) -> None:
    done = _run("ip", "netns", "add", name)
    if done.returncode != 0:
        raise OSError(f"ip netns add {name}: {done.stderr.strip()}")
    up = _run("ip", "-n", name, "link", "set", "lo", "up")
    if up.returncode != 0:
        delete(name)
        raise OSError(f"cannot bring loopback up in {name}: {up.stderr.strip()}")


def add_loss(name: str, fraction: float) -> None:
    """Drop ``fraction`` of the packets between proxies and the peers and routers behind them
    (peers on 127.1/16, routers on 127.3/16), counted."""
    percent = round(fraction * 100)
    ends = "{ 127.1.0.0/16, 127.3.0.0/16 }"
    rules = (
        f"table inet {TABLE} {{\n"
        "  chain out {\n"
        "    type filter hook output priority 0; policy accept;\n"
        f"    ip saddr {ends} ip daddr {ends} numgen random mod 100 < {percent}"
        " counter drop\n"
        "  }\n"
        "}\n"
    )
    done = _run("ip", "netns", "exec", name, "nft", "-f", "-", stdin=rules)
    if done.returncode != 0:
        raise OSError(f"nft in {name}: {done.stderr.strip()}")


def dropped(name: str | None = None) -> int | None:
    """Packets the loss rule of namespace ``name`` (None: the one this process runs in)
    dropped (None: no rule)."""
    inside = ("ip", "netns", "exec", name) if name else ()
    done = _run(*inside, "nft", "-j", "list", "table", "inet", TABLE)
    if done.returncode != 0:
        return None
    total = 0
    for entry in json.loads(done.stdout).get("nftables", []):
        for expr in entry.get("rule", {}).get("expr", []):
            if "counter" in expr:
                total += int(expr["counter"]["packets"])
    return total


def identity(path: str) -> int | None:
    """The inode that names a network namespace, from a namespace's file (``/run/netns/NAME``
    or ``/proc/PID/ns/net``): two processes share a namespace when theirs are equal, as
    ``ip netns identify`` compares them. None if there is no such file."""
    try:
        return os.stat(path).st_ino
    except OSError:
        return None


def of_process(pid: int) -> int | None:
    """The namespace process ``pid`` runs in (:func:`identity`)."""
    return identity(f"/proc/{pid}/ns/net")


def of_name(name: str) -> int | None:
    """The namespace ``ip netns`` calls ``name`` (:func:`identity`)."""
    return identity(f"/run/netns/{name}")


def _setns(fd: int) -> None:
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.setns(fd, CLONE_NEWNET) != 0:
        errno = ctypes.get_errno()
        raise OSError(errno, f"setns: {os.strerror(errno)}")


def socket_in(name: str | None) -> socket.socket:
    """A TCP socket of namespace ``name`` (None: this thread's own). A socket belongs to the
    namespace it was made in, whatever thread uses it later: this thread enters ``name`` for
    the one call and comes back, so a proxy has its two ends in two namespaces. Made with
    protocol TCP named, as asyncio's own are: asyncio turns Nagle off only on such a socket, and
    with Nagle on, a link's small writes waited out the peer's delayed ACK (a query round trip
    through a link took 44 ms instead of 0.4)."""

    def made() -> socket.socket:
        return socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)

    if name is None:
        return made()
    here = os.open("/proc/thread-self/ns/net", os.O_RDONLY)
    try:
        there = os.open(f"/run/netns/{name}", os.O_RDONLY)
        try:
            _setns(there)
            try:
                return made()
            finally:
                _setns(here)
        finally:
            os.close(there)
    finally:
        os.close(here)


def pids(name: str) -> list[int]:
    done = _run("ip", "netns", "pids", name)
    return [int(p) for p in done.stdout.split() if p.isdigit()]


def delete(name: str) -> None:
    """Kill what still runs in the namespace (only ours run there) and delete it: its rules
    go with it."""
    for pid in pids(name):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    _run("ip", "netns", "del", name)
