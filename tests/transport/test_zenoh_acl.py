"""The shipped access-control profile (examples/zenoh/acl-router.json5) over mutual TLS
on
loopback: a robot answers, publishes events and serves its tree under its own name, a robot
whose certificate names another peer cannot declare that peer's queryables, and only the
monitor hears events and asks for trees (spec/protocol.md section 9)."""

from __future__ import annotations

import datetime
import json
from pathlib import Path
from typing import Any

import pytest
import zenoh
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

import ktbt_proto as kp
from ktbt_proto.exchange.answers import answers
from ktbt_proto.exchange.knowledge import KnowledgeBase
from ktbt_proto.exchange.messages import Query, Response, decode, encode
from ktbt_proto.transport.zenoh import ZenohSettings, ZenohTransport
from tests.zenoh_helpers import ROOT, free_port, see, wait_until

pytestmark = pytest.mark.network  # a zenoh router and robots over mutual TLS on loopback

PROFILE = ROOT / "examples" / "zenoh" / "acl-router.json5"
KNOWLEDGE = ROOT / "examples" / "knowledge" / "colours.sbt"
GREEN = "<c>(TargetSeen,colour=2)"


def _pem(path: Path, key: ec.EllipticCurvePrivateKey, cert: x509.Certificate) -> None:
    path.with_suffix(".pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    path.with_suffix(".key").write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )
    )


def make_fleet_pki(folder: Path, *robots: str) -> None:
    """A CA, the router's certificate for localhost, and one client certificate per robot
    whose common name is the robot's peer name."""
    now = datetime.datetime.now(datetime.UTC)

    def build(cn: str, key: Any, issuer: x509.Name, signer: Any, ca: bool) -> x509.Certificate:
        builder = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)]))
            .issuer_name(issuer)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True)
        )
        if not ca:
            builder = builder.add_extension(
                x509.SubjectAlternativeName([x509.DNSName("localhost")]), critical=False
            )
        return builder.sign(signer, hashes.SHA256())

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "ktbt fleet CA")])
    ca = build("ktbt fleet CA", ca_key, ca_name, ca_key, True)
    (folder / "ca.pem").write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    for cn in ("router", *robots):
        key = ec.generate_private_key(ec.SECP256R1())
        _pem(
            folder / cn,
            key,
            build("localhost" if cn == "router" else cn, key, ca_name, ca_key, False),
        )


def robot_settings(folder: Path, name: str, port: int) -> ZenohSettings:
    config = folder / f"{name}.json5"
    tls = {
        "root_ca_certificate": str(folder / "ca.pem"),
        "connect_certificate": str(folder / f"{name}.pem"),
        "connect_private_key": str(folder / f"{name}.key"),
        "enable_mtls": True,
    }
    config.write_text(json.dumps({"transport": {"link": {"tls": tls}}}))
    return ZenohSettings(connect=[f"tls/localhost:{port}"], config=config, mode="client")


def router(folder: Path, port: int, acl: bool) -> Any:
    conf = zenoh.Config.from_file(str(PROFILE))
    for key, value in {
        "listen/endpoints": [f"tls/localhost:{port}"],
        "transport/link/tls/root_ca_certificate": str(folder / "ca.pem"),
        "transport/link/tls/listen_certificate": str(folder / "router.pem"),
        "transport/link/tls/listen_private_key": str(folder / "router.key"),
        "access_control/enabled": acl,
    }.items():
        conf.insert_json5(key, json.dumps(value))
    return zenoh.open(conf)


