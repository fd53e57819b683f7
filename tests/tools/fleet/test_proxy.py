"""The fault layer's proxy over real sockets on loopback: bytes keep their order under delay and
through a hold, a half-close passes and the other direction goes on, a connection accepted while
held is closed when its dialer gives up, and a cut resets connections until the heal."""

from __future__ import annotations

import asyncio
import contextlib
import socket
from collections.abc import Awaitable, Callable

import pytest

from ktbt_proto.tools.fleet import netns
from ktbt_proto.tools.fleet.plan import Link
from ktbt_proto.tools.fleet.proxy import LinkProxy


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


async def _until(done: Callable[[], bool], limit: float = 5.0) -> None:
    deadline = asyncio.get_running_loop().time() + limit
    while not done():
        assert asyncio.get_running_loop().time() < deadline, "timed out"
        await asyncio.sleep(0.01)


Test = Callable[[LinkProxy, list[bytes]], Awaitable[None]]


def _with_proxy(delay: float, body: Test) -> None:
    """A server that echoes back what it got once the stream ends, behind one proxy."""

    async def main() -> None:
        port = _port()
        got: list[bytes] = []

        async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            data = await reader.read()
            got.append(data)
            with contextlib.suppress(OSError):
                writer.write(b"echo:" + data[:16])
                await writer.drain()
                writer.close()

        server = await asyncio.start_server(serve, "127.1.0.1", port)
        link = Link(0, "p1", "p0", "127.2.0.1", "127.1.0.1", "127.1.0.2")
        proxy = LinkProxy(link, port, delay)
        await proxy.start()
        try:
            await body(proxy, got)
        finally:
            await proxy.close()
            server.close()
            await server.wait_closed()

    asyncio.run(main())


async def _dial(port: int) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    return await asyncio.open_connection("127.2.0.1", port)


PAYLOAD = b"".join(i.to_bytes(4, "big") for i in range(50_000))


def test_bytes_keep_their_order_under_delay_and_a_half_close_passes() -> None:
    async def body(proxy: LinkProxy, got: list[bytes]) -> None:
        reader, writer = await _dial(proxy.port)
        for i in range(0, len(PAYLOAD), 1000):
            writer.write(PAYLOAD[i : i + 1000])
            await writer.drain()
        writer.write_eof()  # half-close: the answer must still come back
        answer = await asyncio.wait_for(reader.read(), 10)
        writer.close()
        assert got == [PAYLOAD]
        assert answer == b"echo:" + PAYLOAD[:16]
        assert proxy.counters.delayed_chunks > 0

    _with_proxy(0.05, body)


def test_a_hold_passes_nothing_and_the_heal_delivers_in_order() -> None:
    async def body(proxy: LinkProxy, got: list[bytes]) -> None:
        reader, writer = await _dial(proxy.port)
        writer.write(PAYLOAD[:4])
        await writer.drain()
        await _until(lambda: proxy.counters.bytes == 4)
        proxy.hold()
        writer.write(PAYLOAD[4:50_000])
        await writer.drain()
        writer.write_eof()  # the end is held as well
        await _until(lambda: proxy.counters.bytes_held > 0)
        await asyncio.sleep(0.2)  # what the hold lets through would show here
        assert got == []
        proxy.heal()
        answer = await asyncio.wait_for(reader.read(), 10)
        writer.close()
        assert got == [PAYLOAD[:50_000]]
        assert answer.startswith(b"echo:")

    _with_proxy(0.0, body)


def test_a_connection_given_up_while_held_is_closed_and_counted() -> None:
    async def body(proxy: LinkProxy, got: list[bytes]) -> None:
        proxy.hold()
        _, writer = await _dial(proxy.port)
        await _until(lambda: proxy.counters.connections_held == 1)
        writer.close()
        await _until(lambda: proxy.counters.closed_while_held == 1)
        await _until(lambda: not proxy._conns)
        assert got == []

    _with_proxy(0.0, body)


def test_a_cut_resets_and_refuses_until_the_heal() -> None:
    async def body(proxy: LinkProxy, got: list[bytes]) -> None:
        reader, writer = await _dial(proxy.port)
        writer.write(b"x")
        await writer.drain()
        await _until(lambda: proxy.counters.connections == 1)
        proxy.cut()
        with pytest.raises(ConnectionResetError):
            await asyncio.wait_for(reader.read(), 5)
        writer.close()
        reader, writer = await _dial(proxy.port)
        with pytest.raises(ConnectionResetError):
            await asyncio.wait_for(reader.read(), 5)
        writer.close()
        assert proxy.counters.refused == 1 and proxy.counters.resets == 1
        proxy.heal()
        reader, writer = await _dial(proxy.port)
        writer.write(b"after")
        writer.write_eof()
        assert await asyncio.wait_for(reader.read(), 5) == b"echo:after"
        writer.close()

    _with_proxy(0.0, body)


def test_both_ends_of_a_proxied_connection_send_small_writes_at_once() -> None:
    """A proxy's sockets (netns.socket_in: listening, accepted, dialled on) are ones asyncio
    turns Nagle off on, as on its own: with Nagle on, each small write of a link waited for the
    far end's delayed ACK, some 40 ms a query round trip."""

    async def main() -> None:
        loop = asyncio.get_running_loop()
        listening = netns.socket_in(None)
        listening.bind(("127.1.0.1", 0))
        listening.listen()
        listening.setblocking(False)
        accepted: list[asyncio.StreamWriter] = []
        server = await asyncio.start_server(lambda _r, w: accepted.append(w), sock=listening)
        dialled = netns.socket_in(None)
        dialled.setblocking(False)
        await loop.sock_connect(dialled, listening.getsockname())
        _, writer = await asyncio.open_connection(sock=dialled)
        try:
            await _until(lambda: bool(accepted))
            for end in (writer, accepted[0]):
                sock = end.get_extra_info("socket")
                assert sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY), end
        finally:
            for end in (writer, *accepted):
                end.close()
            server.close()
            await server.wait_closed()

    asyncio.run(main())
