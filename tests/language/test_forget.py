"""Forgetting, the inverse of merging: ``remove`` on trees and ``LiveTree.forget`` on a
running tree, which takes effect at a tick boundary and never cuts a running action short."""

from __future__ import annotations

from typing import ClassVar

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ktbt_proto as kp
from ktbt_proto.merge import remove

CONTROL = "<sl><sq><c>(Danger)<a>(Avoid)<e><k>(new)<e><a>(Walk)<e>"
COLOURS = ("Red", "Green", "Yellow", "Blue")


class Carry:
    """A stateful action that runs for ``length`` ticks, counting ticks and halts."""

    instances: ClassVar[list[Carry]] = []
    length = 3

    def __init__(self, bb: kp.Blackboard) -> None:
        self.ticks = 0
        self.halts = 0
        Carry.instances.append(self)

    def tick(self) -> kp.Status:
        self.ticks += 1
        return kp.RUNNING if self.ticks < self.length else kp.SUCCESS

    def halt(self) -> None:
        self.halts += 1


def registry(log: list[str]) -> kp.Registry:
    reg = kp.Registry()
    reg.flags("Danger", *(f"Sees{c}" for c in COLOURS))
    reg.add_action("Carry", Carry)

    @reg.action("Avoid")
    def avoid(bb: kp.Blackboard) -> kp.Status:
        log.append("Avoid")
        return kp.SUCCESS

    @reg.action("Walk")
    def walk(bb: kp.Blackboard) -> kp.Status:
        log.append("Walk")
        return kp.SUCCESS

    @reg.action("Pick")
    def pick(bb: kp.Blackboard, colour: str = "any") -> kp.Status:
        log.append(f"Pick {colour}")
        return kp.SUCCESS

    return reg


def test_remove_is_the_inverse_of_merge() -> None:
    control = kp.parse(CONTROL)
    merged = kp.merge(control, kp.parse('<a>(Pick, colour="red")'), "new", when=["SeesRed"])
    both = kp.merge(merged, kp.parse("<a>(Pick)"), "new", when=["SeesBlue"])
    assert kp.format_tree(remove(both, "new", ["SeesBlue"]), "compact") == kp.format_tree(
        merged, "compact"
    )
    assert kp.format_tree(remove(merged, "new", ["SeesRed"]), "compact") == kp.format_tree(
        control, "compact"
    )
    assert remove(merged, "new", ["SeesGreen"]) == merged  # nothing answers it: unchanged
    with pytest.raises(kp.MergeError) as err:
        remove(merged, "old", ["SeesRed"])
    assert err.value.code.value == "SBT401"


def test_a_flat_item_is_removed_by_its_conditions() -> None:
    tree = kp.parse("<sl><k>(new)<sq><c>(SeesRed)<a>(Pick)<a>(Walk)<e><e><a>(Walk)<e>")
    assert kp.format_tree(remove(tree, "new", ["SeesRed"]), "compact") == (
        "<sl><k>(new)<e><a>(Walk)<e>"
    )


def test_forgotten_knowledge_stops_at_the_next_tick() -> None:
    log: list[str] = []
    live = kp.LiveTree(CONTROL, registry(log))
    live.merge('<a>(Pick, colour="red")', when=["SeesRed"])
    live.blackboard["SeesRed"] = True
    live.tick()
    assert log == ["Pick red"]
    assert live.forget("new", ["SeesRed"]) is True
    assert "SeesRed" not in kp.format_tree(live.tree, "compact")
    live.tick()
    assert log == ["Pick red", "Walk"]
    assert live.forget("new", ["SeesRed"]) is False  # already gone
    with pytest.raises(kp.MergeError):
        live.forget("old", ["SeesRed"])


def test_forgetting_never_cuts_a_running_action_short() -> None:
    Carry.instances.clear()
    log: list[str] = []
    live = kp.LiveTree(CONTROL, registry(log))
    live.merge("<a>(Carry)", when=["SeesRed"])
    live.blackboard["SeesRed"] = True
    assert live.tick() is kp.RUNNING
    carry = Carry.instances[0]
    assert live.forget("new", ["SeesRed"]) is True
    assert live.tick() is kp.RUNNING  # still there: it was running at the boundary
    assert live.tick() is kp.SUCCESS  # it finished on its own
    assert (carry.ticks, carry.halts) == (3, 0)
    live.tick()  # the next boundary: now it is gone, and the robot walks
    assert log == ["Walk"] and carry.ticks == 3


def test_merge_then_forget_before_a_tick_never_runs() -> None:
    log: list[str] = []
    live = kp.LiveTree(CONTROL, registry(log))
    live.merge("<a>(Pick)", when=["SeesRed"])
    live.forget("new", ["SeesRed"])
    live.blackboard["SeesRed"] = True
    live.tick()
    assert log == ["Walk"]
    assert live.merge("<a>(Pick)", when=["SeesRed"]) is True  # and it can be learned again
    live.tick()
    assert log == ["Walk", "Pick any"]


@settings(max_examples=40, deadline=None)
@given(
    learned=st.lists(st.sampled_from(COLOURS), unique=True, min_size=1),
    forget=st.sets(st.sampled_from(COLOURS)),
    seen=st.sampled_from(COLOURS),
)
def test_a_live_tree_that_forgot_behaves_as_one_that_never_learned(
    learned: list[str], forget: set[str], seen: str
) -> None:
    """Learn some colours, forget some: the tree, and what it does when it sees a colour, are
    those of a tree that learned only the rest."""
    log_a: list[str] = []
    log_b: list[str] = []
    forgetful = kp.LiveTree(CONTROL, registry(log_a))
    fresh = kp.LiveTree(CONTROL, registry(log_b))
    for colour in learned:
        forgetful.merge(f'<a>(Pick, colour="{colour}")', when=[f"Sees{colour}"])
        forgetful.tick()
    for colour in forget:
        assert forgetful.forget("new", [f"Sees{colour}"]) is (colour in learned)
    for colour in learned:
        if colour not in forget:
            fresh.merge(f'<a>(Pick, colour="{colour}")', when=[f"Sees{colour}"])
    assert kp.format_tree(forgetful.tree, "compact") == kp.format_tree(fresh.tree, "compact")
    log_a.clear()
    for live in (forgetful, fresh):
        live.blackboard[f"Sees{seen}"] = True
        live.tick()
    assert log_a == log_b


