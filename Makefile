# Set-up is part of every target: a fresh clone needs only `make demo` or `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
PACKAGES := protocol firmware_py hil_emulator host bootloader tools

.PHONY: all install test test-fast lint typecheck demo bench docs clean compiled clean-compiled

all: test

$(STAMP): pyproject.toml
	@echo "Setting up $(VENV) (a virtual environment with MuJoCo, numpy and the test tools);"
	@echo "the first time this takes a few minutes."
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

lint: $(STAMP)
	$(VENV)/bin/ruff check $(PACKAGES) tests benchmarks

typecheck: $(STAMP)
	$(VENV)/bin/mypy $(PACKAGES)

## make test: lint, type check, then every test (slow ones included), on TEST_WORKERS
## pytest-xdist workers: a test file runs whole on one worker, and the wall-clock tests
## run one at a time on one of them (tests/conftest.py).  TEST_WORKERS=0: one process.
TEST_WORKERS ?= 2
PYTEST_PARALLEL := $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS))
test: lint typecheck
	$(PY) -m pytest -q $(PYTEST_PARALLEL)

## make test-fast: skip the tests marked slow.
test-fast: $(STAMP)
	$(PY) -m pytest -q $(PYTEST_PARALLEL) -m "not slow"

demo: $(STAMP)
	$(PY) -m tools.demo

bench: $(STAMP)
	$(PY) -m benchmarks

docs: $(STAMP)
	$(PY) -m protocol.docgen > docs/PROTOCOL.md

## make compiled: optional compiled core, mypyc C extensions of the emulator's hot modules
## (listed in tools/build_compiled.py) beside their sources; needs a C compiler.  Nothing
## else builds it: the pure-Python modules stay the default.
compiled: $(STAMP)
	$(PY) -m tools.build_compiled

## make clean-compiled: remove those extensions and build/ (back to pure Python).
clean-compiled:
	$(if $(wildcard $(PY)),$(PY),$(PYTHON)) -m tools.build_compiled --clean

clean: clean-compiled
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
