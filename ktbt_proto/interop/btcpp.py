"""stringBT <-> BehaviorTree.CPP v4 XML, so trees can be drawn and edited in Groot2.

Every tree the export accepts survives ``from_xml(to_xml(t)) == t``. The export keeps to the
rules of BT.CPP 4's loader: one root per ``<BehaviorTree>``, a child under every control node,
node IDs and port names without the characters it forbids.

====================  =======================================================================
stringBT              BT.CPP v4 XML
====================  =======================================================================
``<sq>`` / ``<sl>``   ``ReactiveSequence`` / ``ReactiveFallback``
``<msq>``             ``Sequence``: it resumes at its running child and restarts after a
                      FAILURE, like ``<msq>``. ``SequenceWithMemory`` also resumes at a child
                      that *failed*, which stringBT cannot express, so import refuses it.
``<msl>``             ``Fallback`` (resumes at its running child, like ``<msl>``)
``<pl>(M)``           ``Parallel success_count="M" failure_count="N-M+1"``; plain ``<pl>`` is
                      ``success_count="-1" failure_count="1"`` (BT.CPP's "all"). One gap:
                      BT.CPP does not tick again a child that finished earlier in the same
                      activation; stringBT ticks every child on every tick.
``<neg>``             ``Inverter``
``<c>(X, k=v)``       ``<X k="v"/>``, declared ``<Condition ID="X">`` in the model; ``<c>(!X)``
                      is ``<Inverter name="!X">`` around it. The name marks the inverter as a
                      negation (the same behaviour, since a condition never runs), so it
                      imports as ``<c>(!X)``, not ``<neg>``.
``<a>(X, k=v)``       ``<X k="v"/>``, declared ``<Action ID="X">`` in the model
``<wt>(S)``           ``<Sleep msec="round(1000 S)"/>``. When those milliseconds do not read
                      back as exactly S (``<wt>(2.0)``, ``<wt>(0.0015)``), ``name="wt:S"`` keeps
                      the literal; import uses it only while it still agrees with ``msec``.
``<tt1>(N)``          ``<KTBT_TT1 ticks="N">``
``<tt2>(N)``          ``<KTBT_TT2 ticks="N">``
``<w>(N)``            ``<KTBT_WaitTicks ticks="N"/>``
``<k>(name)``         ``<ReactiveFallback name="k:name">`` (a placeholder *is* a reactive
                      selector); empty, it holds one ``<AlwaysFailure/>``, because BT.CPP wants a
                      child under every control node and an empty placeholder fails.
====================  =======================================================================

Every node is written by its element name, as BT.CPP 4 and Groot2 write them: BT.CPP's loader
looks up a ``ReactiveSequence``'s children by element name, so the explicit ``<Action ID="X"/>``
form is refused there ("Unknown node type: Action").

The three ``KTBT_`` nodes are custom because stringBT's timers count ticks and BT.CPP's
(``Delay``, ``Timeout``) count milliseconds; ``Delay`` and ``Timeout`` are therefore not used.
``<TreeNodesModel>`` declares every condition, action and ``KTBT_`` node with its ports, so Groot2
can draw and edit them; a BT.CPP program must register ``KTBT_TT1``, ``KTBT_TT2`` and
``KTBT_WaitTicks`` (semantics in ``spec/stringbt.md``, section 3.2) next to its own nodes.

Names. BT.CPP forbids ``.`` in node IDs and port names, while stringBT names never contain ``-``:
a dot is written as ``-`` (``nav.MoveTo`` -> ``nav-MoveTo``) and read back. Export refuses what
BT.CPP cannot load: arguments named ``ID``, ``name`` or starting with ``_`` (BT.CPP's scripting
attributes), condition or action names that are BT.CPP built-ins or start with ``KTBT_``, and a
name used both as a condition and an action (BT.CPP has one namespace of node IDs).

Values. XML attributes are strings; numbers are written as their stringBT literals and booleans
as ``true``/``false``, which BT.CPP's converters read. A string is written as is, unless it would
read back as something else or cannot be an XML character: if it looks like a number or boolean,
starts with ``"``, is ``{...}`` (spaces aside, BT.CPP's test for a blackboard reference) without
being a reference as below, or holds a control character, it is written as its JSON literal
(quotes included). A subnormal double (``5e-324``) is refused (``SBT310``): BT.CPP's converter
cannot read it. The ``ticks`` of the ``KTBT_`` nodes and ``Sleep``'s ``msec`` are ``unsigned
int`` ports: a larger count is refused (``SBT307``), both ways. Import reads ``true``/``false``,
then stringBT numbers, then JSON string literals; anything else is a string. Port defaults
declared in a TreeNodesModel are not applied.

Blackboard references (spec/stringbt.md section 12). A string that is exactly a key between
braces, ``"{goal}"`` (the key a letter, then letters, digits or ``_``, and not ``name`` or
``ID``: a name BT.CPP accepts as a port), is written unquoted, ``goal="{goal}"``, so BT.CPP wires
the port to the blackboard entry ``goal`` (a Nav2 tree's goal, its path). Such an argument is
declared in the model without a type (the entry's type is the program's), and the tree's
``<SubTree ID=...>`` model lists every key it refers to as an ``inout_port``, so a tree that runs
it as a ``<SubTree>`` wires each one (``goal="{goal}"``, or ``_autoremap="true"``) and BT.CPP
refuses to load one that forgets a key. Import reads ``{goal}`` back as the string ``"{goal}"``,
so the stringBT tree round-trips.

Import accepts both ``<X/>`` (when the TreeNodesModel declares X) and the explicit
``<Action ID="X"/>``, ``<Condition ID="X"/>`` and ``<Decorator ID="KTBT_TT1">`` forms; the
explicit form of a node stringBT maps must name its BT.CPP kind (``<Action ID="Sleep"/>``, never
``<Condition ID="Sleep"/>``). Anything
without a stringBT meaning (``SubTree``, ``Repeat``, ``Delay``, scripting attributes...) is a
:class:`ParseError` whose line and column point at the element; malformed XML is one too, never
an XML exception. DOCTYPE declarations (hence entities) are refused. Comments are not exported.
"""

