"""The monitor's ear on a real zenoh network (spec/protocol.md section 10): hostile catalogs
are counted and the reading goes on; a forger flooding a peer's key spends its own tokens."""

from __future__ import annotations

from collections.abc import Iterator
from datetime import datetime
from typing import Any

import pytest

from ktbt_proto.exchange.events import FleetEvent, encode_event, signed_bytes
from ktbt_proto.exchange.signing import Identity
from ktbt_proto.tools.monitor import listen
from ktbt_proto.tools.monitor.listen import Listener
from ktbt_proto.tools.monitor.state import FleetState
from tests.zenoh_helpers import endpoint, free_port, settings, wait_until

GREEN = "<c>(TargetSeen,colour=2)"


@pytest.fixture
def heard(monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[FleetState, Any]]:
    """A listener on a port of loopback, and a session of the fleet connected to it."""
    from ktbt_proto.transport.zenoh import ZenohSettings, open_session

    monkeypatch.setattr(listen, "CATALOG_EVERY", 0.1)
    port = free_port()
    fleet = FleetState()
    listener = Listener(fleet, settings(port))
    try:
        session = open_session(ZenohSettings(connect=[endpoint(port)]))
        try:
            yield fleet, session
        finally:
            session.close()  # type: ignore[no-untyped-call]
    finally:
        listener.close()


def test_a_hostile_catalog_is_counted_and_the_catalogs_are_still_read(
    heard: tuple[FleetState, Any],
) -> None:
    fleet, session = heard
    good = session.declare_queryable(
        "ktbt/v1/catalog/good", lambda q: q.reply("ktbt/v1/catalog/good", f'["{GREEN}"]'.encode())
    )
    evil = session.declare_queryable(
        "ktbt/v1/catalog/evil", lambda q: q.reply("ktbt/v1/catalog/evil", b'["\\ud800"]')
    )
    try:
        assert wait_until(lambda: fleet.drops["malformed"] >= 3, 15), fleet.stats()
        assert "good" in fleet.peers and fleet.peers["good"].knows
        assert "evil" not in fleet.peers or not fleet.peers["evil"].knows
    finally:
        evil.undeclare()
        good.undeclare()


def test_a_forger_flooding_a_peers_key_does_not_silence_the_peer(
    heard: tuple[FleetState, Any],
) -> None:
    import zenoh

    fleet, session = heard
    r1 = Identity.generate()
    now = datetime.now().astimezone().isoformat(timespec="milliseconds")

    def signed(n: int) -> bytes:
        event = FleetEvent(peer="r1", n=n, t=now, event="query-sent", key=r1.public)
        return encode_event(event.model_copy(update={"sig": r1.sign(signed_bytes(event))}))

    publisher = session.declare_publisher(
        "ktbt/v1/events/r1", congestion_control=zenoh.CongestionControl.BLOCK
    )
    try:
        publisher.put(signed(0))
        assert wait_until(lambda: fleet.events == 1, 10)
        for n in range(5000):  # unsigned, on r1's key: the monitor must drop them
            publisher.put(encode_event(FleetEvent(peer="r1", n=n + 1, t=now, event="merged")))
        publisher.put(signed(1))  # at once, while the forger's tokens are spent
        assert wait_until(lambda: fleet.drops["forged"] + fleet.drops["flood"] >= 5000, 15)
        assert fleet.drops["flood"] > 0, fleet.stats()
        assert wait_until(lambda: fleet.peers["r1"].last_n == 1, 10), fleet.stats()
    finally:
        publisher.undeclare()


def test_a_hostile_tree_reply_is_refused_and_counted_and_a_large_tree_not_served() -> None:
    from ktbt_proto.exchange.messages import MAX_MESSAGE_BYTES
    from ktbt_proto.transport.zenoh import ZenohSettings, ZenohTransport, open_session

    port = free_port()
    fleet = FleetState()
    listener = Listener(fleet, settings(port))
    try:
        session = open_session(ZenohSettings(connect=[endpoint(port)]))
        replies = {
            "good": GREEN.encode(),
            "junk": b"<sq><c>(A)",  # not closed: not stringBT
            "big": b"<c>(" + b"A" * (MAX_MESSAGE_BYTES + 1) + b")",
            "deep": b"<sq>" * 100 + b"<c>(A)" + b"<e>" * 100,  # beyond the depth limit
        }

        def answering(name: str, body: bytes) -> Any:
            def reply(query: Any) -> None:
                query.reply(f"ktbt/v1/tree/{name}", body)

            return session.declare_queryable(f"ktbt/v1/tree/{name}", reply)

        declared = [answering(name, body) for name, body in replies.items()]
        served = ZenohTransport(
            "huge",
            ZenohSettings(connect=[endpoint(port)]),
            publish_events=True,
            tree=lambda: "<c>(" + "A" * MAX_MESSAGE_BYTES + ")",
        )
        silent = ZenohTransport(
            "quiet", ZenohSettings(connect=[endpoint(port)]), tree=lambda: GREEN
        )
        try:
            assert wait_until(lambda: listener.tree("good") is not None, 10)
            assert "TargetSeen" in (listener.tree("good") or "")
            before = fleet.drops["malformed"]
            for name in ("junk", "big", "deep"):
                assert listener.tree(name) is None, name
            assert fleet.drops["malformed"] == before + 3, fleet.stats()
            reasons = " ".join(fleet.reasons["malformed"])
            assert "tree of junk" in reasons and "tree of big" in reasons, reasons
            said = listener.tree("huge") or ""
            assert "the control tree is" in said and str(MAX_MESSAGE_BYTES) in said, said
            assert listener.tree("quiet") is None  # no --publish-events: no tree on the network
            assert listener.tree("<b>") is None
        finally:
            silent.close()
            served.close()
            for entity in declared:
                entity.undeclare()
            session.close()  # type: ignore[no-untyped-call]
    finally:
        listener.close()
