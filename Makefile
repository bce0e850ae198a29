# Quick start: `make demo` and `make test` work on a fresh machine.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
# a worker a core and one more: a test waits part of its time on sockets, subprocesses, the browser
# and the router's minute (one worker a core kept the cores 84 % busy); each worker handed one test
# at a time (the long ones come first: tests/conftest.py); a hung test fails with its stack after
# 20 minutes instead of stalling CI
WORKERS := $(shell $(PY) -c "import os; print(len(os.sched_getaffinity(0)) + 1)")
PYTEST  := $(BIN)/python -m pytest -q -n $(WORKERS) --maxschedchunk 1 --timeout 1200

.PHONY: demo test soak check lint setup browser bench clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	@# the sources byte-compiled once, as pip compiles what it installs: an editable install's are not,
	@# and where PYTHONDONTWRITEBYTECODE is set every command would compile them again as it starts
	$(BIN)/python -m compileall -q groundstation drivers web sim_bridge > /dev/null
	@# the filter's compiled steps too (numba's cache, beside the module), once a machine
	$(BIN)/python -c "from groundstation.estimation import kernels; kernels.warm()"
	touch $(STAMP)

setup: $(STAMP)

# Debian's chromium for the browser tests. Best effort: without it those tests
# skip and say why, so a machine without apt still runs the rest.
browser:
	@command -v chromium >/dev/null 2>&1 || { \
	  if command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
	      || echo "warning: could not install chromium; browser tests will be skipped"; \
	  else echo "warning: chromium not installed and apt-get unavailable; browser tests will be skipped"; fi; }

demo: setup
	$(BIN)/groundstation demo --duration 60

# static checks: lint and format, types, the layer contract
lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy
	$(BIN)/lint-imports

# the quick loop: the static checks and the fast tests
check: lint
	$(PYTEST) -m "not slow and not soak"

# the whole suite (the slowest tests listed at the end: what keeps the loop long)
test: setup browser lint
	$(PYTEST) -m "not soak" --durations=15

# the measurements over many minutes (CI runs them after the suite): ten minutes behind a MAVProxy
# router, 100,000 mutated logs a format on two processes. Side by side, each on a worker of its own:
# the router's ten minutes are a clock's, not the cores', and its streams are asserted to hold on a
# busy machine, as a ground station's laptop is (make test runs its minute beside the diagnoses)
soak: setup
	$(BIN)/python -m pytest -q -n 2 --maxschedchunk 1 -m soak --timeout 3600 --durations=0

bench: setup
	$(BIN)/python bench/sim_speed.py
	$(BIN)/python bench/ingest.py
	$(BIN)/python bench/bulk.py
	$(BIN)/python bench/dashboard.py
	$(BIN)/python bench/estimation.py
	$(BIN)/python bench/control.py
	$(BIN)/python bench/real_logs.py
	$(BIN)/python bench/foreign.py

clean:
	rm -rf $(VENV) out artifacts .pytest_cache .mypy_cache .ruff_cache