from __future__ import annotations

import json
import math
import os
import re
import sys
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import NoReturn
from xml.parsers import expat

from ktbt_proto.errors import ErrorCode, LimitError, ParseError, ValidationError
from ktbt_proto.formatter import format_tree, format_value
from ktbt_proto.limits import DEFAULT_LIMITS, Limits
from ktbt_proto.syntax import parse
from ktbt_proto.tree import (
    Action,
    Args,
    Condition,
    Inverter,
    Node,
    Parallel,
    Placeholder,
    RunTimer,
    Selector,
    SequenceNode,
    Tree,
    Value,
    Visitor,
    Wait,
    WaitTimer,
    as_node,
)
from ktbt_proto.validate import validate

__all__ = ["convert", "from_xml", "to_xml", "trees_from_xml"]

MAIN_TREE = "MainTree"
TT1, TT2, WAIT_TICKS = "KTBT_TT1", "KTBT_TT2", "KTBT_WaitTicks"
RESERVED_PREFIX = "KTBT_"
PLACEHOLDER_PREFIX = "k:"
SECONDS_PREFIX = "wt:"
INDENT = "  "

# BT.CPP 4.8 built-in node IDs (and 4.6's TryCatch, 3.x's SequenceStar): a condition or action
# of the same name could not be registered. The element names BT.CPP's loader reads as document
# structure or as the explicit form cannot name a node either.
_BUILTIN_IDS = (
    "AlwaysFailure AlwaysSuccess AsyncFallback AsyncSequence Delay Fallback ForceFailure "
    "ForceSuccess IfThenElse Inverter KeepRunningUntilFailure LoopBool LoopDouble LoopInt "
    "LoopString Parallel ParallelAll Precondition ReactiveFallback ReactiveSequence Repeat "
    "RetryUntilSuccessful RunOnce Script ScriptCondition Sequence SequenceWithMemory "
    "SetBlackboard SkipUnlessUpdated Sleep SubTree Switch2 Switch3 Switch4 Switch5 Switch6 "
    "Timeout TryCatch UnsetBlackboard WaitValueUpdate WasEntryUpdated WhileDoElse SequenceStar "
    "Action Condition Control Decorator BehaviorTree TreeNodesModel root include"
)
BUILTINS = frozenset(_BUILTIN_IDS.split())

_MAX_TICKS = 2**32 - 1
_NUMBER = re.compile(r"-?[0-9]+(\.[0-9]+)?([eE][+-]?[0-9]+)?")
_STRING = re.compile(r'"([^"\\\x00-\x1f]|\\["\\/bfnrt]|\\u[0-9a-fA-F]{4})*"')
_NOT_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ufffe\uffff]")
# BT.CPP reads a port value as a blackboard reference when, spaces stripped, it is ``{...}``.
_BRACED = re.compile(r" *\{.*\} *", re.DOTALL)
# The braced strings written as references: a key that is a BT.CPP port name (a letter, then
# letters, digits or _, not name or ID), so a <SubTree> can remap it.
_REFERENCE = re.compile(r"\{(?!(?:name|ID)\})(?P<key>[A-Za-z][A-Za-z0-9_]*)\}")
_PORT = re.compile(r"[A-Za-z][A-Za-z0-9_]*(-[A-Za-z_][A-Za-z0-9_]*)*")
_ATTR_ESCAPES = str.maketrans(
    {
        "&": "&amp;",
        "<": "&lt;",
        ">": "&gt;",
        '"': "&quot;",
        "\t": "&#9;",
        "\n": "&#10;",
        "\r": "&#13;",
    }
)
_TEXT_ESCAPES = str.maketrans({"&": "&amp;", "<": "&lt;", ">": "&gt;"})
_PORT_TYPES = {bool: "bool", int: "int", float: "double", str: "std::string"}
_CUSTOM_MODELS = {
    TT1: ("Decorator", "stringBT <tt1>: RUNNING for this many ticks, then the child's status"),
    TT2: ("Decorator", "stringBT <tt2>: the child's status for this many ticks, then FAILURE"),
    WAIT_TICKS: ("Action", "stringBT <w>: RUNNING for this many ticks, then SUCCESS"),
}


