# Two entry points for a fresh machine: `make demo` (the main job) and `make test` (everything, as
# CI runs it). `make check` is the fast loop: lint, types and the tests not marked `integration`.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test check lint types bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test,physics,cluster]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/formation run scenarios/warehouse.yaml --out runs/warehouse

test: $(STAMP)
	$(BIN)/python -m pytest -q

# Tests that start processes, open Zenoh sessions, bind sockets or run whole scenarios are marked
# `integration` (tests/conftest.py marks them by reading them, and fails one that does so unmarked);
# those that take seconds in-process are marked `slow`. `make check` leaves both out, `make test`
# runs them too. A few of the largest scenarios of tests/test_simulation.py run only with
# FORMATION_SLOW=1 (`FORMATION_SLOW=1 make test`), in either.
check: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/python -m mypy
	$(BIN)/python -m pytest -q -m "not integration and not slow"

lint: $(STAMP)
	$(BIN)/ruff check .

types: $(STAMP)
	$(BIN)/python -m mypy

bench: $(STAMP)
	$(BIN)/python benchmarks/solve_time.py

clean:
	rm -rf $(VENV) runs build *.egg-info
