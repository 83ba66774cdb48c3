# aslip_ros: every target sets up whatever is missing first (scripts/setup.sh is idempotent).
SHELL := /bin/bash
.DEFAULT_GOAL := help
VENV := .venv
# ASLIP_LAUNCH_ENV: an env.sh that adds the ROS 2 launch stack (.ci/run sets it to
# build/ros2-launch/env.sh); a shell with ROS 2 Jazzy sourced has the stack already.
ROS := source install/setup.bash && $(if $(ASLIP_LAUNCH_ENV),source $(ASLIP_LAUNCH_ENV) &&)
# Tests run with the colcon install first on PYTHONPATH (generated messages) and never with
# the repository root on sys.path (it would shadow the built package). The whole run has a
# deadline: a hung launch test (upstream WaitForTopics leaves a thread behind) must not hang
# CI; `timeout -k` kills it.
TEST_TIMEOUT ?= 2400
PYTEST := $(ROS) ASLIP_REQUIRE_ROS=1 timeout -k 30 $(TEST_TIMEOUT) $(VENV)/bin/pytest
# The benchmarks (benchmarks/, not installed) run from this checkout: `python -P` keeps the
# working directory off sys.path and the repository root goes after the colcon install, so
# `aslip_ros` is the installed one (with its generated messages) and `benchmarks` this
# checkout's. ARGS adds options: make demo ARGS="--trials 2 --tasks slip_stop".
BENCHMARK := $(ROS) PYTHONPATH="$$PYTHONPATH:$(CURDIR)" $(VENV)/bin/python -P -m

.PHONY: help setup build test test-install test-fast demo demo-variants datasets ablation bench stability transfer lint clean
.PHONY: ablation-baselines magnitude flake-hunt soak-recording latency recipe-budget rotation scale

help:
	@echo "make demo       closed-loop slip-stop and slip-track in the simulated scene (main job)"
	@echo "make demo-variants  the same loops under scene variants and louder robot noise (results/demo_variants/)"
	@echo "make test       the test suite (all but the install tier)"
	@echo "make test-install  make setup's own test and the hardware rehearsal (CI: own step)"
	@echo "make flake-hunt the tests that start processes, RUNS times beside HOGS CPU hogs"
	@echo "make soak-recording  data-collection recordings, nodes started in random order"
	@echo "make setup      venv (.venv), core install (aslip) and colcon build (install/)"
	@echo "make datasets   default simulated datasets (data/)"
	@echo "make ablation   the paper's Table I and II on the scene (results/ablation/)"
	@echo "make ablation-baselines  only the SVM and plain-baseline rows of Table I (minutes)"
	@echo "make magnitude  the package CNN against the plain CNN, one cause at a time (after transfer)"
	@echo "make bench      latency against accuracy (results/bench/)"
	@echo "make latency    tail latency of the live node per step, shipped models (results/latency/)"
	@echo "make stability  accuracy under stressors (results/stability/)"
	@echo "make transfer   train on the default scene, test on held-out variants (results/transfer/)"
	@echo "make recipe-budget  the default aslip train at 4, 8, 16 and 32 min (results/recipes/)"
	@echo "make scale     export and training against 1, 4 and 16 hours of recordings (results/scale/)"
	@echo "make rotation   rotational slip per microphone layout, planar kept (results/rotation/)"
	@echo "                (the benchmark targets run benchmarks/ from this checkout; ARGS=\"...\" adds options)"

setup:
	@bash scripts/setup.sh

build: setup

# CI passes TEST_ARGS="-ra -v" so its log names every test file and test with its outcome.
TEST_ARGS ?= -q -ra
# The suite in one run on TEST_WORKERS pytest-xdist workers, a file to a worker: the in-process
# tests use the cores while the process tests wait on their nodes. On 2 cores, 2 workers kept
# 1.6 cores busy (469 s) and 3 workers 1.85 (392 s); a CI machine took 699 s on 2 workers
# for a suite that took 513 s here. Every verdict waits on events, and the process tier
# holds beside two busy loops (make flake-hunt HOGS=2), the load of the two neighbouring
# tests. The `install` tier (make setup's own test, the hardware rehearsal) is
# `make test-install`, a CI step of its own.
TEST_WORKERS ?= 3
test: setup
	$(PYTEST) test -m "not install" -n $(TEST_WORKERS) --dist loadfile $(TEST_ARGS)

test-install: setup
	$(PYTEST) test -m install $(TEST_ARGS)

test-fast: setup
	$(PYTEST) test -q -ra -m "not slow"

# The flake hunt (README, Tests): the `processes` tier, RUNS whole sessions beside HOGS
# busy loops, a count per test. Run it before a change to nodes, launch files or their tests.
RUNS ?= 5
HOGS ?= 2
flake-hunt: setup
	$(ROS) ASLIP_REQUIRE_ROS=1 $(VENV)/bin/python scripts/flake_hunt.py --runs $(RUNS) \
	  --hogs $(HOGS) $(ARGS)

# Recordings whose nodes start in random order beside HOGS busy loops: every bag must hold
# its metadata (README, Tests).
SOAK ?= 50
soak-recording: setup
	$(ROS) $(VENV)/bin/python scripts/soak_recording.py --launches $(SOAK) --hogs $(HOGS)

demo: setup
	$(BENCHMARK) benchmarks.demo $(ARGS)

# The closed loops in held-out scene variants and with 2x and 4x robot noise (issue #37).
demo-variants: setup
	$(BENCHMARK) benchmarks.demo_variants $(ARGS)

datasets: setup
	$(BENCHMARK) benchmarks.ablation --datasets-only --out results/ablation $(ARGS)

ablation: setup
	$(BENCHMARK) benchmarks.ablation --out results/ablation $(ARGS)

ablation-baselines: setup
	$(BENCHMARK) benchmarks.ablation --baselines-only --out results/ablation $(ARGS)

magnitude: setup
	$(BENCHMARK) benchmarks.magnitude --out results/magnitude $(ARGS)

# ARGS go to the first of the two (the lag benchmark has options of its own: docs/streaming.md).
bench: setup
	$(BENCHMARK) benchmarks.bench --out results/bench $(ARGS)
	$(BENCHMARK) benchmarks.lag --out results/lag --cache results/lag/cache/scale120

# ARGS: --models, --duration (30 s per model), --hogs N (CPU hogs beside).
latency: setup
	$(BENCHMARK) benchmarks.tail_latency --out results/latency $(ARGS)

stability: setup
	$(BENCHMARK) benchmarks.stability --out results/stability $(ARGS)

transfer: setup
	$(BENCHMARK) benchmarks.transfer --out results/transfer $(ARGS)

recipe-budget: setup
	$(BENCHMARK) benchmarks.recipe_budget --out results/recipes $(ARGS)

# Export and training against hours of recordings (#38). ARGS: --hours, --rate, --work.
scale: setup
	$(BENCHMARK) benchmarks.scale --out results/scale $(ARGS)

rotation: setup
	$(BENCHMARK) benchmarks.rotation --out results/rotation $(ARGS)

lint: setup
	$(VENV)/bin/python -m flake8 --max-line-length 99 aslip_ros benchmarks test || true

clean:
	rm -rf build install log .colcon