# -- values and names ------------------------------------------------------------------------


def reference(value: Value) -> str | None:
    """The blackboard key a string argument refers to once exported (``"{goal}"`` -> ``goal``),
    or None: a string that is exactly a key between braces (spec/stringbt.md section 12)."""
    if not isinstance(value, str):
        return None
    match = _REFERENCE.fullmatch(value)
    return match["key"] if match is not None else None


def encode_value(value: Value) -> str:
    """Attribute text BT.CPP's converters read naturally, and :func:`decode_value` reads back to
    the same value and type (see the module docstring); a blackboard reference (``"{goal}"``) is
    written as BT.CPP reads one, unquoted (spec/stringbt.md section 12)."""
    if not isinstance(value, str):
        return format_value(value)
    if value in ("true", "false") or value.startswith('"') or _NUMBER.fullmatch(value):
        return json.dumps(value, ensure_ascii=False)
    if _REFERENCE.fullmatch(value):
        return value
    if _BRACED.fullmatch(value):
        return json.dumps(value, ensure_ascii=False)
    if _NOT_XML.search(value):
        quoted = json.dumps(value, ensure_ascii=False)
        return quoted.replace("\ufffe", "\\ufffe").replace("\uffff", "\\uffff")
    return value


def decode_value(text: str) -> Value:
    if text == "true" or text == "false":
        return text == "true"
    if _NUMBER.fullmatch(text):
        return float(text) if any(c in text for c in ".eE") else int(text)
    if _STRING.fullmatch(text):
        decoded: str = json.loads(text)
        return decoded
    return text


def btcpp_name(name: str) -> str:
    """A stringBT name as a BT.CPP node ID or port name: ``nav.MoveTo`` -> ``nav-MoveTo``."""
    return name.replace(".", "-")


def _same(a: object, b: object) -> bool:
    return type(a) is type(b) and repr(a) == repr(b)


def _msec(seconds: int | float) -> int:
    return round(Fraction(seconds) * 1000)  # exact: no overflow, no double rounding


def _seconds(msec: int) -> int | float:
    return msec // 1000 if msec % 1000 == 0 else msec / 1000


# -- export ----------------------------------------------------------------------------------


@dataclass(slots=True)
class _Out:
    """An element about to be written; children still stringBT nodes are converted lazily."""

    tag: str
    attrs: list[tuple[str, str]]
    children: list[Node | _Out | str] = field(default_factory=list)  # str: text, alone


