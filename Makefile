# dxl_servo_driver: setup, run, test, bench. Each target runs `setup` first, so any one of them works
# on a fresh machine. See README.md.
SHELL := /bin/bash
ENV := . tools/env.sh &&
PARAMS ?= config/sim.yaml
PYTEST_ARGS ?=
# make test's workers: most process tests wait on the simulator's wire, so two share two cores
# (test/conftest.py gives each worker DDS domains of its own). TEST_WORKERS=0: one process.
TEST_WORKERS ?= 2

.PHONY: setup run test test-fast fuzz bench bench-scale clean

setup:
	@bash tools/setup_env.sh

run: setup
	@$(ENV) exec install/dxl_servo_driver/lib/dxl_servo_driver/node --ros-args --params-file $(PARAMS)

test: setup
	@$(ENV) python -m pytest -n $(TEST_WORKERS) $(PYTEST_ARGS)

# The unit tier: the layers below the node, in this process (test/conftest.py marks the tiers).
test-fast: setup
	@$(ENV) python -m pytest -m "unit and not soak" $(PYTEST_ARGS)

# The Hypothesis tests at random with 20 times the examples (test/conftest.py, profile fuzz).
fuzz: setup
	@$(ENV) HYPOTHESIS_PROFILE=fuzz python -m pytest -m hypothesis $(PYTEST_ARGS)

bench: setup
	@$(ENV) python bench/run_bench.py

bench-scale: setup
	@$(ENV) python bench/run_bench.py scale

clean:
	rm -rf build install log bench-results
