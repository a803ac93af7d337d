# Two commands on a fresh machine: `make serve` (the service on the embedded simulator)
# and `make test` (lint, type-check and the whole test suite). Both create the virtualenv
# in .venv on first use. `make serve PORT=8131 ARGS='--config path/to/lab.toml'` chooses the port
# and passes more options to `uavbar-supervisor serve`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
PORT ?= 8000
ARGS ?=
export OPENBLAS_NUM_THREADS := 1

.PHONY: serve equilibria test test-fast test-px4-flight lint browser

# Set-up takes a few minutes on a fresh machine (numpy, scipy, casadi, ...): each step
# says what it does, and pip shows what it downloads.
$(BIN)/.installed: pyproject.toml
	@echo "set-up 1/4: a virtualenv in $(VENV)"
	$(PYTHON) -m venv $(VENV)
	@echo "set-up 2/4: pip itself"
	$(BIN)/pip install --upgrade pip
	@echo "set-up 3/4: the project and its dependencies (a few minutes the first time)"
	$(BIN)/pip install -e '.[dev]'
	@echo "set-up 4/4: HPIPM's AVX2 build (optional; on failure casadi's own is used)"
	-$(BIN)/python -m supervisor.cli.hpipm_install
	touch $@
	@echo "set-up done"

serve: $(BIN)/.installed
	$(BIN)/uavbar-supervisor serve --set api.port=$(PORT) $(ARGS)

equilibria: $(BIN)/.installed
	$(BIN)/uavbar-supervisor equilibria --theta-l-deg 45

lint: $(BIN)/.installed
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

# The dashboard test drives Debian's chromium; as root (CI) it is installed here.
browser:
	@command -v chromium >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && \
		apt-get update -qq && apt-get install -y -qq chromium >/dev/null; } || \
		echo "chromium is not installed: the dashboard browser tests will be skipped"

# The tests on the wall clock (serve, real PX4, the browser) run in two lanes, at most two
# at once, each on a worker of its own from the start, and the rest beside them on one
# worker per core more, pure computation niced (tests/conftest.py); the thirty slowest
# are listed at the end, for whoever works on the suite's length.
WORKERS ?= $(shell echo $$(( $$(nproc) + 1 )))
test: lint browser
	$(BIN)/pytest -n $(WORKERS) --dist loadgroup --no-loadscope-reorder --durations=30

# The quick loop while editing: lint, then the tests not marked slow (about 2 minutes).
test-fast: lint
	$(BIN)/pytest -m "not slow" -x -q

# The closed-loop flights on real PX4 SITL (whole flight, killed flight process, three PX4s
# under the plate): not yet robust, so not part of `make test` (issue 16). The plate's
# flew 15 of 18 flights, the failures a burst of sensor samples after a stall of the world
# that kicked PX4's rate loop; since that fix, 10 of 10 (docs/results.md, issue 31).
test-px4-flight: $(BIN)/.installed
	$(BIN)/pytest -m px4_flight