class _Exporter(Visitor[_Out]):
    """Each node as its BehaviorTree.CPP element (stringbt.md section 12), the models of the
    node IDs it meets gathered as it goes."""

    def __init__(self) -> None:
        self.kinds: dict[str, str] = {}  # node ID -> "Condition" | "Action"
        self.ports: dict[str, dict[str, set[str]]] = {}  # node ID -> port -> types
        self.custom: set[str] = set()
        self.references: set[str] = set()  # the blackboard keys the tree's arguments name

    def _refuse(self, node: Node, message: str) -> NoReturn:
        raise ValidationError(ErrorCode.INVALID_NAME, message, node.line, node.column)

    def _leaf(self, kind: str, node: Condition | Action) -> _Out:
        name = node.name
        if name in BUILTINS or name.startswith(RESERVED_PREFIX):
            self._refuse(node, f"{name!r} is a BT.CPP built-in or reserved node ID")
        ident = btcpp_name(name)
        if self.kinds.setdefault(ident, kind) != kind:
            self._refuse(node, f"{name!r} is both a condition and an action; BT.CPP has one ID")
        ports = self.ports.setdefault(ident, {})
        attrs: list[tuple[str, str]] = []
        for key, value in node.args:
            port = btcpp_name(key)
            if not _PORT.fullmatch(port) or port in ("ID", "name"):
                self._refuse(node, f"argument {key!r} of {name!r} cannot be a BT.CPP port name")
            if isinstance(value, float) and 0 < abs(value) < sys.float_info.min:
                message = f"argument {key!r}: BT.CPP cannot read the subnormal double {value!r}"
                raise ValidationError(ErrorCode.INVALID_VALUE, message, node.line, node.column)
            types = ports.setdefault(port, set())
            entry = reference(value)
            if entry is None:
                types.add(_PORT_TYPES[type(value)])
            else:  # the entry's type is the program's: the port is declared untyped
                self.references.add(entry)
            attrs.append((port, encode_value(value)))
        return _Out(ident, attrs)

    def _ticks(self, node: Node, ticks: int | float, unit: str = "ticks") -> str:
        """The ``ticks`` port of a ``KTBT_`` node or ``Sleep``'s ``msec``, both an ``unsigned
        int`` in BT.CPP."""
        if ticks > _MAX_TICKS:
            message = f"{ticks} {unit} is more than BT.CPP's unsigned int holds ({_MAX_TICKS})"
            raise ValidationError(ErrorCode.INVALID_DURATION, message, node.line, node.column)
        return format_value(ticks)

    def condition(self, node: Condition) -> _Out:
        out = self._leaf("Condition", node)
        return _Out("Inverter", [("name", "!" + node.name)], [out]) if node.negated else out

    def action(self, node: Action) -> _Out:
        return self._leaf("Action", node)

    def wait(self, node: Wait) -> _Out:
        if node.unit == "ticks":
            self.custom.add(WAIT_TICKS)
            return _Out(WAIT_TICKS, [("ticks", self._ticks(node, node.duration))])
        msec = _msec(node.duration)
        attrs = [("msec", self._ticks(node, msec, "msec"))]
        if not _same(_seconds(msec), node.duration):
            attrs.insert(0, ("name", SECONDS_PREFIX + format_value(node.duration)))
        return _Out("Sleep", attrs)

    def sequence(self, node: SequenceNode) -> _Out:
        return _Out("Sequence" if node.memory else "ReactiveSequence", [], list(node.children))

    def selector(self, node: Selector) -> _Out:
        return _Out("Fallback" if node.memory else "ReactiveFallback", [], list(node.children))

    def placeholder(self, node: Placeholder) -> _Out:
        name = [("name", PLACEHOLDER_PREFIX + node.name)]
        kids: list[Node | _Out | str] = list(node.children) or [_Out("AlwaysFailure", [])]
        return _Out("ReactiveFallback", name, kids)

    def parallel(self, node: Parallel) -> _Out:
        n, m = len(node.children), node.threshold
        counts = [("success_count", "-1" if m is None else str(m))]
        counts.append(("failure_count", str(1 if m is None else n - m + 1)))
        return _Out("Parallel", counts, list(node.children))

    def inverter(self, node: Inverter) -> _Out:
        return _Out("Inverter", [], list(node.children))

    def wait_timer(self, node: WaitTimer) -> _Out:
        return self._timer(TT1, node)

    def run_timer(self, node: RunTimer) -> _Out:
        return self._timer(TT2, node)

    def _timer(self, ident: str, node: WaitTimer | RunTimer) -> _Out:
        self.custom.add(ident)
        return _Out(ident, [("ticks", self._ticks(node, node.ticks))], list(node.children))

    def model(self, tree_id: str) -> list[_Out]:
        """The ``<TreeNodesModel>`` entries: each condition and action with its ports, each
        ``KTBT_`` node, and the tree itself as a ``<SubTree>`` whose ports are the blackboard
        keys it refers to (none: no entry)."""
        entries: list[tuple[str, str, list[Node | _Out | str]]] = []
        if self.references:
            keys: list[Node | _Out | str] = [
                _Out("inout_port", [("name", key)]) for key in sorted(self.references)
            ]
            entries.append(("SubTree", tree_id, keys))
        for ident, kind in self.kinds.items():
            ports: list[Node | _Out | str] = []
            for port, types in sorted(self.ports[ident].items()):
                typed = [("type", next(iter(types)))] if len(types) == 1 else []
                ports.append(_Out("input_port", [("name", port), *typed]))
            entries.append((kind, ident, ports))
        for ident in self.custom:
            kind, doc = _CUSTOM_MODELS[ident]
            ticks = _Out("input_port", [("name", "ticks"), ("type", "unsigned int")], [doc])
            entries.append((kind, ident, [ticks]))
        entries.sort(key=lambda entry: entry[:2])
        return [_Out(kind, [("ID", ident)], ports) for kind, ident, ports in entries]


def _attrs(attrs: list[tuple[str, str]]) -> str:
    return "".join(f' {k}="{v.translate(_ATTR_ESCAPES)}"' for k, v in attrs)


def to_xml(tree: Tree | Node, *, tree_id: str = MAIN_TREE) -> str:
    """The tree as a BT.CPP v4 document (indented, ending with a newline), as the
    ``<BehaviorTree>`` ``tree_id`` (a learned item's file names its own, see ``sidecar``).

    Raises a :class:`StringBTError` for an invalid tree or for names BT.CPP cannot load.
    """
    validate(tree)
    exporter = _Exporter()
    body = _Out("BehaviorTree", [("ID", tree_id)], [as_node(tree)])
    lines = ['<?xml version="1.0" encoding="UTF-8"?>']
    lines.append(f"<root{_attrs([('BTCPP_format', '4'), ('main_tree_to_execute', tree_id)])}>")
    # Convert the tree first, so the model below knows every node it used.
    _write(body, 1, exporter, lines)
    _write(_Out("TreeNodesModel", [], [*exporter.model(tree_id)]), 1, exporter, lines)
    lines.append("</root>\n")
    return "\n".join(lines)


