# Two commands do all the set-up: `make run` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
TSTAMP := $(VENV)/.installed-test
ROBOTS ?= 20
SCENE  ?= circle

.PHONY: run test lint bench clean

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install -q -e .
	touch $@

$(TSTAMP): pyproject.toml $(STAMP)
	$(PY) -m pip install -q -e '.[test]'
	# pyrvo (RVO2 bindings) is the reference for cross-checks; its metadata pins an old numpy, hence --no-deps.
	$(PY) -m pip install -q --no-deps 'pyrvo>=0.4'
	touch $@

run: $(STAMP)
	$(VENV)/bin/pixelswarm run $(SCENE) --robots $(ROBOTS)

lint: $(TSTAMP)
	$(VENV)/bin/lint-imports

test: $(TSTAMP)
	$(VENV)/bin/lint-imports
	$(PY) -m pytest -q

bench: $(TSTAMP)
	$(PY) -m bench.run_all

clean:
	rm -rf $(VENV) runs .pytest_cache
