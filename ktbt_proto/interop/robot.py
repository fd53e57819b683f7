"""A robot as the network tools build it, whatever runs it (``ktbt peer``, ``ktbt fleet``,
the ROS 2 node): its knowledge file (stringBT, or a BehaviorTree.CPP robot's skills as XML),
its control tree with that knowledge in its placeholders, the placeholder it learns into, and
the search-and-rescue demo robot used when a robot is given no vocabulary of its own
(``spec/protocol.md`` section 4.5).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated

from pydantic import Field
from pydantic import ValidationError as PydanticError

from ktbt_proto.blackboard import Blackboard
from ktbt_proto.exchange.knowledge import KnowledgeBase
from ktbt_proto.exchange.messages import Response
from ktbt_proto.files import read_at_most
from ktbt_proto.formatter import format_tree
from ktbt_proto.interop.sidecar import read_skills
from ktbt_proto.limits import DEFAULT_LIMITS
from ktbt_proto.merge import merge
from ktbt_proto.registry import Registry
from ktbt_proto.status import RUNNING, SUCCESS, Status
from ktbt_proto.syntax import parse
from ktbt_proto.tree import Placeholder, Tree

log = logging.getLogger("ktbt.robot")

LEARNER_CONTROL = "<sl><k>(prior)<e><k>(new)<e><e>"
"""The control tree of a robot given a vocabulary but no ``--control``: it runs only what it
knows (what a learner beside a BehaviorTree.CPP program, ``--export-learned``, needs)."""


def learning_slot(tree: Tree) -> str | None:
    """The placeholder a robot learns into: ``<k>(new)`` if its control tree has one, else its
    last placeholder (the lowest priority in a selector); None without any (spec/protocol.md
    section 4.5)."""
    names = [n.name for n, _ in tree.walk() if isinstance(n, Placeholder)]
    if not names:
        return None
    return "new" if "new" in names else names[-1]


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


def with_knowledge(
    control: str | Tree, knowledge: KnowledgeBase | None, fallback: str = "prior"
) -> str | Tree:
    """The control tree with ``knowledge``'s items in their placeholders (``fallback`` when the
    tree has no placeholder of an item's name, ``prior`` if it has one): what the agent starts
    knowing, and teaches."""
    if knowledge is None or not len(knowledge):
        return control
    tree = parse(control) if isinstance(control, str) else control
    names = {n.name for n, _ in tree.walk() if isinstance(n, Placeholder)}
    for item in knowledge:
        tree = merge(tree, item.subtree, item_slot(names, item.segment, fallback), item.conditions)
    return tree


def item_slot(names: set[str], segment: str, fallback: str) -> str:
    """Where an item a robot starts with goes, its control tree having the placeholders
    ``names``: the one its ``segment`` names, else ``prior``, else ``fallback``."""
    if segment in names:
        return segment
    return "prior" if "prior" in names else fallback


Colour = Annotated[int, Field(ge=1, le=4)]
"""The demo's colours: 1 to 4. A received skill naming colour 7, -999 or "red" is refused."""

DEMO_CONTROL = """<sl>
    <sq>
        <c>(Carrying)
        <a>(DeliverToZone)
    <e>
    <k>(prior)<e>
    <k>(new)<e>
    <a>(RandomWalk)
<e>
"""
"""The demo robot's control tree: deliver what it carries, else what it knows, else walk."""


def demo_registry() -> Registry:
    """The search-and-rescue vocabulary of the example knowledge, with stand-in actions."""
    reg = Registry()
    reg.flags("Carrying")

    @reg.condition("TargetSeen")
    def target_seen(bb: Blackboard, colour: Colour) -> bool:
        return bool(bb.get("target") == colour)

    @reg.action("PickTreasure")
    def pick(bb: Blackboard) -> Status:
        bb["Carrying"] = True
        return SUCCESS

    @reg.action("AssignCollectionPoint")
    def assign(bb: Blackboard, colour: Colour) -> Status:
        bb["zone"] = colour
        return SUCCESS

    @reg.action("DeliverToZone")
    def deliver(bb: Blackboard) -> Status:
        bb["Carrying"] = False
        bb["delivered"] = bb.get("delivered", 0) + 1
        return SUCCESS

    @reg.action("RandomWalk")
    def walk(bb: Blackboard) -> Status:
        return RUNNING

    return reg
