"""Fleet events: what a peer's transfer log records, published for a fleet view
(``spec/protocol.md`` section 10).

A peer started with ``--publish-events`` puts one :class:`FleetEvent` on
``ktbt/v1/events/<peer>`` for every event its transfer log records (section 8). The event is
bounded (:data:`MAX_EVENT_BYTES`; long text is clipped), names the knowledge item by the digest
of its sequence, carries the publisher's sequence number and the count of events it dropped,
and is signed when the peer has a key pair. The publisher is rate-limited by a token bucket:
an event beyond the rate is dropped and counted, never queued, so a busy peer never slows its
own exchanges down. Events flow one way: the log hands them to its sinks
(:meth:`TransferLog.add_sink`), the publisher is one.

A receiver (``ktbt monitor``) decodes with :func:`decode_event`, which refuses, with a reason,
whatever is oversized, malformed, or signed with a signature that does not verify.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from typing import Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    TypeAdapter,
    ValidationError,
    ValidationInfo,
    model_validator,
)

from ktbt_proto.exchange.messages import (
    KEY_PATTERN,
    MAX_REASON,
    NAME_PATTERN,
    SIGNATURE_PATTERN,
    WIRE,
    MessageRefused,
    require_version_and_type,
    wire_fields,
)
from ktbt_proto.exchange.refusals import fault, internal_error
from ktbt_proto.exchange.signing import Identity, verify
from ktbt_proto.exchange.transferlog import Event
from ktbt_proto.items import sequence_digest

PREFIX = "ktbt/v1/events"
MAX_EVENT_BYTES = 8192
"""An encoded event is never larger; a receiver refuses a larger one before parsing it."""
MAX_SEQUENCE = 2048
"""An event's ``sequence`` text is clipped to this many characters (its digest is of all of it)."""
EVENT_DOMAIN = b"ktbt/v1/event\x00"
"""Prefix of the bytes a peer signs, so no other signed text can be taken for an event."""
DEFAULT_RATE = 200.0
"""Events a second a publisher sends at most, sustained."""
DEFAULT_BURST = 400
"""Events a publisher may send at once after a quiet spell."""

KEPT_KINDS = frozenset({Event.MERGED, Event.FORGOTTEN, Event.REFUSED})
"""What changes the fleet view (a tree's knowledge, a refusal) takes its own bucket, apart from
queries and answers: a busy peer's merges and forgets are never dropped for its chatter."""

_DIGEST = r"^[0-9a-f]{64}$"

_KIND = r"^[a-z][a-z-]{0,31}$"
"""An event's kind: one of section 8's (``transferlog.Event``); a receiver shows a kind it does
not know as it came, so a log that learns a new kind publishes it without a new model."""


class FleetEvent(BaseModel):
    """One event of one peer's transfer log, as published (section 10)."""

    model_config = ConfigDict(
        extra="forbid", frozen=True, strict=True, json_schema_extra=require_version_and_type
    )

    v: Literal[1] = Field(default=1, description="Protocol version (the integer 1).")
    type: Literal["event"] = "event"
    peer: str = Field(pattern=NAME_PATTERN, description="The publishing peer: whose log it is.")
    n: int = Field(ge=0, le=2**53, description="The publisher's count of events before this one.")
    t: str = Field(max_length=40, description="When it was recorded: UTC, ISO 8601.")
    event: str = Field(pattern=_KIND, description="What happened: a kind of section 8.")
    item: str | None = Field(
        default=None, pattern=_DIGEST, description="SHA-256 of the sequence, hexadecimal."
    )
    sequence: str | None = Field(
        default=None, max_length=MAX_SEQUENCE, description="The sequence (clipped)."
    )
    id: str | None = Field(default=None, pattern=NAME_PATTERN, description="The query's id.")
    sender: str | None = Field(
        default=None, pattern=NAME_PATTERN, description="Who sent it to the peer."
    )
    to: str | None = Field(
        default=None, pattern=NAME_PATTERN, description="Whom the peer answered."
    )
    teacher: str | None = Field(
        default=None, pattern=NAME_PATTERN, description="Who taught a merge."
    )
    author: str | None = Field(
        default=None, pattern=KEY_PATTERN, description="The item's author key."
    )
    reason: str | None = Field(default=None, max_length=MAX_REASON, description="Why.")
    where: str | None = Field(default=None, max_length=32, description="Who refused.")
    on: str | None = Field(default=None, max_length=200, description="Key expression refused.")
    tick: int | None = Field(default=None, ge=0, le=2**53, description="The agent's tick.")
    dropped: int = Field(default=0, ge=0, le=2**53, description="Events the peer dropped so far.")
    key: str | None = Field(default=None, pattern=KEY_PATTERN, description="The peer's public key.")
    sig: str | None = Field(default=None, pattern=SIGNATURE_PATTERN, description="Its signature.")

    @model_validator(mode="before")
    @classmethod
    def _wire(cls, data: Any, info: ValidationInfo) -> Any:
        """Received, an event names ``v`` and ``type`` (section 1); ``v`` is never a boolean;
        strict, so ``"n": "5"`` or ``"tick": 1.0`` is refused, not coerced."""
        if isinstance(data, dict) and info.context == WIRE and "type" not in data:
            raise ValueError("an event names its type 'type'")
        return wire_fields(data, info)


