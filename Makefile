# Two commands do all the set-up: `make run` and `make test`.
# Each creates .venv when missing and installs the project from pyproject.toml.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
TSTAMP := $(VENV)/.installed-test
SCENE  ?= paper-sequence
ROBOTS ?=
RUN_ARGS ?=

.PHONY: run test lint bench clean

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install -q -e .
	touch $@

# pyrvo (RVO2's bindings) is the reference of the ORCA cross-checks and benchmarks; its metadata
# pins an old numpy, so it goes in without its dependencies (they are ours already).
$(TSTAMP): pyproject.toml $(STAMP)
	$(PY) -m pip install -q -e '.[test]'
	$(PY) -m pip install -q --no-deps 'pyrvo>=0.4'
	touch $@

run: $(STAMP)
	$(VENV)/bin/pixelswarm run $(SCENE) $(if $(ROBOTS),--robots $(ROBOTS)) $(RUN_ARGS)

lint: $(TSTAMP)
	$(VENV)/bin/lint-imports

test: $(TSTAMP)
	$(VENV)/bin/lint-imports
	$(PY) -m pytest -q

bench: $(TSTAMP)
	$(PY) -m bench.run_all

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis
