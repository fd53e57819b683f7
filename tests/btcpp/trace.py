"""One run of a tree with scripted leaves, printed the same way by each engine.

A script gives every condition and action an outcome per tick (``S``, ``F``, ``R``, cycled), so a
leaf's result depends only on its name and the tick, never on how often an engine called it.
A trace lists, per tick, ``tick K``, the leaf calls with the arguments the node received
(``call NAME port=value``), the halted actions (``halt NAME``) and ``status STATUS``; after the
last tick the whole tree is halted (``halt tree``), as a program that stops does. The C++ side
is ``tests/btcpp/harness.cpp``, which may also set blackboard entries for ``{key}`` references
(spec/stringbt.md section 12) to read; the two engines are compared on trees without them.
"""

from __future__ import annotations

import json
import subprocess
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import ktbt_proto as kp
from ktbt_proto.interop.btcpp import RESERVED_PREFIX, encode_value
from ktbt_proto.tree import Value

Ports = tuple[tuple[str, str], ...]  # (port, type), sorted by port


@dataclass(frozen=True)
class Leaf:
    kind: str  # "c" or "a"
    outcomes: str
    ports: Ports = ()


@dataclass
class Script:
    ticks: int
    leaves: dict[str, Leaf] = field(default_factory=dict)  # BT.CPP ID -> leaf
    blackboard: dict[str, str] = field(default_factory=dict)
    """The harness's blackboard entries (strings), which a ``{key}`` reference reads: BT.CPP's
    alone (``LiveTree`` has no blackboard), so :func:`live_trace` refuses a script with any."""

    def text(self) -> str:
        lines = [f"ticks {self.ticks}"]
        lines.extend(f"set {key} {text}" for key, text in self.blackboard.items())
        for ident, leaf in self.leaves.items():
            ports = " ".join(f"{port}:{kind}" for port, kind in leaf.ports)
            lines.append(f"{leaf.kind} {ident} {leaf.outcomes} {ports}".rstrip())
        return "\n".join(lines) + "\n"


_TYPES = {"int": "int", "double": "double", "bool": "bool"}


def model(xml: str) -> dict[str, tuple[str, Ports]]:
    """The conditions and actions the TreeNodesModel declares: ID -> (kind, ports with the
    type the harness reads them as; ``string`` where the model gives none or a string)."""
    declared: dict[str, tuple[str, Ports]] = {}
    for entry in ET.fromstring(xml.encode()).iterfind("TreeNodesModel/*"):
        ident = entry.get("ID", "")
        if entry.tag not in ("Condition", "Action") or ident.startswith(RESERVED_PREFIX):
            continue
        ports = tuple(
            sorted(
                (port.get("name", ""), _TYPES.get(port.get("type", ""), "string"))
                for port in entry.iterfind("input_port")
            )
        )
        declared[ident] = ("c" if entry.tag == "Condition" else "a", ports)
    return declared


def script_for(xml: str, outcomes: Mapping[str, str], ticks: int) -> Script:
    """A script for every leaf of ``xml``; ``outcomes`` by stringBT name (default ``F``/``S``)."""
    script = Script(ticks)
    for ident, (kind, ports) in model(xml).items():
        default = "F" if kind == "c" else "S"
        script.leaves[ident] = Leaf(kind, outcomes.get(ident.replace("-", "."), default), ports)
    return script


def _shown(value: Value, kind: str) -> str:
    """How the harness prints a value read from a port of this type (see harness.cpp)."""
    if kind == "int":
        return str(value)
    if kind == "double":
        assert isinstance(value, float)
        return format(value, ".17g")
    if kind == "bool":
        return "true" if value else "false"
    return json.dumps(encode_value(value), ensure_ascii=False)


def compact(trace: list[str]) -> str:
    """A trace on one line, for pinning one: ticks apart by "; ", lines by ", "."""
    ticks: list[list[str]] = []
    for line in trace:
        if line.startswith("tick "):
            ticks.append([])
        elif line != "halt tree" and ticks:
            ticks[-1].append(line)
    return "; ".join(", ".join(lines) for lines in ticks)


_STATUS = {"S": kp.SUCCESS, "F": kp.FAILURE, "R": kp.RUNNING}


def live_trace(tree: kp.Tree, script: Script) -> list[str]:
    """Tick ``tree`` in a ``LiveTree`` whose leaves follow ``script``; the trace."""
    assert not script.blackboard, "LiveTree has no blackboard for {key} references to read"
    log: list[str] = []
    clock = [0]

    def outcome(leaf: Leaf) -> kp.Status:
        return _STATUS[leaf.outcomes[(clock[0] - 1) % len(leaf.outcomes)]]

    def call(ident: str, leaf: Leaf, args: Mapping[str, Any]) -> None:
        given = {key.replace(".", "-"): value for key, value in args.items()}
        shown = [
            f" {port}={_shown(given[port], kind)}" for port, kind in leaf.ports if port in given
        ]
        log.append(f"call {ident}{''.join(shown)}")

    registry = kp.Registry()
    for ident, leaf in script.leaves.items():
        name = ident.replace("-", ".")
        if leaf.kind == "c":
            registry.add_condition(name, _condition(ident, leaf, call, outcome))
        else:
            registry.add_action(name, _action(ident, leaf, call, outcome, log))
    live = kp.LiveTree(tree, registry)
    for tick in range(1, script.ticks + 1):
        clock[0] = tick
        log.append(f"tick {tick}")
        log.append(f"status {live.tick().name}")
    log.append("halt tree")
    live.halt()
    return log


Call = Callable[[str, Leaf, Mapping[str, Any]], None]


def _condition(
    ident: str, leaf: Leaf, call: Call, outcome: Callable[[Leaf], kp.Status]
) -> Callable[..., bool]:
    def holds(blackboard: object, **args: Any) -> bool:
        call(ident, leaf, args)
        return outcome(leaf) is kp.SUCCESS

    return holds


def _action(
    ident: str, leaf: Leaf, call: Call, outcome: Callable[[Leaf], kp.Status], log: list[str]
) -> type:
    class Scripted:
        def __init__(self, blackboard: object, **args: Any) -> None:
            self.args = args

        def tick(self) -> kp.Status:
            call(ident, leaf, self.args)
            return outcome(leaf)

        def halt(self) -> None:
            log.append(f"halt {ident}")

    return Scripted


def btcpp_trace(harness: Path, xml: str, script: Script, work: Path) -> list[str]:
    """The harness's trace of ``xml`` under ``script`` (BehaviorTree.CPP built from source)."""
    tree_file, script_file = work / "tree.xml", work / "script.txt"
    tree_file.write_text(xml, encoding="utf-8")
    script_file.write_text(script.text(), encoding="utf-8")
    done = subprocess.run(
        [str(harness), str(tree_file), str(script_file)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    return done.stdout.split("\n")[:-1]  # not splitlines(): a string may hold U+0085


def wheel_trace(xml: str, script: Script) -> list[str]:
    """The same run through ``behaviortreepy`` (BehaviorTree.CPP 4.8.2 compiled, leaves
    registered by name only, so only trees without arguments or ``KTBT_`` nodes load)."""
    import behaviortreepy as bt

    statuses = {"S": bt.NodeStatus.SUCCESS, "F": bt.NodeStatus.FAILURE, "R": bt.NodeStatus.RUNNING}
    log: list[str] = []
    clock = [0]
    factory = bt.BehaviorTreeFactory()

    def scripted(ident: str, leaf: Leaf) -> Callable[[Any], Any]:
        def run(node: Any) -> Any:
            log.append(f"call {ident}")
            return statuses[leaf.outcomes[(clock[0] - 1) % len(leaf.outcomes)]]

        return run

    for ident, leaf in script.leaves.items():
        assert not leaf.ports, "behaviortreepy registers leaves without ports"
        run = scripted(ident, leaf)
        if leaf.kind == "c":
            factory.register_simple_condition(ident, run)
        else:

            def halted(node: Any, ident: str = ident) -> None:
                log.append(f"halt {ident}")

            factory.register_simple_stateful_action(ident, run, run, halted)
    tree = factory.create_tree_from_text(xml)
    for tick in range(1, script.ticks + 1):
        clock[0] = tick
        log.append(f"tick {tick}")
        log.append(f"status {bt.to_string(tree.tick_exactly_once())}")
    log.append("halt tree")
    tree.halt_tree()
    return log
