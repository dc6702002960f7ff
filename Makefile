# The two commands of the README:
#   make demo   set everything up and run the main job on defaults (writes results/)
#   make test   set everything up and run ruff, mypy and every test (slow ones with small settings)

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
CORE   := $(VENV)/.core
export MUJOCO_GL ?= egl

.PHONY: install demo test test-fast lint bench suite clean

# The core (pip install dynoplan) on the pinned CPU build of PyTorch.
$(CORE): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	# Pin the CPU build of PyTorch first: an unpinned torch pulls a multi-GB CUDA build.
	$(BIN)/pip install --quiet torch==2.13.0
	touch $(CORE)

# One stamp per extra: .venv/.installed-gear and -ray (make demo: the gear run's episodes on
# every CPU), .venv/.installed-dev (make test).
$(VENV)/.installed-%: $(CORE) pyproject.toml
	$(BIN)/pip install --quiet -e ".[$*]"
	touch $@

install: $(VENV)/.installed-dev

demo: $(VENV)/.installed-gear $(VENV)/.installed-ray
	$(BIN)/dynoplan random-walk --out results/random-walk
	$(BIN)/dynoplan gear run --out results/gear

lint: $(VENV)/.installed-dev
	$(BIN)/ruff check .
	$(BIN)/mypy

# Tests on TEST_WORKERS processes (pytest-xdist); the tests sharing a costly session
# fixture (a quick gear run, a Ray runtime) run on one worker (tests/conftest.py).
TEST_WORKERS ?= 2
test: lint
	$(BIN)/pytest -m "not slow" -n $(TEST_WORKERS) --dist loadgroup --durations=10
	$(BIN)/pytest -m slow -n $(TEST_WORKERS) --dist loadgroup --durations=15

test-fast: $(VENV)/.installed-dev
	$(BIN)/pytest -m "not slow" -x

bench: $(VENV)/.installed-dev
	$(BIN)/python benchmarks/planner.py

# The composition suite (docs/suite.md) in its own environment: Meta-World pins mujoco
# 3.3.0, which cannot sit beside the gear's MuJoCo.
SUITE_VENV := .venv-suite
$(SUITE_VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(SUITE_VENV)
	$(SUITE_VENV)/bin/pip install --quiet --upgrade pip
	$(SUITE_VENV)/bin/pip install --quiet torch==2.13.0
	$(SUITE_VENV)/bin/pip install --quiet -e ".[suite]"
	touch $@

suite: $(SUITE_VENV)/.installed
	$(SUITE_VENV)/bin/python -m benchmarks.suite --seeds 0,1,2 --episodes 30 --jobs 2 \
		--out results/suite

clean:
	rm -rf $(VENV) $(SUITE_VENV) results .mypy_cache .ruff_cache .pytest_cache