@pytest.mark.parametrize("acl", [True, False], ids=["profile", "without-access-control"])
def test_only_the_named_robot_serves_its_name(tmp_path: Path, acl: bool) -> None:
    make_fleet_pki(tmp_path, "t", "m", "r1")
    port = free_port()
    kb = KnowledgeBase.from_tree(kp.parse(KNOWLEDGE.read_text()))
    reached: list[str] = []
    session = router(tmp_path, port, acl)
    try:
        with (
            ZenohTransport("t", robot_settings(tmp_path, "t", port), lookup=answers(kb)),
            ZenohTransport("m", robot_settings(tmp_path, "m", port), serving=False) as impostor,
            ZenohTransport("r1", robot_settings(tmp_path, "r1", port), serving=False) as asker,
        ):

            def forge(q: Any) -> None:
                asked = decode(q.payload.to_bytes())
                reached.append(asked.id)
                forged = Response(id=asked.id, sender="t", sequence=GREEN, subtree="<a>(X)")
                q.reply("ktbt/v1/knowledge/t", encode(forged))
                q.drop()

            impostor._declared.append(
                impostor.session.declare_queryable("ktbt/v1/knowledge/t", forge)
            )
            see(asker, "t")
            # The router handles what one peer sends in order: once the impostor's late answer,
            # put after its declaration, reaches the asker's inbox, the declaration has reached
            # the router and been routed, or denied.
            late = Response(id="after", sender="m", sequence=GREEN, subtree="<a>(Wait)")
            impostor.session.put("ktbt/v1/inbox/r1", encode(late))
            assert wait_until(lambda: any(m.id == "after" for m in asker.receive()))
            got = asker.ask(Query(id="q1", sender="r1", sequence=GREEN), 3)
    finally:
        session.close()
    if acl:
        # The robot with t's certificate answers; no query reached the impostor's queryable.
        assert [(a.sender, a.subtree != "<a>(X)") for a in got] == [("t", True)]
        assert reached == [] and asker.refused == 0
    else:
        # Without the profile, the impostor hears the query and answers in t's name (on the
        # `any` policy, whichever of the two comes first takes t's place).
        assert reached == ["q1"] and [a.sender for a in got] == ["t"]


@pytest.mark.parametrize("acl", [True, False], ids=["profile", "without-access-control"])
def test_a_robot_publishes_events_on_its_own_key_and_only_the_monitor_hears_them(
    tmp_path: Path, acl: bool
) -> None:
    from ktbt_proto.transport.zenoh import open_session

    make_fleet_pki(tmp_path, "r1", "m", "monitor")
    port = free_port()
    heard: list[str] = []
    overheard: list[str] = []
    inbox: list[bytes] = []
    session = router(tmp_path, port, acl)
    opened = []
    try:
        r1, impostor, monitor = (
            open_session(robot_settings(tmp_path, name, port)) for name in ("r1", "m", "monitor")
        )
        opened = [r1, impostor, monitor]
        monitor.declare_subscriber("ktbt/v1/events/*", lambda s: heard.append(str(s.key_expr)))
        impostor.declare_subscriber("ktbt/v1/events/*", lambda s: overheard.append(str(s.key_expr)))
        r1.declare_subscriber("ktbt/v1/inbox/r1", lambda s: inbox.append(s.payload.to_bytes()))
        assert wait_until(lambda: (r1.put("ktbt/v1/events/r1", b"0"), heard)[1] != [])
        impostor.put("ktbt/v1/events/t", b"forged")
        impostor.put("ktbt/v1/inbox/r1", b"after")  # handled after the forged put
        assert wait_until(lambda: b"after" in inbox)
        before = heard.count("ktbt/v1/events/r1")
        r1.put("ktbt/v1/events/r1", b"last")
        assert wait_until(lambda: heard.count("ktbt/v1/events/r1") > before)
        if not acl:
            assert wait_until(
                lambda: "ktbt/v1/events/t" in heard and "ktbt/v1/events/r1" in overheard
            )
    finally:
        for opened_session in opened:
            opened_session.close()  # type: ignore[no-untyped-call]
        session.close()
    if acl:
        # The impostor hears only its own put (a session delivers to itself), never r1's.
        assert set(heard) == {"ktbt/v1/events/r1"} and set(overheard) <= {"ktbt/v1/events/t"}


