# Two commands on a fresh clone (needs Python ≥ 3.11 and GNU make):
#   make run    create .venv on first use (reused after), install beambench, run the contact sweep on the sim
#   make test   the same venv with the dev extra; lint, format, type and import-layer checks, then the tests
#   make soak   the soak tier only: more race repetitions, the whole 2-min calibration test (CI runs it after make test)
# Variables: PYTHON (python3), VENV (.venv), OUT (data), RUN_ARGS (extra `beambench run` flags),
# PYTEST_ARGS (e.g. tests/test_run_sim.py), PYTEST_WORKERS (4: two cores, and many tests wait on real time; 0 runs in one process). `make clean-venv` removes the venv.

PYTHON ?= python3
VENV ?= .venv
OUT ?= data
RUN_ARGS ?=
PYTEST_ARGS ?=
# pytest-xdist workers: a quarter of the suite's time is spent waiting (real-time emulated peers, CAN and NatNet
# timeouts, subprocesses), so on 2 cores a third worker fills those waits (measured on this machine, same tree:
# -n 2 294 s, -n 3 271 s; CPU use 76 % -> 85 %);
# --dist loadfile: a worker takes whole modules from one queue (a module's shared fixtures are made once; with
# worksteal a module split between workers made its emulated runs in each, 7 runs instead of 2), and the queue is
# longest module first by the last run's times (tests/longest_first.py, pytest's cache), so no long module starts
# last (same tree: worksteal 217-222 s, loadfile 204-208 s; docs/evidence.md)
PYTEST_WORKERS ?= 4
# pytest runs with bytecode caching on even where the environment sets PYTHONDONTWRITEBYTECODE: without it each
# worker re-rewrote every test module's asserts (collection 11 s -> 6 s of CPU) and every subprocess recompiled
# beambench. The caches are __pycache__/ folders (git-ignored, never in the wheel).
BIN := $(VENV)/bin
RUN_STAMP := $(VENV)/.beambench-run
DEV_STAMP := $(VENV)/.beambench-dev

.PHONY: run test soak lint clean-venv

run: $(RUN_STAMP)
	$(BIN)/beambench run protocols/contact_sweep.yaml --out $(OUT) $(RUN_ARGS)

test: $(DEV_STAMP)
	@status=0; \
	for check in "ruff check src tests benchmarks" "ruff format --check src tests benchmarks" "mypy" "lint-imports"; do \
	  echo "== $$check"; $(BIN)/$$check || status=1; \
	done; \
	echo "== pytest"; env -u PYTHONDONTWRITEBYTECODE $(BIN)/python -m pytest -q -n $(PYTEST_WORKERS) --dist loadfile --no-loadscope-reorder $(PYTEST_ARGS); rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "pytest collected no tests — that is a failure for this project" >&2; rc=1; fi; \
	if [ $$status -ne 0 ]; then echo "lint, format, type or import checks failed (see above)" >&2; fi; \
	[ $$rc -eq 0 ] && [ $$status -eq 0 ]

soak: $(DEV_STAMP)
	env -u PYTHONDONTWRITEBYTECODE $(BIN)/python -m pytest -q -n $(PYTEST_WORKERS) --dist loadfile --no-loadscope-reorder --soak -m soak $(PYTEST_ARGS)

lint: $(DEV_STAMP)
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks
	$(BIN)/mypy
	$(BIN)/lint-imports

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# Reinstalled when pyproject.toml changes; editable, so source edits need no reinstall.
$(RUN_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(DEV_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	touch $@ $(RUN_STAMP)

clean-venv:
	rm -rf $(VENV)
