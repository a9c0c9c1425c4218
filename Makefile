# Two entry points do all set-up on a fresh machine: `make run` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test lint bench clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[dev]"
	touch $(STAMP)

run: $(STAMP)
	MUJOCO_GL=egl $(BIN)/wbc demo --out out --force

lint: $(STAMP)
	$(BIN)/ruff check .

test: lint
	MUJOCO_GL=egl $(BIN)/python -m pytest

bench: $(STAMP)
	$(BIN)/python -m benchmarks --out out/bench

clean:
	rm -rf $(VENV) out
