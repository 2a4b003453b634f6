# Two entry points: `make repro` (the whole pipeline) and `make test` (the test suite).
# Both create or reuse the virtual environment in .venv/.

SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
PIP := $(BIN)/python -m pip install --quiet --disable-pip-version-check -c constraints.txt

export PATH := $(abspath $(BIN)):$(PATH)
export DVC_NO_ANALYTICS := 1
export PYTHONHASHSEED := 0

.PHONY: venv test repro params bench clean-venv

venv: $(STAMP)

$(STAMP): requirements.txt constraints.txt pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(PIP) -r requirements.txt
	$(PIP) --no-deps -e .
	@touch $@

test: $(STAMP)
	$(BIN)/python -m pytest

# DVC composes params.yaml from conf/ only on `dvc exp run`; compose it here too so an
# edit to conf/ is never silently ignored by `dvc repro`.
params: $(STAMP)
	$(BIN)/python -m nanosysid.config compose

repro: params
	$(BIN)/dvc repro
	$(BIN)/python -m nanosysid.readme

bench: $(STAMP)
	@for f in benchmarks/*.py; do echo "== $$f"; $(BIN)/python $$f || exit 1; done

clean-venv:
	rm -rf $(VENV)
