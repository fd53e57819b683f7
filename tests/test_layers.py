"""The language layer never reaches up (ARCHITECTURE.md): nothing that parses, formats, checks,
merges, renders or runs a tree imports the knowledge base, agents, messages, transports, the
peer commands, the command line or the simulator, directly or through another module of ours.

Imports are read from the source (``ast``), every one of them: at the top, inside functions, and
under ``TYPE_CHECKING``, since a layer that names a type from above depends on it all the same.
"""

from __future__ import annotations

import ast
from collections.abc import Iterable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "ktbt_proto"

LANGUAGE = (
    "ktbt_proto.blackboard",
    "ktbt_proto.control",
    "ktbt_proto.errors",
    "ktbt_proto.format",
    "ktbt_proto.interop",
    "ktbt_proto.interop.btcpp",
    "ktbt_proto.interop.pytrees",
    "ktbt_proto.interop.pytrees_control",
    "ktbt_proto.items",
    "ktbt_proto.limits",
    "ktbt_proto.merge",
    "ktbt_proto.registry",
    "ktbt_proto.render",
    "ktbt_proto.runtime",
    "ktbt_proto.status",
    "ktbt_proto.syntax",
    "ktbt_proto.tree",
    "ktbt_proto.validate",
)
"""The modules of the language layer: stringBT, its trees and their live runtime."""

ABOVE = (
    "ktbt_proto.knowledge",
    "ktbt_proto.agent",
    "ktbt_proto.messages",
    "ktbt_proto.transport",
    "ktbt_proto.peer",
    "ktbt_proto.cli",
    "ktbt_proto.signing",
    "ktbt_proto.trust",
    "ktbt_proto.transferlog",
    "ktbt_proto.memory",
    "ktbt_sim",
)
"""What the language must not depend on: the protocol, its tools, and the simulator."""


def source_of(module: str, package: Path) -> Path | None:
    """The file of ``module`` (``a.b.c``) under the folder that holds package ``a``."""
    base = package.parent.joinpath(*module.split("."))
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def imports_of(module: str, package: Path) -> set[str]:
    """Every module ``module`` imports, relative imports resolved to absolute names; for
    ``from X import name``, ``X.name`` too when that is a module of ours."""
    path = source_of(module, package)
    assert path is not None, module
    is_package = path.name == "__init__.py"
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = module.split(".")
                keep = len(parts) - node.level + (1 if is_package else 0)
                base = ".".join(parts[:keep] + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            found.add(base)
            for alias in node.names:
                if source_of(f"{base}.{alias.name}", package) is not None:
                    found.add(f"{base}.{alias.name}")
    return found


def reaches(start: str, package: Path) -> dict[str, list[str]]:
    """Every module of ours ``start`` imports, directly or not, with the chain that gets there."""
    own = package.name
    chains: dict[str, list[str]] = {start: [start]}
    todo = [start]
    while todo:
        current = todo.pop()
        for name in sorted(imports_of(current, package)):
            if name.split(".")[0] != own or name in chains:
                chains.setdefault(name, [*chains[current], name])
                continue
            chains[name] = [*chains[current], name]
            if source_of(name, package) is not None:
                todo.append(name)
    return chains


def violations(modules: Iterable[str], forbidden: Iterable[str], package: Path) -> list[str]:
    banned = tuple(forbidden)
    found = []
    for module in modules:
        for name, chain in reaches(module, package).items():
            if any(name == b or name.startswith(b + ".") for b in banned):
                found.append(" -> ".join(chain))
    return sorted(found)


@pytest.mark.parametrize("module", LANGUAGE)
def test_the_language_layer_imports_nothing_above_it(module: str) -> None:
    assert source_of(module, PACKAGE) is not None, f"{module} is gone: update LANGUAGE"
    assert violations([module], ABOVE, PACKAGE) == []


def test_a_reach_through_another_module_is_found(tmp_path: Path) -> None:
    """The check itself: an upward import two steps away, relative or lazy, is reported."""
    package = tmp_path / "pkg"
    (package / "sub").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "sub" / "__init__.py").write_text("from .. import low\n")
    (package / "low.py").write_text("def f():\n    from .mid import g\n")
    (package / "mid.py").write_text("from pkg import high\n")
    (package / "high.py").write_text("import os\n")
    (package / "clean.py").write_text("from .low import f\n")
    found = violations(["pkg.sub", "pkg.clean"], ["pkg.high"], package)
    assert found == [
        "pkg.clean -> pkg.low -> pkg.mid -> pkg.high",
        "pkg.sub -> pkg.low -> pkg.mid -> pkg.high",
    ]
