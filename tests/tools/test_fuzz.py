"""The fuzz target runs clean on a few inputs, and it does catch a broken property."""

from __future__ import annotations

from pathlib import Path

import pytest

from ktbt_proto.errors import ErrorCode, StringBTError
from ktbt_proto.tools import fuzz


def test_a_short_run_finds_nothing(tmp_path: Path) -> None:
    lines: list[str] = []
    assert fuzz.run(400, seed=0, out=tmp_path, report=lines.append) == 0
    assert "400 inputs" in lines[-1] and "inputs/s" in lines[-1]
    assert not list(tmp_path.iterdir())


def test_a_broken_round_trip_is_reported_with_its_input(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(fuzz, "format_tree", lambda tree, style: "<a>(Other)")
    assert fuzz.run(200, seed=0, out=tmp_path, report=lambda _: None) > 0
    saved = sorted(tmp_path.glob("*.txt"))
    assert saved and "round trip changed the tree" in saved[0].read_text()
    assert saved[0].with_suffix(".bin").exists()


def test_fast_and_reference_parsers_must_agree(monkeypatch: pytest.MonkeyPatch) -> None:
    def disagreeing(text: str) -> object:
        raise StringBTError(ErrorCode.EMPTY, "no node")

    monkeypatch.setattr(fuzz, "parse_reference", disagreeing)
    with pytest.raises(fuzz.Failure, match="parse_reference gives"):
        fuzz.check_text("<a>(X)", fuzz._fuzz_registry())