def _write(top: _Out, depth: int, exporter: _Exporter, lines: list[str]) -> None:
    """Append ``top`` as indented XML, without recursion (trees may be deep)."""
    stack: list[tuple[Node | _Out | str, int]] = [(top, depth)]  # str: a closing tag
    while stack:
        item, level = stack.pop()
        pad = INDENT * level
        if isinstance(item, str):
            lines.append(pad + item)
            continue
        out = item if isinstance(item, _Out) else exporter.visit(item)
        head = pad + f"<{out.tag}{_attrs(out.attrs)}"
        kids = out.children
        if not kids:
            lines.append(head + "/>")
        elif isinstance(kids[0], str):
            lines.append(f"{head}>{kids[0].translate(_TEXT_ESCAPES)}</{out.tag}>")
        else:
            lines.append(head + ">")
            stack.append((f"</{out.tag}>", level))
            stack.extend((child, level + 1) for child in reversed(kids))


# -- import ----------------------------------------------------------------------------------


@dataclass(eq=False, slots=True)
class _El:
    tag: str
    attrs: dict[str, str]
    line: int
    column: int
    children: list[_El] = field(default_factory=list)


_KINDS = {
    "ReactiveSequence": "sq",
    "Sequence": "msq",
    "ReactiveFallback": "sl",
    "Fallback": "msl",
    "Parallel": "pl",
    "Inverter": "neg",
    "Sleep": "wt",
    TT1: "tt1",
    TT2: "tt2",
    WAIT_TICKS: "w",
}
_ATTRIBUTES = {
    "pl": {"success_count", "failure_count"},
    "wt": {"msec"},
    "tt1": {"ticks"},
    "tt2": {"ticks"},
    "w": {"ticks"},
}
_DECORATORS = {"neg", "tt1", "tt2"}
# The explicit form of a node stringBT maps: <Action ID="Sleep"/>, never <Condition ID="Sleep"/>.
_EXPLICIT_TAG = {kind: "Control" for kind in ("sq", "msq", "sl", "msl", "pl")}
_EXPLICIT_TAG.update(neg="Decorator", tt1="Decorator", tt2="Decorator", wt="Action", w="Action")
_EXPLICIT = {"Action": "a", "Condition": "c", "Decorator": None, "Control": None}
_HINTS = {
    "SequenceWithMemory": "it resumes at a child that failed, which stringBT cannot express",
    "SubTree": "inline the subtree",
    "AlwaysFailure": "it stands only alone in an empty placeholder <ReactiveFallback name='k:...'>",
}


class _Reader:
    """Expat, with positions in code points and no DOCTYPE, into a small element tree."""

    def __init__(self, text: str, limits: Limits) -> None:
        self.text = text
        self.data = text.encode("utf-8")
        self.parser = expat.ParserCreate("UTF-8")
        self.root: _El | None = None
        self.stack: list[_El] = []
        self.count = 0
        # Generous bounds against hostile input; validation applies the exact limits later.
        self.max_depth = 2 * limits.max_depth + 8
        self.max_elements = 2 * limits.max_nodes + 1000
        self.max_literal = limits.max_literal
        self._cursor = (0, 1, 1)  # byte index, line, column: positions are asked in order

    def position(self, index: int) -> tuple[int, int]:
        start, line, column = self._cursor if index >= self._cursor[0] else (0, 1, 1)
        chunk = self.data[start:index]
        newlines = chunk.count(b"\n")
        if newlines:
            line += newlines
            chunk = chunk[chunk.rindex(b"\n") + 1 :]
            column = 1
        column += len(chunk.decode("utf-8", "replace"))
        self._cursor = (index, line, column)
        return line, column

    def fail(self, code: ErrorCode, message: str, at: _El | None = None) -> NoReturn:
        if at is None:
            line, column = self.position(max(self.parser.CurrentByteIndex, 0))
        else:
            line, column = at.line, at.column
        kind = LimitError if code.value.startswith("SBT2") else ParseError
        raise kind(code, message, line, column, source=self.text)

    def read(self) -> _El:
        p = self.parser
        p.StartElementHandler = self._start
        p.EndElementHandler = self._end
        p.StartDoctypeDeclHandler = self._doctype
        p.EntityDeclHandler = self._doctype
        p.SetParamEntityParsing(expat.XML_PARAM_ENTITY_PARSING_NEVER)
        try:
            p.Parse(self.data, True)
        except expat.ExpatError as exc:
            line, column = self.position(max(p.ErrorByteIndex, 0))
            message = f"malformed XML: {expat.ErrorString(exc.code)}"
            raise ParseError(
                ErrorCode.UNEXPECTED_TOKEN, message, line, column, source=self.text
            ) from None
        if self.root is None:  # expat fails on a document without an element first
            raise ParseError(ErrorCode.EMPTY, "no element in the document", 1, 1)
        return self.root

    def _doctype(self, *_: object) -> None:
        self.fail(ErrorCode.UNEXPECTED_TOKEN, "DOCTYPE and entity declarations are refused")

    def _start(self, tag: str, attrs: dict[str, str]) -> None:
        self.count += 1
        if len(self.stack) >= self.max_depth:
            self.fail(ErrorCode.TOO_DEEP, "elements nested deeper than the depth limit allows")
        if self.count > self.max_elements:
            self.fail(ErrorCode.TOO_MANY_NODES, "more elements than the node limit allows")
        for value in (tag, *attrs, *attrs.values()):
            if len(value) > self.max_literal:
                self.fail(ErrorCode.LITERAL_TOO_LONG, "name or value longer than the limit")
        line, column = self.position(self.parser.CurrentByteIndex)
        element = _El(tag, attrs, line, column)
        if self.stack:
            self.stack[-1].children.append(element)
        else:
            self.root = element
        self.stack.append(element)

    def _end(self, tag: str) -> None:
        self.stack.pop()


