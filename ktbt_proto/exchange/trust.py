"""Which answers a learner accepts, by their signatures (``spec/protocol.md`` section 7).

A :class:`Policy` is one of three: ``any`` accepts what today's protocol accepts (signatures,
when present, must still verify: a forged signature is never accepted); ``signed`` wants the
item's author signature and the sending hop's signature, both valid; ``trusted`` wants that and
an author whose key is in the learner's :class:`TrustStore`. A store may also bind names to
keys: a reply whose ``sender`` the store names must then be hop-signed by that name's key.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path

from ktbt_proto.exchange.messages import Response
from ktbt_proto.exchange.signing import (
    KeyFileError,
    hop_bytes,
    item_bytes,
    public_key,
    read_key_file,
    verify,
)

MAX_TRUST_FILE = 1_000_000


class Policy(StrEnum):
    ANY = "any"
    SIGNED = "signed"
    TRUSTED = "trusted"


@dataclass(frozen=True)
class TrustStore:
    """Trusted author keys, and the keys of the peers known by name."""

    keys: frozenset[str] = frozenset()
    names: dict[str, str] = field(default_factory=dict)

    @classmethod
    def parse(cls, text: str, where: str = "trust store") -> TrustStore:
        """One entry a line: ``KEY`` or ``NAME KEY`` (what ``ktbt peer keygen`` prints);
        ``#`` starts a comment. Raises :class:`KeyFileError` naming the line."""
        keys: set[str] = set()
        names: dict[str, str] = {}
        for number, raw in enumerate(text.splitlines(), 1):
            words = raw.split("#", 1)[0].split()
            if not words:
                continue
            if len(words) > 2:
                raise KeyFileError(f"{where}:{number}: expected 'KEY' or 'NAME KEY'")
            try:
                key = public_key(words[-1])
            except KeyFileError as exc:
                raise KeyFileError(f"{where}:{number}: {exc}") from None
            keys.add(key)
            if len(words) == 2:
                names[words[0]] = key
        return cls(frozenset(keys), names)

    @classmethod
    def load(cls, path: str | Path) -> TrustStore:
        data = read_key_file(path, MAX_TRUST_FILE, "trust store")
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            raise KeyFileError(f"trust store {path} is not UTF-8") from None
        return cls.parse(text, str(path))


def refusal(response: Response, policy: Policy, store: TrustStore | None = None) -> str | None:
    """Why ``response`` is refused under ``policy``, or None if its signatures are acceptable."""
    if response.author is not None and response.signature is not None:
        if not verify(
            response.author, response.signature, item_bytes(response.sequence, response.subtree)
        ):
            return "the author's signature does not match the item"
    elif policy is not Policy.ANY:
        return "the item is not signed by its author"
    if response.key is not None and response.hop is not None:
        if not verify(response.key, response.hop, hop_bytes(response)):
            return "the sender's signature does not match the reply"
    elif policy is not Policy.ANY:
        return "the reply is not signed by its sender"
    if store is not None:
        bound = store.names.get(response.sender)
        if bound is not None and response.key != bound:
            return f"the reply is not signed by the key the trust store gives {response.sender}"
    if policy is Policy.TRUSTED and (store is None or response.author not in store.keys):
        return f"author {response.author} is not in the trust store"
    return None
