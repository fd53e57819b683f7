"""Runtime behaviour of the decorators and tick timers (spec sections 3.2 and 3.3).

Every test drives scripted leaves (``runtime_helpers``) and asserts, tick by tick, the status of
the tree and exactly which leaves were ticked (``"A"``, ``"G?"``) and halted (``"~A"``).
"""

from __future__ import annotations

import pytest

from ktbt_proto.status import Status
from tests.runtime_helpers import F, Harness, R, S

WAITING: tuple[Status, list[str]] = (R, [])

# -- inverter <neg> ----------------------------------------------------------------------------


@pytest.mark.parametrize(("child", "expected"), [(S, F), (F, S), (R, R)])
def test_inverter_swaps_success_and_failure_and_passes_running(
    child: Status, expected: Status
) -> None:
    h = Harness()
    h.action("A", child)
    assert h.tick(h.live("<neg><a>(A)<e>")) == (expected, ["A"])


def test_inverter_over_a_running_child_until_it_finishes() -> None:
    h = Harness()
    h.action("A", R, R, S)
    live = h.live("<neg><a>(A)<e>")
    assert h.run(live, 3) == [(R, ["A"]), (R, ["A"]), (F, ["A"])]
    assert h.halt(live) == []


def test_inverter_halted_halts_its_running_child() -> None:
    h = Harness()
    h.condition("G")
    h.action("A", R)
    h.bb["G"] = True
    live = h.live("<sq><c>(G)<neg><a>(A)<e><e>")
    assert h.tick(live) == (R, ["G?", "A"])
    h.bb["G"] = False
    assert h.tick(live) == (F, ["G?", "~A"])
    assert h.halt(live) == []


def test_inverted_condition_guard() -> None:
    h = Harness()
    h.condition("X")
    h.action("A", R)
    live = h.live("<sq><neg><c>(X)<e><a>(A)<e>")
    assert h.tick(live) == (R, ["X?", "A"])
    h.bb["X"] = True
    assert h.tick(live) == (F, ["X?", "~A"])


# -- TT1 <tt1>(N), the wait timer --------------------------------------------------------------


def test_tt1_waits_n_ticks_without_ticking_the_child_then_returns_its_status() -> None:
    h = Harness()
    h.action("A", F, S)
    live = h.live("<tt1>(2)<a>(A)<e>")
    assert h.run(live, 6) == [
        WAITING,
        WAITING,
        (F, ["A"]),
        # The child finished, so the activation ended: the next tick waits again.
        WAITING,
        WAITING,
        (S, ["A"]),
    ]


def test_tt1_keeps_ticking_a_running_child_without_waiting_again() -> None:
    h = Harness()
    h.action("A", R, R, S)
    live = h.live("<tt1>(1)<a>(A)<e>")
    assert h.run(live, 6) == [
        WAITING,
        (R, ["A"]),
        (R, ["A"]),
        (S, ["A"]),
        WAITING,
        (S, ["A"]),
    ]


def test_tt1_zero_is_its_child() -> None:
    h = Harness()
    h.action("A", R, S, F, R)
    live = h.live("<tt1>(0)<a>(A)<e>")
    assert h.run(live, 4) == [(R, ["A"]), (S, ["A"]), (F, ["A"]), (R, ["A"])]


def test_tt1_halt_during_the_wait_resets_the_wait() -> None:
    h = Harness()
    h.condition("G")
    h.action("A", S)
    h.bb["G"] = True
    live = h.live("<sq><c>(G)<tt1>(2)<a>(A)<e><e>")
    assert h.tick(live) == (R, ["G?"])  # one tick of the wait spent
    h.bb["G"] = False
    assert h.tick(live) == (F, ["G?"])  # TT1 halted (no action was running)
    h.bb["G"] = True
    # A new activation: two full ticks of waiting before the child is ticked.
    assert h.run(live, 3) == [(R, ["G?"]), (R, ["G?"]), (S, ["G?", "A"])]


def test_tt1_halt_halts_a_running_child_and_restarts_the_wait() -> None:
    h = Harness()
    h.condition("G")
    h.action("A", R)
    h.bb["G"] = True
    live = h.live("<sq><c>(G)<tt1>(1)<a>(A)<e><e>")
    assert h.run(live, 3) == [(R, ["G?"]), (R, ["G?", "A"]), (R, ["G?", "A"])]
    h.bb["G"] = False
    assert h.tick(live) == (F, ["G?", "~A"])
    h.bb["G"] = True
    assert h.run(live, 2) == [(R, ["G?"]), (R, ["G?", "A"])]


def test_tt1_live_halt() -> None:
    h = Harness()
    h.action("A", R)
    live = h.live("<tt1>(1)<a>(A)<e>")
    assert h.tick(live) == WAITING
    assert h.halt(live) == []
    assert h.tick(live) == WAITING  # the wait restarted
    assert h.tick(live) == (R, ["A"])
    assert h.halt(live) == ["~A"]
    assert h.halt(live) == []
    assert h.run(live, 2) == [WAITING, (R, ["A"])]


