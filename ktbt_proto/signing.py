"""Signed knowledge: Ed25519 key pairs, the exact bytes that are signed, and verification.

Two signatures travel with an answer (``spec/protocol.md`` section 7):

- the **item signature**, by the knowledge item's author, over the item's canonical form. It
  does not name the message, the sender or the query, so it stays valid when a learner teaches
  the item onward, and every later learner can still tell who wrote it;
- the **hop signature**, by the peer sending this one reply, over the reply's ``id``, ``sender``
  and item (with its author signature), binding the name ``sender`` to a key for this query.

Keys and signatures are written as unpadded base64url (RFC 4648 section 5): 43 characters for a
32-byte public key, 86 for a 64-byte signature. The primitives are ``cryptography``'s Ed25519
(RFC 8032), which is deterministic: equal bytes and key give equal signatures.
"""

from __future__ import annotations

import base64
import binascii
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from .messages import Response

ITEM_DOMAIN = b"ktbt/v1/item\x00"
"""Prefix of the bytes an author signs, so no other signed text can be mistaken for an item."""
HOP_DOMAIN = b"ktbt/v1/reply\x00"
"""Prefix of the bytes a sending peer signs."""
_SEP = b"\x00"  # canonical compact stringBT never holds a NUL (it is escaped in strings)
MAX_KEY_FILE = 4096


class KeyFileError(ValueError):
    """A key file or key text that cannot be read; the message says why in one line."""


def b64(data: bytes) -> str:
    return base64.urlsafe_b64encode(data).rstrip(b"=").decode("ascii")


def unb64(text: str) -> bytes:
    return base64.urlsafe_b64decode(text + "=" * (-len(text) % 4))


def item_bytes(sequence: str, subtree: str) -> bytes:
    """What an author signs: ``"ktbt/v1/item" NUL sequence NUL subtree``, both in canonical
    compact stringBT, UTF-8."""
    return ITEM_DOMAIN + sequence.encode("utf-8") + _SEP + subtree.encode("utf-8")


def hop_bytes(response: Response) -> bytes:
    """What a sending peer signs: ``"ktbt/v1/reply" NUL id NUL sender NUL sequence NUL subtree
    NUL author NUL signature`` (author and signature empty when the item is unsigned)."""
    parts = (
        response.id,
        response.sender,
        response.sequence,
        response.subtree,
        response.author or "",
        response.signature or "",
    )
    return HOP_DOMAIN + _SEP.join(p.encode("utf-8") for p in parts)


_P = 2**255 - 19
_D = -121665 * pow(121666, _P - 2, _P) % _P
_SQRT_M1 = pow(2, (_P - 1) // 4, _P)


@lru_cache(maxsize=4096)
def small_order(raw: bytes) -> bool:
    """Whether a 32-byte Ed25519 public key is a point of small order (or no point at all).

    Such a key "verifies" forged signatures: with the all-zero key and signature, one message in
    four passes OpenSSL's check. A key is refused unless 8 times its point is not the identity
    (RFC 8032 section 5.1.3 decoding; affine twisted Edwards arithmetic)."""
    y = int.from_bytes(raw, "little") & ((1 << 255) - 1)
    sign = raw[31] >> 7
    if y >= _P:
        return True
    u, v = (y * y - 1) % _P, (_D * y * y + 1) % _P
    x2 = u * pow(v, _P - 2, _P) % _P
    x = pow(x2, (_P + 3) // 8, _P)
    if x * x % _P != x2:
        x = x * _SQRT_M1 % _P
    if x * x % _P != x2 or (x == 0 and sign):
        return True
    if x & 1 != sign:
        x = _P - x
    for _ in range(3):  # 8P
        xy = x * y % _P
        dxy = _D * xy * xy % _P
        x, y = (
            2 * xy * pow(1 + dxy, _P - 2, _P) % _P,
            (y * y + x * x) * pow(1 - dxy, _P - 2, _P) % _P,
        )
    return x == 0 and y == 1


def verify(key: str, signature: str, data: bytes) -> bool:
    """Whether ``signature`` (base64url) is ``key``'s (base64url) Ed25519 signature of data.
    A key of small order verifies nothing."""
    try:
        raw = unb64(key)
        if len(raw) != 32 or small_order(raw):
            return False
        public = Ed25519PublicKey.from_public_bytes(raw)
        public.verify(unb64(signature), data)
    except (InvalidSignature, ValueError, binascii.Error):
        return False
    return True


@dataclass(frozen=True)
class SignedItem:
    """An answer a peer can give: the compact subtree and, if known, its author's signature."""

    subtree: str
    author: str | None = None
    signature: str | None = None


class Identity:
    """A peer's Ed25519 key pair (``ktbt peer keygen``)."""

    def __init__(self, private: Ed25519PrivateKey) -> None:
        self._private = private
        raw = private.public_key().public_bytes(
            serialization.Encoding.Raw, serialization.PublicFormat.Raw
        )
        self.public = b64(raw)
        """The public key, base64url: what others put in their trust store."""

    @classmethod
    def generate(cls) -> Identity:
        return cls(Ed25519PrivateKey.generate())

    def sign(self, data: bytes) -> str:
        return b64(self._private.sign(data))

    def sign_item(self, sequence: str, subtree: str) -> SignedItem:
        """Author an item: sign its canonical form."""
        return SignedItem(subtree, self.public, self.sign(item_bytes(sequence, subtree)))

    def sign_reply(self, response: Response) -> Response:
        """The same response with this peer's key and hop signature."""
        unsigned = response.model_copy(update={"key": None, "hop": None})
        return Response.model_validate(
            {
                **unsigned.model_dump(exclude_none=True),
                "key": self.public,
                "hop": self.sign(hop_bytes(unsigned)),
            }
        )

    # -- files ------------------------------------------------------------------------------

    def save(self, path: str | Path) -> Path:
        """Write the private key (PKCS#8 PEM, mode 0600, never over an existing file) and,
        next to it, ``<path>.pub``: the public key on one line. Returns the public key's path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        pem = self._private.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(pem)
        public = path.with_name(path.name + ".pub")
        public.write_text(self.public + "\n", encoding="ascii")
        return public

    @classmethod
    def load(cls, path: str | Path) -> Identity:
        """Read a private key written by :meth:`save`; raises :class:`KeyFileError`."""
        try:
            with open(path, "rb") as f:
                data = f.read(MAX_KEY_FILE + 1)
        except OSError as exc:
            raise KeyFileError(f"cannot read key {path}: {exc.strerror or exc}") from None
        if len(data) > MAX_KEY_FILE:
            raise KeyFileError(f"{path} is not a key file (larger than {MAX_KEY_FILE} bytes)")
        try:
            private = serialization.load_pem_private_key(data, password=None)
        except (ValueError, TypeError) as exc:
            raise KeyFileError(f"{path} is not an unencrypted PEM private key: {exc}") from None
        if not isinstance(private, Ed25519PrivateKey):
            raise KeyFileError(f"{path} holds a {type(private).__name__}, not an Ed25519 key")
        return cls(private)


def public_key(text: str) -> str:
    """Check a public key written as base64url; return it, or raise :class:`KeyFileError`."""
    text = text.strip()
    try:
        raw = unb64(text)
        Ed25519PublicKey.from_public_bytes(raw)
    except (ValueError, binascii.Error):
        raise KeyFileError(f"{text[:60]!r} is not an Ed25519 public key in base64url") from None
    if b64(raw) != text or small_order(raw):
        raise KeyFileError(f"{text[:60]!r} is not an Ed25519 public key in base64url")
    return text
