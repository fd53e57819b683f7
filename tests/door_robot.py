"""A door-opening robot: the vocabulary and behaviours the tests of vocabulary files, of py_trees
robots and of the flat item form's re-run trap share (spec/stringbt.md, sections 4.1 and 5.1).

``TurnHandle`` turns 30 degrees a tick, so the flat item re-runs ``GraspHandle`` while it turns.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

import ktbt_proto as kp

FLAT = (
    '<sq><c>(DoorClosed)<c>(HandleSeen, side="left")'
    "<a>(GraspHandle)<a>(TurnHandle, degrees=60)<a>(Push)<e>"
)
MEMORY = (
    '<sq><c>(DoorClosed)<c>(HandleSeen, side="left")'
    "<msq><a>(GraspHandle)<a>(TurnHandle, degrees=60)<a>(Push)<e><e>"
)
SEQUENCE = ["DoorClosed", 'HandleSeen(side="left")']
STEP = 30
Side = Literal["left", "right"]
Degrees = Annotated[int, Field(ge=1, le=90)]

VOCABULARY = """\
# The conditions and actions a robot can execute, with their arguments
# (spec/stringbt.md, section 5.1).

[conditions.DoorClosed]
flag = true

[conditions.HandleSeen]
doc = "Whether the handle is seen on that side of the door."
arguments.side = { type = "str", choices = ["left", "right"] }

[actions.GraspHandle]
doc = "Close the gripper on the handle."

[actions.Push]
doc = "Push the door open."

[actions.TurnHandle]
doc = "Turn the grasped handle, 30 degrees a tick."
arguments.degrees = { type = "int", ge = 1, le = 90 }
"""
"""What ``write_vocabulary(door_registry())`` writes."""


def door_registry(reg: kp.Registry | None = None) -> kp.Registry:
    """The door robot's registry, its behaviours logging into ``bb["log"]``; registered into
    ``reg`` if given (one loaded from the vocabulary file, say), a new one otherwise."""
    reg = kp.Registry() if reg is None else reg
    reg.flags("DoorClosed")

    @reg.condition("HandleSeen")
    def handle_seen(bb: kp.Blackboard, side: Side) -> bool:
        """Whether the handle is seen on that side of the door."""
        return bool(bb.get("handle") == side)

    @reg.action("GraspHandle")
    def grasp(bb: kp.Blackboard) -> kp.Status:
        """Close the gripper on the handle."""
        bb["log"].append("grasp")
        return kp.SUCCESS

    @reg.action("TurnHandle")
    class TurnHandle:
        """Turn the grasped handle, 30 degrees a tick."""

        def __init__(self, bb: kp.Blackboard, degrees: Degrees) -> None:
            self.bb, self.degrees, self.turned = bb, degrees, 0

        def tick(self) -> kp.Status:
            self.turned += STEP
            self.bb["log"].append(f"turn {self.turned}/{self.degrees}")
            if self.turned < self.degrees:
                return kp.RUNNING
            self.turned = 0
            return kp.SUCCESS

        def halt(self) -> None:
            self.turned = 0

    @reg.action("Push")
    def push(bb: kp.Blackboard) -> kp.Status:
        """Push the door open."""
        bb["log"].append("push")
        bb["DoorClosed"] = False
        return kp.SUCCESS

    return reg


def door_blackboard() -> kp.Blackboard:
    """A closed door with its handle seen on the left, and an empty log."""
    bb = kp.Blackboard()
    bb["DoorClosed"], bb["handle"], bb["log"] = True, "left", []
    return bb
