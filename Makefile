# The two commands a newcomer needs: `make demo` and `make test`. Each creates .venv if missing.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: demo test test-fast lint typecheck docs pytest bench studies fuzz interop soak ros2 clean

# The ROS 2 wheels (the ros2 extra) depend on lark-parser 0.12, which writes the same
# lark/ folder as lark 1.x (added to an environment that has lark already, it wins) and type
# stubs mypy would prefer to lark 1.x's own: put 1.x back, remove the stubs.
LARK_1X = $(BIN)/python -m ktbt_proto.tools.ros2.interfaces

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# `make demo` runs a simulator study, so it installs the sim extra; the core is `pip install .`.
$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[sim]'
	touch $@

# The ROS 2 wheels come with the ros2 extra unless a ROS 2 is sourced (ROS_DISTRO set): then
# its own rclpy is used and nothing of ROS is installed twice (docs/tutorials/ros2.md).
$(VENV)/.installed-dev: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	if [ -n "$$ROS_DISTRO" ]; then echo "ROS 2 $$ROS_DISTRO is sourced: its rclpy is used (no ros2 extra)"; \
	else $(BIN)/python -m pip install --quiet -e '.[ros2]'; fi
	$(LARK_1X)
	touch $@ $(VENV)/.installed

demo: $(VENV)/.installed
	$(BIN)/ktbt demo

lint: $(VENV)/.installed-dev
	$(BIN)/ruff check .
	$(BIN)/lint-imports --no-cache
	$(BIN)/ruff format --check ktbt_proto ktbt_sim tests benchmarks

typecheck: $(VENV)/.installed-dev
	$(BIN)/mypy

# The documentation site (docs/, Sphinx with MyST) into build/docs/, warnings as errors; the
# command-line reference is generated from the ktbt command as it builds.
docs: $(VENV)/.installed-dev
	$(BIN)/sphinx-build -W --keep-going -q -b html docs build/docs

# Two workers (pytest-xdist): most tests wait on processes, sessions and browsers, so two run
# side by side on two cores in about half the time. Every test owns its ports, folders and
# network namespaces, and none depends on another's order.
pytest: $(VENV)/.installed-dev
	$(BIN)/python -m ktbt_proto.tools.ros2.interfaces build
	$(BIN)/python -m pytest -n 2

test: lint typecheck docs pytest

# The quick loop (under a minute): every test but the slow ones and those that start processes
# or zenoh sessions. `make test` runs them all.
test-fast: $(VENV)/.installed-dev
	$(BIN)/python -m pytest -m "not slow and not network"

bench: $(VENV)/.installed-dev
	$(BIN)/python -m ktbt_proto.tools.ros2.interfaces build
	$(BIN)/python -m benchmarks

# The paper's studies, our teaching-rule study and the calibration against the release's own
# data, at full size; figures and tables land in docs/results/. RELEASE_DATA is the release's
# SimData folder (from its public repository) holding the two calibration runs.
RELEASE_DATA ?= release-data
RELEASE_NL := NL_0_0_10_10_10_10_N_45_18_19_18_200_-1
RELEASE_RL := RL_0_0_10_10_10_10_N_100_100_100_100_200_-1
studies: $(VENV)/.installed
	$(BIN)/ktbt sim run all --out results/studies
	$(BIN)/ktbt sim run teaching --out results/studies
	$(BIN)/ktbt sim run modes --out results/studies
	$(BIN)/ktbt sim run calibration --out results/calibration --release-csv
	$(BIN)/ktbt sim plot results/studies
	mkdir -p docs/results
	cp results/studies/*.png results/studies/summary.md docs/results/
	$(BIN)/ktbt sim compare results/calibration/calibration-nl $(RELEASE_DATA)/$(RELEASE_NL) --out docs/results/calibration-nl
	$(BIN)/ktbt sim compare results/calibration/calibration-rl $(RELEASE_DATA)/$(RELEASE_RL) --out docs/results/calibration-rl

# Mutation fuzzing of the parsers, the formatter round trip, the validator and the message
# decoder for FUZZ_SECONDS, one worker process per core, printing inputs per second (not part of
# `make test`, which runs a short fixed-seed run and the inputs kept in tests/data/fuzz/):
# FUZZ_SECONDS=... FUZZ_INPUTS=... FUZZ_SEED=... FUZZ_WORKERS=... make fuzz
FUZZ_SECONDS ?= 60
FUZZ_INPUTS ?=
FUZZ_SEED ?=
FUZZ_WORKERS ?=
fuzz: $(VENV)/.installed-dev
	$(BIN)/python -m ktbt_proto.tools.fuzz $(if $(FUZZ_SECONDS),--seconds $(FUZZ_SECONDS)) \
		$(if $(FUZZ_INPUTS),--inputs $(FUZZ_INPUTS)) $(if $(FUZZ_SEED),--seed $(FUZZ_SEED)) \
		$(if $(FUZZ_WORKERS),--workers $(FUZZ_WORKERS))

# BehaviorTree.CPP itself as the judge of our XML, and a C++ robot learning beside a KT-BT agent
# (not part of `make test`): the library is built from source once per version and compiler into
# ~/.cache/ktbt (minutes the first time), with the example programs and KT-BT's plugin library
# libktbt_nodes.so (examples/btcpp/), then the differential and sidecar tests run against it, and
# Nav2's two ways of loading a learned tree (test_btcpp_nav2.py): Jazzy's, a navigation tree
# by file path that runs it as a <SubTree>, and newer Nav2's, by ID from a folder; the KTBT_
# nodes loaded by name from the plugin library, as Nav2 loads its plugin_lib_names.
interop: $(VENV)/.installed-dev
	$(BIN)/python -m tests.btcpp.build
	KTBT_INTEROP=1 $(BIN)/python -m pytest tests/interop/test_btcpp_engine.py tests/interop/test_btcpp_learner.py \
		tests/interop/test_btcpp_nav2.py

# The heavy runs (not part of `make test`): the tests marked soak (KTBT_SOAK=1), such as the
# monitor in Chromium over a fleet of 100 peer processes; then the fleet study: real peer
# processes under loss, delay, a partition and churn; every run checked; the table and the
# figure land in docs/results/ (fleet.md, fleet.png). About 9 minutes on 2 cores for the
# study; packet loss needs root and nftables.
soak: $(VENV)/.installed-dev
	KTBT_SOAK=1 nice $(BIN)/python -m pytest -m soak
	nice $(BIN)/ktbt fleet study --out results/fleet --docs docs/results

clean:
	rm -rf $(VENV) build dist .pytest_cache .mypy_cache .ruff_cache .hypothesis fuzz-failures

# KT-BT on ROS 2 (docs/tutorials/ros2.md): ros2/ktbt_interfaces and ros2/ktbt_example_interfaces
# built from the ROS 2 Jazzy wheels (`make test` installs them unless a ROS 2 is sourced, on
# x86_64 Linux) into .venv, each skipped while up to date: about 40 s of CPU the first time,
# under a second after. `make pytest` builds it first
# the same way (and where there are no wheels says the ROS tests will skip).
ros2: $(VENV)/.installed-dev
	$(BIN)/ktbt ros2 build
