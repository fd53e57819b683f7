"""Runtime behaviour of the composites (spec section 3.1) and of placeholders (section 4).

Every test drives scripted leaves (``runtime_helpers``) and asserts, tick by tick, the status of
the tree and exactly which leaves were ticked (``"A"``, ``"X?"``) and halted (``"~A"``).
"""

from __future__ import annotations

import pytest

from ktbt_proto.status import Status
from tests.runtime_helpers import F, Harness, R, S

# -- reactive sequence <sq> --------------------------------------------------------------------


def test_sequence_reevaluates_conditions_every_tick() -> None:
    h = Harness()
    h.condition("X")
    h.action("A", R, R, S)
    h.bb["X"] = True
    live = h.live("<sq><c>(X)<a>(A)<e>")
    assert h.run(live, 3) == [(R, ["X?", "A"]), (R, ["X?", "A"]), (S, ["X?", "A"])]


def test_sequence_returns_the_first_status_that_is_not_success() -> None:
    h = Harness()
    h.action("A", S)
    h.action("B", F)
    h.action("C", S)
    assert h.tick(h.live("<sq><a>(A)<a>(B)<a>(C)<e>")) == (F, ["A", "B"])
    assert h.tick(h.live("<sq><a>(A)<a>(C)<e>")) == (S, ["A", "C"])


def test_sequence_condition_turning_false_halts_the_running_action_on_that_tick() -> None:
    h = Harness()
    h.condition("X")
    h.action("A", R)
    h.bb["X"] = True
    live = h.live("<sq><c>(X)<a>(A)<e>")
    assert h.run(live, 2) == [(R, ["X?", "A"]), (R, ["X?", "A"])]
    h.bb["X"] = False
    assert h.tick(live) == (F, ["X?", "~A"])
    # Halted once: the action is no longer running, so it is not halted again.
    assert h.run(live, 2) == [(F, ["X?"]), (F, ["X?"])]
    assert h.halt(live) == []
    h.bb["X"] = True
    assert h.tick(live) == (R, ["X?", "A"])


def test_sequence_left_child_starting_to_run_halts_the_running_child_to_its_right() -> None:
    h = Harness()
    h.action("A", S, R)
    h.action("B", R)
    live = h.live("<sq><a>(A)<a>(B)<e>")
    assert h.run(live, 2) == [(R, ["A", "B"]), (R, ["A", "~B"])]


def test_sequence_does_not_halt_a_child_that_finished_by_itself() -> None:
    h = Harness()
    h.action("A", R, S, S, F)
    h.action("B", R)
    live = h.live("<sq><a>(A)<a>(B)<e>")
    assert h.run(live, 4) == [
        (R, ["A"]),
        (R, ["A", "B"]),  # A was running and succeeded by itself: no "~A"
        (R, ["A", "B"]),
        (F, ["A", "~B"]),
    ]


def test_sequence_running_child_failing_by_itself_is_not_halted() -> None:
    h = Harness()
    h.action("A", S)
    h.action("B", R, F)
    live = h.live("<sq><a>(A)<a>(B)<e>")
    assert h.run(live, 3) == [(R, ["A", "B"]), (F, ["A", "B"]), (F, ["A", "B"])]
    assert h.halt(live) == []


# -- reactive selector <sl> --------------------------------------------------------------------


def test_selector_returns_the_first_status_that_is_not_failure() -> None:
    h = Harness()
    h.action("A", F)
    h.action("B", S)
    h.action("C", S)
    h.action("D", F)
    assert h.tick(h.live("<sl><a>(A)<a>(B)<a>(C)<e>")) == (S, ["A", "B"])
    assert h.tick(h.live("<sl><a>(A)<a>(D)<e>")) == (F, ["A", "D"])


def test_selector_higher_branch_starting_to_run_preempts_the_lower_one() -> None:
    h = Harness()
    h.condition("X")
    h.action("A", R)
    h.action("B", R)
    live = h.live("<sl><sq><c>(X)<a>(A)<e><a>(B)<e>")
    assert h.run(live, 2) == [(R, ["X?", "B"]), (R, ["X?", "B"])]
    h.bb["X"] = True
    assert h.run(live, 2) == [(R, ["X?", "A", "~B"]), (R, ["X?", "A"])]
    # The guard turns false: the inner sequence halts A, and B starts a new activation.
    h.bb["X"] = False
    assert h.tick(live) == (R, ["X?", "~A", "B"])


def test_selector_higher_branch_succeeding_preempts_the_lower_one() -> None:
    h = Harness()
    h.condition("X")
    h.action("B", R)
    live = h.live("<sl><c>(X)<a>(B)<e>")
    assert h.tick(live) == (R, ["X?", "B"])
    h.bb["X"] = True
    assert h.tick(live) == (S, ["X?", "~B"])
    assert h.tick(live) == (S, ["X?"])
    assert h.halt(live) == []


def test_selector_does_not_halt_a_child_that_finished_by_itself() -> None:
    h = Harness()
    h.action("A", F)
    h.action("B", R, F)
    h.action("C", R)
    live = h.live("<sl><a>(A)<a>(B)<a>(C)<e>")
    assert h.run(live, 3) == [
        (R, ["A", "B"]),
        (R, ["A", "B", "C"]),  # B failed by itself: no "~B"
        (R, ["A", "B", "C"]),
    ]
    assert h.halt(live) == ["~C"]


# -- the paper's control tree ------------------------------------------------------------------

PAPER = (
    "<sl><sq><c>(_collisionDetectedF)<a>(CollisionAvoidance)<e><sq><c>(_waitF)<a>(StopWalk)<e>"
    "<sq><c>(_treasureOnBoardF)<sl><sq><c>(_inZoneF)<a>(PlaceTreasure)<e><sq><c>(!_inZoneF)"
    "<a>(WalkToCollection)<e><e><e><a>(RandomWalk)<e>"
)
GUARDS = ["_collisionDetectedF?", "_waitF?", "_treasureOnBoardF?"]


def paper_harness() -> Harness:
    h = Harness()
    h.condition("_collisionDetectedF", "_waitF", "_treasureOnBoardF", "_inZoneF")
    for name in ("StopWalk", "PlaceTreasure", "WalkToCollection", "RandomWalk"):
        h.action(name, R)
    return h


def test_paper_collision_avoidance_preempts_random_walk_on_the_same_tick() -> None:
    h = paper_harness()
    h.action("CollisionAvoidance", R, S)
    live = h.live(PAPER)
    assert h.run(live, 2) == [(R, [*GUARDS, "RandomWalk"])] * 2
    h.bb["_collisionDetectedF"] = True
    assert h.tick(live) == (R, ["_collisionDetectedF?", "CollisionAvoidance", "~RandomWalk"])
    assert h.tick(live) == (S, ["_collisionDetectedF?", "CollisionAvoidance"])
    h.bb["_collisionDetectedF"] = False
    assert h.tick(live) == (R, [*GUARDS, "RandomWalk"])
    assert h.log.count("~RandomWalk") == 1
    assert h.log.count("~CollisionAvoidance") == 0


def test_paper_collision_clearing_halts_avoidance_and_walk_resumes() -> None:
    h = paper_harness()
    h.action("CollisionAvoidance", R)
    live = h.live(PAPER)
    assert h.tick(live) == (R, [*GUARDS, "RandomWalk"])
    h.bb["_collisionDetectedF"] = True
    assert h.tick(live) == (R, ["_collisionDetectedF?", "CollisionAvoidance", "~RandomWalk"])
    h.bb["_collisionDetectedF"] = False
    # The collision sequence halts its action as soon as its guard fails, then the walk starts.
    halted_first = ["_collisionDetectedF?", "~CollisionAvoidance", *GUARDS[1:], "RandomWalk"]
    assert h.tick(live) == (R, halted_first)