class _Importer:
    def __init__(self, reader: _Reader) -> None:
        self.reader = reader
        self.model: dict[str, str] = {}  # node ID -> TreeNodesModel kind

    def fail(self, code: ErrorCode, message: str, at: _El) -> NoReturn:
        self.reader.fail(code, message, at)

    def unsupported(self, el: _El, why: str) -> NoReturn:
        self.fail(ErrorCode.UNKNOWN_TAG, f"<{el.tag}> is not supported: {why}", el)

    def trees(self, root: _El) -> dict[str, _El]:
        """The document's ``<BehaviorTree>`` elements by ID (the first of an ID), its model
        read on the way."""
        if root.tag != "root":
            self.unsupported(root, "a BT.CPP document's element is <root>")
        version = root.attrs.get("BTCPP_format", "4")
        if version != "4":
            self.fail(ErrorCode.UNEXPECTED_TOKEN, f"BTCPP_format {version!r}; only 4 is read", root)
        trees: dict[str, _El] = {}
        for child in root.children:
            if child.tag == "BehaviorTree":
                trees.setdefault(child.attrs.get("ID", ""), child)
            elif child.tag == "TreeNodesModel":
                for entry in child.children:
                    if "ID" in entry.attrs:
                        self.model[entry.attrs["ID"]] = entry.tag
            else:
                self.unsupported(child, "a <root> holds <BehaviorTree> and <TreeNodesModel>")
        return trees

    def document(self, root: _El) -> Node:
        trees = self.trees(root)
        main = root.attrs.get("main_tree_to_execute")
        if main is not None and main not in trees:
            self.fail(ErrorCode.EMPTY, f"no <BehaviorTree ID={main!r}> to execute", root)
        if main is None and len(trees) != 1:
            what = "no <BehaviorTree>" if not trees else "several trees, no main_tree_to_execute"
            self.fail(ErrorCode.EMPTY, what, root)
        return self.body(trees[main] if main is not None else next(iter(trees.values())))

    def body(self, body: _El) -> Node:
        """The one root node of a ``<BehaviorTree>``."""
        if not body.children:
            self.fail(ErrorCode.EMPTY, "the <BehaviorTree> holds no node", body)
        if len(body.children) > 1:
            self.fail(
                ErrorCode.EXTRA_ROOT, "a <BehaviorTree> holds one root node", body.children[1]
            )
        return self.tree(body.children[0])

    def kind(self, el: _El) -> tuple[str, str]:
        """What the element is (a value of ``_KINDS``, or "c", "a", "k") and its node ID."""
        tag, attrs = el.tag, el.attrs
        explicit = tag in _EXPLICIT
        ident = attrs.get("ID", "") if explicit else tag
        if explicit and not ident:
            self.fail(ErrorCode.UNEXPECTED_TOKEN, f"<{tag}> needs an ID attribute", el)
        kind = _KINDS.get(ident)
        if kind is not None and explicit and tag != _EXPLICIT_TAG[kind]:
            self.unsupported(el, f"{ident} is BT.CPP's own {_EXPLICIT_TAG[kind]} node")
        if kind is None:
            leaf = _EXPLICIT.get(tag if explicit else self.model.get(ident, ""))
            reserved = ident in BUILTINS or ident.startswith(RESERVED_PREFIX)
            if leaf is not None and not reserved:
                self.check_attrs(el, None, explicit)
                return leaf, ident
            if ident in _HINTS or reserved:
                why = _HINTS.get(ident, "stringBT has no such node")
            else:
                why = "neither a node stringBT maps nor a condition or action in TreeNodesModel"
            self.unsupported(el, why if ident == tag else f"ID {ident!r}: {why}")
        if kind == "sl" and attrs.get("name", "").startswith(PLACEHOLDER_PREFIX):
            kind = "k"
        self.check_attrs(el, _ATTRIBUTES.get(kind, set()), explicit)
        return kind, ident

    def check_attrs(self, el: _El, allowed: set[str] | None, explicit: bool) -> None:
        """``allowed`` None: a condition or action, whose other attributes are its arguments."""
        for key in el.attrs:
            if key == "name" or (key == "ID" and explicit):
                continue
            if key.startswith("_"):
                self.fail(ErrorCode.UNEXPECTED_TOKEN, f"scripting attribute {key!r} refused", el)
            if key == "ID" or (allowed is not None and key not in allowed):
                self.fail(ErrorCode.UNEXPECTED_TOKEN, f"<{el.tag}> takes no {key!r}", el)
            if allowed is None and not _PORT.fullmatch(key):
                self.fail(ErrorCode.INVALID_NAME, f"port {key!r} has no stringBT name", el)

    def integer(self, el: _El, key: str, default: str | None = None) -> int:
        text = el.attrs.get(key, default)
        value = decode_value(text) if text is not None else None
        if not isinstance(value, int) or isinstance(value, bool):
            count = key.endswith("count")
            code = ErrorCode.INVALID_THRESHOLD if count else ErrorCode.INVALID_DURATION
            self.fail(code, f"<{el.tag}> needs an integer {key}, not {text!r}", el)
        return value

    def unsigned(self, el: _El, key: str) -> int:
        """A ``ticks`` or ``msec`` port, which BT.CPP reads as an ``unsigned int``."""
        value = self.integer(el, key)
        if value > _MAX_TICKS:
            message = f"<{el.tag}> {key} {value} is more than BT.CPP's unsigned int holds"
            self.fail(ErrorCode.INVALID_DURATION, message, el)
        return value

    def leaf(self, el: _El, kind: str, ident: str, negated: bool = False) -> Node:
        pos = (el.line, el.column)
        if kind == "w":
            return Wait(self.unsigned(el, "ticks"), "ticks", pos=pos)
        if kind == "wt":
            msec = self.unsigned(el, "msec")
            try:
                seconds = _seconds(msec)
            except OverflowError:
                self.fail(ErrorCode.INVALID_DURATION, f"<{el.tag}> msec {msec} is too large", el)
            literal = el.attrs.get("name", "").removeprefix(SECONDS_PREFIX)
            if el.attrs.get("name", "").startswith(SECONDS_PREFIX) and _NUMBER.fullmatch(literal):
                exact = decode_value(literal)  # a number: _NUMBER matched it whole
                if isinstance(exact, int | float) and math.isfinite(exact) and _msec(exact) == msec:
                    seconds = exact
            return Wait(seconds, "seconds", pos=pos)
        name = ident.replace("-", ".")
        args: Args = tuple(
            (k.replace("-", "."), decode_value(v))
            for k, v in el.attrs.items()
            if k not in ("ID", "name")
        )
        if kind == "c":
            return Condition(name, negated, args, pos=pos)
        return Action(name, args, pos=pos)

    def negation(self, el: _El) -> Node | None:
        """``<c>(!X)``: an inverter named ``!X`` over condition X (see the module docstring)."""
        name = el.attrs.get("name", "")
        if not name.startswith("!") or len(el.children) != 1:
            return None
        child = el.children[0]
        kind, ident = self.kind(child)
        if kind != "c" or ident.replace("-", ".") != name[1:] or child.children:
            return None
        return self.leaf(child, kind, ident, negated=True)

    def tree(self, top: _El) -> Node:
        """Convert bottom-up without recursion (a hostile document may be very deep)."""
        done: list[Node] = []
        todo: list[tuple[_El, str | None]] = [(top, None)]
        while todo:
            el, ready = todo.pop()
            if ready is None:
                kind, ident = self.kind(el)
                kids = el.children
                if kind in ("c", "a", "w", "wt"):
                    if kids:
                        self.fail(ErrorCode.UNEXPECTED_TOKEN, f"<{el.tag}> takes no child", kids[0])
                    done.append(self.leaf(el, kind, ident))
                    continue
                negated = self.negation(el) if kind == "neg" else None
                if negated is not None:
                    done.append(negated)
                    continue
                if kind == "k" and len(kids) == 1 and kids[0].tag == "AlwaysFailure":
                    if kids[0].children or set(kids[0].attrs) - {"name"}:
                        self.unsupported(kids[0], "it takes no attributes or children here")
                    name = el.attrs["name"].removeprefix(PLACEHOLDER_PREFIX)
                    done.append(Placeholder((), name, pos=(el.line, el.column)))
                    continue
                if kind in _DECORATORS and len(kids) != 1:
                    self.fail(ErrorCode.DECORATOR_ARITY, f"<{el.tag}> needs exactly one child", el)
                if not kids and kind != "k":
                    self.fail(ErrorCode.EMPTY_COMPOSITE, f"<{el.tag}> needs a child", el)
                todo.append((el, kind))
                todo.extend((child, None) for child in reversed(kids))
                continue
            n = len(el.children)
            children = tuple(done[len(done) - n :])
            del done[len(done) - n :]
            done.append(self.container(el, ready, children))
        return done[0]

    def container(self, el: _El, kind: str, children: tuple[Node, ...]) -> Node:
        pos = (el.line, el.column)
        if kind in ("sq", "msq"):
            return SequenceNode(children, kind == "msq", pos=pos)
        if kind in ("sl", "msl"):
            return Selector(children, kind == "msl", pos=pos)
        if kind == "k":
            return Placeholder(children, el.attrs["name"].removeprefix(PLACEHOLDER_PREFIX), pos=pos)
        if kind == "neg":
            return Inverter(children, pos=pos)
        if kind in ("tt1", "tt2"):
            timer = WaitTimer if kind == "tt1" else RunTimer
            return timer(children, self.unsigned(el, "ticks"), pos=pos)
        # BT.CPP counts a negative count from the end: -1 is all N children.
        n = len(children)
        success = self.integer(el, "success_count", "-1")
        failure = self.integer(el, "failure_count", "1")
        need = success + n + 1 if success < 0 else success
        if (failure + n + 1 if failure < 0 else failure) != n - need + 1:
            message = (
                f"Parallel with success_count={success}, failure_count={failure} fails earlier "
                f"or later than stringBT's (failure_count must be N - success_count + 1)"
            )
            self.fail(ErrorCode.INVALID_THRESHOLD, message, el)
        return Parallel(children, None if success == -1 else need, pos=pos)


