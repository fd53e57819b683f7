"""Our Groot2 publisher against BehaviorTree.CPP's own ``Groot2Publisher`` (through
``behaviortreepy``): the same port-less tree, ticked with the same leaf outcomes, asked the same
requests. Replies must have the same structure, and the same bytes where the protocol fixes them
(spec/groot2.md section 7)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass, field

import pytest

import ktbt_proto as kp
from ktbt_proto.interop.btcpp import to_xml
from tests.groot2_helpers import (
    PORTLESS,
    Client,
    client,
    elements,
    is_uuid4,
    reserve_ports,
    statuses,
)

bt = pytest.importorskip("behaviortreepy", reason="pip install 'ktbt[btcpp]'")
groot2 = pytest.importorskip("ktbt_proto.interop.groot2", reason="pip install 'ktbt[groot]'")


@dataclass
class World:
    """What every leaf returns, shared by both engines."""

    collision: bool = False
    in_zone: bool = True
    avoidance: kp.Status = kp.RUNNING
    calls: list[str] = field(default_factory=list)


def _btcpp_xml() -> str:
    """What ``ktbt convert`` writes for the tree, loaded by BT.CPP as it is."""
    return to_xml(kp.parse(PORTLESS))


class Pair:
    """The same tree in LiveTree and BehaviorTree.CPP, each served by its own publisher."""

    def __init__(self) -> None:
        self.world = w = World()
        reg = kp.Registry()
        reg.add_condition("_collisionDetectedF", lambda bb: w.collision)
        reg.add_condition("_inZoneF", lambda bb: w.in_zone)
        reg.add_action("CollisionAvoidance", lambda bb: w.avoidance)
        reg.add_action("WalkToCollection", lambda bb: kp.SUCCESS)
        reg.add_action("RandomWalk", lambda bb: kp.RUNNING)
        self.live = kp.LiveTree(PORTLESS, reg)
        s = bt.NodeStatus
        to_bt = {kp.SUCCESS: s.SUCCESS, kp.FAILURE: s.FAILURE, kp.RUNNING: s.RUNNING}
        factory = bt.BehaviorTreeFactory()
        factory.register_simple_condition(
            "_collisionDetectedF", lambda n: s.SUCCESS if w.collision else s.FAILURE
        )
        factory.register_simple_condition(
            "_inZoneF", lambda n: s.SUCCESS if w.in_zone else s.FAILURE
        )
        factory.register_simple_action("WalkToCollection", lambda n: s.SUCCESS)
        factory.register_simple_stateful_action(
            "CollisionAvoidance", lambda n: to_bt[w.avoidance], lambda n: to_bt[w.avoidance]
        )
        factory.register_simple_stateful_action(
            "RandomWalk", lambda n: s.RUNNING, lambda n: s.RUNNING
        )
        self.factory = factory
        self.tree = factory.create_tree_from_text(_btcpp_xml())
        self.ours_port, self.theirs_port = reserve_ports(2)
        self.ours = groot2.Groot2Publisher(self.live, self.ours_port)
        self.theirs = bt.Groot2Publisher(self.tree, self.theirs_port)
        self.us = Client(self.ours_port)
        self.them = Client(self.theirs_port)

    def tick(self) -> None:
        self.live.tick()
        self.tree.tick_once()

    def both(self, kind: str, *payload: bytes, protocol: int = 2) -> tuple[list[bytes], ...]:
        return (
            self.us.request(kind, *payload, protocol=protocol),
            self.them.request(kind, *payload, protocol=protocol),
        )

    def close(self) -> None:
        self.us.close()
        self.them.close()
        self.ours.close()
        del self.theirs  # BT.CPP's publisher unbinds when destroyed


@pytest.fixture
def pair() -> Iterator[Pair]:
    p = Pair()
    try:
        yield p
    finally:
        p.close()


def _same_header(ours: list[bytes], theirs: list[bytes]) -> None:
    assert len(ours[0]) == len(theirs[0]) == 22
    assert ours[0][:6] == theirs[0][:6]  # protocol, type and request id, echoed
    assert is_uuid4(ours[0][6:]) and is_uuid4(theirs[0][6:])


def test_full_tree_has_the_same_nodes_and_ids(pair: Pair) -> None:
    ours, theirs = pair.both("T")
    assert len(ours) == len(theirs) == 2
    _same_header(ours, theirs)
    mine = [(uid, what) for uid, what, _ in elements(ours[1])]
    btcpp = [(uid, what) for uid, what, _ in elements(theirs[1])]
    assert mine == btcpp
    assert [uid for uid, _ in mine] == list(range(1, 12))


def test_statuses_are_the_same_bytes_tick_by_tick(pair: Pair) -> None:
    ours, theirs = pair.both("S")
    _same_header(ours, theirs)
    assert ours[1] == theirs[1]  # nothing ticked yet: every node IDLE
    w = pair.world
    script = [
        (False, True, kp.RUNNING),  # RandomWalk runs
        (True, True, kp.RUNNING),  # a collision: avoidance runs, RandomWalk is halted
        (True, True, kp.SUCCESS),  # avoidance done
        (False, False, kp.SUCCESS),  # out of the zone: WalkToCollection succeeds
        (False, True, kp.RUNNING),  # RandomWalk again
    ]
    for collision, in_zone, avoidance in script:
        w.collision, w.in_zone, w.avoidance = collision, in_zone, avoidance
        pair.tick()
        ours, theirs = pair.both("S")
        assert statuses(ours[1]) == statuses(theirs[1]), (collision, in_zone, avoidance)
        assert ours[1] == theirs[1]


def test_blackboard_dump_is_the_same_bytes(pair: Pair) -> None:
    pair.live.blackboard.update({"count": 3, "name": "r1"})
    board = pair.tree.root_blackboard()
    board.set_int("count", 3)
    board.set_string("name", "r1")
    for names in (b"MainTree", b"", b"nobody", b"MainTree;nobody"):
        ours, theirs = pair.both("B", names)
        _same_header(ours, theirs)
        assert ours[1:] == theirs[1:], names


def test_hooks_replace_a_result_in_both(pair: Pair) -> None:
    """A pre-tick hook that forces ``_collisionDetectedF`` to SUCCESS makes both trees avoid."""
    uid = next(u for u, what, _ in elements(pair.both("T")[0][1]) if what == "_collisionDetectedF")
    hook = {
        "uid": uid,
        "position": 0,
        "enabled": True,
        "mode": 1,
        "once": False,
        "desired_status": "SUCCESS",
    }
    ours, theirs = pair.both("D")
    assert ours[1:] == theirs[1:] == [b"[]"]
    ours, theirs = pair.both("I", json.dumps(hook).encode())
    assert len(ours) == len(theirs) == 1
    _same_header(ours, theirs)
    ours, theirs = pair.both("D")
    assert ours[1:] == theirs[1:]
    assert json.loads(ours[1]) == [hook]
    pair.tick()
    ours, theirs = pair.both("S")
    assert ours[1] == theirs[1]
    running = {u for u, byte in statuses(ours[1]) if byte == 1}
    avoid = next(u for u, what, _ in elements(pair.both("T")[0][1]) if what == "CollisionAvoidance")
    assert avoid in running
    removal = json.dumps({"uid": uid, "position": 0}).encode()
    ours, theirs = pair.both("R", removal)
    assert len(ours) == len(theirs) == 1
    ours, theirs = pair.both("R", removal)  # gone: both say so
    assert ours == theirs == [b"error", b"Node ID not found"]
    unlock = {"uid": uid, "position": 0, "desired_status": "SUCCESS", "remove_when_done": True}
    ours, theirs = pair.both("U", json.dumps(unlock).encode())
    assert ours == theirs == [b"error", b"Node ID not found"]
    for kind in "AX":
        ours, theirs = pair.both(kind)
        assert len(ours) == len(theirs) == 1
        _same_header(ours, theirs)


def test_recording_has_the_same_structure(pair: Pair) -> None:
    ours, theirs = pair.both("r", b"start")
    assert len(ours) == len(theirs) == 2
    assert ours[1].isdigit() and theirs[1].isdigit()
    assert abs(int(ours[1]) - int(theirs[1])) < 60_000_000  # microseconds since the epoch
    pair.tick()
    ours, theirs = pair.both("t")
    assert len(ours) == len(theirs) == 2
    assert len(ours[1]) % 9 == 0 and len(theirs[1]) % 9 == 0 and ours[1] and theirs[1]
    ids = {u for u, _, _ in elements(pair.both("T")[0][1])}
    for record in (ours[1][i : i + 9] for i in range(0, len(ours[1]), 9)):
        assert int.from_bytes(record[6:8], "little") in ids and record[8] in (0, 1, 2, 3)
    ours, theirs = pair.both("r", b"stop")
    assert len(ours) == len(theirs) == 1


@pytest.mark.parametrize(
    "frames",
    [
        [b"abc"],
        [b"\x02S\x00\x00\x00\x00\x00"],
        [bytes([2, ord("Z"), 0, 0, 0, 0])],
        [bytes([2, 0, 0, 0, 0, 0])],
        [bytes([2, ord("B"), 1, 0, 0, 0])],
        [bytes([2, ord("I"), 1, 0, 0, 0])],
        [bytes([2, ord("U"), 1, 0, 0, 0])],
        [bytes([2, ord("R"), 1, 0, 0, 0])],
        [bytes([2, ord("r"), 1, 0, 0, 0])],
    ],
)
def test_malformed_requests_get_the_same_error(pair: Pair, frames: list[bytes]) -> None:
    assert pair.us.raw(frames) == pair.them.raw(frames)


def test_another_protocol_id_is_refused_where_btcpp_answers(pair: Pair) -> None:
    """A difference (spec/groot2.md section 6): BT.CPP answers a request of another
    protocol as if it were protocol 2, and overwrites the id in its reply; we refuse it."""
    ours, theirs = pair.both("S", protocol=3)
    assert ours[0] == b"error"
    assert theirs[0][0] == 2 and len(theirs) == 2


def test_the_served_xml_loads_in_btcpp(pair: Pair) -> None:
    """The XML we serve loads in BehaviorTree.CPP itself (the ids and names we add are its own
    attributes) and ticks as ours does."""
    with client(pair.ours_port) as c:
        xml = c.request("T")[1].decode()
    reloaded = pair.factory.create_tree_from_text(xml)
    assert reloaded.tick_once() == bt.NodeStatus.RUNNING
    assert pair.live.tick() is kp.RUNNING