def test_paper_treasure_subtree_switches_between_its_branches() -> None:
    h = paper_harness()
    h.action("CollisionAvoidance", R)
    live = h.live(PAPER)
    h.bb["_treasureOnBoardF"] = True
    assert h.tick(live) == (R, [*GUARDS, "_inZoneF?", "_inZoneF?", "WalkToCollection"])
    h.bb["_inZoneF"] = True
    assert h.tick(live) == (R, [*GUARDS, "_inZoneF?", "PlaceTreasure", "~WalkToCollection"])
    h.bb["_treasureOnBoardF"] = False
    assert h.tick(live) == (R, [*GUARDS, "~PlaceTreasure", "RandomWalk"])


# -- memory composites <msq> <msl> -------------------------------------------------------------


def test_memory_sequence_resumes_at_the_running_child() -> None:
    h = Harness()
    h.condition("X")
    h.action("A", R, S)
    h.action("B", R, R, S)
    h.bb["X"] = True
    live = h.live("<msq><c>(X)<a>(A)<a>(B)<e>")
    assert h.tick(live) == (R, ["X?", "A"])
    h.bb["X"] = False  # not re-evaluated while the sequence resumes
    assert h.run(live, 3) == [(R, ["A", "B"]), (R, ["B"]), (S, ["B"])]
    # Finishing reset the memory: the next tick starts at the first child again.
    assert h.tick(live) == (F, ["X?"])
    assert h.halt(live) == []


def test_memory_sequence_resets_after_failure() -> None:
    h = Harness()
    h.action("A", S)
    h.action("B", R, F)
    live = h.live("<msq><a>(A)<a>(B)<e>")
    assert h.run(live, 3) == [(R, ["A", "B"]), (F, ["B"]), (F, ["A", "B"])]


def test_memory_sequence_resets_after_halt() -> None:
    h = Harness()
    h.condition("G")
    h.action("A", S)
    h.action("B", R)
    h.bb["G"] = True
    live = h.live("<sq><c>(G)<msq><a>(A)<a>(B)<e><e>")
    assert h.run(live, 2) == [(R, ["G?", "A", "B"]), (R, ["G?", "B"])]
    h.bb["G"] = False
    assert h.tick(live) == (F, ["G?", "~B"])
    h.bb["G"] = True
    assert h.tick(live) == (R, ["G?", "A", "B"])


def test_memory_sequence_resets_after_live_halt() -> None:
    h = Harness()
    h.action("A", S)
    h.action("B", R)
    live = h.live("<msq><a>(A)<a>(B)<e>")
    assert h.run(live, 2) == [(R, ["A", "B"]), (R, ["B"])]
    assert h.halt(live) == ["~B"]
    assert h.tick(live) == (R, ["A", "B"])


def test_memory_selector_resumes_at_the_running_child() -> None:
    h = Harness()
    h.action("A", F)
    h.action("B", R, R, F)
    h.action("C", S)
    live = h.live("<msl><a>(A)<a>(B)<a>(C)<e>")
    assert h.run(live, 4) == [
        (R, ["A", "B"]),
        (R, ["B"]),
        (S, ["B", "C"]),
        (S, ["A", "B", "C"]),  # reset after finishing
    ]


def test_memory_selector_is_not_preempted_but_reactive_selector_is() -> None:
    for tag, second in (("msl", (R, ["B"])), ("sl", (S, ["X?", "~B"]))):
        h = Harness()
        h.condition("X")
        h.action("B", R)
        live = h.live(f"<{tag}><c>(X)<a>(B)<e>")
        assert h.tick(live) == (R, ["X?", "B"])
        h.bb["X"] = True
        assert h.tick(live) == second, tag


def test_memory_selector_resets_after_halt() -> None:
    h = Harness()
    h.condition("G")
    h.action("A", F)
    h.action("B", R)
    h.bb["G"] = True
    live = h.live("<sq><c>(G)<msl><a>(A)<a>(B)<e><e>")
    assert h.run(live, 2) == [(R, ["G?", "A", "B"]), (R, ["G?", "B"])]
    h.bb["G"] = False
    assert h.tick(live) == (F, ["G?", "~B"])
    h.bb["G"] = True
    assert h.tick(live) == (R, ["G?", "A", "B"])


