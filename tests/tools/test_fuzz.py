"""The fuzz target: a short fixed-seed run finds nothing, every input that once broke a property
(``tests/data/fuzz/inputs.json``) holds it now, the mutations reach the places such bugs hide,
and a broken property is caught and saved with its input.

``tests/data/fuzz/inputs.json`` holds ``texts`` and ``messages``, each a list of ``{"input",
"broke"}``: the input as it is handed to ``check_text`` (a str) or to ``check_message`` (its
UTF-8 bytes), and what it broke when it was found.
"""

from __future__ import annotations

import json
import random
import re
import subprocess
from pathlib import Path
from typing import Any

import pytest

from ktbt_proto.errors import ErrorCode, StringBTError
from ktbt_proto.tools import fuzz

ROOT = Path(__file__).resolve().parents[2]
FOUND = json.loads((ROOT / "tests" / "data" / "fuzz" / "inputs.json").read_text(encoding="utf-8"))
# A leaf without parentheses whose name is true or false, then a '.': the fast parser raised an
# AssertionError on all of them (spec/stringbt.md sections 1 and 2: ``true.5`` is the keyword
# ``true``, then a '.' that starts no token).
BARE_KEYWORD_LEAF = re.compile(r"<[ca]>\s*!?\s*(true|false)\.")


def test_a_short_run_finds_nothing(tmp_path: Path) -> None:
    lines: list[str] = []
    assert fuzz.run(3_000, seed=0, out=tmp_path, report=lines.append) == 0
    assert "3,000 inputs" in lines[-1] and "inputs/s" in lines[-1] and "1 worker" in lines[-1]
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("case", FOUND["texts"], ids=lambda case: repr(case["input"])[:40])
def test_every_text_that_broke_a_property_holds_it_now(case: dict[str, Any]) -> None:
    fuzz.check_text(case["input"], fuzz._fuzz_registry())


@pytest.mark.parametrize("case", FOUND["messages"], ids=lambda case: repr(case["input"])[:40])
def test_every_message_that_broke_a_property_holds_it_now(case: dict[str, Any]) -> None:
    fuzz.check_message(case["input"].encode("utf-8"))


def test_the_found_inputs_of_the_bare_leaf_class_are_kept() -> None:
    texts = [case["input"] for case in FOUND["texts"]]
    for text in ("<c>true.5", "<sq><c>true.5<e>", "<a>false.1e", "<a>true.", "<c>false.."):
        assert text in texts
    assert "<a>true. " in texts
    assert sum(bool(BARE_KEYWORD_LEAF.search(text)) for text in texts) >= 10


def test_the_mutations_write_bare_leaves_named_true_or_false_then_a_dot() -> None:
    corpus = fuzz.load_corpus()
    rng = random.Random(0)
    made = [fuzz.next_text(rng, corpus) for _ in range(20_000)]
    assert any(BARE_KEYWORD_LEAF.search(text) for text in made)


def test_the_seeds_are_the_vectors_and_every_sbt_file_of_the_repository() -> None:
    texts, messages = fuzz.seed_corpus()
    listed = subprocess.run(
        ["git", "-C", str(ROOT), "ls-files", "*.sbt"], capture_output=True, text=True
    )
    if listed.returncode != 0:
        pytest.skip("not a git checkout")
    sbt = listed.stdout.split()
    assert len(sbt) >= 8
    for name in sbt:
        assert (ROOT / name).read_text(encoding="utf-8") in texts, name
    for name in ("valid", "invalid", "knowledge"):
        vectors = json.loads((ROOT / "spec" / "vectors" / f"{name}.json").read_text())
        assert all(case["input"] in texts for case in vectors)
    vectors = json.loads((ROOT / "spec" / "vectors" / "messages.json").read_text())
    assert len(messages) >= len(vectors)
    assert fuzz.load_corpus().pieces  # leaves and subtrees cut from them


def test_a_parser_that_raises_anything_else_is_caught(monkeypatch: pytest.MonkeyPatch) -> None:
    def failing(text: str) -> object:
        raise AssertionError

    monkeypatch.setattr(fuzz, "parse", failing)
    with pytest.raises(fuzz.Failure, match="parse raised AssertionError"):
        fuzz.check_text("<c>true.5", fuzz._fuzz_registry())


def test_a_broken_round_trip_is_reported_with_its_input(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(fuzz, "format_tree", lambda tree, style: "<a>(Other)")
    assert fuzz.run(200, seed=0, out=tmp_path, report=lambda _: None) > 0
    saved = sorted(tmp_path.glob("*.txt"))
    assert saved and "round trip changed the tree" in saved[0].read_text()
    assert saved[0].with_suffix(".bin").exists()


@pytest.mark.network  # starts worker processes
def test_two_workers_share_the_inputs_and_report_their_failures(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(fuzz, "format_tree", lambda tree, style: "<a>(Other)")
    lines: list[str] = []
    failures = fuzz.run(300, seed=0, out=tmp_path, report=lines.append, workers=2)
    assert failures > 0
    assert "300 inputs" in lines[-1] and "2 workers" in lines[-1]
    assert f"{failures} failures" in lines[-1]
    assert sum(line.startswith("FAIL") for line in lines) == failures
    names = {p.name for p in tmp_path.glob("*.bin")}
    assert any(name.startswith("text-0-") for name in names)
    assert any(name.startswith("text-0w1-") for name in names)


def test_a_run_for_a_set_time_ends_and_counts_its_inputs(tmp_path: Path) -> None:
    lines: list[str] = []
    assert fuzz.run(None, seed=0, out=tmp_path, report=lines.append, seconds=0.3) == 0
    assert lines[-1].startswith("done: ") and not lines[-1].startswith("done: 0 inputs")


def test_the_command_runs_clean(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["--inputs", "100", "--seed", "3", "--workers", "1", "--out", str(tmp_path)]
    assert fuzz.main(args) == 0
    assert "100 inputs" in capsys.readouterr().out


def test_fast_and_reference_parsers_must_agree(monkeypatch: pytest.MonkeyPatch) -> None:
    def disagreeing(text: str) -> object:
        raise StringBTError(ErrorCode.EMPTY, "no node")

    monkeypatch.setattr(fuzz, "parse_reference", disagreeing)
    with pytest.raises(fuzz.Failure, match="parse_reference gives"):
        fuzz.check_text("<a>(X)", fuzz._fuzz_registry())
