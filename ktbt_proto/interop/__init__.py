"""Trees in other behaviour-tree tools: BehaviorTree.CPP v4 XML (Groot2) and py_trees, and
KT-BT inside other robot stacks: a py_trees tree an agent learns into (``pytrees_control``,
whose ``py_trees_control`` is also ``kp.py_trees_control``), a BehaviorTree.CPP program beside
its agent (``sidecar``), Groot2 monitoring (``groot2``) and a ROS 2 node (``ros2``, whose
``attach`` is also ``kp.attach``).

py_trees is optional (``pip install ktbt[py-trees]``), so ``to_py_trees`` is imported on first
use: this package loads without it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ktbt_proto.interop.btcpp import convert, from_xml, to_xml

if TYPE_CHECKING:
    from ktbt_proto.interop.pytrees import to_py_trees

__all__ = ["convert", "from_xml", "to_py_trees", "to_xml"]


def __getattr__(name: str) -> Any:
    if name == "to_py_trees":
        from ktbt_proto.interop.pytrees import to_py_trees

        return to_py_trees
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
