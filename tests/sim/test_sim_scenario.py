"""Simulator scenarios: the paper's presets, files, and refusals of impossible settings."""

from __future__ import annotations

from pathlib import Path

import pytest

from ktbt_sim.scenario import PRESETS, Mode, Robots, Scenario, Targets, preset


def test_presets_follow_the_papers_tables() -> None:
    assert preset("bl1").robots == Robots.of(0, 40, 0, 0, 0, 0)
    assert preset("bl1").mode is Mode.NO_TRANSFER
    assert preset("bl2").robots == preset("ktbt").robots == Robots.of(0, 0, 10, 10, 10, 10)
    assert preset("ktbt").mode is Mode.KT_BT
    assert preset("ktbt-obstacles").arena.obstacles and not preset("ktbt").arena.obstacles
    assert [preset(f"opportunities-{n}").targets for n in (10, 25, 50, 100)] == [
        Targets.each(n) for n in (10, 25, 50, 100)
    ]
    assert [preset(f"range-{r}").comm_range for r in (100, 200, 500, 800, 1000)] == [
        100,
        200,
        500,
        800,
        1000,
    ]
    assert preset("range-500").robots.label() == "39I-1M"
    for name, scenario in PRESETS.items():
        if name.startswith("el-"):  # the release's own EL runs: 50 robots, 20,000 iterations
            assert (scenario.robots.total, scenario.iterations) == (50, 20_000)
            continue
        assert scenario.robots.total == 40  # the paper keeps 40 robots in every study
        long = name.startswith(("calibration", "heterogeneity", "opportunities"))
        iterations = 100_000 if long else 50_000  # the heterogeneity figures run past 70k
        assert (scenario.iterations, scenario.trials, scenario.timing.dt) == (iterations, 20, 0.02)
    with pytest.raises(ValueError, match="no preset 'nope'"):
        preset("nope")


def test_files_round_trip_and_errors_name_the_field(tmp_path: Path) -> None:
    toml = tmp_path / "s.toml"
    toml.write_text(
        'name = "mine"\nmode = "kt-bt"\ncomm_range = 350\n'
        "[robots]\nignorant = 20\nmulti = 2\n[targets]\nred = 5\ngreen = 5\nyellow = 5\nblue = 5\n"
    )
    scenario = Scenario.load(toml)
    assert (scenario.robots.total, scenario.targets.total, scenario.comm_range) == (22, 20, 350)
    as_json = tmp_path / "s.json"
    as_json.write_text(scenario.dump())
    assert Scenario.load(as_json) == scenario
    bad = tmp_path / "bad.toml"
    bad.write_text("[robots]\nred = -1\n")
    with pytest.raises(ValueError, match=r"robots\.red"):
        Scenario.load(bad)
    bad.write_text("colour_range = 3\n")
    with pytest.raises(ValueError, match="colour_range"):
        Scenario.load(bad)
    with pytest.raises(ValueError, match="at least one robot"):
        Scenario(robots=Robots())
    with pytest.raises(ValueError, match="half_size"):
        preset("ktbt").with_(arena={"half_size": 1000})  # the release's arena is fixed
    with pytest.raises(ValueError):
        Scenario.load(tmp_path / "missing.toml")


def test_a_scenario_names_the_physical_values_of_its_numbers() -> None:
    """The paper's range 200 is a 636-unit radius in the release (3 x 200 to the other's
    body); one iteration is 0.02 s; the counters give 501 and 500 iterations (§5.3, §1, §7)."""
    derived = preset("range-200").derived()
    assert derived["comm_radius_units"] == 3 * 200 + 36
    assert derived["seconds_per_iteration"] == 0.02
    assert derived["simulated_seconds"] == 1000.0
    assert (derived["wait_iterations"], derived["cooldown_iterations"]) == (501, 500)
    assert preset("calibration-nl").targets == Targets(red=45, green=18, yellow=19, blue=18)
