"""ARCHITECTURE.md cannot drift from the package: every module and subpackage of ``ktbt_proto``
and ``ktbt_sim`` is named in it under its layer, every module it names exists, and the layer
order it states is the import-linter ``layers`` contract in ``pyproject.toml`` (which
``lint-imports`` enforces on the imports themselves). The API reference page names every module
too, so a new one is documented."""

from __future__ import annotations

import importlib.util
import pkgutil
import re
import tomllib
from pathlib import Path

import ktbt_proto
import ktbt_sim

ROOT = Path(__file__).resolve().parents[2]
TEXT = (ROOT / "ARCHITECTURE.md").read_text(encoding="utf-8")
LANGUAGE = "the language"
ENTRY = "ktbt_proto.__main__"


def walk(package: object) -> dict[str, bool]:
    """Every module and subpackage below the package (name: is a package), found on disk
    without importing the modules themselves."""
    name = package.__name__  # type: ignore[attr-defined]
    path = package.__path__  # type: ignore[attr-defined]
    return {m.name: m.ispkg for m in pkgutil.walk_packages(path, name + ".")}


PROTO = walk(ktbt_proto)
SIM = walk(ktbt_sim)


def sections() -> dict[str, set[str]]:
    """Under each ``###`` heading of "Where each concern lives": the modules its tables name in
    their first column, keyed by the heading up to its parenthesis."""
    found: dict[str, set[str]] = {}
    current = None
    for line in TEXT.splitlines():
        if line.startswith("### "):
            current = line[4:].split(" (")[0].strip()
            found[current] = set()
        elif line.startswith("## "):
            current = None
        elif current is not None and (cell := re.match(r"\| `([\w.]+)` \|", line)):
            found[current].add(cell[1])
    return found


def stated_order() -> list[str]:
    """The numbered list under "The layers, top to bottom": a subpackage or the language."""
    body = TEXT.split("## The layers, top to bottom", 1)[1].split("\n## ", 1)[0]
    order = []
    for item in re.findall(r"^\d+\. (.*)$", body, re.M):
        name = re.match(r"`(\w+)`", item)
        order.append(name[1] if name else LANGUAGE if item.startswith(LANGUAGE) else item)
    return order


def contract() -> list[str]:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    (layers,) = [c for c in config["tool"]["importlinter"]["contracts"] if c["id"] == "layers"]
    assert layers["containers"] == ["ktbt_proto"]
    return list(layers["layers"])


def layer_of(module: str) -> str:
    top = module.split(".")[1]
    return top if PROTO.get(f"ktbt_proto.{top}") else LANGUAGE


def test_the_layer_order_is_the_import_contracts() -> None:
    order = contract()
    as_named = [layer if PROTO.get(f"ktbt_proto.{layer}") else LANGUAGE for layer in order]
    assert stated_order() == as_named
    (siblings,) = [layer for layer in order if not PROTO.get(f"ktbt_proto.{layer}")]
    language = {f"ktbt_proto.{name.strip()}" for name in siblings.split(":")}
    assert sections()[LANGUAGE] == language


def test_every_module_is_named_under_its_layer() -> None:
    named = sections()
    assert set(named) == {*stated_order(), "The simulator"}
    for module in PROTO:
        if module == ENTRY:
            assert f"`{ENTRY}`" in TEXT
            continue
        layer = layer_of(module)
        assert module in named[layer], f"{module}: name it in ARCHITECTURE.md under {layer}"
    for layer in stated_order():
        if layer != LANGUAGE:
            assert f"ktbt_proto.{layer}" in named[layer]
    for module in SIM:
        assert module in named["The simulator"], f"{module}: name it in ARCHITECTURE.md"


def test_every_module_named_exists_under_the_layer_it_is_named_in() -> None:
    for layer, modules in sections().items():
        for module in modules:
            assert importlib.util.find_spec(module) is not None, module
            if layer == "The simulator":
                assert module.startswith("ktbt_sim.")
            else:
                assert layer_of(module) == layer, f"{module} is not in {layer}"


def test_the_api_reference_documents_every_library_module() -> None:
    api = (ROOT / "docs" / "reference" / "api.md").read_text(encoding="utf-8")
    documented = set(re.findall(r"^\.\. automodule:: ([\w.]+)", api, re.M))
    library = {m for m in PROTO if layer_of(m) != "tools" and m != ENTRY and not PROTO[m]}
    assert library <= documented, sorted(library - documented)
    assert documented <= {*PROTO, "ktbt_proto"}, sorted(documented - {*PROTO, "ktbt_proto"})
