"""Test tiers (CONTRIBUTING.md): ``network`` marks a test that starts processes or opens zenoh
sessions, ``slow`` one that takes more than about 5 s; ``make test-fast`` runs the others.
``soak`` marks a heavy run (a fleet of 100 peer processes), skipped unless ``KTBT_SOAK=1``:
``make soak`` runs those, ``make test`` does not.

Most tests carry their marks where they are written. The simulator's tests are marked from the
table below instead, until their module says it itself; ``tests/suites/test_tiers.py`` checks that
every name in it is still a test of that module.
"""

from __future__ import annotations

import os
import platform
import sys

import pytest

from ktbt_proto.tools.ros2 import interfaces

SIMULATOR_TIERS: dict[str, dict[str, tuple[str, ...]]] = {
    "test_sim_experiment.py": {
        "test_one_and_two_workers_give_identical_results": ("network",),
        "test_a_killed_sweep_resumes_with_only_the_missing_trials": ("network", "slow"),
        "test_a_folder_of_another_scenario_is_refused": ("network", "slow"),
        "test_ray_executor_matches_the_local_pool": ("network", "slow"),
        "test_sim_plot_draws_files_from_a_real_sweep": ("network", "slow"),
        "test_demo_prints_the_summary_and_writes_the_figure": ("network", "slow"),
        "test_sim_list_and_scenario_print_what_a_user_can_run": ("network",),
        "test_sim_view_records_frames_headless": ("network", "slow"),
        "test_user_errors_are_one_line_and_exit_2": ("network", "slow"),
    },
    "test_sim_plots.py": {  # the studies they draw are run once, for the three of them
        "test_every_figure_is_written_as_png_and_svg": ("slow",),
        "test_summary_has_a_row_per_scenario": ("slow",),
        "test_a_study_keeps_only_its_figures_and_scenarios": ("slow",),
    },
    "test_sim_records.py": {
        "test_our_rows_written_as_the_release_writes_them_read_back_the_same": ("slow",),
        "test_compare_against_the_release_excerpt": ("network", "slow"),
        "test_sim_plot_reads_a_release_folder": ("network", "slow"),
        "test_sim_run_writes_a_release_simdata_folder_that_compare_reads": ("network", "slow"),
        "test_sim_run_modes_exports_each_mode_under_its_own_name_and_compare_reads_it": (
            "network",
            "slow",
        ),
    },
    "test_sim_world.py": {
        "test_world_invariants_hold_every_step": ("slow",),
        "test_same_seed_same_run_bit_for_bit": ("slow",),
        "test_skipping_ticks_changes_nothing": ("slow",),
        "test_memory_size_caps_teaching": ("slow",),
        "test_robots_learn_by_real_messages": ("slow",),
    },
}
"""Module, then test function (every parameter of it), then its marks."""


@pytest.hookimpl(tryfirst=True)  # before ``-m`` deselects by mark
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    soak = os.environ.get("KTBT_SOAK") == "1"
    for item in items:
        function = getattr(item, "originalname", item.name)
        for name in SIMULATOR_TIERS.get(item.path.name, {}).get(function, ()):
            item.add_marker(name)
        if not soak and item.get_closest_marker("soak") is not None:
            item.add_marker(pytest.mark.skip(reason="a heavy run: make soak (KTBT_SOAK=1)"))


@pytest.fixture(scope="session")
def ros2_built() -> None:
    """rclpy and ktbt_interfaces importable in this environment (built if need be)."""
    if not interfaces.has_wheels() and interfaces.system_ros() is None:
        pytest.skip(
            f"no ROS 2 wheels for {platform.machine()} {sys.platform} CPython "
            f"{platform.python_version()} (only {interfaces.WHEEL_PLATFORMS}) and no sourced ROS 2"
        )
    if interfaces.system_ros() is None:
        try:
            interfaces.build(lambda line: print(line, file=sys.stderr))
        except interfaces.Ros2Unavailable as exc:
            pytest.fail(f"ROS 2 on {platform.machine()} {sys.platform}: {exc}")
