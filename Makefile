# Two commands for a newcomer: `make demo` and `make test`. Both create .venv.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test test-all lint format bench venv clean unitree

venv: $(STAMP)

$(STAMP): pyproject.toml setup.py
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@echo "[make] installing quadmanip and its dependencies into $(VENV) (first run takes a few minutes)"
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	@touch $(STAMP)

# The Unitree SDK2 adapter's extra (docs/hardware.md): Debian's Cyclone DDS library, the
# Python binding built against it (CYCLONEDDS_HOME: a prefix of links to where Debian
# puts lib/, include/, bin/), and the SDK's Python package. The SDK package is installed
# without its dependencies: it asks for opencv-python, which would clash with the
# headless OpenCV the project uses, and it needs only cyclonedds and numpy.
UNITREE_STAMP := $(VENV)/.unitree-installed
DDS_HOME := $(abspath $(VENV))/cyclonedds-home
DDS_LIB := /usr/lib/$(shell gcc -dumpmachine 2>/dev/null || echo x86_64-linux-gnu)

unitree: $(UNITREE_STAMP)

$(UNITREE_STAMP): $(STAMP)
	@dpkg -s cyclonedds-dev >/dev/null 2>&1 || { \
	  echo "[make] installing Debian's cyclonedds-dev (the DDS library of the Unitree SDK)"; \
	  if [ "$$(id -u)" = 0 ]; then apt-get install -y -q cyclonedds-dev >/dev/null || \
	    { apt-get update -q >/dev/null && apt-get install -y -q cyclonedds-dev >/dev/null; }; \
	  else sudo apt-get install -y -q cyclonedds-dev; fi; }
	@mkdir -p $(DDS_HOME)/lib $(DDS_HOME)/bin
	@ln -sfn /usr/include $(DDS_HOME)/include
	@ln -sf $(DDS_LIB)/libddsc.so $(DDS_LIB)/libcycloneddsidl.so $(DDS_HOME)/lib/
	@ln -sfn $(DDS_LIB)/cmake $(DDS_HOME)/lib/cmake
	@ln -sf /usr/bin/idlc $(DDS_HOME)/bin/
	@echo "[make] building the Cyclone DDS Python binding and installing the Unitree SDK"
	CYCLONEDDS_HOME=$(DDS_HOME) $(PY) -m pip install -q -e '.[dev,unitree]'
	$(PY) -m pip install -q --no-deps unitree-sdk2py-dimos==1.0.3
	@touch $(UNITREE_STAMP)

# A short tidy-up in the living room (two objects, drawers shut): 7-10 min on 2 cores (428 s wall on 2026-12-03 evening, 608 s on a slower night).
DEMO_ARGS ?= --scenario short-20 --json demo-output/tidyup.json --rerun demo-output/tidyup.rrd \
	--film demo-output/film --set behavior.drawers.places=[] --set 'behavior.task.zones=["living_floor","living_table"]'

demo: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(VENV)/bin/quadmanip tidyup $(DEMO_ARGS)

test: $(STAMP) $(UNITREE_STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m pytest

test-all: $(STAMP) $(UNITREE_STAMP)
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
	-MUJOCO_GL=$${MUJOCO_GL:-egl} $(VENV)/bin/quadmanip bench perception --json bench-results/perception.json --parts detect,probe

clean:
	rm -rf $(VENV) build *.egg-info bench-results demo-output
