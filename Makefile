# Two commands do everything on a fresh machine: `make demo` and `make test`.
# Both create .venv if missing and install the project (and its dev tools) into it.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test test-fast bench lint schema models clean help

help:
	@echo "make demo    set up and run the main scenario (rellis_ev_yield) end to end"
	@echo "make test    set up and run the whole test suite"
	@echo "make bench   run every benchmark in bench/ and write docs/benchmarks.md (BENCH_ARGS=--quick: quick runs)"
	@echo "make lint    ruff"
	@echo "make schema  regenerate protocol/schema/*.json from the message models"
	@echo "make models  train the project's models (needs the optional 'train' extra)"

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install --quiet -e '.[dev,sumo]' --config-settings editable_mode=compat
	@touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/iea demo

# The suite in two phases: the tests that start processes or Zenoh sessions or time themselves (marker `serial`)
# one at a time, the rest (pure, deterministic, CPU-bound) on TEST_WORKERS processes (pytest-xdist, a test file per
# worker so module fixtures run once). Both phases run; make fails if either does.
TEST_WORKERS ?= 2
# $(call test_phases,SELECTION): both phases of the tests whose markers match SELECTION ("" for all)
test_phases = $(PY) -m pytest -m "$(1)not serial" -n $(TEST_WORKERS) --dist loadfile; parallel=$$?; \
	$(PY) -m pytest -m "$(1)serial"; serial=$$?; \
	echo "make: parallel phase exit $$parallel, serial phase exit $$serial"; \
	[ $$parallel -eq 0 ] && [ $$serial -eq 0 ]

test: $(STAMP)
	@$(call test_phases,)

test-fast: $(STAMP)
	@$(call test_phases,not slow and )

# Every bench in full, one after the other (hours on 2 cores), then docs/benchmarks.md from their --json records
# (kept in runs/bench). BENCH_ARGS=--quick: the quick runs instead (minutes); BENCH_ARGS="--only NAME ...": some.
BENCH_ARGS ?=
bench: $(STAMP)
	$(PY) -m bench.report --run $(BENCH_ARGS) --outputs runs/bench --out docs/benchmarks.md

lint: $(STAMP)
	$(VENV)/bin/ruff check .

schema: $(STAMP)
	$(VENV)/bin/iea schema

models: $(STAMP)
	$(PY) -m pip install --quiet -e '.[dev,sumo,train]' --config-settings editable_mode=compat
	$(PY) -m models.train_all

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache .hypothesis runs
