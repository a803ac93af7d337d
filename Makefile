# Two commands on a fresh machine: `make serve` (the service on the embedded simulator)
# and `make test` (lint, type-check and the whole test suite). Both create the virtualenv
# in .venv on first use.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
export OPENBLAS_NUM_THREADS := 1

.PHONY: serve equilibria test test-fast test-px4-flight lint browser

$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	-$(BIN)/python -m supervisor.cli.hpipm_install  # AVX2 HPIPM; on failure casadi's own
	touch $@

serve: $(BIN)/.installed
	$(BIN)/uavbar-supervisor serve

equilibria: $(BIN)/.installed
	$(BIN)/uavbar-supervisor equilibria --theta-l 45

lint: $(BIN)/.installed
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

# The dashboard test drives Debian's chromium; as root (CI) it is installed here.
browser:
	@command -v chromium >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && \
		apt-get update -qq && apt-get install -y -qq chromium >/dev/null; } || \
		echo "chromium is not installed: the dashboard browser tests will be skipped"

test: lint browser
	$(BIN)/pytest

# The quick loop while editing: lint, then the tests not marked slow (about 2 minutes).
test-fast: lint
	$(BIN)/pytest -m "not slow" -x -q

# The closed-loop flights on real PX4 SITL (whole flight, killed flight process): not yet
# robust, so not part of `make test` (issue 16).
test-px4-flight: $(BIN)/.installed
	$(BIN)/pytest -m px4_flight
