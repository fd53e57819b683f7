"""A Groot2 client for the tests, written from BehaviorTree.CPP's groot2_protocol.h, and the
trees both publishers serve in them."""

from __future__ import annotations

import contextlib
import json
import socket
import struct
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from typing import Any

import zmq

HEADER = struct.Struct("<BBI")
CONTROL_TAGS = {"Condition", "Action", "Decorator", "Control"}

# A port-less tree: every leaf BehaviorTree.CPP can load without ports.
PORTLESS = """<sl>
    <sq>
        <c>(_collisionDetectedF)
        <a>(CollisionAvoidance)
    <e>
    <k>(new)<e>
    <sq>
        <c>(!_inZoneF)
        <a>(WalkToCollection)
    <e>
    <a>(RandomWalk)
<e>
"""


def reserve_ports(pairs: int, singles: int = 0) -> list[int]:
    """``pairs`` Groot2 ports (each with its next port free too), then ``singles`` single ports,
    all distinct: every one is held until all are picked, so none overlaps another."""
    held: list[socket.socket] = []
    taken: set[int] = set()
    out: list[int] = []

    def grab(port: int) -> bool:
        sock = socket.socket()
        try:
            sock.bind(("127.0.0.1", port))
        except OSError:
            sock.close()
            return False
        held.append(sock)
        taken.add(sock.getsockname()[1])
        return True

    try:
        while len(out) < pairs:
            if not grab(0):
                raise RuntimeError("no free port")
            port = held[-1].getsockname()[1]
            if port < 65535 and port + 1 not in taken and grab(port + 1):
                out.append(port)
        for _ in range(singles):
            if not grab(0):
                raise RuntimeError("no free port")
            out.append(held[-1].getsockname()[1])
        return out
    finally:
        for sock in held:
            sock.close()


def free_ports() -> int:
    """A port p with p + 1 free as well (REP and PUB), on loopback."""
    for _ in range(50):
        with socket.socket() as a:
            a.bind(("127.0.0.1", 0))
            port = a.getsockname()[1]
            if port >= 65535:
                continue
            with socket.socket() as b:
                try:
                    b.bind(("127.0.0.1", port + 1))
                except OSError:
                    continue
            return int(port)
    raise RuntimeError("no two consecutive free ports")


class Client:
    """A REQ socket speaking the Groot2 protocol; every exchange times out after ``timeout`` s."""

    def __init__(self, port: int, timeout: float = 5.0) -> None:
        self.context = zmq.Context()
        self.port = port
        self.timeout = int(timeout * 1000)
        self.socket = self._connect()
        self.next_id = 0x01020304

    def _connect(self) -> zmq.Socket[bytes]:
        sock = self.context.socket(zmq.REQ)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.RCVTIMEO, self.timeout)
        sock.setsockopt(zmq.SNDTIMEO, self.timeout)
        sock.connect(f"tcp://127.0.0.1:{self.port}")
        return sock

    def raw(self, frames: list[bytes]) -> list[bytes]:
        try:
            self.socket.send_multipart(frames)
            return self.socket.recv_multipart()
        except zmq.Again:  # a REQ socket that timed out is stuck: a new one for the next
            self.socket.close(linger=0)
            self.socket = self._connect()
            raise

    def request(self, kind: str, *payload: bytes, protocol: int = 2) -> list[bytes]:
        self.next_id += 1
        return self.raw([HEADER.pack(protocol, ord(kind), self.next_id), *payload])

    def json(self, kind: str, value: Any) -> list[bytes]:
        return self.request(kind, json.dumps(value).encode())

    def close(self) -> None:
        self.context.destroy(linger=0)


@contextlib.contextmanager
def client(port: int, timeout: float = 5.0) -> Iterator[Client]:
    c = Client(port, timeout)
    try:
        yield c
    finally:
        c.close()


def elements(xml: bytes) -> list[tuple[int, str, str]]:
    """(uid, what the element is, its name) for every node of the main tree, in document order.
    What it is: the registration ID (``<Condition ID="X"/>`` and ``<X/>`` are both X)."""
    root = ET.fromstring(xml)
    body = root.find("BehaviorTree")
    assert body is not None
    out = []
    for el in body.iter():
        if el is body:
            continue
        what = el.get("ID", el.tag) if el.tag in CONTROL_TAGS else el.tag
        out.append((int(el.get("_uid", "-1")), what, el.get("name", "")))
    return out


def statuses(buffer: bytes) -> list[tuple[int, int]]:
    """(uid, status byte) records of a STATUS reply."""
    assert len(buffer) % 3 == 0
    return [struct.unpack_from("<HB", buffer, i) for i in range(0, len(buffer), 3)]


def is_uuid4(tree_id: bytes) -> bool:
    return len(tree_id) == 16 and tree_id[6] & 0xF0 == 0x40 and tree_id[8] & 0xC0 == 0x80
