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

.PHONY: run test test-fast lint bench clean

# A fresh clone's first `make run` or `make test` spends a minute or two in pip, which -q keeps
# quiet: a line before each long step says what is happening.
$(PY):
	@echo "make: creating $(VENV) with $(PYTHON) and upgrading its pip"
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

CORE := pyproject.toml setup.py $(wildcard agent/core/*.pyx agent/core/*.pxd sim/bodies/*.pyx)
$(STAMP): $(CORE) | $(PY)
	@echo "make: installing pixelswarm and its dependencies into $(VENV) and compiling its core with Cython (a minute or two the first time)"
	$(PY) -m pip install -q -e .
	touch $@

# The sources' bytecode, brought up to date before a run: a robot's process then neither compiles
# them at start nor keeps the compiler's memory, also where PYTHONDONTWRITEBYTECODE stops Python saving it.
# Optimised (-OO) too, for ours, numpy and zenoh: what a robot's own process runs (agent.runtime.interpreter).
BYTECODE := echo "make: bringing the bytecode of our sources, numpy and zenoh up to date (longer the first time)" && \
	$(PY) -m compileall -q -o 0 -o 2 agent coordinator transport sim hardware && \
	$(PY) -c "import compileall, os, re, numpy, zenoh; [compileall.compile_dir(os.path.dirname(m.__file__), \
	quiet=1, optimize=2, rx=re.compile('/tests/')) for m in (numpy, zenoh)]"

# The project and the test tools in one pip call, which stands for `make run`'s install too: each
# `pip install -e` compiles the core again. pyrvo (RVO2's bindings) is the reference of the ORCA
# cross-checks and benchmarks; its metadata pins an old numpy, so it goes in without its dependencies.
$(TSTAMP): $(CORE) | $(PY)
	@echo "make: installing pixelswarm, its dependencies and the test tools (pytest, ruff, mypy, import-linter, rerun-sdk, ...) into $(VENV) and compiling its core with Cython (a few minutes the first time)"
	$(PY) -m pip install -q -e '.[test]'
	@echo "make: installing pyrvo, RVO2's bindings, the reference of the ORCA cross-checks"
	$(PY) -m pip install -q --no-deps 'pyrvo>=0.4'
	touch $(STAMP) $@

run: $(STAMP)
	@$(BYTECODE)
	$(VENV)/bin/pixelswarm run $(SCENE) $(if $(ROBOTS),--robots $(ROBOTS)) $(RUN_ARGS)

# Lint and format (ruff), the packages' import contracts and types (mypy): part of every test run.
LINT := $(VENV)/bin/ruff check . && $(VENV)/bin/ruff format --check . && $(VENV)/bin/lint-imports
lint: $(TSTAMP)
	$(LINT)
	$(VENV)/bin/mypy

# The whole suite: the in-process tests, then the end-to-end runs (marked slow) on every core, then
# the runs on the wall clock, where another run beside them makes robots late: the light ones (marked
# wall_clock) two at a time, the emulated-hardware ones in one lane, and the busy ones (serial) alone.
# Not one pass of both: the in-process tests' CPU beside the lock-step runs made those runs slower
# than the pass saved, and a viewer beside them missed its robots. Three workers on two cores: a test
# that waits on its processes or the bus leaves a core idle that a third worker takes.
test: test-fast
	$(PY) -m pytest -q -m "slow and not serial and not wall_clock" -n 3 --dist loadgroup --durations=10
	$(PY) -m pytest -q -m "slow and wall_clock" -n 2 --dist loadgroup --durations=5
	$(PY) -m pytest -q -m "slow and serial" --durations=5

# Everyday work: the suite without the end-to-end runs marked slow. --dist loadgroup: a module whose
# costly module fixture its tests share runs on one worker (its xdist_group), which makes it once.
# mypy (a single core for half a minute on a fresh clone) checks the types beside the tests, which
# leave part of the second core idle; its report follows theirs.
test-fast: $(TSTAMP)
	$(LINT)
	@$(BYTECODE)
	@echo "make: the fast tests, with mypy checking the types beside them"
	@$(VENV)/bin/mypy > $(VENV)/mypy.out 2>&1 & types=$$!; \
	$(PY) -m pytest -q -m "not slow" -n 3 --dist loadgroup; tests=$$?; \
	wait $$types; typed=$$?; cat $(VENV)/mypy.out; [ $$tests -eq 0 ] && [ $$typed -eq 0 ]

bench: $(TSTAMP)
	@$(BYTECODE)
	$(PY) -m bench.run_all

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis
