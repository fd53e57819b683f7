"""The simulator's modules import one another one way (spec/simulator.md, module table): no
cycle, and no mechanism imports ``world``, which only orchestrates. Type-only imports count:
they are dependencies a reader follows too."""

from __future__ import annotations

import ast
from pathlib import Path

import networkx as nx

PACKAGE = Path(__file__).resolve().parents[2] / "ktbt_sim"
MECHANISMS = ("geometry", "motion", "sensing", "timers", "teaching", "robot", "records", "state")


def imports() -> nx.DiGraph:
    graph = nx.DiGraph()
    for path in PACKAGE.glob("*.py"):
        graph.add_node(path.stem)
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                names = [node.module] if node.module else [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("ktbt_sim"):
                parts = (node.module or "").split(".")
                names = parts[1:2] if len(parts) > 1 else [a.name for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name.split(".")[1] for a in node.names if a.name.startswith("ktbt_sim.")]
            else:
                continue
            for name in names:
                graph.add_edge(path.stem, name.split(".")[0])
    return graph


def test_the_import_graph_has_no_cycle() -> None:
    graph = imports()
    assert {"world", "records", "results", "teaching", "robot"} <= set(graph)
    assert list(nx.simple_cycles(graph)) == []


def test_no_mechanism_imports_the_world() -> None:
    graph = imports()
    assert [m for m in MECHANISMS if graph.has_edge(m, "world")] == []
    assert not graph.has_edge("records", "results")
