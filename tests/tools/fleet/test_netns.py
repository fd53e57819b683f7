"""The loss rule in a namespace of its own drops real packets between peers and routers (a
router listens on 127.3/16, a peer on 127.1/16), and the namespace goes with its rules."""

from __future__ import annotations

import os
import random
import shutil
import subprocess
import sys

import pytest

from ktbt_proto.tools.fleet import netns
from tests.zenoh_helpers import ROOT

pytestmark = pytest.mark.skipif(
    os.geteuid() != 0 or not shutil.which("ip") or not shutil.which("nft"),
    reason="needs root, ip and nft",
)

SEND = """
import socket, sys
from ktbt_proto.tools.fleet import netns
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
