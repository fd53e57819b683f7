"""Answers: what a robot that knows a sequence sends back, and what its catalog lists.

One way to make an answer (``spec/protocol.md`` sections 2 and 7): the item's compact stringBT,
its author's signature kept, or, unsigned, signed by the holder as its author when it has a key
pair (:func:`signed_answer`); then the response to one query, hop-signed by the peer that sends
it (:func:`answer_to`). An agent's teach tree, an application-timed agent (the simulator's), the
zenoh binding's knowledge servers and fleet members, and in-memory agents' streams all use
these functions.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ktbt_proto.exchange.knowledge import Knowledge, KnowledgeBase
from ktbt_proto.exchange.messages import Query, Response, encode
from ktbt_proto.exchange.signing import Identity, SignedItem
from ktbt_proto.formatter import format_tree


def signed_answer(item: Knowledge, identity: Identity | None) -> SignedItem:
    """An item as a peer answers it: its author's signature kept, or, unsigned, signed by this
    peer as its author when it has a key pair (section 7)."""
    subtree = format_tree(item.subtree, "compact")
    if item.author is not None:
        return SignedItem(subtree, item.author, item.signature)
    if identity is not None:
        return identity.sign_item(item.key, subtree)
    return SignedItem(subtree)


def answer_to(
    query: Query,
    sender: str,
    item: Knowledge | SignedItem,
    identity: Identity | None,
    sequence: str | None = None,
) -> Response:
    """The response ``sender`` gives to ``query`` for ``sequence`` (one of those it asks,
    section 1; its first by default) from ``item`` (an item it holds, or one already made by
    :func:`signed_answer`), hop-signed with ``identity`` when it has a key pair (section 7).
    Raises pydantic's ``ValidationError`` if it is too large to send (section 1): no peer could
    accept it."""
    signed = item if isinstance(item, SignedItem) else signed_answer(item, identity)
    response = Response.of(
        query.id,
        sender,
        query.sequence if sequence is None else sequence,
        signed.subtree,
        signed.author,
        signed.signature,
    )
    return identity.sign_reply(response) if identity is not None else response


TEMPLATE_ID = "x" * 64
"""A query id of the longest form (section 1), for :func:`encoded_answer`: an answer made with
it fits a message with any id."""


def encoded_answer(sender: str, sequence: str, item: SignedItem) -> tuple[bytes, bytes]:
    """The encoded response ``sender`` gives for ``sequence`` with ``item`` to any query, not
    hop-signed, split where the query's id goes: ``head + id + tail`` is the bytes of
    ``encode(answer_to(query, sender, item, None, sequence))`` for a query with that id (a
    response's fields encode in their order, the id first of the strings, and an id holds
    nothing JSON escapes, section 1). Made once per item, so that a knowledge server without a
    key pair answers each query with one concatenation, not a message built and encoded anew.
    Raises pydantic's ``ValidationError`` if the answer is too large to send (section 1)."""
    response = Response.of(TEMPLATE_ID, sender, sequence, item.subtree, item.author, item.signature)
    head, tail = encode(response).split(f'"{TEMPLATE_ID}"'.encode(), 1)
    return head + b'"', b'"' + tail


def answers(
    knowledge: KnowledgeBase, identity: Identity | None = None
) -> Callable[[str], SignedItem | None]:
    """A server's lookup: every answer formatted (and, with a key pair, signed by this server
    as its author) once, so a query costs one dict lookup."""
    return {item.key: signed_answer(item, identity) for item in knowledge}.get


def live_answers(
    knowledge: Callable[[], KnowledgeBase], identity: Identity | None = None
) -> Callable[[str], SignedItem | None]:
    """A fleet member's lookup (spec/protocol.md section 4.5): what its agent knows now, learned
    and forgotten items included, each formatted and signed as :func:`answers` does, once per
    item. It runs in the queryable's one callback thread, the only one to touch its cache."""
    made: dict[str, tuple[Knowledge, SignedItem]] = {}

    def lookup(key: str) -> SignedItem | None:
        item = knowledge().lookup(key)
        if item is None:
            made.pop(key, None)
            return None
        cached = made.get(key)
        if cached is None or cached[0] is not item:
            cached = made[key] = (item, signed_answer(item, identity))
        return cached[1]

    return lookup


def catalog(
    knowledge: KnowledgeBase, identity: Identity | None = None
) -> Callable[[], list[str | dict[str, Any]]]:
    """What the catalog queryable answers: each sequence with its provenance (a peer with a key
    pair is the author of the items it holds unsigned: it signs them when it answers). The
    same list while the knowledge is unchanged (:attr:`KnowledgeBase.version`), since a ROS
    robot compares its catalog with the one it showed at every tick: read it, never change
    it."""
    own = identity.public if identity is not None else None
    built: list[tuple[int, list[str | dict[str, Any]]]] = []

    def entries() -> list[str | dict[str, Any]]:
        if built and built[0][0] == knowledge.version:
            return built[0][1]
        out: list[str | dict[str, Any]] = []
        for item in knowledge:
            entry = {
                "sequence": item.key,
                "author": item.author or own,
                "teacher": item.source,
                "received_at": item.received_at,
            }
            out.append({k: v for k, v in entry.items() if v is not None})
        built[:] = [(knowledge.version, out)]
        return out

    return entries