def _reader(data: str | bytes, limits: Limits) -> _Reader:
    """The document read as elements; a :class:`StringBTError` for what is not XML or too
    large."""
    if len(data) > limits.max_size:
        raise LimitError(ErrorCode.TOO_LARGE, f"input larger than {limits.max_size}")
    if isinstance(data, bytes):
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError as exc:
            line = data.count(b"\n", 0, exc.start) + 1
            start = data.rfind(b"\n", 0, exc.start) + 1
            column = len(data[start : exc.start].decode("utf-8", "replace")) + 1
            raise ParseError(ErrorCode.INVALID_UTF8, "input is not UTF-8", line, column) from None
    else:
        text = data
    text = text.removeprefix("\ufeff")
    bad = re.search("[\ud800-\udfff]", text)
    if bad is not None:
        line = text.count("\n", 0, bad.start()) + 1
        column = bad.start() - text.rfind("\n", 0, bad.start())
        raise ParseError(ErrorCode.INVALID_UTF8, "lone surrogate in the text", line, column)
    if not text.strip():
        raise ParseError(ErrorCode.EMPTY, "no XML element at all")
    return _Reader(text, limits)


def from_xml(data: str | bytes, *, limits: Limits = DEFAULT_LIMITS) -> Tree:
    """Read a BT.CPP v4 document back into a validated stringBT tree.

    Raises a :class:`StringBTError` (never an XML exception) whose line and column point into
    the XML: malformed XML, an element or attribute stringBT cannot express, an invalid tree.
    """
    reader = _reader(data, limits)
    tree = Tree(_Importer(reader).document(reader.read()))
    validate(tree, limits=limits)
    return tree


