# Two commands for a fresh machine:
#   make demo   create .venv, install torchik (CPU build of torch) with what the demo uses, track the built-in
#               walking scenario and write walk.rrd (open it with .venv/bin/rerun walk.rrd) and walk.json
#   make test   create .venv, install torchik with the test extras, run the test suite
# make check: ruff and mypy (what CI runs beside the tests).
# For a CUDA build of torch:  make demo TORCH="torch==2.13.0 --index-url https://download.pytorch.org/whl/cu128"

PYTHON ?= python3
VENV ?= .venv
TORCH ?= torch==2.13.0
BIN := $(VENV)/bin

.PHONY: demo test check bench clean

$(VENV)/.torch:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q $(TORCH)
	touch $@

$(VENV)/.torchik: $(VENV)/.torch pyproject.toml
	$(BIN)/pip install -q -e ".[viz,robots]"
	touch $@

$(VENV)/.torchik-test: $(VENV)/.torch pyproject.toml
	$(BIN)/pip install -q -e ".[test]"
	touch $@

$(VENV)/.torchik-dev: $(VENV)/.torch pyproject.toml
	$(BIN)/pip install -q -e ".[dev]"
	touch $@

demo: $(VENV)/.torchik
	$(BIN)/torchik models
	$(BIN)/torchik track --scenario walking --model human66 --rrd walk.rrd --report walk.json --force
	@echo "open the recording with: $(BIN)/rerun walk.rrd"

test: $(VENV)/.torchik-test
	$(BIN)/python -m pytest -q -n 2 --dist loadfile  # both cores; a module's tests on one worker (its fixtures built once)

check: $(VENV)/.torchik-dev
	$(BIN)/ruff check torchik tests experiments
	$(BIN)/mypy

bench: $(VENV)/.torchik-test
	$(BIN)/python experiments/bench_kinematics.py

clean:
	rm -rf $(VENV)
