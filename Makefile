# Set-up is part of every target: a fresh clone needs only `make demo` or `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
PACKAGES := protocol firmware_py hil_emulator host bootloader tools

.PHONY: all install test test-long test-fast lint typecheck demo bench docs clean compiled clean-compiled

all: test

$(STAMP): pyproject.toml
	@echo "Setting up $(VENV) (a virtual environment with MuJoCo, numpy and the test tools);"
	@echo "the first time this takes a few minutes."
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $(STAMP)

## The compiled core (mypyc C extensions of the emulator's hot modules, listed in
## tools/build_compiled.py), on by default: the set-up builds it where a C compiler exists
## (once, a few minutes on 2 cores; again when one of its sources changes), saying so in one
## line, or says in one line that the emulator runs pure Python (no compiler, a failed build).
## COMPILED_CORE=no skips it; LOWCOST_PURE_PYTHON=1 removes a build at set-up and makes a
## process import the sources although a build exists.  Both builds behave the same; the
## compiled one takes about 1.8x less CPU per simulated second (docs/EMULATOR.md).
COMPILED_CORE ?= yes
PURE_PYTHON := $(filter-out 0,$(LOWCOST_PURE_PYTHON))
## (listed by the venv's Python once it exists: the listing imports the project, whose
## dependencies only the venv has; before the first set-up the core is built anyway)
## A newer source only makes make ask: the set-up's step builds only when the build's record
## of its sources' digests differs from them (a touch, a checkout back, rebuild nothing).
COMPILED_SOURCES := $(if $(filter yes,$(COMPILED_CORE)),$(shell $(if $(wildcard $(PY)),$(PY),$(PYTHON)) -m tools.build_compiled --sources 2>/dev/null))
CORE := $(VENV)/.compiled-core-$(if $(PURE_PYTHON),pure,$(COMPILED_CORE))

$(CORE): $(STAMP) $(COMPILED_SOURCES)
	@$(if $(filter yes,$(COMPILED_CORE)),$(PY) -m tools.build_compiled --setup,true)
	@rm -f $(VENV)/.compiled-core-*
	@touch $(CORE)

install: $(CORE)

lint: $(STAMP)
	$(VENV)/bin/ruff check $(PACKAGES) tests benchmarks

typecheck: $(STAMP)
	$(VENV)/bin/mypy $(PACKAGES) benchmarks tests

## make test: lint, type check, then every test but the longest campaigns (marked long; the
## slot update's 200 cases, the one-slot flashing's 25: make test-long), slow ones included, on TEST_WORKERS pytest-xdist
## workers: a test file runs whole on one worker (the campaigns' independent shards spread
## over both), and the wall-clock tests run one at a time on one of them (tests/conftest.py).
## About 15 minutes from a fresh clone on an idle 2-core machine, set-up and compiled core
## included (11 minutes of tests); about 11.5 with the set-up done.  pytest --cpu-durations=N
## says where the time goes (per test, file and worker).
## TEST_WORKERS=0: one process.
TEST_WORKERS ?= 2
PYTEST_PARALLEL := $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS))
test: lint typecheck $(CORE)
	$(PY) -m pytest -q $(PYTEST_PARALLEL) -m "not long"

## make test-long: what make test runs, and the long campaigns.
test-long: lint typecheck $(CORE)
	$(PY) -m pytest -q $(PYTEST_PARALLEL)

## make test-fast: skip the tests marked slow (and long).
test-fast: $(CORE)
	$(PY) -m pytest -q $(PYTEST_PARALLEL) -m "not slow and not long"

demo: $(CORE)
	$(PY) -m tools.demo $(if $(PROFILE),--profile $(PROFILE))

bench: $(CORE)
	$(PY) -m benchmarks

docs: $(STAMP)
	$(PY) -m protocol.docgen > docs/PROTOCOL.md

## make compiled: build the compiled core now (beside the sources; needs a C compiler),
## saying what fails where it cannot.
compiled: $(STAMP)
	$(PY) -m tools.build_compiled

## make clean-compiled: remove those extensions and build/ (pure Python until the next
## set-up builds them again; LOWCOST_PURE_PYTHON=1 make ... keeps pure Python).
clean-compiled:
	$(if $(wildcard $(PY)),$(PY),$(PYTHON)) -m tools.build_compiled --clean
	rm -f $(VENV)/.compiled-core-*

clean: clean-compiled
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
