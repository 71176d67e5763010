# canimucal — the two README commands (`make demo`, `make test`) and their helpers.
# Prerequisites on Debian 12: make, python3-venv (apt-get install make python3-venv).

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
DEMO_OUT ?= demo-out

.PHONY: all venv demo test test-vcan lowest lint bench clean

all: test

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' || \
	  { echo "error: Python >= 3.11 is needed (found $$($(PYTHON) --version))"; exit 1; }
	@$(PYTHON) -c 'import ensurepip, venv' 2>/dev/null || \
	  { echo "error: the venv module is missing; install it with: sudo apt-get install python3-venv"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

venv: $(STAMP)

# The main job against the built-in simulated IMU.
demo: $(STAMP)
	$(BIN)/canimucal demo --out $(DEMO_OUT)

# The whole unit, device, procedure, TUI and CLI suite (HIL tests over vcan: `make test-vcan`).
# Two workers (TEST_WORKERS=0: one process), one BLAS thread each (as the CLI runs: §7 of
# docs/design.md); the slowest tests are listed at the end.
TEST_WORKERS ?= 2
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1
export MKL_NUM_THREADS ?= 1
test: $(STAMP)
	$(BIN)/python -m pytest -q -m "not vcan" -n $(TEST_WORKERS) --durations=25

lint: $(STAMP)
	$(BIN)/ruff check canimucal tests benchmarks firmware/tools
	$(BIN)/ruff format --check canimucal tests benchmarks firmware/tools
	$(BIN)/mypy
	$(BIN)/lint-imports

# The dependency bounds CI proves: the lowest versions pyproject.toml allows
# (.ci/lowest-constraints.txt) in a venv of their own, and the tests that exercise them:
# Textual (tui), python-can and canopen (device, simnode), numpy and scipy (model, io, sim).
LOWEST := .venv-lowest
lowest:
	$(PYTHON) -m venv $(LOWEST)
	$(LOWEST)/bin/python -m pip install --quiet --upgrade pip
	$(LOWEST)/bin/python -m pip install --quiet -c .ci/lowest-constraints.txt -e '.[dev]'
	$(LOWEST)/bin/python -m pytest -q -m "not vcan" -n $(TEST_WORKERS) -p no:cacheprovider \
	  tests/tui tests/device tests/simnode tests/model tests/io tests/sim

bench: $(STAMP)
	$(BIN)/python benchmarks/accuracy.py

clean:
	rm -rf $(VENV) $(LOWEST) $(DEMO_OUT) .pytest_cache .mypy_cache .ruff_cache

# --- test-vcan (issue 3) ---
# HIL tests over SocketCAN vcan0: natively where vcan0 exists, else inside ../shared/tools/canvm
# (needs root there). Outside CI it may skip with the reason; with CI=true it fails if it cannot
# run them. Prints "vcan: N passed, M failed".
test-vcan: $(STAMP)
	PYTHON=$(BIN)/python ./scripts/test_vcan.sh
