"""KT-BT: behaviour trees that robots share while they run.

``import ktbt_proto as kp`` gives what a robot builder uses: the stringBT language (parse,
format, check, merge, the live runtime) and knowledge exchange (agents, their knowledge, trust
and signing, memory, the transfer log, the in-memory network and zenoh). Interop with other
tools, which needs their optional extras, is in ``ktbt_proto.interop`` (``py_trees_control``,
BehaviorTree.CPP XML, Groot2). ``ARCHITECTURE.md`` says what each layer holds; the reference
documentation lists every name below.
"""

from ktbt_proto.blackboard import Blackboard
from ktbt_proto.errors import ErrorCode, LimitError, ParseError, StringBTError, ValidationError
from ktbt_proto.exchange.agent import Agent, Timing
from ktbt_proto.exchange.application import ApplicationTimedAgent
from ktbt_proto.exchange.core import Metrics
from ktbt_proto.exchange.knowledge import Knowledge, KnowledgeBase
from ktbt_proto.exchange.memory import MemoryPolicy
from ktbt_proto.exchange.messages import ErrorReply, Query, Response
from ktbt_proto.exchange.overhearing import Ear
from ktbt_proto.exchange.security import Security
from ktbt_proto.exchange.signing import Identity
from ktbt_proto.exchange.transferlog import Event, TransferLog
from ktbt_proto.exchange.trust import Policy, TrustStore
from ktbt_proto.formatter import format_tree
from ktbt_proto.items import sequence_key, show_sequence
from ktbt_proto.limits import DEFAULT_LIMITS, Limits
from ktbt_proto.merge import MergeError, merge, remove
from ktbt_proto.registry import Registry, StatefulAction, load_vocabulary
from ktbt_proto.render import render
from ktbt_proto.runtime import LiveTree
from ktbt_proto.status import FAILURE, RUNNING, SUCCESS, Status
from ktbt_proto.syntax import parse
from ktbt_proto.transport.memory import MemoryNetwork
from ktbt_proto.transport.zenoh import ZenohSettings, ZenohTransport
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
    "Agent",
    "ApplicationTimedAgent",
    "Blackboard",
    "Comments",
    "Condition",
    "Container",
    "Ear",
    "ErrorCode",
    "ErrorReply",
    "Event",
    "Identity",
    "Inverter",
    "Knowledge",
    "KnowledgeBase",
    "LimitError",
    "Limits",
    "LiveTree",
    "MemoryNetwork",
    "MemoryPolicy",
    "MergeError",
    "Metrics",
    "Node",
    "Parallel",
    "ParseError",
    "Placeholder",
    "Policy",
    "Query",
    "Registry",
    "Response",
    "RunTimer",
    "Security",
    "Selector",
    "SequenceNode",
    "StatefulAction",
    "Status",
    "StringBTError",
    "SupportsNames",
    "Timing",
    "TransferLog",
    "Tree",
    "TrustStore",
    "ValidationError",
    "Vocabulary",
    "Wait",
    "WaitTimer",
    "ZenohSettings",
    "ZenohTransport",
    "find_problems",
    "format_tree",
    "load_vocabulary",
    "merge",
    "parse",
    "remove",
    "render",
    "sequence_key",
    "show_sequence",
    "validate",
]

__version__ = "0.1.0"
