"""What a receiver checks in an answer before it believes it (``ktbt_proto.exchange.receiving``,
spec/protocol.md section 2): each rule refuses with a one-line reason naming the sender, and an
answer that passes comes back parsed."""

from __future__ import annotations

import pytest

import ktbt_proto as kp
from ktbt_proto.exchange.answers import answer_to
from ktbt_proto.exchange.knowledge import Knowledge
from ktbt_proto.exchange.messages import Query, Response
from ktbt_proto.exchange.receiving import (
    RECEIVE_LIMITS,
    Refused,
    check,
    check_provenance,
    read_item,
)
from ktbt_proto.items import parse_sequence, sequence_key

SEQUENCE = sequence_key(["TargetSeen(colour=2)"])


def registry() -> kp.Registry:
    reg = kp.Registry()

    @reg.condition("TargetSeen")
    def target_seen(bb: kp.Blackboard, colour: int) -> bool:
        return bool(bb.get("target") == colour)

    @reg.action("Pick")
    def pick(bb: kp.Blackboard) -> kp.Status:
        return kp.SUCCESS

    return reg


def answer(subtree: str, sequence: str = SEQUENCE, sender: str = "t") -> Response:
    return Response(id="q1", sender=sender, sequence=sequence, subtree=subtree)


def test_an_answer_that_passes_comes_back_parsed() -> None:
    conditions, subtree = check(answer("<a>(Pick)"), SEQUENCE, registry=registry())
    assert sequence_key(conditions) == SEQUENCE
    assert subtree == kp.Action("Pick")


def test_an_answer_to_another_question_is_refused() -> None:
    other = sequence_key(["TargetSeen(colour=3)"])
    with pytest.raises(Refused, match=r"^from t: answers .* not the question$"):
        check_provenance(answer("<a>(Pick)", other), SEQUENCE, kp.Policy.ANY)


def test_an_unsigned_answer_is_refused_when_signatures_are_required() -> None:
    with pytest.raises(Refused, match=r"^from t: ") as refused:
        check_provenance(answer("<a>(Pick)"), SEQUENCE, kp.Policy.SIGNED)
    assert "\n" not in refused.value.reason


def test_a_signed_answer_passes_a_trust_store_that_names_its_author() -> None:
    author = kp.Identity.generate()
    item = Knowledge(parse_sequence(SEQUENCE), kp.Action("Pick"))
    signed = answer_to(Query(id="q1", sender="l", sequence=SEQUENCE), "t", item, author)
    store = kp.TrustStore.parse(f"t {author.public}")
    check_provenance(signed, SEQUENCE, kp.Policy.TRUSTED, store)
    with pytest.raises(Refused):
        check_provenance(signed, SEQUENCE, kp.Policy.TRUSTED, kp.TrustStore.parse(""))


@pytest.mark.parametrize(
    ("subtree", "code"),
    [
        ("<a>(Fly)", "SBT306"),  # an action the receiver cannot execute
        ("<a>(Pick, speed=3)", "SBT311"),  # an argument its behaviour does not take
        ("<sq>" * 40 + "<a>(Pick)" + "<e>" * 40, "SBT2"),  # deeper than the receive limits
        ("<a>(Pick", "SBT1"),  # not stringBT
    ],
)
def test_what_the_receiver_cannot_run_is_refused_with_its_code(subtree: str, code: str) -> None:
    with pytest.raises(Refused) as refused:
        read_item(answer(subtree), RECEIVE_LIMITS, registry())
    assert refused.value.reason.startswith(f"from t: {code}")