_ADAPTER: TypeAdapter[FleetEvent] = TypeAdapter(FleetEvent)


def signed_bytes(event: FleetEvent) -> bytes:
    """What a peer signs: ``"ktbt/v1/event" NUL`` and the event's JSON without ``sig``, keys
    sorted, no spaces, non-ASCII as UTF-8 (every value is a string or an integer)."""
    fields = event.model_dump(exclude_none=True, exclude={"sig"})
    text = json.dumps(fields, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return EVENT_DOMAIN + text.encode("utf-8")


def encode_event(event: FleetEvent) -> bytes:
    return event.model_dump_json(exclude_none=True).encode("utf-8")


def decode_event(data: bytes, max_bytes: int = MAX_EVENT_BYTES) -> FleetEvent:
    """Check one received event: size, JSON, schema, then a signature present must verify.
    Raises :class:`MessageRefused` with the reason."""
    if len(data) > max_bytes:
        raise MessageRefused(f"event of {len(data)} bytes exceeds the limit of {max_bytes}")
    try:
        fault("message", data)
        event = _ADAPTER.validate_json(data, context=WIRE)
        if (event.key is None) != (event.sig is None):
            raise MessageRefused(f"event {event.n} of {event.peer}: key and sig come together")
        signed = event.sig is not None
        if signed and not verify(event.key or "", event.sig or "", signed_bytes(event)):
            raise MessageRefused(f"event {event.n} of {event.peer}: its signature does not verify")
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first.get("loc", ())) or "event"
        raise MessageRefused(f"invalid event: {where}: {first.get('msg', 'invalid')}") from None
    except MessageRefused:
        raise
    except Exception as exc:  # a reader's own failure is a refusal too (section 2.1)
        raise MessageRefused(internal_error(exc)) from exc
    return event


def clip(value: object, most: int) -> str:
    """``value`` as one line of at most ``most`` characters (a peer's text is shown bounded,
    spec/protocol.md section 10)."""
    text = " ".join(str(value).split())
    return text if len(text) <= most else text[: most - 3] + "..."