NESTED_CONTROL = "<sl><k>(new)<e><a>(Go)<e>"
FLAGS = ("A", "B", "C")


def nested_registry(log: list[str]) -> kp.Registry:
    reg = kp.Registry()
    reg.flags(*FLAGS)

    @reg.action("Go")
    def go(bb: kp.Blackboard) -> kp.Status:
        log.append("Go")
        return kp.SUCCESS

    return reg


def item_body(slot: str, flag: str, nested: bool) -> str:
    """A leaf skill, or one holding a placeholder of its own named for where it sits."""
    return f"<sl><k>({slot}_{flag})<e><a>(Go)<e>" if nested else "<a>(Go)"


Model = dict[str, list[tuple[str, bool]]]  # placeholder -> its items in order: (flag, nested)


def rebuild(model: Model, log: list[str]) -> kp.LiveTree:
    """A tree that learned, from scratch, exactly what ``model`` holds (parents first)."""
    live = kp.LiveTree(NESTED_CONTROL, nested_registry(log))
    todo = ["new"]
    while todo:
        slot = todo.pop(0)
        for flag, nested in model.get(slot, []):
            live.merge(item_body(slot, flag, nested), slot, when=[flag])
            if nested:
                todo.append(f"{slot}_{flag}")
    return live


def drop(model: Model, slot: str) -> None:
    """Remove ``slot`` and every placeholder nested in its items from the model."""
    for flag, nested in model.pop(slot, []):
        if nested:
            drop(model, f"{slot}_{flag}")


@settings(max_examples=200, deadline=None)
@given(
    ops=st.lists(
        st.tuples(
            st.booleans(),  # merge (True) or forget
            st.integers(0, 5),  # which placeholder, among those the model names
            st.sampled_from(FLAGS),
            st.booleans(),  # the item holds a placeholder of its own
            st.booleans(),  # tick after the operation
        ),
        max_size=16,
    )
)
def test_merges_and_forgets_into_nested_placeholders_match_a_tree_built_from_scratch(
    ops: list[tuple[bool, int, str, bool, bool]],
) -> None:
    """Any sequence of merges and forgets, into placeholders nested inside learned items, leaves
    the live tree equal to one that learned only what remains; every refusal is a
    StringBTError (a forget once made a later merge into a shifted placeholder crash)."""
    log: list[str] = []
    live = kp.LiveTree(NESTED_CONTROL, nested_registry(log))
    model: Model = {"new": []}
    for merge, which, flag, nested, tick in ops:
        names = [*sorted(model), "gone"]
        slot = names[which % len(names)]
        held = dict(model.get(slot, []))
        if merge:
            if slot not in model:
                with pytest.raises(kp.MergeError):
                    live.merge(item_body(slot, flag, nested), slot, when=[flag])
            elif flag in held and (held[flag] != nested or model.get(f"{slot}_{flag}")):
                # Another subtree for the same sequence (a nested item that has learned inside
                # is no longer the item that was taught) is a conflict.
                with pytest.raises(kp.MergeError):
                    live.merge(item_body(slot, flag, nested), slot, when=[flag])
            else:
                changed = live.merge(item_body(slot, flag, nested), slot, when=[flag])
                assert changed is (flag not in held)
                if changed:
                    model[slot].append((flag, nested))
                    if nested:
                        model[f"{slot}_{flag}"] = []
        elif slot not in model:
            with pytest.raises(kp.MergeError):
                live.forget(slot, [flag])
        else:
            assert live.forget(slot, [flag]) is (flag in held)
            if flag in held:
                model[slot] = [entry for entry in model[slot] if entry[0] != flag]
                if held[flag]:
                    drop(model, f"{slot}_{flag}")
        if tick:
            live.tick()
    fresh_log: list[str] = []
    fresh = rebuild(model, fresh_log)
    assert kp.format_tree(live.tree, "compact") == kp.format_tree(fresh.tree, "compact")
    for tree in (live, fresh):
        for name in FLAGS:
            tree.blackboard[name] = True
    log.clear()
    live.tick()
    fresh.tick()
    assert log == fresh_log


def test_a_forget_does_not_leave_a_stale_path_to_a_later_nested_placeholder() -> None:
    """The reproduction: a merge into a placeholder nested in an item after a forgotten one."""
    log: list[str] = []
    live = kp.LiveTree(NESTED_CONTROL, nested_registry(log))
    live.merge("<a>(Go)", "new", when=["A"])
    live.merge("<sl><k>(inner)<e><a>(Go)<e>", "new", when=["B"])
    live.merge("<a>(Go)", "inner", when=["A"])
    live.forget("new", when=["A"])
    assert live.merge("<a>(Go)", "inner", when=["B"]) is True
    assert kp.format_tree(live.tree, "compact") == (
        "<sl><k>(new)<sq><c>(B)<sl><k>(inner)<sq><c>(A)<a>(Go)<e><sq><c>(B)<a>(Go)<e><e>"
        "<a>(Go)<e><e><e><a>(Go)<e>"
    )