# -- parallel <pl> <pl>(M) ---------------------------------------------------------------------


def test_parallel_ticks_every_child_every_tick() -> None:
    h = Harness()
    h.action("A", R, S)
    h.action("B", S)
    h.action("C", R, R, S)
    live = h.live("<pl><a>(A)<a>(B)<a>(C)<e>")
    assert h.run(live, 3) == [
        (R, ["A", "B", "C"]),
        (R, ["A", "B", "C"]),
        (S, ["A", "B", "C"]),
    ]


@pytest.mark.parametrize(
    ("tag", "statuses", "expected", "halted"),
    [
        # <pl> with N = 2: M = N, so any failure fails it.
        ("<pl>", (S, S), S, []),
        ("<pl>", (S, R), R, []),
        ("<pl>", (R, R), R, []),
        ("<pl>", (F, R), F, ["~B"]),
        ("<pl>", (R, F), F, ["~A"]),
        ("<pl>", (S, F), F, []),
        # <pl>(2) with N = 2: the same as <pl>.
        ("<pl>(2)", (S, R), R, []),
        ("<pl>(2)", (R, F), F, ["~A"]),
        # <pl>(1) with N = 2: one success suffices; fails only when both fail.
        ("<pl>(1)", (S, R), S, ["~B"]),
        ("<pl>(1)", (R, S), S, ["~A"]),
        ("<pl>(1)", (F, R), R, []),
        ("<pl>(1)", (F, F), F, []),
        ("<pl>(1)", (R, R), R, []),
    ],
)
def test_parallel_thresholds_with_two_children(
    tag: str, statuses: tuple[Status, Status], expected: Status, halted: list[str]
) -> None:
    h = Harness()
    h.action("A", statuses[0])
    h.action("B", statuses[1])
    live = h.live(f"{tag}<a>(A)<a>(B)<e>")
    assert h.tick(live) == (expected, ["A", "B", *halted])


@pytest.mark.parametrize(
    ("statuses", "expected", "halted"),
    [
        # N = 3, M = 2: SUCCESS when >= 2 succeed, FAILURE when > 1 (= N - M) fail.
        ((S, S, R), S, ["~C"]),
        ((S, R, S), S, ["~B"]),
        ((S, S, S), S, []),
        ((S, S, F), S, []),
        ((S, R, R), R, []),
        ((F, R, R), R, []),
        ((S, F, R), R, []),
        ((R, R, R), R, []),
        ((F, F, R), F, ["~C"]),
        ((R, F, F), F, ["~A"]),
        ((F, S, F), F, []),
    ],
)
def test_parallel_threshold_two_of_three(
    statuses: tuple[Status, Status, Status], expected: Status, halted: list[str]
) -> None:
    h = Harness()
    for name, status in zip("ABC", statuses, strict=True):
        h.action(name, status)
    live = h.live("<pl>(2)<a>(A)<a>(B)<a>(C)<e>")
    assert h.tick(live) == (expected, ["A", "B", "C", *halted])


def test_parallel_does_not_halt_a_child_that_finished_by_itself() -> None:
    h = Harness()
    h.action("A", R, S)
    h.action("B", R)
    live = h.live("<pl>(1)<a>(A)<a>(B)<e>")
    assert h.run(live, 2) == [(R, ["A", "B"]), (S, ["A", "B", "~B"])]
    assert h.halt(live) == []


def test_parallel_halts_running_children_when_it_finishes_over_several_ticks() -> None:
    h = Harness()
    h.action("A", R, R, F)
    h.action("B", R)
    h.action("C", R)
    live = h.live("<pl><a>(A)<a>(B)<a>(C)<e>")
    assert h.run(live, 3) == [
        (R, ["A", "B", "C"]),
        (R, ["A", "B", "C"]),
        (F, ["A", "B", "C", "~B", "~C"]),
    ]
    assert h.halt(live) == []
    # A new activation ticks every child again.
    assert h.tick(live) == (F, ["A", "B", "C", "~B", "~C"])


