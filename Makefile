# dxl_servo_driver: setup, run, test, bench. Each target runs `setup` first, so any one of them works
# on a fresh machine. See README.md.
SHELL := /bin/bash
ENV := . tools/env.sh &&
PARAMS ?= config/sim.yaml
PYTEST_ARGS ?=

.PHONY: setup run test bench clean

setup:
	@bash tools/setup_env.sh

run: setup
	@if [ ! -f dxl_servo_driver/node.py ]; then \
	  echo 'make run: the driver node is not built yet (issue 4); the simulator is there:'; \
	  echo '  . .venv/bin/activate && . install/setup.bash && virtual_bus --ids 1 2 3'; \
	  exit 1; fi
	@$(ENV) exec install/dxl_servo_driver/lib/dxl_servo_driver/node --ros-args --params-file $(PARAMS)

test: setup
	@$(ENV) python -m pytest $(PYTEST_ARGS)

bench: setup
	@$(ENV) python bench/run_bench.py

clean:
	rm -rf build install log bench-results
