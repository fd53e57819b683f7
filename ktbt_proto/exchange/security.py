"""A peer's security settings, given as one object (``spec/protocol.md`` sections 7 and 8).

What a peer signs with, what it accepts and where it writes what happened: an agent, a knowledge
server and ``ktbt peer`` all take these four together, and pass them on unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

from ktbt_proto.exchange.signing import Identity
from ktbt_proto.exchange.transferlog import TransferLog
from ktbt_proto.exchange.trust import Policy, TrustStore


@dataclass(frozen=True)
class Security:
    """``identity``: the key pair that signs the items this peer authors and every answer it
    sends (section 7); None: it signs nothing. ``policy`` and ``trust``: which answers it
    accepts, by their signatures (section 7). ``log``: the transfer log every exchange is
    written to (section 8); None: none."""

    identity: Identity | None = None
    policy: Policy = Policy.ANY
    trust: TrustStore | None = None
    log: TransferLog | None = None
