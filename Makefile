# Two commands for a fresh machine:
#   make demo   create .venv, install torchik (CPU build of torch), track the built-in walking scenario and
#               write walk.rrd (open it with .venv/bin/rerun walk.rrd) and walk.json
#   make test   create .venv, install torchik with the test extras, run the test suite
# For a CUDA build of torch:  make demo TORCH="torch==2.13.0 --index-url https://download.pytorch.org/whl/cu128"

PYTHON ?= python3
VENV ?= .venv
TORCH ?= torch==2.13.0
BIN := $(VENV)/bin

.PHONY: demo test bench clean

$(VENV)/.torch:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q $(TORCH)
	touch $@

$(VENV)/.torchik: $(VENV)/.torch pyproject.toml
	$(BIN)/pip install -q -e .
	touch $@

$(VENV)/.torchik-test: $(VENV)/.torch pyproject.toml
	$(BIN)/pip install -q -e ".[test]"
	touch $@

demo: $(VENV)/.torchik
	$(BIN)/torchik models
	$(BIN)/torchik track --scenario walking --model human66 --rrd walk.rrd --report walk.json --force
	@echo "open the recording with: $(BIN)/rerun walk.rrd"

test: $(VENV)/.torchik-test
	$(BIN)/python -m pytest -q

bench: $(VENV)/.torchik-test
	$(BIN)/python experiments/bench_kinematics.py

clean:
	rm -rf $(VENV)
