"""Simulator metrics against cases worked out by hand (the arithmetic is in the comments)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ktbt_sim import records
from ktbt_sim.metrics import (
    entropy,
    heterogeneity,
    knowledge_levels,
    level_distance,
    mean_knowledge_score,
    rao,
    summary,
    t_fraction,
)
from ktbt_sim.results import Results
from ktbt_sim.scenario import preset
from ktbt_sim.world import RECORD_COLUMNS


def test_entropy_by_hand() -> None:
    assert float(entropy([0.5, 0.5])) == pytest.approx(math.log(2))  # 2 · (-0.5 ln 0.5)
    assert float(entropy([0.5, 0.5], base=2)) == pytest.approx(1.0)
    assert float(entropy([1.0, 0.0, 0.0])) == 0.0  # one species; 0 log 0 = 0, no NaN
    assert float(entropy([0.25] * 4, base=2)) == pytest.approx(2.0)
    rows = entropy([[1.0, 0.0], [0.5, 0.5]])  # vectorised over leading axes
    assert rows == pytest.approx([0.0, math.log(2)])
    with pytest.raises(ValueError, match="log base"):
        entropy([1.0], base=1)


def test_rao_by_hand() -> None:
    d1 = np.array([[0.0, 1.0], [1.0, 0.0]])
    # Ordered pairs i != j: p0 p1 d + p1 p0 d = 2 · 0.25 · 1.
    assert float(rao([0.5, 0.5], d1)) == pytest.approx(0.5)
    # Distance 2, exponent 2: 2 · 0.25 · 2² = 2.
    assert float(rao([0.5, 0.5], 2 * d1, exponent=2)) == pytest.approx(2.0)
    assert float(rao([1.0, 0.0], d1)) == 0.0
    # Three levels 0, 1, 2 a third each, d = |i - j|: pairs (0,1),(1,2) at 1 and (0,2) at 2,
    # each twice: 2 · (1/9) · (1 + 1 + 2) = 8/9.
    d3 = level_distance(3, unit=1.0)
    assert float(rao([1 / 3] * 3, d3)) == pytest.approx(8 / 9)
    with pytest.raises(ValueError, match="distance must be"):
        rao([0.5, 0.5], level_distance(3))


def test_level_distance_uses_the_knowledge_score_unit() -> None:
    d = level_distance()
    assert d.shape == (5, 5)
    assert d[0, 4] == 1.0 and d[0, 1] == 0.25 and d[3, 1] == 0.5 and d[2, 2] == 0.0


def test_heterogeneity_is_zero_for_a_homogeneous_group() -> None:
    for counts in ([40, 0, 0, 0, 0], [0, 40, 0, 0, 0], [0, 0, 0, 0, 40]):
        c, d, h = heterogeneity(counts)
        assert (float(c), float(d), float(h)) == (0.0, 0.0, 0.0)


def test_heterogeneity_of_39_ignorant_and_1_multi_by_hand() -> None:
    counts = [39, 0, 0, 0, 1]  # p0 = 0.975, p4 = 0.025
    # E = -(0.975 ln 0.975 + 0.025 ln 0.025) = 0.0246849 + 0.0922220 = 0.1169068
    # Q = 2 · 0.975 · 0.025 · (4 · 0.25)¹ = 0.04875;  H = E · Q = 0.0056992
    c, d, h = heterogeneity(counts)
    assert float(c) == pytest.approx(0.1169068, abs=1e-7)
    assert float(d) == pytest.approx(0.04875)
    assert float(h) == pytest.approx(0.0056992, abs=1e-7)
    # The paper's printed form: d in colours (0..4) and squared: Q = 2 · 0.975 · 0.025 · 16.
    _, d_paper, h_paper = heterogeneity(counts, exponent=2, distance=level_distance(unit=1.0))
    assert float(d_paper) == pytest.approx(0.78)
    assert float(h_paper) == pytest.approx(0.1169068 * 0.78, abs=1e-6)
    # Base 2 only rescales complexity: E / ln 2 = 0.1686609.
    c2, _, _ = heterogeneity(counts, base=2)
    assert float(c2) == pytest.approx(0.1686609, abs=1e-7)


def test_heterogeneity_is_vectorised_over_trials_and_rows() -> None:
    counts = np.array([[[39, 0, 0, 0, 1], [0, 40, 0, 0, 0]], [[20, 0, 0, 0, 20], [0, 0, 0, 0, 0]]])
    c, d, h = heterogeneity(counts)
    assert c.shape == d.shape == h.shape == (2, 2)
    assert d[1, 0] == pytest.approx(0.5)  # half g0, half g4: 2 · 0.25 · 1
    assert c[1, 0] == pytest.approx(math.log(2))
    assert h[0, 1] == 0.0
    assert np.isnan(h[1, 1])  # nobody to measure


def test_mean_knowledge_score_by_hand() -> None:
    assert float(mean_knowledge_score([39, 0, 0, 0, 1])) == pytest.approx(0.025)  # 1·4·0.25/40
    assert float(mean_knowledge_score([0, 40, 0, 0, 0])) == pytest.approx(0.25)
    # (10·1 + 10·2 + 10·3 + 10·4) · 0.25 / 50 = 100 · 0.25 / 50 = 0.5
    assert float(mean_knowledge_score([10, 10, 10, 10, 10])) == pytest.approx(0.5)
    assert mean_knowledge_score([[0, 0, 0, 0, 40], [40, 0, 0, 0, 0]]) == pytest.approx([1, 0])


def test_knowledge_levels_counts_colours_known() -> None:
    known = np.array(
        [
            [False, False, False, False],  # g0
            [True, False, False, False],  # g1
            [False, True, False, False],  # g1
            [True, False, True, True],  # g3
            [True, True, True, True],  # g4
        ]
    )
    assert knowledge_levels(known).tolist() == [1, 2, 0, 1, 1]
    assert knowledge_levels(np.zeros((40, 4), dtype=bool)).tolist() == [40, 0, 0, 0, 0]


def test_t_fraction_by_hand_including_a_trial_that_never_gets_there() -> None:
    iterations = np.array([10, 20, 30, 40])
    collected = np.array(
        [
            [50, 98, 99, 100],  # 99 of 100 first at iteration 30
            [99, 99, 100, 100],  # already at the first row: 10
            [90, 95, 97, 98],  # never: NaN, not the run length
        ]
    )
    t99 = t_fraction(collected, 100, iterations)
    assert t99[:2].tolist() == [30.0, 10.0] and np.isnan(t99[2])
    assert t_fraction(collected, 100, iterations, 0.95).tolist() == [20.0, 10.0, 20.0]
    # ceil(0.99 · 40) = 40: 39 of 40 is not 99 %.
    assert np.isnan(t_fraction(np.array([[39, 39]]), 40, [10, 20])[0])
    # 0.29 · 100 is 28.999999999999996 in floats; it must still need 29.
    assert t_fraction(np.array([[28, 29]]), 100, [10, 20], 0.29).tolist() == [20.0]


def _results(collected: list[list[int]], finals: dict[str, list[int]]) -> Results:
    trials, rows = len(collected), len(collected[0])
    data = {c: np.zeros((trials, rows), dtype=np.int64) for c in RECORD_COLUMNS[1:]}
    data["collected"] = np.array(collected)
    for column, values in finals.items():
        data[column][:, -1] = values
    return Results(preset("bl2"), tuple(range(trials)), np.array([10, 20, 30]), data)


def test_summary_means_stds_and_reached_counts() -> None:
    res = _results(
        [[50, 99, 100], [90, 95, 100], [10, 20, 80]],  # 100 targets; t99 = 20, 30, never
        {
            "queries": [10, 20, 30],
            "responses": [1, 2, 3],
            "lost": [0, 0, 3],
            "knows_1": [40, 20, 0],
            "knows_4": [0, 20, 40],
        },
    )
    s = summary(res)
    assert s["trials"] == 3
    assert s["collected_pct_mean"] == pytest.approx(280 / 3)
    assert s["collected_pct_std"] == pytest.approx(np.std([100, 100, 80], ddof=1))
    assert (s["t99_mean"], s["t99_reached"]) == (25.0, 2)  # mean of 20 and 30 only
    assert s["t99_std"] == pytest.approx(math.sqrt(50))  # (5² + 5²) / (2 - 1)
    assert (s["t95_mean"], s["t95_reached"]) == (20.0, 2)  # 99 and 95 both by 20
    assert (s["queries_mean"], s["queries_std"]) == (20.0, 10.0)
    assert s["lost_mean"] == 1.0 and s["responses_mean"] == 2.0
    assert (s["knows_4_mean"], s["knows_1_mean"], s["knows_0_mean"]) == (20.0, 20.0, 0.0)
    # Scores 0.25, (20·0.25 + 20·1)/40 = 0.625, 1.0.
    assert s["knowledge_score_mean"] == pytest.approx((0.25 + 0.625 + 1.0) / 3)


def test_summary_reads_knowledge_when_collection_ended_and_at_an_iteration() -> None:
    res = _results([[50, 100, 100], [90, 95, 100], [10, 20, 80]], {})
    res.data["knows_4"][:] = [[1, 2, 3], [4, 5, 6], [7, 8, 9]]
    s = summary(res)
    assert (s["t100_mean"], s["t100_reached"]) == (25.0, 2)  # 20 and 30; the third never
    assert s["knows_4_end_mean"] == (2 + 6) / 2  # at each trial's first row with everything
    early = summary(res, at=25)
    assert early["iteration"] == 20 and s["iteration"] == 30
    assert early["knows_4_mean"] == (2 + 5 + 8) / 3
    assert early["collected_pct_mean"] == pytest.approx((100 + 95 + 20) / 3)


def test_summary_of_one_trial_has_no_spread_and_nothing_reached_is_nan() -> None:
    s = summary(_results([[10, 20, 30]], {}))
    assert s["collected_pct_mean"] == 30.0 and math.isnan(s["collected_pct_std"])
    assert s["t99_reached"] == 0 and math.isnan(s["t99_mean"]) and math.isnan(s["t99_std"])


def test_colour_sets_as_species_10rgyb_starts_heterogeneous() -> None:
    from ktbt_sim import metrics

    # 10 R + 10 G + 10 Y + 10 B: four species of a quarter each. Complexity ln 4; any two of
    # them differ in 2 colours (distance 2 x 0.25 = 0.5), and there are 12 ordered pairs:
    # disparity = 12 x 1/16 x 0.5 = 0.375.
    counts = np.zeros(metrics.SETS)
    for bits in (1, 2, 4, 8):
        counts[bits] = 10
    complexity, disparity, hetero = metrics.heterogeneity(counts, distance=metrics.set_distance())
    assert complexity == pytest.approx(math.log(4))
    assert disparity == pytest.approx(0.375)
    assert hetero == pytest.approx(math.log(4) * 0.375)
    assert records.set_name(0) == "set_none" and records.set_name(0b1011) == "set_RGB"
    assert metrics.set_distance()[0, 15] == pytest.approx(1.0)  # nothing vs all four colours
