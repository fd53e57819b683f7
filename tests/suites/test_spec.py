"""The specification and the code agree: grammar text, error codes, conformance vectors."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest

import ktbt_proto as kp
from ktbt_proto.errors import ErrorCode
from ktbt_proto.limits import DEFAULT_LIMITS
from ktbt_proto.syntax import _parse_fast, grammar_path, grammar_text, parse_reference

SPEC = Path(__file__).resolve().parents[2] / "spec"
STRINGBT_MD = (SPEC / "stringbt.md").read_text(encoding="utf-8")


def vectors(name: str) -> list[dict[str, Any]]:
    data: list[dict[str, Any]] = json.loads((SPEC / "vectors" / f"{name}.json").read_text())
    return data


def test_spec_quotes_the_grammar_verbatim() -> None:
    block = re.search(r"```lark\n(.*?)```", STRINGBT_MD, re.S)
    assert block is not None
    assert block.group(1) == grammar_text()


def test_the_packaged_grammar_is_the_normative_one() -> None:
    """The package reads its own copy (``ktbt_proto/grammar``, shipped in the wheel); the
    repository's ``grammar/stringbt.lark`` is the normative text, byte for byte the same."""
    normative = SPEC.parent / "grammar" / "stringbt.lark"
    assert normative.read_bytes() == grammar_path().read_bytes()


def test_spec_error_table_matches_the_codes() -> None:
    rows = re.findall(r"^\| `(SBT\d{3})` \| ([a-z0-9-]+) \|", STRINGBT_MD, re.M)
    assert rows == [(c.value, c.name.lower().replace("_", "-")) for c in ErrorCode]


def test_spec_limit_defaults_match_the_code() -> None:
    for figure in (
        DEFAULT_LIMITS.max_size,
        DEFAULT_LIMITS.max_depth,
        DEFAULT_LIMITS.max_nodes,
        DEFAULT_LIMITS.max_literal,
    ):
        assert f"| {figure:,} " in STRINGBT_MD


@pytest.mark.parametrize("case", vectors("valid"), ids=lambda c: c["name"])
def test_valid_vectors(case: dict[str, Any]) -> None:
    tree = kp.parse(case["input"])
    assert kp.format_tree(tree, "compact") == case["compact"]
    assert kp.format_tree(tree, "pretty") == case["pretty"]
    assert kp.parse(case["compact"]) == tree
    assert kp.parse(case["pretty"]) == tree
    # The fast path read it itself, and the grammar agrees on the tree.
    assert _parse_fast(case["input"], DEFAULT_LIMITS) is not None
    assert parse_reference(case["input"]) == tree


@pytest.mark.parametrize("case", vectors("invalid"), ids=lambda c: c["name"])
def test_invalid_vectors(case: dict[str, Any]) -> None:
    expected = (case["code"], case["line"], case["column"])
    for parse in (kp.parse, parse_reference):
        with pytest.raises(kp.StringBTError) as info:
            parse(case["input"])
        err = info.value
        assert (err.code.value, err.line, err.column) == expected
        assert err.excerpt.splitlines()[-1].strip() == "^"


@pytest.mark.parametrize("case", vectors("validation"), ids=lambda c: c["name"])
def test_validation_vectors(case: dict[str, Any]) -> None:
    registry = case.get("registry")
    vocabulary = kp.Vocabulary.of(registry["conditions"], registry["actions"]) if registry else None
    problems = kp.find_problems(kp.parse(case["input"]), vocabulary)
    assert [[p.code.value, p.line, p.column] for p in problems] == case["problems"]


def test_vectors_cover_every_parse_error_code() -> None:
    seen = (
        {c["code"] for c in vectors("invalid")}
        | {p[0] for c in vectors("validation") for p in c["problems"]}
        | {w[0] for c in vectors("knowledge") for w in c["warnings"]}
    )
    # Bytes, huge inputs and programmatic trees: covered by the unit tests, not by text vectors.
    not_in_vectors = {
        "SBT100",
        "SBT201",
        "SBT203",
        "SBT303",
        "SBT310",
        "SBT311",
        "SBT401",
        "SBT402",
        "SBT403",
    }
    assert {c.value for c in ErrorCode} - not_in_vectors <= seen


def test_message_schema_file_matches_the_models() -> None:
    from ktbt_proto.exchange.messages import schema_text

    committed = (SPEC / "schemas" / "message.json").read_text()
    assert committed == schema_text(), "regenerate spec/schemas/message.json from the models"


def test_protocol_examples_are_valid_messages() -> None:
    from ktbt_proto.exchange.messages import Query, Response, decode

    text = (SPEC / "protocol.md").read_text()
    block = re.search(r"```json\n(.*?)```", text, re.S)
    assert block is not None
    lines = block.group(1).strip().split("\n", 1)
    assert isinstance(decode(lines[0].encode()), Query)
    assert isinstance(decode(lines[1].replace("\n", " ").encode()), Response)
