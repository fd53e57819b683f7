"""A robot's knowledge file, read whatever runs the robot (``ktbt peer``, ``ktbt fleet``, the
ROS 2 node, ``attach``): stringBT whose placeholders hold the items, or a BehaviorTree.CPP
robot's skills as XML (``spec/protocol.md`` section 4.5, ``spec/stringbt.md`` section 12.1).
"""

from __future__ import annotations

from pathlib import Path

from pydantic import ValidationError as PydanticError

from ktbt_proto.exchange.knowledge import KnowledgeBase
from ktbt_proto.exchange.messages import Response
from ktbt_proto.files import read_at_most
from ktbt_proto.formatter import format_tree
from ktbt_proto.interop.sidecar import read_skills
from ktbt_proto.limits import DEFAULT_LIMITS
from ktbt_proto.syntax import parse

__all__ = ["load_knowledge"]


def load_knowledge(path: str | Path) -> KnowledgeBase:
    """A knowledge file: stringBT whose ``<k>(...)`` placeholders hold the items to serve, or
    (``.xml``) a BehaviorTree.CPP robot's skills (:func:`ktbt_proto.interop.sidecar.read_skills`).
    At most one byte past the size limit is read (``/dev/zero`` is refused, not read until
    memory runs out). Items too large to send, signed and all, are refused here, not at every
    query."""
    data = read_at_most(path, DEFAULT_LIMITS.max_size)
    if Path(path).suffix.lower() == ".xml":
        kb = read_skills(data)
    else:
        kb = KnowledgeBase.from_tree(parse(data))
    for item in kb:
        subtree = format_tree(item.subtree, "compact")
        try:  # the largest a reply can be: longest id and name, both signatures
            Response(
                id="i" * 64,
                sender="s" * 64,
                sequence=item.key,
                subtree=subtree,
                author="A" * 43,
                signature="A" * 86,
                key="A" * 43,
                hop="A" * 86,
            )
        except PydanticError:
            raise ValueError(f"{path}: the subtree for {item.key} is too large to send") from None
    if not len(kb):
        raise ValueError(
            f"{path}: no knowledge items (inside a <k>(...): <sq>, the conditions, the actions)"
        )
    return kb
