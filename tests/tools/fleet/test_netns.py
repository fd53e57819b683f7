"""The loss rule in a namespace of its own drops real packets between peers and routers (a
router listens on 127.3/16, a peer on 127.1/16), and the namespace goes with its rules; a
link's proxy joins two namespaces (two router groups) and is the only path between them."""

from __future__ import annotations

import asyncio
import os
import random
import shutil
import subprocess
import sys

import pytest

from ktbt_proto.tools.fleet import netns
from ktbt_proto.tools.fleet.plan import Link
from ktbt_proto.tools.fleet.proxy import LinkProxy
from tests.zenoh_helpers import ROOT

pytestmark = pytest.mark.skipif(
    os.geteuid() != 0 or not shutil.which("ip") or not shutil.which("nft"),
    reason="needs root, ip and nft",
)

SEND = """
import socket, sys
from ktbt_proto.tools.fleet import netns
from ktbt_proto.tools.fleet.plan import Link
from ktbt_proto.tools.fleet.proxy import LinkProxy
src, dst = sys.argv[1], sys.argv[2]
before = netns.dropped() or 0
with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
    s.bind((src, 0))
    for _ in range(20):
        try:
            s.sendto(b"x", (dst, 9))
        except PermissionError:  # dropped on output: the sender is told
            pass
print((netns.dropped() or 0) - before)
"""


@pytest.mark.parametrize(("src", "dst"), [("127.1.0.1", "127.1.0.2"), ("127.1.0.1", "127.3.0.1"),
                                          ("127.3.0.1", "127.1.0.2")])  # fmt: skip
def test_loss_drops_packets_between_peers_and_routers(src: str, dst: str) -> None:
    name = f"ktbt-fleet-test-{os.getpid()}-{random.randrange(1 << 20):x}"
    netns.create(name)
    try:
        netns.add_loss(name, 0.99)
        done = subprocess.run(
            ["ip", "netns", "exec", name, sys.executable, "-c", SEND, src, dst],
            cwd=ROOT, capture_output=True, text=True, timeout=30,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        assert int(done.stdout) >= 10  # 99 % of 20: fewer than 10 is a rule that missed them
    finally:
        netns.delete(name)
    assert (
        name not in subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    )


def test_a_proxy_is_the_only_path_between_two_namespaces_and_its_cut_cuts_them() -> None:
    """Two namespaces, as two router groups: a listener in one, its link's proxy listening in
    the other's and connecting on in the first's. Bytes pass through it; nothing reaches the
    listener's address from the dialer's namespace directly; a cut resets the connection."""
    tag = f"{os.getpid()}-{random.randrange(1 << 20):x}"
    near, far = f"ktbt-fleet-test-{tag}-a", f"ktbt-fleet-test-{tag}-b"
    for name in (near, far):
        netns.create(name)

    async def main() -> None:
        port = 7447
        listener = netns.socket_in(far)
        listener.bind(("127.3.0.1", port))
        listener.listen()
        listener.setblocking(False)

        async def echo(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            while data := await reader.read(1024):
                writer.write(data)
                await writer.drain()
            writer.close()

        server = await asyncio.start_server(echo, sock=listener)
        link = Link(0, "r1", "r0", "127.2.0.1", "127.3.0.1", "127.3.0.2")
        proxy = LinkProxy(link, port, listen_in=near, connect_in=far)
        await proxy.start()
        loop = asyncio.get_running_loop()
        try:
            direct = netns.socket_in(near)
            direct.setblocking(False)
            with pytest.raises(ConnectionRefusedError), direct:
                await loop.sock_connect(direct, ("127.3.0.1", port))
            dialer = netns.socket_in(near)
            dialer.setblocking(False)
            await loop.sock_connect(dialer, ("127.2.0.1", port))
            reader, writer = await asyncio.open_connection(sock=dialer)
            writer.write(b"across")
            assert await asyncio.wait_for(reader.readexactly(6), 5) == b"across"
            assert proxy.counters.connections == 1 and proxy.counters.bytes == 12
            proxy.cut()
            with pytest.raises((ConnectionResetError, asyncio.IncompleteReadError)):
                await asyncio.wait_for(reader.readexactly(1), 5)
            assert proxy.counters.resets == 1
            writer.close()
        finally:
            await proxy.close()
            server.close()

    try:
        asyncio.run(main())
    finally:
        for name in (near, far):
            netns.delete(name)
