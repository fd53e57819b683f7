"""Signed knowledge, trust policies, typed arguments, floods and the transfer log, on the
in-memory transport and on files (spec/protocol.md sections 2, 5, 7 and 8)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Annotated

import pytest
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import Field
from typer.testing import CliRunner

import ktbt_proto as kp
from ktbt_proto.exchange.agent import Agent, Timing
from ktbt_proto.exchange.knowledge import KnowledgeBase
from ktbt_proto.exchange.messages import (
    MessageRefused,
    Query,
    Response,
    decode,
    encode,
    schema_text,
)
from ktbt_proto.exchange.security import Security
from ktbt_proto.exchange.signing import (
    Identity,
    KeyFileError,
    b64,
    hop_bytes,
    item_bytes,
    unb64,
    verify,
)
from ktbt_proto.exchange.transferlog import Event, TransferLog, read
from ktbt_proto.exchange.trust import Policy, TrustStore, refusal
from ktbt_proto.tools.cli import app
from ktbt_proto.transport import MemoryNetwork

ROOT = Path(__file__).resolve().parents[2]
SEQ = "<c>(TargetSeen,colour=2)"
SUB = "<sq><a>(Pick,colour=2)<e>"
CONTROL = "<sl><k>(prior)<e><k>(new)<e><a>(Walk)<e>"
KNOWER = f"<sl><k>(prior)<sq>{SEQ}{SUB}<e><e><k>(new)<e><a>(Walk)<e>"
SEQUENCE = ["TargetSeen(colour=2)"]
Colour = Annotated[int, Field(ge=1, le=4)]


class Gripper:
    """A stateful action with a typed argument: built when a tree holding it is merged."""

    def __init__(self, bb: kp.Blackboard, force: int) -> None:
        self.force = force + 0

    def tick(self) -> kp.Status:
        return kp.SUCCESS

    def halt(self) -> None:
        pass


def registry() -> kp.Registry:
    reg = kp.Registry()

    @reg.condition("TargetSeen")
    def target_seen(bb: kp.Blackboard, colour: Colour) -> bool:
        return bool(bb.get("target") == colour)

    @reg.action("Pick")
    def pick(bb: kp.Blackboard, colour: Colour = 1) -> kp.Status:
        bb["picked"] = colour + 0  # a string here would raise at tick time
        return kp.SUCCESS

    @reg.action("Walk")
    def walk(bb: kp.Blackboard) -> kp.Status:
        return kp.RUNNING

    reg.add_action("Grip", Gripper)
    return reg


def agent(
    net: MemoryNetwork,
    name: str,
    tree: str = CONTROL,
    *,
    security: Security = Security(),  # noqa: B008
    repeat_every: int = 0,
    knowledge_path: str | Path | None = None,
) -> Agent:
    return Agent(
        name,
        tree,
        registry(),
        net.join(name),
        timing=Timing(wait=20, cooldown=5, repeat_every=repeat_every),
        security=security,
        knowledge_path=knowledge_path,
    )


def run(net: MemoryNetwork, agents: list[Agent], ticks: int) -> None:
    for _ in range(ticks):
        net.step()
        for a in agents:
            a.tick()


# -- the signed bytes, as the spec gives them -------------------------------------------------


def test_signing_vector_verifies_as_specified() -> None:
    vector = json.loads((ROOT / "spec" / "vectors" / "signing.json").read_text())
    author = Identity.from_seed(bytes.fromhex(vector["author_seed"]))
    hop = Identity.from_seed(bytes.fromhex(vector["hop_seed"]))
    assert (author.public, hop.public) == (vector["author"], vector["hop_key"])
    response = decode(json.dumps(vector["response"]).encode())
    assert isinstance(response, Response)
    assert item_bytes(response.sequence, response.subtree).hex() == vector["item_bytes_hex"]
    unsigned = response.model_copy(update={"key": None, "hop": None})
    assert hop_bytes(unsigned).hex() == vector["hop_bytes_hex"]
    # Ed25519 is deterministic: the same key and bytes give the vector's signatures.
    assert author.sign(bytes.fromhex(vector["item_bytes_hex"])) == response.signature
    assert hop.sign(bytes.fromhex(vector["hop_bytes_hex"])) == response.hop
    assert refusal(response, Policy.TRUSTED, TrustStore.parse(vector["author"])) is None
    # A second, independent implementation gives the same keys and signatures.
    theirs = Ed25519PrivateKey.from_private_bytes(bytes.fromhex(vector["author_seed"]))
    assert b64(theirs.public_key().public_bytes_raw()) == vector["author"]
    assert b64(theirs.sign(bytes.fromhex(vector["item_bytes_hex"]))) == response.signature


def test_signatures_and_key_files_agree_with_a_second_implementation(tmp_path: Path) -> None:
    """OpenSSL's Ed25519 (through ``cryptography``) and ours accept each other's signatures and
    key files: a key written by either loads in the other and signs the same bytes alike."""
    data = item_bytes(SEQ, SUB)
    theirs = Ed25519PrivateKey.generate()
    their_public = b64(theirs.public_key().public_bytes_raw())
    assert verify(their_public, b64(theirs.sign(data)), data)
    assert not verify(their_public, b64(theirs.sign(data)), data + b" ")
    ours = Identity.generate()
    ours_in_theirs = Ed25519PublicKey.from_public_bytes(unb64(ours.public))
    ours_in_theirs.verify(unb64(ours.sign(data)), data)  # raises when it does not verify
    with pytest.raises(InvalidSignature):
        ours_in_theirs.verify(unb64(ours.sign(data)), data + b" ")
    # Their PEM loads here, and ours there: the same key, the same signatures.
    pem = theirs.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    (tmp_path / "theirs.key").write_bytes(pem)
    loaded = Identity.load(tmp_path / "theirs.key")
    assert loaded.public == their_public
    assert loaded.sign(data) == b64(theirs.sign(data))
    ours.save(tmp_path / "ours.key")
    back = serialization.load_pem_private_key((tmp_path / "ours.key").read_bytes(), None)
    assert isinstance(back, Ed25519PrivateKey)
    assert b64(back.public_key().public_bytes_raw()) == ours.public
    assert b64(back.sign(data)) == ours.sign(data)
    # Other private keys they write are refused, naming the file: encrypted, another curve.
    others = {
        "encrypted.key": theirs.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.BestAvailableEncryption(b"secret"),
        ),
        "p256.key": ec.generate_private_key(ec.SECP256R1()).private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        ),
        "openssh.key": theirs.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.OpenSSH,
            serialization.NoEncryption(),
        ),
        "trailing.key": pem + pem,
    }
    for name, text in others.items():
        (tmp_path / name).write_bytes(text)
        with pytest.raises(KeyFileError, match=re.escape(str(tmp_path / name))):
            Identity.load(tmp_path / name)


def signed(author: Identity, hop: Identity, sender: str = "t", **change: str) -> Response:
    item = author.sign_item(SEQ, SUB)
    plain = Response(
        id="q",
        sender=sender,
        sequence=SEQ,
        subtree=SUB,
        author=item.author,
        signature=item.signature,
    )
    return hop.sign_reply(plain).model_copy(update=change)


def test_policies_and_forgeries() -> None:
    a, t, m = Identity.generate(), Identity.generate(), Identity.generate()
    good = signed(a, t)
    unsigned = Response(id="q", sender="t", sequence=SEQ, subtree=SUB)
    store = TrustStore.parse(f"# trusted authors\n{a.public}\nt {t.public}  # the teacher\n")
    assert refusal(unsigned, Policy.ANY) is None
    assert "not signed" in (refusal(unsigned, Policy.SIGNED) or "")
    assert refusal(good, Policy.SIGNED) is None
    assert refusal(good, Policy.TRUSTED, store) is None
    assert "not in the trust store" in (refusal(signed(m, t), Policy.TRUSTED, store) or "")
    # Forgeries are refused under every policy, "any" included.
    for forged in (
        good.model_copy(update={"subtree": "<a>(Walk)"}),  # the item changed
        good.model_copy(update={"sender": "x"}),  # the sender renamed
        good.model_copy(update={"id": "other"}),  # replayed to another query
    ):
        assert refusal(forged, Policy.ANY) is not None
    # A name the store binds must be signed by its key.
    assert "trust store gives t" in (refusal(signed(a, m), Policy.SIGNED, store) or "")
    # A key of small order "verifies" forged signatures in OpenSSL: it verifies nothing here.
    assert not any(verify("A" * 43, "A" * 86, bytes([n])) for n in range(16))
    with pytest.raises(KeyFileError):
        TrustStore.parse("A" * 43)


def test_key_files_and_trust_stores(tmp_path: Path) -> None:
    me = Identity.generate()
    public = me.save(tmp_path / "me.key")
    assert Identity.load(tmp_path / "me.key").public == me.public
    assert public.read_text().strip() == me.public
    assert (tmp_path / "me.key").stat().st_mode & 0o077 == 0
    with pytest.raises(FileExistsError):
        me.save(tmp_path / "me.key")
    for bad in ("/dev/zero", str(public), str(tmp_path / "none")):
        with pytest.raises(KeyFileError):
            Identity.load(bad)
    for text, where in (("a b c", ":1:"), ("\n\nnot-a-key", ":3:"), ("t " + "A" * 44, ":1:")):
        with pytest.raises(KeyFileError, match=where):
            TrustStore.parse(text)


# -- messages ---------------------------------------------------------------------------------


def test_wire_slips_are_closed() -> None:
    query = json.loads(encode(Query(id="q", sender="s", sequence=SEQ)))
    for bad in ({**query, "v": True}, {k: v for k, v in query.items() if k != "v"}):
        with pytest.raises(MessageRefused):
            decode(json.dumps(bad).encode())
    with pytest.raises(MessageRefused) as info:
        decode(b'{"type":"' + b"q" * 1000 + b'"}')
    assert len(info.value.reason) <= 200
    schema = json.loads(schema_text())
    for part in schema["$defs"].values():
        assert {"v", "type"} <= set(part["required"])
    # No response that every receiver would refuse can be built: the limits compose.
    with pytest.raises(ValueError, match="more than a message may"):
        Response(id="q", sender="s", sequence=SEQ, subtree="\x01" * 20_000)


# -- what an agent accepts ------------------------------------------------------------------


def answer_to(learner: Agent, subtree: str, sender: str = "evil") -> Response:
    asking = learner._asking
    assert asking is not None and asking.query is not None
    return Response(id=asking.query.id, sender=sender, sequence=SEQ, subtree=subtree)


@pytest.mark.parametrize(
    ("subtree", "reason"),
    [
        ("<a>(Pick,colour=-999)", "SBT310"),
        ('<a>(Pick,colour="red")', "SBT310"),
        ("<a>(Pick,colour=true)", "SBT310"),
        ("<a>(Grip,force=1.5)", "SBT310"),
        ("<w>(" + "9" * 200 + ")", "SBT307"),
        ("<tt1>(" + "9" * 200 + ")<a>(Walk)<e>", "SBT307"),
    ],
)
def test_harmful_knowledge_is_refused_before_the_merge(subtree: str, reason: str) -> None:
    net = MemoryNetwork()
    learner = agent(net, "i")
    evil = net.join("evil")
    learner.encounter(SEQUENCE)
    learner.tick()
    before = learner.control.tree
    evil.send("i", answer_to(learner, subtree))
    learner.blackboard["target"] = 2
    run(net, [learner], 3)  # would raise at tick time had it been merged
    assert not learner.knows(SEQUENCE) and learner.control.tree == before
    assert any(reason in why for _, why in learner.metrics.refusals)


def test_trusted_learner_refuses_unsigned_and_forged_answers_and_learns_the_signed_one(
    tmp_path: Path,
) -> None:
    author, teacher_key, mallory = Identity.generate(), Identity.generate(), Identity.generate()
    store = TrustStore.parse(f"{author.public}\n")
    net = MemoryNetwork()
    log = TransferLog(tmp_path / "i.log")
    learner = agent(net, "i", security=Security(policy=Policy.TRUSTED, trust=store, log=log))
    teacher = agent(net, "t", KNOWER, security=Security(identity=author))
    relay = agent(net, "r", security=Security(identity=teacher_key))
    evil = net.join("evil")
    learner.encounter(SEQUENCE)
    learner.tick()
    forged = mallory.sign_reply(answer_to(learner, "<a>(Walk)"))
    evil.send("i", answer_to(learner, "<a>(Walk)"))  # unsigned, and first
    evil.send("i", forged)  # signed by an untrusted key, and not by the author
    run(net, [learner, teacher], 3)
    assert learner.knows(SEQUENCE)
    item = learner.knowledge.lookup(SEQ)
    assert item is not None and (item.source, item.author) == ("t", author.public)
    assert learner.metrics.refused == 2
    # Taught onward, the item keeps its author and signature; the relay signs the hop.
    net2 = MemoryNetwork()
    source = agent(net2, "t", KNOWER, security=Security(identity=author))
    relay = agent(net2, "r", security=Security(identity=teacher_key))
    relay.encounter(SEQUENCE)
    run(net2, [relay, source], 3)
    assert relay.knows(SEQUENCE)
    source.transport.close()  # gone: only the relay can teach now
    third = agent(net2, "c", security=Security(policy=Policy.TRUSTED, trust=store), repeat_every=2)
    third.encounter(SEQUENCE)
    run(net2, [third, relay], 12)
    learned = third.knowledge.lookup(SEQ)
    assert learned is not None and (learned.source, learned.author) == ("r", author.public)
    log.close()
    events = [e for e in read(tmp_path / "i.log") if isinstance(e, dict)]
    assert [e["event"] for e in events].count("refused") == 2
    assert {"query-sent", "answer-received", "merged"} <= {e["event"] for e in events}


def test_a_flood_after_the_honest_answer_does_not_push_it_out() -> None:
    net = MemoryNetwork()
    learner = agent(net, "i")
    teacher = agent(net, "t", KNOWER)
    evil = net.join("evil")
    learner.encounter(SEQUENCE)
    learner.tick()
    teacher.tick()  # the honest answer is now in the learner's inbox
    junk = answer_to(learner, "<a>(Walk)")
    for _ in range(10_000):
        evil.send("i", junk)
    learner.tick()
    item = learner.knowledge.lookup(SEQ)
    assert item is not None and item.source == "t"
    refused = learner.metrics.refused + learner.transport.refused  # type: ignore[attr-defined]
    # Every junk answer is counted: refused at the full inbox, or, once in it, as a late answer
    # to a question the honest answer had already closed (never merged either way).
    late = learner.metrics.late_answers
    assert late > 0 and refused > 0
    assert refused + late == 10_000


# -- files ------------------------------------------------------------------------------------


def test_provenance_is_saved_and_shown(tmp_path: Path) -> None:
    author = Identity.generate()
    net = MemoryNetwork()
    learner = agent(net, "i", knowledge_path=tmp_path / "kb.json")
    teacher = agent(net, "t", KNOWER, security=Security(identity=author))
    learner.encounter(SEQUENCE)
    run(net, [learner, teacher], 3)
    saved = json.loads((tmp_path / "kb.json").read_text())["knowledge"][0]
    assert saved["author"] == author.public and saved["source"] == "t"
    assert verify(saved["author"], saved["signature"], item_bytes(SEQ, saved["subtree"]))
    assert saved["received_at"].endswith("+00:00")
    shown = CliRunner().invoke(app, ["kb", "show", str(tmp_path / "kb.json")])
    assert shown.exit_code == 0
    assert f"author    {author.public}" in shown.output and "(valid)" in shown.output
    assert "teacher   t" in shown.output
    bad = CliRunner().invoke(app, ["kb", "show", "/dev/zero"])
    assert bad.exit_code == 1 and "Traceback" not in bad.output


def test_a_truncated_save_file_keeps_its_whole_items(tmp_path: Path) -> None:
    path = tmp_path / "kb.json"
    items = [
        {
            "sequence": f"<c>(TargetSeen,colour={c})",
            "subtree": "<a>(Pick)",
            "segment": "new",
            "source": "t",
            "learned_at": 1,
        }
        for c in (1, 2, 3)
    ]
    text = json.dumps({"version": 1, "knowledge": items}, indent=1)
    path.write_text(text[: text.rindex("colour=3")])  # the third item torn
    net = MemoryNetwork()
    robot = agent(net, "i", knowledge_path=path)
    assert robot.knows(["TargetSeen(colour=1)"]) and robot.knows(["TargetSeen(colour=2)"])
    assert "kept 2 whole items" in robot.metrics.refusals[0][1]
    assert not path.exists() and len(list(tmp_path.glob("kb.json.damaged-*"))) == 1
    with pytest.raises(ValueError, match="larger than"):
        KnowledgeBase.load("/dev/zero")


def test_ktbt_log_reads_a_transfer_log(tmp_path: Path) -> None:
    path = tmp_path / "x.log"
    with TransferLog(path) as log:
        log.record(Event.QUERY_SENT, peer="i", id="q1", sequence=SEQ)
        log.record(Event.REFUSED, peer="i", reason="from x: the item is not signed by its author")
    with path.open("a") as f:
        f.write('{"torn')
    result = CliRunner().invoke(app, ["log", str(path), "--event", "refused"])
    assert result.exit_code == 0
    assert "i refused reason: from x: the item is not signed" in result.output
    assert "query-sent 1, refused 1" in result.output
    assert "line 3: not a JSON object" in result.output
    wrong = CliRunner().invoke(app, ["log", str(path), "--event", "refusd"])
    assert wrong.exit_code == 2 and "'query-sent'" in wrong.output  # the choices are listed


def test_keygen_writes_a_key_pair_and_a_trust_line(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["peer", "keygen", str(tmp_path / "r1.key"), "--id", "r1"])
    assert result.exit_code == 0, result.output
    line = result.output.strip().splitlines()[-1]
    assert TrustStore.parse(line).names["r1"] == Identity.load(tmp_path / "r1.key").public
    again = CliRunner().invoke(app, ["peer", "keygen", str(tmp_path / "r1.key")])
    assert again.exit_code == 2


def test_a_teacher_refuses_to_send_an_answer_no_peer_could_accept() -> None:
    huge = "<sq>" + "<a>(Pick,colour=2)" * 3_500 + "<e>"  # 63,000 characters, within its limits
    tree = f"<sl><k>(prior)<sq>{SEQ}{huge}<e><e><k>(new)<e><a>(Walk)<e>"
    net = MemoryNetwork()
    teacher = agent(net, "t", tree, security=Security(identity=Identity.generate()))
    learner = agent(net, "i")
    learner.encounter(SEQUENCE)
    run(net, [learner, teacher], 3)
    assert not learner.knows(SEQUENCE)
    assert any("cannot answer" in why for _, why in teacher.metrics.refusals)


def test_a_save_path_that_is_not_a_file_is_never_written(tmp_path: Path) -> None:
    net = MemoryNetwork()
    robot = agent(net, "i", knowledge_path="/dev/zero")
    assert robot.knowledge_path is None and "nothing will be saved" in robot.metrics.refusals[0][1]


AUTHOR, HOP = Identity.generate(), Identity.generate()


@settings(max_examples=60, deadline=None)
@given(
    sequence=st.text(min_size=1, max_size=40).filter(lambda t: "\x00" not in t),
    subtree=st.text(min_size=1, max_size=200).filter(lambda t: "\x00" not in t),
    field=st.sampled_from(["id", "sender", "sequence", "subtree"]),
)
def test_any_change_to_a_signed_answer_is_refused(sequence: str, subtree: str, field: str) -> None:
    item = AUTHOR.sign_item(sequence, subtree)
    answer = HOP.sign_reply(
        Response(
            id="q",
            sender="t",
            sequence=sequence,
            subtree=subtree,
            author=item.author,
            signature=item.signature,
        )
    )
    store = TrustStore.parse(AUTHOR.public)
    assert refusal(answer, Policy.TRUSTED, store) is None
    assert decode(encode(answer)) == answer
    changed = answer.model_copy(update={field: getattr(answer, field) + "x"})
    assert refusal(changed, Policy.ANY, store) is not None
