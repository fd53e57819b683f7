"""Trees in other behaviour-tree tools: BehaviorTree.CPP v4 XML (Groot2) and py_trees.

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
