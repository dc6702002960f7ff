# The two commands of the README:
#   make demo   set everything up and run the main job on defaults (writes results/)
#   make test   set everything up and run ruff, mypy and every test (slow ones with small settings)

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
export MUJOCO_GL ?= egl

.PHONY: install demo test test-fast lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	# Pin the CPU build of PyTorch first: an unpinned torch pulls a multi-GB CUDA build.
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e ".[dev]"
	touch $(STAMP)

install: $(STAMP)

demo: install
	$(BIN)/dynoplan random-walk --out results/random-walk
	$(BIN)/dynoplan gear run --out results/gear

lint: install
	$(BIN)/ruff check .
	$(BIN)/mypy

test: lint
	$(BIN)/pytest -m "not slow"
	$(BIN)/pytest -m slow

test-fast: install
	$(BIN)/pytest -m "not slow" -x

bench: install
	$(BIN)/python benchmarks/planner.py

clean:
	rm -rf $(VENV) results .mypy_cache .ruff_cache .pytest_cache
