"""What a receiver checks in an answer before it believes it (``spec/protocol.md`` section 2).

The one set of checks every receiver runs, whoever it is: an agent before it merges (direct,
overheard or buffered), a knowledge server before it serves what it overheard, ``ktbt peer ask``
before it prints. :func:`check_provenance` is the cheap part (the answer is to the sequence
asked, its signatures satisfy the trust policy); :func:`read_item` parses the sequence and the
subtree within the receive limits and validates them against the receiver's registry, when it
has one (an agent's merge checks the item against its vocabulary itself). Each raises
:class:`Refused` with the reason a receiver counts and logs.
"""

from __future__ import annotations

from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.messages import Response
from ktbt_proto.exchange.refusals import fault, internal_error
from ktbt_proto.exchange.trust import Policy, TrustStore, refusal
from ktbt_proto.items import parse_sequence
from ktbt_proto.limits import Limits
from ktbt_proto.registry import Registry
from ktbt_proto.syntax import parse
from ktbt_proto.tree import Condition, Node
from ktbt_proto.validate import validate

RECEIVE_LIMITS = Limits(
    max_size=60_000, max_depth=32, max_nodes=2_000, max_literal=256, max_number=1_000_000
)
"""What a learner accepts from a peer: far tighter than a file on disk."""


class Refused(Exception):
    """An answer is not believed; ``reason`` says why in one line (its sender included)."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


def check_provenance(
    response: Response, sequence: str, policy: Policy, trust: TrustStore | None = None
) -> None:
    """Rules 2 and 3 of section 2: the answer is to ``sequence``, and its signatures satisfy
    ``policy`` (and the names ``trust`` binds to keys)."""
    if response.sequence != sequence:
        raise Refused(f"from {response.sender}: answers {response.sequence}, not the question")
    why = refusal(response, policy, trust)
    if why is not None:
        raise Refused(f"from {response.sender}: {why}")


def read_item(
    response: Response, limits: Limits = RECEIVE_LIMITS, registry: Registry | None = None
) -> tuple[tuple[Condition, ...], Node]:
    """Rules 4 and 5: the conditions and the subtree, parsed within ``limits`` (numbers
    included) and validated against ``registry`` (names, arguments, types and ranges). Without
    a registry, rule 5 is left to the merge, which checks the whole item against the control
    tree's own (an agent's :meth:`~ktbt_proto.exchange.core.AgentCore.accept`): an item is
    checked against the vocabulary once."""
    try:
        fault("item", response.subtree)
        conds = parse_sequence(response.sequence, limits)
        subtree = parse(response.subtree, limits=limits).root
        validate(subtree, registry, limits=limits)
    except StringBTError as err:
        raise Refused(f"from {response.sender}: {err.code.value} {err.message}") from None
    except Exception as exc:  # a reader's own failure is a refusal too (section 2.1)
        raise Refused(f"from {response.sender}: {internal_error(exc)}") from exc
    return conds, subtree


def check(
    response: Response,
    sequence: str,
    policy: Policy = Policy.ANY,
    trust: TrustStore | None = None,
    limits: Limits = RECEIVE_LIMITS,
    registry: Registry | None = None,
) -> tuple[tuple[Condition, ...], Node]:
    """:func:`check_provenance`, then :func:`read_item`."""
    check_provenance(response, sequence, policy, trust)
    return read_item(response, limits, registry)
