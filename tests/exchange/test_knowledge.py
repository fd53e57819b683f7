"""The knowledge base (``ktbt_proto.exchange.knowledge``, spec/protocol.md section 5): the items
a control tree's placeholders hold, keyed by the canonical sequence (section 1), the first
answer kept; saved as JSON with each item's provenance (sections 5 and 7) and read back the same;
a file too large, not UTF-8, of another version or malformed refused with a clear error; the
whole items of a damaged file salvaged; the temporaries a killed save left found and removed.

Agents resuming from these files are shown in tests/exchange/test_agent.py, test_trust.py and
test_core.py; the durable write itself in tests/language/test_files.py.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.knowledge import (
    MAX_FILE,
    Knowledge,
    KnowledgeBase,
    remove_stale_temporaries,
    salvage,
)
from ktbt_proto.exchange.receiving import RECEIVE_LIMITS
from ktbt_proto.files import temporary_name
from ktbt_proto.formatter import format_tree
from ktbt_proto.items import parse_sequence, sequence_key
from ktbt_proto.syntax import parse
from ktbt_proto.validate import find_problems

TREE = (
    "<sl>"
    "<k>(prior)<sq><c>(TargetSeen, colour=2)<c>(!Carrying)<a>(Pick, colour=2)<a>(Walk)<e>"
    "<a>(Loose)<e>"
    "<k>(new)<sq><c>(Door, open=true)<a>(Push)<e><e>"
    "<a>(Walk)"
    "<e>"
)
GREEN = "<c>(TargetSeen,colour=2)<c>(!Carrying)"
DOOR = "<c>(Door,open=true)"


def item(sequence: str, subtree: str, segment: str = "new", **provenance: Any) -> Knowledge:
    """An item as a peer taught it: ``provenance`` is ``source``, ``learned_at``, ``author``,
    ``signature`` and ``received_at``."""
    return Knowledge(parse_sequence(sequence), parse(subtree).root, segment, **provenance)


def compact(kb: KnowledgeBase) -> dict[str, str]:
    return {k.key: format_tree(k.subtree, "compact") for k in kb}


# -- from a tree, lookup, add, remove ---------------------------------------------------------


def test_the_items_of_a_trees_placeholders_keyed_by_their_canonical_sequence() -> None:
    kb = KnowledgeBase.from_tree(parse(TREE))
    assert kb.keys() == [GREEN, DOOR]  # in the tree's order; the loose action is no item
    assert [(k.segment, k.source, k.learned_at) for k in kb] == [
        ("prior", None, None),
        ("new", None, None),
    ]
    # An item written flat, as the paper does: its actions are one Sequence subtree.
    assert compact(kb) == {GREEN: "<sq><a>(Pick,colour=2)<a>(Walk)<e>", DOOR: "<a>(Push)"}
    green = kb.lookup(GREEN)
    assert green is not None and format_tree(green.item(), "compact") == (
        f"<sq>{GREEN}<sq><a>(Pick,colour=2)<a>(Walk)<e><e>"
    )
    assert KnowledgeBase.from_tree(parse("<sl><a>(Walk)<k>(new)<e><e>")).keys() == []


def test_lookup_by_key_and_by_conditions_typed_text_through_its_key() -> None:
    kb = KnowledgeBase.from_tree(parse(TREE))
    green = kb.lookup(GREEN)
    assert green is not None
    assert kb.lookup(green.conditions) is green and green.key == GREEN
    assert kb.lookup(parse_sequence(GREEN)) is green
    typed = sequence_key(["TargetSeen(colour = 2), !Carrying"])  # as people type it
    assert kb.lookup(typed) is green
    assert kb.lookup("<c>(TargetSeen, colour=2)<c>(!Carrying)") is None  # a key is canonical
    assert kb.lookup(sequence_key(["TargetSeen(colour=2)"])) is None  # a part is another one
    assert GREEN in kb and "<c>(Nope)" not in kb and len(kb) == 2


def test_the_first_answer_is_kept_and_a_removed_item_can_be_added_again() -> None:
    kb = KnowledgeBase([item(DOOR, "<a>(Push)")])
    assert kb.add(item(DOOR, "<a>(Kick)", source="x")) is False  # not an update
    assert compact(kb) == {DOOR: "<a>(Push)"}
    assert kb.add(item(GREEN, "<a>(Pick,colour=2)")) is True
    assert list(kb) == [kb.lookup(DOOR), kb.lookup(GREEN)]
    removed = kb.remove(parse_sequence(DOOR))
    assert removed is not None and format_tree(removed.subtree, "compact") == "<a>(Push)"
    assert kb.remove(DOOR) is None and DOOR not in kb and len(kb) == 1
    assert kb.add(item(DOOR, "<a>(Kick)")) is True
    assert compact(kb)[DOOR] == "<a>(Kick)"


def test_a_catalog_is_built_again_only_when_an_item_comes_or_goes() -> None:
    """A robot compares its catalog with the one it showed at every tick (section 11): the
    same list while nothing changed, a new one once an item is added or removed, but not
    when an add keeps the first answer."""
    from ktbt_proto.exchange.answers import catalog

    kb = KnowledgeBase([item(DOOR, "<a>(Push)", source="t1")])
    entries = catalog(kb)
    first = entries()
    assert entries() is first and first == [{"sequence": DOOR, "teacher": "t1"}]
    assert kb.add(item(DOOR, "<a>(Kick)", source="x")) is False
    assert entries() is first
    kb.add(item(GREEN, "<a>(Pick,colour=2)", source="t2"))
    second = entries()
    assert second is not first and [e["sequence"] for e in second] == [DOOR, GREEN]  # type: ignore[index]
    kb.remove(DOOR)
    assert entries() == [{"sequence": GREEN, "teacher": "t2"}]
    assert kb.remove(DOOR) is None and entries() == [{"sequence": GREEN, "teacher": "t2"}]


def test_the_items_as_a_tree_one_placeholder_per_segment() -> None:
    kb = KnowledgeBase.from_tree(parse(TREE))
    kb.add(item("<c>(Low)", "<a>(Dock)", "prior"))
    shown = kb.tree()
    assert format_tree(shown, "compact") == (
        f"<sl><k>(prior)<sq>{GREEN}<sq><a>(Pick,colour=2)<a>(Walk)<e><e>"
        f"<sq><c>(Low)<a>(Dock)<e><e><k>(new)<sq>{DOOR}<a>(Push)<e><e><e>"
    )
    assert sorted(KnowledgeBase.from_tree(shown).keys()) == sorted(kb.keys())
    assert format_tree(KnowledgeBase().tree(), "compact") == "<sl><k>(new)<e><e>"


def test_the_items_as_a_tree_name_each_placeholder_once() -> None:
    nested = "<sl><k>(new)<sq><c>(C)<k>(inner)<sq><c>(D)<a>(Z)<e><e><e><e><e>"
    kb = KnowledgeBase.from_tree(parse(nested))
    assert kb.keys() == ["<c>(C)", "<c>(D)"]
    assert find_problems(kb.tree()) == []


# -- save and load ----------------------------------------------------------------------------


def test_a_saved_base_loads_as_it_was_provenance_included(tmp_path: Path) -> None:
    signed = item(
        GREEN, "<sq><a>(Pick,colour=2)<a>(Walk)<e>", source="t", learned_at=3,
        author="A6EHv_POEL4dcN0Y50vAmWfk1jCbpQ1fHdyGZBJVMbg", signature="0o2o",
        received_at="2026-12-01T17:28:54+00:00",
    )  # fmt: skip
    unsigned = item(DOOR, "<a>(Push)", "prior", source="u", learned_at=4.5)
    innate = item("<c>(Low)", "<a>(Dock)")
    kb = KnowledgeBase([signed, unsigned, innate])
    path = tmp_path / "kb" / "l.json"
    kb.save(path)
    data = json.loads(path.read_text(encoding="utf-8"))
    assert data["version"] == 1
    assert data["knowledge"][0] == {
        "sequence": GREEN, "subtree": "<sq><a>(Pick,colour=2)<a>(Walk)<e>", "segment": "new",
        "source": "t", "learned_at": 3, "author": "A6EHv_POEL4dcN0Y50vAmWfk1jCbpQ1fHdyGZBJVMbg",
        "signature": "0o2o", "received_at": "2026-12-01T17:28:54+00:00",
    }  # fmt: skip
    assert data["knowledge"][2] == {  # absent provenance is left out, not written null
        "sequence": "<c>(Low)", "subtree": "<a>(Dock)", "segment": "new", "source": None,
        "learned_at": None,
    }  # fmt: skip
    loaded = KnowledgeBase.load(path)
    assert list(loaded) == [signed, unsigned, innate]
    assert KnowledgeBase.from_json(kb.to_json()).keys() == kb.keys()


def test_an_entry_without_optional_fields_takes_their_defaults() -> None:
    text = json.dumps({"version": 1, "knowledge": [
        {"sequence": DOOR, "subtree": "<a>(Push)"},
        {"sequence": GREEN, "subtree": "<a>(Pick)", "learned_at": "yesterday", "source": 7},
    ]})  # fmt: skip
    door, green = KnowledgeBase.from_json(text)
    assert (door.segment, door.source, door.learned_at, door.author) == ("new", None, None, None)
    assert (green.source, green.learned_at) == ("7", None)  # not a number: no tick


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('{"version": 2, "knowledge": []}', "not a version-1 knowledge file"),
        ('{"knowledge": []}', "not a version-1 knowledge file"),
        ("[1]", "not a version-1 knowledge file"),
        ('{"version": 1, "knowledge": {"a": 1}}', "'knowledge' must be a list of objects"),
        ('{"version": 1, "knowledge": ["x"]}', "'knowledge' must be a list of objects"),
        ('{"version": 1, "knowledge": [{"subtree": "<a>(X)"}]}', "malformed knowledge file"),
        ('{"version": 1, "knowledge": [', "Expecting value"),
    ],
)
def test_a_file_that_is_not_a_knowledge_base_is_refused_saying_why(
    tmp_path: Path, text: str, message: str
) -> None:
    path = tmp_path / "kb.json"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ValueError, match=message):
        KnowledgeBase.load(path)


def test_a_tree_beyond_the_limits_given_is_refused_as_a_tree(tmp_path: Path) -> None:
    deep = "<sq>" * 40 + "<a>(Pick)" + "<e>" * 40
    path = tmp_path / "kb.json"
    KnowledgeBase([item(DOOR, deep)]).save(path)
    assert len(KnowledgeBase.load(path)) == 1  # within a file's own limits
    with pytest.raises(StringBTError) as refused:
        KnowledgeBase.load(path, RECEIVE_LIMITS)
    assert refused.value.code.value == "SBT202"


def test_a_file_larger_than_a_knowledge_file_may_be_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "kb.json"
    with open(path, "wb") as f:
        f.truncate(MAX_FILE + 1)  # sparse: one byte over, nothing written
    with pytest.raises(ValueError) as refused:
        KnowledgeBase.load(path)
    assert str(refused.value) == (
        f"{path} is larger than a knowledge file may be ({MAX_FILE} bytes)"
    )


def test_a_file_that_is_not_utf8_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "kb.json"
    path.write_bytes(b'{"version": 1, "knowledge": [{"sequence": "<c>(\xff)"}]}')
    with pytest.raises(ValueError) as refused:
        KnowledgeBase.load(path)
    assert str(refused.value) == f"{path} is not UTF-8"


def test_a_file_that_cannot_be_read_raises_the_os_error(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        KnowledgeBase.load(tmp_path / "missing.json")
    with pytest.raises(IsADirectoryError):
        KnowledgeBase.load(tmp_path)


# -- salvage ----------------------------------------------------------------------------------


def saved_text(*entries: dict[str, object]) -> str:
    return json.dumps({"version": 1, "knowledge": list(entries)}, indent=1)


def entry(colour: int, **fields: object) -> dict[str, object]:
    return {"sequence": f"<c>(TargetSeen,colour={colour})", "subtree": f"<a>(Pick,colour={colour})",
            "segment": "new", "source": "t", "learned_at": colour, **fields}  # fmt: skip


def test_salvage_keeps_the_whole_items_of_a_truncated_file_with_their_provenance() -> None:
    text = saved_text(entry(1, author="A" * 43), entry(2), entry(3))
    torn = text[: text.rindex("colour=3")]
    items = salvage(torn)
    assert [(k.key, k.source, k.learned_at) for k in items] == [
        ("<c>(TargetSeen,colour=1)", "t", 1),
        ("<c>(TargetSeen,colour=2)", "t", 2),
    ]
    assert items[0].author == "A" * 43
    assert [k.key for k in salvage(text)] == [f"<c>(TargetSeen,colour={c})" for c in (1, 2, 3)]


@pytest.mark.parametrize(
    ("text", "kept"),
    [
        ("", 0),
        ('{"version": 1}', 0),
        ('{"version": 1, "knowledge": [', 0),
        (saved_text(entry(1), entry(2, subtree="<a>(Pick")), 1),  # the second does not parse
        (saved_text(entry(1), {"subtree": "<a>(X)"}, entry(3)), 1),  # no sequence: stops there
        ('{"version": 1, "knowledge": [' + json.dumps(entry(1)) + ", 7, {}]}", 1),
        ('{"version": 9, "knowledge": [' + json.dumps(entry(1)) + "]}", 1),  # another version
    ],
)
def test_salvage_reads_items_in_turn_until_one_cannot_be_read(text: str, kept: int) -> None:
    assert len(salvage(text)) == kept


def test_salvage_holds_each_item_to_the_limits_given() -> None:
    deep = "<sq>" * 40 + "<a>(Pick)" + "<e>" * 40
    text = saved_text(entry(1), entry(2, subtree=deep))
    assert len(salvage(text)) == 2
    assert len(salvage(text, RECEIVE_LIMITS)) == 1


@settings(max_examples=60, deadline=None)
@given(st.text(max_size=300))
def test_salvage_never_raises(text: str) -> None:
    salvage('{"version": 1, "knowledge": [' + text)
    salvage(text)


# -- temporaries a killed save left -----------------------------------------------------------


def test_only_the_temporaries_of_the_file_saved_are_removed(tmp_path: Path) -> None:
    path = tmp_path / "kb.json"
    assert remove_stale_temporaries(path) == []  # nothing saved yet, nothing left
    assert remove_stale_temporaries(tmp_path / "missing" / "kb.json") == []
    KnowledgeBase([item(DOOR, "<a>(Push)")]).save(path)
    assert remove_stale_temporaries(path) == []  # a save that finished leaves none
    ours = [temporary_name(path), temporary_name(path)]
    for tmp in ours:
        tmp.write_text("torn", encoding="utf-8")
    theirs = temporary_name(tmp_path / "other.json")
    theirs.write_text("another file's", encoding="utf-8")
    assert sorted(remove_stale_temporaries(path)) == sorted(ours)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["kb.json", theirs.name])
    assert KnowledgeBase.load(path).keys() == [DOOR]


def test_the_temporaries_of_a_file_whose_name_extends_it_are_left_alone(tmp_path: Path) -> None:
    path = tmp_path / "kb.json"
    theirs = temporary_name(tmp_path / "kb.json.bak")
    theirs.write_text("a save of kb.json.bak, in progress", encoding="utf-8")
    assert remove_stale_temporaries(path) == []
    assert theirs.exists()