def test_parallel_halted_by_its_parent_halts_its_running_children() -> None:
    h = Harness()
    h.condition("G")
    h.action("A", R)
    h.action("B", S)
    h.action("C", R)
    h.bb["G"] = True
    live = h.live("<sq><c>(G)<pl><a>(A)<a>(B)<a>(C)<e><e>")
    assert h.tick(live) == (R, ["G?", "A", "B", "C"])
    h.bb["G"] = False
    assert h.tick(live) == (F, ["G?", "~A", "~C"])
    assert h.tick(live) == (F, ["G?"])


# -- knowledge placeholders <k>(name) ----------------------------------------------------------


def test_empty_placeholder_fails() -> None:
    h = Harness()
    h.action("B", R)
    assert h.tick(h.live("<k>(new)<e>")) == (F, [])
    live = h.live("<sl><k>(prior)<e><k>(new)<e><a>(B)<e>")
    assert h.tick(live) == (R, ["B"])


def test_placeholder_is_a_selector() -> None:
    h = Harness()
    h.action("A", F)
    h.action("B", S)
    h.action("C", S)
    h.action("D", F)
    assert h.tick(h.live("<k>(prior)<a>(A)<a>(B)<a>(C)<e>")) == (S, ["A", "B"])
    assert h.tick(h.live("<k>(prior)<a>(A)<a>(D)<e>")) == (F, ["A", "D"])


def test_placeholder_is_reactive_and_preempts_its_running_item() -> None:
    h = Harness()
    h.condition("X")
    h.action("A", R)
    h.action("B", R)
    live = h.live("<k>(prior)<sq><c>(X)<a>(A)<e><a>(B)<e>")
    assert h.tick(live) == (R, ["X?", "B"])
    h.bb["X"] = True
    assert h.tick(live) == (R, ["X?", "A", "~B"])
    h.bb["X"] = False
    assert h.tick(live) == (R, ["X?", "~A", "B"])
    assert h.halt(live) == ["~B"]


def test_merged_knowledge_preempts_the_fallback_from_the_next_tick() -> None:
    h = Harness()
    h.condition("X")
    h.action("A", R)
    h.action("Walk", R)
    h.bb["X"] = True
    live = h.live("<sl><k>(new)<e><a>(Walk)<e>")
    assert h.tick(live) == (R, ["Walk"])
    assert live.merge("<a>(A)", "new", when=["X"]) is True
    assert h.log[-1] == "Walk"  # merging ticks and halts nothing
    assert h.tick(live) == (R, ["X?", "A", "~Walk"])


# -- halting the whole tree --------------------------------------------------------------------


def test_live_halt_halts_every_running_action_exactly_once() -> None:
    h = Harness()
    h.action("A", R)
    h.action("B", S)
    h.action("C", R)
    h.action("D", S)
    live = h.live("<pl><a>(A)<sq><a>(B)<a>(C)<e><a>(D)<e>")
    assert h.tick(live) == (R, ["A", "B", "C", "D"])
    assert h.halt(live) == ["~A", "~C"]
    assert h.halt(live) == []
    assert h.tick(live) == (R, ["A", "B", "C", "D"])
    assert h.halt(live) == ["~A", "~C"]


def test_live_halt_on_a_finished_or_fresh_tree_halts_nothing() -> None:
    h = Harness()
    h.action("A", R, S)
    live = h.live("<sq><a>(A)<e>")
    assert h.halt(live) == []
    assert h.run(live, 2) == [(R, ["A"]), (S, ["A"])]
    assert h.halt(live) == []


def test_live_halt_reaches_actions_deep_in_nested_composites() -> None:
    h = Harness()
    h.condition("X")
    h.action("A", R)
    h.bb["X"] = True
    live = h.live("<sl><msq><c>(X)<k>(p)<sq><sl><a>(A)<e><e><e><e><e>")
    assert h.tick(live) == (R, ["X?", "A"])
    assert h.halt(live) == ["~A"]
    assert h.halt(live) == []
    assert h.tick(live) == (R, ["X?", "A"])
