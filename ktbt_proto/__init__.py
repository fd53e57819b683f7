"""KT-BT: behaviour trees that robots share while they run.

``import ktbt_proto as kp`` is the front door: the names a robot builder uses, whatever layer
defines them. The stringBT language (``kp.parse``, ``kp.format_tree``, ``kp.validate``,
``kp.merge``, the live runtime ``kp.LiveTree``, the errors a caller catches), an agent and what
it is built from (``kp.Agent``, ``kp.Security``, ``kp.KnowledgeBase``, ``kp.FleetMember``), the
transports it talks through (``kp.MemoryNetwork``, ``kp.ZenohTransport``), and the control trees
of other tools it learns into (``kp.py_trees_control``, and ``kp.attach`` for a ROS 2 node).

Each name is imported from its module on first use. Importing the package, or a language module
such as ``ktbt_proto.syntax``, therefore loads neither zenoh nor pydantic nor ROS 2: a tool that
only parses or formats starts fast, and runs where the network libraries are missing.
``kp.py_trees_control`` needs the ``py-trees`` extra and ``kp.attach`` rclpy (the ``ros2``
extra), when they are first used.

Everything else stays in its module: the node types and helpers of the language
(``ktbt_proto.tree``, ``ktbt_proto.items``, ``ktbt_proto.errors.ErrorCode``), the wire messages
(``ktbt_proto.exchange.messages``), overhearing, memory policy and the transfer log
(``ktbt_proto.exchange.overhearing``, ``.memory``, ``.transferlog``), the application-timed
agent (``ktbt_proto.exchange.application``), and interop with other tools
(``ktbt_proto.interop``). ``ARCHITECTURE.md`` says what each layer holds; the reference
documentation describes every module.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ktbt_proto.blackboard import Blackboard
    from ktbt_proto.control import ControlTree
    from ktbt_proto.errors import LimitError, ParseError, StringBTError, ValidationError
    from ktbt_proto.exchange.agent import Agent, Timing
    from ktbt_proto.exchange.knowledge import KnowledgeBase
    from ktbt_proto.exchange.member import FleetMember
    from ktbt_proto.exchange.security import Security
    from ktbt_proto.exchange.signing import Identity
    from ktbt_proto.exchange.transport import Transport
    from ktbt_proto.exchange.trust import Policy, TrustStore
    from ktbt_proto.formatter import format_tree
    from ktbt_proto.interop.pytrees_control import py_trees_control
    from ktbt_proto.interop.ros2.embed import attach
    from ktbt_proto.limits import Limits
    from ktbt_proto.merge import MergeError, merge
    from ktbt_proto.registry import Registry
    from ktbt_proto.render import render
    from ktbt_proto.runtime import LiveTree
    from ktbt_proto.status import FAILURE, RUNNING, SUCCESS, Status
    from ktbt_proto.syntax import parse
    from ktbt_proto.tools.vocabulary import load_vocabulary
    from ktbt_proto.transport.memory import MemoryNetwork
    from ktbt_proto.transport.zenoh import ZenohSettings, ZenohTransport
    from ktbt_proto.tree import Action, Condition, SequenceNode, Tree
    from ktbt_proto.validate import Vocabulary, find_problems, validate

_HOME = {
    # the language
    "parse": "ktbt_proto.syntax",
    "format_tree": "ktbt_proto.formatter",
    "validate": "ktbt_proto.validate",
    "find_problems": "ktbt_proto.validate",
    "Vocabulary": "ktbt_proto.validate",
    "merge": "ktbt_proto.merge",
    "MergeError": "ktbt_proto.merge",
    "render": "ktbt_proto.render",
    "Tree": "ktbt_proto.tree",
    "Action": "ktbt_proto.tree",
    "Condition": "ktbt_proto.tree",
    "SequenceNode": "ktbt_proto.tree",
    "Registry": "ktbt_proto.registry",
    "load_vocabulary": "ktbt_proto.tools.robot",
    "Blackboard": "ktbt_proto.blackboard",
    "LiveTree": "ktbt_proto.runtime",
    "ControlTree": "ktbt_proto.control",
    "Status": "ktbt_proto.status",
    "SUCCESS": "ktbt_proto.status",
    "FAILURE": "ktbt_proto.status",
    "RUNNING": "ktbt_proto.status",
    "StringBTError": "ktbt_proto.errors",
    "ParseError": "ktbt_proto.errors",
    "LimitError": "ktbt_proto.errors",
    "ValidationError": "ktbt_proto.errors",
    "Limits": "ktbt_proto.limits",
    # knowledge exchange
    "Agent": "ktbt_proto.exchange.agent",
    "Timing": "ktbt_proto.exchange.agent",
    "FleetMember": "ktbt_proto.exchange.member",
    "Security": "ktbt_proto.exchange.security",
    "Identity": "ktbt_proto.exchange.signing",
    "Policy": "ktbt_proto.exchange.trust",
    "TrustStore": "ktbt_proto.exchange.trust",
    "KnowledgeBase": "ktbt_proto.exchange.knowledge",
    "Transport": "ktbt_proto.exchange.transport",
    # transports
    "MemoryNetwork": "ktbt_proto.transport.memory",
    "ZenohTransport": "ktbt_proto.transport.zenoh",
    "ZenohSettings": "ktbt_proto.transport.zenoh",
    # other tools' trees
    "py_trees_control": "ktbt_proto.interop.pytrees_control",
    "attach": "ktbt_proto.interop.ros2.embed",
}
"""Each public name and the module that defines it, where ``__getattr__`` imports it from."""

__all__ = [
    "FAILURE",
    "RUNNING",
    "SUCCESS",
    "Action",
    "Agent",
    "Blackboard",
    "Condition",
    "ControlTree",
    "FleetMember",
    "Identity",
    "KnowledgeBase",
    "LimitError",
    "Limits",
    "LiveTree",
    "MemoryNetwork",
    "MergeError",
    "ParseError",
    "Policy",
    "Registry",
    "Security",
    "SequenceNode",
    "Status",
    "StringBTError",
    "Timing",
    "Transport",
    "Tree",
    "TrustStore",
    "ValidationError",
    "Vocabulary",
    "ZenohSettings",
    "ZenohTransport",
    "attach",
    "find_problems",
    "format_tree",
    "load_vocabulary",
    "merge",
    "parse",
    "py_trees_control",
    "render",
    "validate",
]

__version__ = "0.1.0"


if not TYPE_CHECKING:  # a type checker sees the imports above, and flags any other name

    def __getattr__(name: str) -> Any:
        """A public name, imported from its module the first time it is asked for, then kept."""
        home = _HOME.get(name)
        if home is None:
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(home), name)
        globals()[name] = value
        return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})


class _FrontDoor(types.ModuleType):
    """The package's module type. Three public functions share their module's name
    (``validate``, ``merge``, ``render``); importing such a module binds the module under that
    name on the package, so ``kp.merge`` would become a module whenever ``ktbt_proto.merge`` was
    imported first. The package keeps the function: the submodule stays in ``sys.modules``,
    where every import finds it."""

    def __setattr__(self, name: str, value: Any) -> None:
        if isinstance(value, types.ModuleType) and _HOME.get(name) == f"{__name__}.{name}":
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _FrontDoor
