"""KT-BT: behaviour trees that robots share while they run.

The public names below are a contract (``ARCHITECTURE.md`` at the repository root says what
each layer holds); everything else may move.
"""

from ktbt_proto.blackboard import Blackboard
from ktbt_proto.errors import ErrorCode, LimitError, ParseError, StringBTError, ValidationError
from ktbt_proto.formatter import format_tree
from ktbt_proto.limits import DEFAULT_LIMITS, Limits
from ktbt_proto.merge import MergeError, merge, remove
from ktbt_proto.registry import Registry, StatefulAction, load_vocabulary
from ktbt_proto.render import render
from ktbt_proto.runtime import LiveTree
from ktbt_proto.status import FAILURE, RUNNING, SUCCESS, Status
from ktbt_proto.syntax import parse, parse_reference
from ktbt_proto.tree import (
    Action,
    Comments,
    Condition,
    Container,
    Inverter,
    Node,
    Parallel,
    Placeholder,
    RunTimer,
    Selector,
    SequenceNode,
    Tree,
    Wait,
    WaitTimer,
)
from ktbt_proto.validate import SupportsNames, Vocabulary, find_problems, validate

__all__ = [
    "DEFAULT_LIMITS",
    "FAILURE",
    "RUNNING",
    "SUCCESS",
    "Action",
    "Blackboard",
    "Comments",
    "Condition",
    "Container",
    "ErrorCode",
    "Inverter",
    "LimitError",
    "Limits",
    "LiveTree",
    "MergeError",
    "Node",
    "Parallel",
    "ParseError",
    "Placeholder",
    "Registry",
    "RunTimer",
    "Selector",
    "SequenceNode",
    "StatefulAction",
    "Status",
    "StringBTError",
    "SupportsNames",
    "Tree",
    "ValidationError",
    "Vocabulary",
    "Wait",
    "WaitTimer",
    "find_problems",
    "format_tree",
    "load_vocabulary",
    "merge",
    "parse",
    "parse_reference",
    "remove",
    "render",
    "validate",
]

__version__ = "0.1.0"