def test_tt1_parks_an_enclosing_sequence() -> None:
    h = Harness()
    h.action("A", S)
    h.action("B", S)
    h.action("C", S)
    live = h.live("<sq><a>(A)<tt1>(2)<a>(B)<e><a>(C)<e>")
    assert h.run(live, 4) == [(R, ["A"]), (R, ["A"]), (S, ["A", "B", "C"]), (R, ["A"])]


# -- TT2 <tt2>(N), the run timer ---------------------------------------------------------------


def test_tt2_time_up_halts_the_child_and_fails_on_the_same_tick() -> None:
    h = Harness()
    h.action("A", R)
    live = h.live("<tt2>(3)<a>(A)<e>")
    assert h.run(live, 6) == [
        (R, ["A"]),
        (R, ["A"]),
        (F, ["A", "~A"]),
        # A new activation: three more ticks.
        (R, ["A"]),
        (R, ["A"]),
        (F, ["A", "~A"]),
    ]
    assert h.halt(live) == []


def test_tt2_child_finishing_early_ends_the_activation() -> None:
    h = Harness()
    h.action("A", R, S, R)
    live = h.live("<tt2>(3)<a>(A)<e>")
    assert h.run(live, 5) == [
        (R, ["A"]),
        (S, ["A"]),
        (R, ["A"]),  # tick 1 of a new activation
        (R, ["A"]),
        (F, ["A", "~A"]),
    ]


@pytest.mark.parametrize("last", [S, F])
def test_tt2_child_finishing_on_its_nth_tick_returns_its_status(last: Status) -> None:
    h = Harness()
    h.action("A", R, last)
    live = h.live("<tt2>(2)<a>(A)<e>")
    assert h.run(live, 2) == [(R, ["A"]), (last, ["A"])]
    assert h.halt(live) == []


@pytest.mark.parametrize("status", [S, F])
def test_tt2_child_finishing_at_once(status: Status) -> None:
    h = Harness()
    h.action("A", status)
    live = h.live("<tt2>(2)<a>(A)<e>")
    assert h.run(live, 3) == [(status, ["A"])] * 3


def test_tt2_one() -> None:
    h = Harness()
    h.action("A", R, S)
    live = h.live("<tt2>(1)<a>(A)<e>")
    assert h.run(live, 3) == [(F, ["A", "~A"]), (S, ["A"]), (S, ["A"])]


def test_tt2_zero_fails_without_ticking_the_child() -> None:
    h = Harness()
    h.action("A", R)
    live = h.live("<tt2>(0)<a>(A)<e>")
    assert h.run(live, 3) == [(F, [])] * 3
    assert h.halt(live) == []


def test_tt2_halt_halts_the_running_child_and_resets_the_count() -> None:
    h = Harness()
    h.condition("G")
    h.action("A", R)
    h.bb["G"] = True
    live = h.live("<sq><c>(G)<tt2>(3)<a>(A)<e><e>")
    assert h.run(live, 2) == [(R, ["G?", "A"]), (R, ["G?", "A"])]
    h.bb["G"] = False
    assert h.tick(live) == (F, ["G?", "~A"])
    h.bb["G"] = True
    # A new activation: the child gets three full ticks again.
    assert h.run(live, 3) == [(R, ["G?", "A"]), (R, ["G?", "A"]), (F, ["G?", "A", "~A"])]


def test_tt2_live_halt() -> None:
    h = Harness()
    h.action("A", R)
    live = h.live("<tt2>(2)<a>(A)<e>")
    assert h.tick(live) == (R, ["A"])
    assert h.halt(live) == ["~A"]
    assert h.halt(live) == []
    assert h.run(live, 2) == [(R, ["A"]), (F, ["A", "~A"])]


def test_tt2_time_up_halts_a_whole_running_subtree() -> None:
    h = Harness()
    h.action("A", R)
    h.action("B", S)
    h.action("C", R)
    live = h.live("<tt2>(2)<pl><a>(A)<a>(B)<a>(C)<e><e>")
    assert h.run(live, 2) == [(R, ["A", "B", "C"]), (F, ["A", "B", "C", "~A", "~C"])]


def test_tt2_over_tt1_times_out_during_the_wait() -> None:
    h = Harness()
    h.action("A", S)
    live = h.live("<tt2>(2)<tt1>(3)<a>(A)<e><e>")
    # The wait timer is still waiting at TT2's second tick: it is halted (its wait reset).
    assert h.run(live, 4) == [(R, []), (F, []), (R, []), (F, [])]
    live2 = h.live("<tt2>(3)<tt1>(2)<a>(A)<e><e>")
    assert h.run(live2, 4) == [(R, []), (R, []), (S, ["A"]), (R, [])]
