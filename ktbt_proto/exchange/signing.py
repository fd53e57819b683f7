"""Signed knowledge: Ed25519 key pairs, the exact bytes that are signed, and verification.

Two signatures travel with an answer (``spec/protocol.md`` section 7):

- the **item signature**, by the knowledge item's author, over the item's canonical form. It
  does not name the message, the sender or the query, so it stays valid when a learner teaches
  the item onward, and every later learner can still tell who wrote it;
- the **hop signature**, by the peer sending this one reply, over the reply's ``id``, ``sender``
  and item (with its author signature), binding the name ``sender`` to a key for this query.

Keys and signatures are written as unpadded base64url (RFC 4648 section 5): 43 characters for a
32-byte public key, 86 for a 64-byte signature. The primitives are libsodium's Ed25519 (RFC 8032)
through PyNaCl, which is deterministic: equal bytes and key give equal signatures. A private key
file is the one PKCS#8 form of an Ed25519 key (RFC 8410): a fixed 16-byte DER prefix and the
32-byte seed, in a PEM ``PRIVATE KEY`` block (RFC 7468), as OpenSSL writes it.
"""

from __future__ import annotations

import base64
import binascii
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

from ktbt_proto.exchange.messages import Response
from ktbt_proto.files import TooLarge, read_bounded

if TYPE_CHECKING:
    from nacl.signing import SigningKey

# PyNaCl (libsodium, about 2 MB resident) is imported where a key signs or verifies, so that a
# peer that never meets a signature never loads it.

ITEM_DOMAIN = b"ktbt/v1/item\x00"
"""Prefix of the bytes an author signs, so no other signed text can be mistaken for an item."""
HOP_DOMAIN = b"ktbt/v1/reply\x00"
"""Prefix of the bytes a sending peer signs."""
_SEP = b"\x00"  # canonical compact stringBT never holds a NUL (it is escaped in strings)
MAX_KEY_FILE = 4096
PKCS8_PREFIX = bytes.fromhex("302e020100300506032b657004220420")
"""DER of PKCS#8 ``PrivateKeyInfo`` (version 0, algorithm id-Ed25519 1.3.101.112, no parameters)
up to the 32-byte seed it ends with (RFC 8410 section 7)."""
_PEM_BEGIN = b"-----BEGIN PRIVATE KEY-----"
_PEM_END = b"-----END PRIVATE KEY-----"


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
    from nacl.exceptions import CryptoError
    from nacl.signing import VerifyKey

    try:
        raw = unb64(key)
        if len(raw) != 32 or small_order(raw):
            return False
        VerifyKey(raw).verify(data, unb64(signature))
    except (CryptoError, ValueError, binascii.Error):
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

    def __init__(self, private: SigningKey) -> None:
        self._private = private
        self.public = b64(bytes(private.verify_key))
        """The public key, base64url: what others put in their trust store."""

    @classmethod
    def generate(cls) -> Identity:
        from nacl.signing import SigningKey

        return cls(SigningKey.generate())

    @classmethod
    def from_seed(cls, seed: bytes) -> Identity:
        """The key pair of a 32-byte seed (RFC 8032's private key), as the vectors give them."""
        if len(seed) != 32:
            raise ValueError(f"an Ed25519 seed is 32 bytes, not {len(seed)}")
        from nacl.signing import SigningKey

        return cls(SigningKey(seed))

    def sign(self, data: bytes) -> str:
        return b64(self._private.sign(data).signature)

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
        der = base64.b64encode(PKCS8_PREFIX + bytes(self._private)).decode("ascii")
        pem = _PEM_BEGIN + b"\n" + der.encode("ascii") + b"\n" + _PEM_END + b"\n"
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(pem)
        public = path.with_name(path.name + ".pub")
        public.write_text(self.public + "\n", encoding="ascii")
        return public

    @classmethod
    def load(cls, path: str | Path) -> Identity:
        """Read a private key written by :meth:`save`; raises :class:`KeyFileError`."""
        data = read_key_file(path, MAX_KEY_FILE, "key")
        return cls.from_seed(_pkcs8_seed(data, path))


def read_key_file(path: str | Path, limit: int, what: str) -> bytes:
    """A key or a trust store's bytes (``what`` names it), read bounded; raises
    :class:`KeyFileError` in one line for a file that is missing, unreadable or too large."""
    try:
        return read_bounded(path, limit)
    except TooLarge:
        raise KeyFileError(f"cannot read {what} {path}: larger than {limit} bytes") from None
    except OSError as exc:
        raise KeyFileError(f"cannot read {what} {path}: {exc.strerror or exc}") from None


def _pkcs8_seed(data: bytes, path: str | Path) -> bytes:
    """The seed of an unencrypted PKCS#8 Ed25519 key in one PEM block; anything else (another
    algorithm, an encrypted key, text around the block, a second block) is refused."""
    lines = data.strip().splitlines()
    if len(lines) < 3 or lines[0].strip() != _PEM_BEGIN or lines[-1].strip() != _PEM_END:
        raise KeyFileError(f"{path} is not a PEM private key (-----BEGIN PRIVATE KEY-----)")
    try:
        der = base64.b64decode(b"".join(line.strip() for line in lines[1:-1]), validate=True)
    except (ValueError, binascii.Error):
        raise KeyFileError(f"{path} is not a PEM private key: its body is not base64") from None
    if len(der) != len(PKCS8_PREFIX) + 32 or not der.startswith(PKCS8_PREFIX):
        raise KeyFileError(f"{path} is not an unencrypted PKCS#8 Ed25519 private key")
    return der[len(PKCS8_PREFIX) :]


def public_key(text: str) -> str:
    """Check a public key written as base64url; return it, or raise :class:`KeyFileError`."""
    text = text.strip()
    try:
        raw = unb64(text)
    except (ValueError, binascii.Error):
        raise KeyFileError(f"{text[:60]!r} is not an Ed25519 public key in base64url") from None
    if len(raw) != 32 or b64(raw) != text or small_order(raw):
        raise KeyFileError(f"{text[:60]!r} is not an Ed25519 public key in base64url")
    return text
