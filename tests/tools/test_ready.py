"""``--ready FILE`` (spec/protocol.md section 4.5): what a supervisor such as ``ktbt fleet run``
reads to learn that a peer or router is up, instead of its printed text. Real processes on
loopback, each waited on by its file appearing."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.zenoh_helpers import ROOT, endpoint, free_port, ktbt_process, wait_until

pytestmark = pytest.mark.network

COLOURS = ROOT / "examples" / "knowledge" / "colours.sbt"


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["router"], {"peer": "router", "knows": None}),
        (["serve", "--id", "t1", "--knowledge", str(COLOURS)], {"peer": "t1", "knows": 4}),
        (["run", "--id", "r1", "--knowledge", str(COLOURS), "--duration", "600"],
         {"peer": "r1", "knows": 4}),
    ],
)  # fmt: skip
def test_a_process_says_it_is_up_in_its_ready_file(
    tmp_path: Path, args: list[str], said: dict[str, object]
) -> None:
    ready = tmp_path / "up.json"
    with ktbt_process("peer", *args, "--listen", endpoint(free_port()), "--ready", str(ready)):
        assert wait_until(ready.exists, 60), f"{args[0]} never wrote {ready}"
        assert json.loads(ready.read_text()) == said
    assert not list(tmp_path.glob("*.tmp*"))  # written whole, by a rename
