"""KT-BT: behaviour trees that robots share while they run.

The public names below are a contract (``ARCHITECTURE.md`` at the repository root says what
each layer holds); everything else may move.
"""

from .blackboard import Blackboard
from .errors import ErrorCode, LimitError, ParseError, StringBTError, ValidationError
from .format import format
from .limits import DEFAULT_LIMITS, Limits
from .merge import MergeError, merge, remove
from .registry import Registry, StatefulAction
from .render import render
from .runtime import LiveTree
from .status import FAILURE, RUNNING, SUCCESS, Status
from .syntax import parse, parse_reference
from .tree import (
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
    Sequence,
    Tree,
    Wait,
    WaitTimer,
)
from .validate import SupportsNames, Vocabulary, check, validate

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
    "Sequence",
    "StatefulAction",
    "Status",
    "StringBTError",
    "SupportsNames",
    "Tree",
    "ValidationError",
    "Vocabulary",
    "Wait",
    "WaitTimer",
    "check",
    "format",
    "merge",
    "parse",
    "parse_reference",
    "remove",
    "render",
    "validate",
]

__version__ = "0.1.0"