@pytest.mark.parametrize("acl", [True, False], ids=["profile", "without-access-control"])
def test_only_the_monitor_asks_for_trees_and_each_robot_serves_its_own(
    tmp_path: Path, acl: bool
) -> None:
    """The control tree of a robot publishing events (section 10) reaches the monitor; a
    robot's queryable on another's tree key gets no query, its reply on another's tree key
    never leaves the router, and a robot asking for a tree gets none."""
    from ktbt_proto.formatter import format_tree
    from ktbt_proto.render import render
    from ktbt_proto.tools.monitor.listen import Listener
    from ktbt_proto.tools.monitor.state import FleetState
    from ktbt_proto.transport.zenoh import open_session

    make_fleet_pki(tmp_path, "t", "r1", "monitor")
    port = free_port()
    kb = KnowledgeBase.from_tree(kp.parse(KNOWLEDGE.read_text()))
    tree = format_tree(kb.tree(), "compact")
    forged: list[str] = []  # queries that reached r1's queryable on t's tree key
    misplaced: list[str] = []  # queries r1's own tree queryable answered on t's key

    def forge(q: Any) -> None:
        forged.append(str(q.key_expr))
        q.reply("ktbt/v1/tree/t", b"<a>(Forged)")
        q.drop()

    def misplace(q: Any) -> None:
        misplaced.append(str(q.key_expr))
        q.reply("ktbt/v1/tree/t", b"<a>(Misplaced)")  # the query accepts any key
        q.drop()

    def replies(session: Any, key: str, **options: Any) -> list[tuple[str, bytes]]:
        # Every reply: zenoh's default consolidation keeps one a key, so a forged reply on
        # t's key could hide behind t's own (or t's behind it).
        none = zenoh.ConsolidationMode.NONE
        return [
            (str(r.ok.key_expr), r.ok.payload.to_bytes())
            for r in session.get(key, timeout=1.0, consolidation=none, **options)
            if r.ok is not None
        ]

    session = router(tmp_path, port, acl)
    opened: list[Any] = []
    try:
        t = ZenohTransport(
            "t",
            robot_settings(tmp_path, "t", port),
            lookup=answers(kb),
            publish_events=True,
            tree=lambda: tree,
        )
        opened.append(t)
        r1 = open_session(robot_settings(tmp_path, "r1", port))
        opened.append(r1)
        r1.declare_queryable("ktbt/v1/tree/t", forge)
        r1.declare_queryable("ktbt/v1/tree/r1", misplace)
        # What one peer sends the router handles in order: once this late answer reaches t's
        # inbox, both declarations have been routed, or denied.
        late = Response(id="after", sender="r1", sequence=GREEN, subtree="<a>(Wait)")
        r1.put("ktbt/v1/inbox/t", encode(late))
        assert wait_until(lambda: any(m.id == "after" for m in t.receive()))
        fleet = FleetState()
        listener = Listener(fleet, robot_settings(tmp_path, "monitor", port))
        opened.append(listener)
        assert wait_until(lambda: listener.tree("t") == render(kp.parse(tree)))
        monitor = open_session(robot_settings(tmp_path, "monitor", port))
        opened.append(monitor)
        everyone = replies(monitor, "ktbt/v1/tree/t", target=zenoh.QueryTarget.ALL)
        anywhere = replies(monitor, "ktbt/v1/tree/r1", accept_replies=zenoh.ReplyKeyExpr.ANY)
        by_robot = replies(r1, "ktbt/v1/tree/t", allowed_destination=zenoh.Locality.REMOTE)
    finally:
        for entity in reversed(opened):
            entity.close()
        session.close()
    assert misplaced != []  # r1's own tree key is asked in either case
    if acl:
        # Every queryable on t's key was asked: only t's answered; r1's reply on t's key was
        # stopped; a robot asking for a tree gets nothing.
        assert forged == [] and everyone == [("ktbt/v1/tree/t", tree.encode())]
        assert anywhere == [] and by_robot == []
    else:
        assert forged != [] and ("ktbt/v1/tree/t", b"<a>(Forged)") in everyone
        assert anywhere == [("ktbt/v1/tree/t", b"<a>(Misplaced)")]
        assert ("ktbt/v1/tree/t", tree.encode()) in by_robot