def trees_from_xml(data: str | bytes, *, limits: Limits = DEFAULT_LIMITS) -> dict[str, Tree]:
    """Every ``<BehaviorTree>`` of a BT.CPP v4 document, by ID, each a validated stringBT tree
    (a robot's skills, one tree each: :func:`ktbt_proto.interop.sidecar.read_skills`). Raises
    as :func:`from_xml` does; a document without a tree is ``SBT`` ``EMPTY``."""
    reader = _reader(data, limits)
    importer = _Importer(reader)
    root = reader.read()
    found = importer.trees(root)
    if not found:
        importer.fail(ErrorCode.EMPTY, "no <BehaviorTree>", root)
    trees = {ident: Tree(importer.body(el)) for ident, el in found.items()}
    for tree in trees.values():
        validate(tree, limits=limits)
    return trees


def document_tree_ids(data: str | bytes) -> tuple[list[str], str | None]:
    """The ``<BehaviorTree>`` IDs of a BT.CPP document and its ``main_tree_to_execute``, read
    as Nav2's ``BehaviorTreeEngine::parseTreeInfo`` reads them before it registers a file from
    its ``bt_search_directories`` (the sidecar checks the IDs it writes against them: spec/
    stringbt.md section 12.2). Only the root's children are looked at, so any BT.CPP
    document reads, whatever its nodes. Raises a :class:`StringBTError` for malformed XML."""
    root = _reader(data, DEFAULT_LIMITS).read()
    ids = [el.attrs["ID"] for el in root.children if el.tag == "BehaviorTree" and "ID" in el.attrs]
    return ids, root.attrs.get("main_tree_to_execute")


# -- files -----------------------------------------------------------------------------------


def convert(in_path: str | os.PathLike[str], out_path: str | os.PathLike[str]) -> None:
    """Convert ``.sbt`` to BT.CPP ``.xml`` or back, by the files' extensions.

    Raises ``ValueError`` for any other pair of extensions, a :class:`StringBTError` for an
    input that does not convert, and ``OSError`` for files that cannot be read or written.
    """
    source, target = Path(in_path), Path(out_path)
    pair = (source.suffix.lower(), target.suffix.lower())
    if pair == (".sbt", ".xml"):
        text = to_xml(parse(source.read_bytes()))
    elif pair == (".xml", ".sbt"):
        text = format_tree(from_xml(source.read_bytes()))
    else:
        raise ValueError(f"convert .sbt to .xml or .xml to .sbt, not {pair[0]!r} to {pair[1]!r}")
    with open(target, "w", encoding="utf-8", newline="\n") as f:
        f.write(text)
