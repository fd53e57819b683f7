"""Durable file replacement (``ktbt_proto.files``): a crash leaves the old or the new file."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from ktbt_proto.files import replacing, temporary_name, write_atomic


def test_write_atomic_replaces_text_and_bytes(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "kb.json"
    write_atomic(path, "one\n")
    assert path.read_text(encoding="utf-8") == "one\n"
    write_atomic(path, b"\x00two")
    assert path.read_bytes() == b"\x00two"
    assert [p.name for p in path.parent.iterdir()] == ["kb.json"]  # no temporary left


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "kb.json"
    path.write_text("old", encoding="utf-8")
    with pytest.raises(RuntimeError), replacing(path) as tmp:
        tmp.write_text("half", encoding="utf-8")
        raise RuntimeError("crash while writing")
    assert path.read_text(encoding="utf-8") == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["kb.json"]


def test_a_symlink_is_written_through_and_the_mode_kept_on_request(tmp_path: Path) -> None:
    target = tmp_path / "real.sbt"
    target.write_text("<a>(Go)\n", encoding="utf-8")
    os.chmod(target, 0o640)
    link = tmp_path / "link.sbt"
    link.symlink_to(target)
    write_atomic(link, "<a>(Stop)\n", keep_mode=True)
    assert link.is_symlink() and target.read_text(encoding="utf-8") == "<a>(Stop)\n"
    assert target.stat().st_mode & 0o777 == 0o640


def test_a_knowledge_save_is_durable_and_its_stale_temporaries_are_found(tmp_path: Path) -> None:
    """What a save killed midway leaves (files.temporary_name) is what a restart removes, also
    when the saved path is a symlink (the temporary lies beside the link's target)."""
    from ktbt_proto.exchange.knowledge import KnowledgeBase, remove_stale_temporaries
    from ktbt_proto.syntax import parse

    real = tmp_path / "data" / "kb.json"
    link = tmp_path / "kb.json"
    kb = KnowledgeBase.from_tree(parse("<k>(new)<sq><c>(A)<a>(Go)<e><e>"))
    kb.save(real)
    link.symlink_to(real)
    kb.save(link)
    assert link.is_symlink() and KnowledgeBase.load(link).keys() == ["<c>(A)"]
    torn = [temporary_name(real), temporary_name(real)]
    for tmp in torn:
        tmp.write_text("torn", encoding="utf-8")
    (real.parent / ".kb.json.keep").write_text("not ours", encoding="utf-8")
    assert sorted(remove_stale_temporaries(link)) == sorted(torn)
    assert sorted(p.name for p in real.parent.iterdir()) == [".kb.json.keep", "kb.json"]
