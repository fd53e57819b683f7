"""The fault layer's user-space half: one asyncio TCP proxy per link.

A link is ``open`` (bytes pass, after the link's one-way ``delay`` in each direction, in
order), ``held`` (a silent partition: sockets stay up, bytes read are held and nothing more is
read, so the kernel buffers fill; new connections are accepted and never connected onwards,
and closed when their dialer gives up; an end of stream is held too; at the heal the held bytes
flow on) or ``cut`` (a hard cut: every connection reset, new ones reset
at once, until the heal). Every link counts what it did, so a fault that did not happen shows.

A proxy may join two network namespaces (a fleet through routers, a namespace a router group):
it listens in its dialer's and connects on in its listener's (netns.socket_in), and is then the
only path between them.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Literal

from ktbt_proto.tools.fleet import netns
from ktbt_proto.tools.fleet.plan import Link

State = Literal["open", "held", "cut"]
CHUNK = 65536
FIN_WAIT = 2.0
"""Seconds a half-closed connection may go on in the other direction before both are closed
(a dead peer's neighbour may never close its side)."""
QUEUED = 1 << 20
"""Bytes a delayed direction may hold in flight before it stops reading (as a slow link's
window would)."""


@dataclass
class Counters:
    connections: int = 0
    bytes: int = 0
    chunks_held: int = 0
    bytes_held: int = 0
    connections_held: int = 0
    closed_while_held: int = 0
    resets: int = 0
    refused: int = 0
    delayed_chunks: int = 0


@dataclass(eq=False)
class LinkProxy:
    link: Link
    port: int
    delay: float = 0.0
    state: State = "open"
    counters: Counters = field(default_factory=Counters)
    linked: Callable[[Link], None] | None = None
    """Told each time a connection of this link reaches its listener: the link is up (a mark
    of a transfer's timeline)."""
    dialled_held: Callable[[Link], None] | None = None
    """Told each time a connection of this link is accepted while it is held: its dialer gave
    the silent link up (its lease) and dialled again."""
    listen_in: str | None = None
    """The network namespace the proxy listens in (its dialer's; None: the runner's)."""
    connect_in: str | None = None
    """The network namespace it connects on in (its listener's; None: the runner's)."""

    def __post_init__(self) -> None:
        self._open = asyncio.Event()
        self._open.set()
        self._server: asyncio.Server | None = None
        self._conns: set[tuple[asyncio.StreamWriter, asyncio.StreamWriter | None]] = set()

    async def start(self) -> None:
        sock = netns.socket_in(self.listen_in)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((self.link.proxy, self.port))
            sock.listen(100)
            sock.setblocking(False)
        except OSError:
            sock.close()
            raise
        self._server = await asyncio.start_server(self._accept, sock=sock)

    def hold(self) -> None:
        self.state = "held"
        self._open.clear()

    def cut(self) -> None:
        self.state = "cut"
        self._open.clear()
        for a, b in list(self._conns):
            self.counters.resets += 1
            _reset(a)
            if b is not None:
                _reset(b)
        self._conns.clear()

    def heal(self) -> None:
        self.state = "open"
        self._open.set()

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
        for a, b in list(self._conns):
            a.close()
            if b is not None:
                b.close()
        self._conns.clear()
        self._open.set()  # held connections wake, find themselves closed, and end
        if self._server is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._server.wait_closed(), 2)

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        with contextlib.suppress(asyncio.CancelledError):  # the run is ending
            await self._forward(reader, writer)

    async def _forward(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self.state == "cut":
            self.counters.refused += 1
            _reset(writer)
            return
        pair: tuple[asyncio.StreamWriter, asyncio.StreamWriter | None] = (writer, None)
        self._conns.add(pair)
        try:
            early: bytes | None = b""
            if not self._open.is_set():
                self.counters.connections_held += 1
                if self.dialled_held is not None:
                    self.dialled_held(self.link)
                early = await self._wait_open(reader)
                if early is None:  # the dialer gave up while held
                    self.counters.closed_while_held += 1
                    return
            if pair not in self._conns:  # cut meanwhile
                return
            try:
                up_reader, up_writer = await asyncio.wait_for(self._connect(), 5)
            except (OSError, TimeoutError):
                writer.close()
                return
            self._conns.discard(pair)
            pair = (writer, up_writer)
            self._conns.add(pair)
            self.counters.connections += 1
            if self.linked is not None:
                self.linked(self.link)
            if early:
                up_writer.write(early)
            pumps = {
                asyncio.ensure_future(self._pump(reader, up_writer, pair)),
                asyncio.ensure_future(self._pump(up_reader, writer, pair)),
            }
            try:
                _, left = await asyncio.wait(pumps, return_when=asyncio.FIRST_COMPLETED)
                if left:  # half-closed: the other direction may finish, for a while
                    _, left = await asyncio.wait(left, timeout=FIN_WAIT)
            finally:
                for pump in pumps:
                    pump.cancel()
                await asyncio.gather(*pumps, return_exceptions=True)
        finally:
            self._conns.discard(pair)
            for w in pair:
                if w is not None:
                    w.close()

    async def _connect(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        """On to the listener, from the dialer's address, in the listener's namespace."""
        sock = netns.socket_in(self.connect_in)
        try:
            sock.setblocking(False)
            sock.bind((self.link.bind, 0))
            await asyncio.get_running_loop().sock_connect(sock, (self.link.target, self.port))
        except BaseException:
            sock.close()
            raise
        return await asyncio.open_connection(sock=sock)

    async def _wait_open(self, reader: asyncio.StreamReader) -> bytes | None:
        """Wait for the heal on a connection accepted while held, watching for its end: what
        the dialer sent meanwhile (up to one chunk, then nothing more is read), or None if it
        closed first."""
        held = b""
        opened = asyncio.ensure_future(self._open.wait())
        try:
            while not self._open.is_set() and len(held) < CHUNK:
                read = asyncio.ensure_future(reader.read(CHUNK - len(held)))
                await asyncio.wait({opened, read}, return_when=asyncio.FIRST_COMPLETED)
                if not read.done():
                    read.cancel()
                    with contextlib.suppress(asyncio.CancelledError, OSError):
                        await read
                    break
                try:
                    data = read.result()
                except OSError:
                    return None
                if not data:
                    return None
                self.counters.chunks_held += 1
                self.counters.bytes_held += len(data)
                held += data
            await opened
        finally:
            opened.cancel()
        return held

    async def _pump(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        pair: tuple[asyncio.StreamWriter, asyncio.StreamWriter | None],
    ) -> None:
        """Copy one direction; with a delay, a queue of (due time, bytes) keeps the order."""
        queue: deque[tuple[float, bytes]] = deque()
        wake, room = asyncio.Event(), asyncio.Event()
        room.set()
        queued = 0
        done = False

        async def send() -> None:
            nonlocal queued
            while True:
                while not queue:
                    if done:
                        return
                    wake.clear()
                    await wake.wait()
                due, data = queue.popleft()
                wait = due - time.monotonic()
                if wait > 0:
                    await asyncio.sleep(wait)
                writer.write(data)
                await writer.drain()
                queued -= len(data)
                if queued < QUEUED:
                    room.set()

        sender = asyncio.ensure_future(send()) if self.delay else None
        ended = False  # the stream ended cleanly: pass the end on, as a half-close
        try:
            while True:
                data = await reader.read(CHUNK)
                if not self._open.is_set():  # held: neither bytes nor the end pass
                    if data:
                        self.counters.chunks_held += 1
                        self.counters.bytes_held += len(data)
                    await self._open.wait()
                    if pair not in self._conns:
                        break
                if not data:
                    ended = True
                    break
                self.counters.bytes += len(data)
                if sender is None:
                    writer.write(data)
                    await writer.drain()
                else:
                    self.counters.delayed_chunks += 1
                    queue.append((time.monotonic() + self.delay, data))
                    queued += len(data)
                    wake.set()
                    if queued >= QUEUED:
                        room.clear()
                        await room.wait()
        except (OSError, asyncio.IncompleteReadError):
            pass
        finally:
            done = True
            wake.set()
            if sender is not None:
                with contextlib.suppress(Exception):
                    await asyncio.wait_for(sender, self.delay + 1)
            if ended and writer.can_write_eof() and not writer.is_closing():
                with contextlib.suppress(OSError):
                    writer.write_eof()  # the other direction goes on; both close at its end
            else:
                writer.close()


def _reset(writer: asyncio.StreamWriter) -> None:
    """Close with RST (SO_LINGER 0), as a link that is cut, not one that is shut."""
    sock = writer.get_extra_info("socket")
    if sock is not None:
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    writer.transport.abort()


class FaultLayer:
    """The proxies of every link of a fleet."""

    def __init__(
        self,
        links: list[Link],
        port: int,
        delay: float = 0.0,
        linked: Callable[[Link], None] | None = None,
        dialled_held: Callable[[Link], None] | None = None,
        spaces: dict[str, str] | None = None,
    ) -> None:
        """``spaces``: the network namespace of each fleet member not in the runner's own."""
        near = spaces or {}
        self.proxies = {}
        for link in links:
            self.proxies[link.index] = LinkProxy(
                link, port, delay, linked=linked, dialled_held=dialled_held,
                listen_in=near.get(link.dialer), connect_in=near.get(link.listener),
            )  # fmt: skip

    async def start(self) -> None:
        for proxy in self.proxies.values():
            await proxy.start()

    def apply(self, links: list[Link], state: State) -> None:
        for link in links:
            proxy = self.proxies[link.index]
            {"held": proxy.hold, "cut": proxy.cut, "open": proxy.heal}[state]()

    def counters(self) -> dict[int, dict[str, int]]:
        return {i: asdict(p.counters) for i, p in self.proxies.items()}

    async def close(self) -> None:
        await asyncio.gather(*(p.close() for p in self.proxies.values()), return_exceptions=True)