def from_log(entry: dict[str, Any], n: int, dropped: int = 0) -> FleetEvent:
    """The event for one transfer-log entry. Text fields are clipped to their bounds; a field
    that does not fit the model (a name a hostile peer sent, say) is left out rather than
    sent, so every event the log records can be published."""
    sequence = entry.get("sequence")
    fields: dict[str, Any] = {
        "peer": entry["peer"],
        "n": n,
        "t": str(entry["t"])[:40],
        "event": entry["event"],
        "dropped": dropped,
    }
    if isinstance(sequence, str):
        fields["item"] = sequence_digest(sequence)
        clipped = sequence[: MAX_SEQUENCE - 3] + "..."
        fields["sequence"] = sequence if len(sequence) <= MAX_SEQUENCE else clipped
    for name in ("id", "sender", "to", "teacher", "author", "where", "tick"):
        if entry.get(name) is not None:
            fields[name] = entry[name]
    if entry.get("reason") is not None:
        fields["reason"] = clip(entry["reason"], MAX_REASON)
    if entry.get("key") is not None:  # a transport's refusal: the key expression refused
        fields["on"] = clip(entry["key"], 200)
    try:
        event = FleetEvent.model_validate(fields)
    except ValidationError as exc:
        for error in exc.errors():
            loc = error.get("loc", ())
            if loc and loc[0] not in ("peer", "n", "t", "event", "dropped"):
                fields.pop(str(loc[0]), None)
        event = FleetEvent.model_validate(fields)
    while len(encode_event(event)) > MAX_EVENT_BYTES - 200:  # room for key and sig
        text = event.sequence or ""  # only escaped control characters make it this long
        event = event.model_copy(update={"sequence": text[: len(text) // 2] + "..."})
    return event


class RateLimit:
    """A token bucket: ``rate`` a second sustained, ``burst`` at once."""

    def __init__(
        self, rate: float, burst: int, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.rate, self.burst, self._clock = rate, burst, clock
        self._tokens, self._last = float(burst), clock()

    def take(self) -> bool:
        now = self._clock()
        self._tokens = min(self.burst, self._tokens + (now - self._last) * self.rate)
        self._last = now
        if self._tokens < 1:
            return False
        self._tokens -= 1
        return True


class EventPublisher:
    """A transfer-log sink that publishes each event (section 10) through ``put``, which takes
    the encoded event (a zenoh publisher's ``put``: see :meth:`on_session`). Thread-safe: the
    log records from zenoh callbacks and the agent's loop."""

    def __init__(
        self,
        peer: str,
        put: Callable[[bytes], None],
        identity: Identity | None = None,
        rate: float = DEFAULT_RATE,
        burst: int = DEFAULT_BURST,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.peer, self._put, self.identity = peer, put, identity
        self._limit = RateLimit(rate, burst, clock)
        self._kept = RateLimit(rate, burst, clock)
        """The bucket of :data:`KEPT_KINDS`, apart, so a flood of queries never drops them."""
        self._lock = threading.Lock()
        self.sent = 0
        """Events published."""
        self.dropped = 0
        """Events not published because the rate was exceeded."""

    @classmethod
    def on_session(cls, session: Any, peer: str, **options: Any) -> tuple[EventPublisher, Any]:
        """A publisher on ``ktbt/v1/events/<peer>`` of a zenoh session, and the zenoh publisher
        to undeclare when done."""
        publisher = session.declare_publisher(f"{PREFIX}/{peer}")
        return cls(peer, publisher.put, **options), publisher

    def __call__(self, entry: dict[str, Any]) -> None:
        # Everything, the put included, under one lock: the events leave in the order of their
        # numbers, so a receiver counts a gap as a loss (a zenoh put with the default drop
        # congestion control does not block).
        with self._lock:
            limit = self._kept if entry.get("event") in KEPT_KINDS else self._limit
            if not limit.take():
                self.dropped += 1
                return
            try:
                event = from_log({**entry, "peer": self.peer}, self.sent, self.dropped)
            except (ValidationError, KeyError):  # not an event of section 8's shape
                self.dropped += 1
                return
            if self.identity is not None:
                event = event.model_copy(update={"key": self.identity.public})
                event = event.model_copy(update={"sig": self.identity.sign(signed_bytes(event))})
            self.sent += 1
            try:
                self._put(encode_event(event))
            except Exception:  # a closing session: the event is lost with it
                self.dropped += 1


def json_schema() -> dict[str, object]:
    """The JSON Schema of an event (``spec/schemas/event.json``)."""
    return _ADAPTER.json_schema()


def schema_text() -> str:
    """What ``spec/schemas/event.json`` holds (a test keeps the file equal to it)."""
    return json.dumps(json_schema(), indent=2, sort_keys=True) + "\n"
