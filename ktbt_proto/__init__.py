"""KT-BT: behaviour trees that robots share while they run.

The public names below are a contract (``ARCHITECTURE.md``); everything else may move.
"""

from .errors import ErrorCode, LimitError, ParseError, StringBTError, ValidationError
from .format import format
from .limits import DEFAULT_LIMITS, Limits
from .merge import MergeError, merge
from .render import render
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
    "Action",
    "Comments",
    "Condition",
    "Container",
    "ErrorCode",
    "Inverter",
    "LimitError",
    "Limits",
    "MergeError",
    "Node",
    "Parallel",
    "ParseError",
    "Placeholder",
    "RunTimer",
    "Selector",
    "Sequence",
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
    "render",
    "validate",
]

__version__ = "0.1.0"
