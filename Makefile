# Two commands for a newcomer: `make demo` and `make test`. Both create .venv.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test test-all lint format bench venv clean

venv: $(STAMP)

$(STAMP): pyproject.toml setup.py
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@echo "[make] installing quadmanip and its dependencies into $(VENV) (first run takes a few minutes)"
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	@touch $(STAMP)

demo: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(VENV)/bin/quadmanip demo

test: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m pytest

test-all: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m pytest -m ''

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(PY) -m pytest -q tests/unit/test_layers.py  # import-linter's layer contracts

format: $(STAMP)
	$(VENV)/bin/ruff format .
	$(VENV)/bin/ruff check --fix .

# Every benchmark writes JSON to bench-results/ (numbers and commands: docs/benchmarks.md).
# The manipulation matrix runs over the full stack, one fresh stack per trial: about an hour.
# A benchmark whose module is not installed yet says so and the others still run.
bench: $(STAMP)
	mkdir -p bench-results
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(VENV)/bin/quadmanip bench bus --json bench-results/bus.json
	-MUJOCO_GL=$${MUJOCO_GL:-egl} $(VENV)/bin/quadmanip bench sim --json bench-results/sim.json
	-MUJOCO_GL=$${MUJOCO_GL:-egl} $(VENV)/bin/quadmanip bench locomotion --json bench-results/locomotion.json
	-MUJOCO_GL=$${MUJOCO_GL:-egl} $(VENV)/bin/quadmanip bench manipulation --json bench-results/manipulation.json

clean:
	rm -rf $(VENV) build *.egg-info bench-results demo-output
