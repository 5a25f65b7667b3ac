# Two commands on a fresh machine: `make demo` and `make test`. Each builds the venv it needs.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: setup demo test bench lint clean

setup: $(STAMP)

# Idempotent: rebuilt only when the project's dependency list changes.
# torch==2.13.0 goes in first: it is the CPU wheel; an unpinned torch would pull a CUDA build.
$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -e ".[rl,bridge,render,bench,dev,ray,camera]"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/swarm-phd demo

test: $(STAMP)
	$(PY) -m pytest

# Figures go to benchmarks/RESULTS.md by hand, with the date and the machine.
bench: $(STAMP)
	$(VENV)/bin/swarm-phd bench --json runs/bench/env.json
	$(PY) benchmarks/bench_sensors.py
	$(PY) benchmarks/bench_detection_curves.py --json runs/bench/detection_curves.json
	$(PY) benchmarks/bench_lidar_pd_calibration.py --json runs/bench/lidar_pd_calibration.json
	$(PY) benchmarks/bench_bank.py --json runs/bench/bank.json
	$(PY) benchmarks/bench_phd_vs_stonesoup.py --json runs/bench/phd_vs_stonesoup.json
	$(PY) benchmarks/bench_scaling.py --json runs/bench/scaling.json
	$(PY) benchmarks/bench_feed_profiles.py --sizes 20,1000
	$(PY) benchmarks/bench_load.py --steps 300 --repeats 2 --json runs/bench/load.json
	$(PY) benchmarks/bench_set_pooling.py --json runs/bench/set_pooling.json
	$(PY) benchmarks/bench_training.py --rollouts 2 --json runs/bench/training.json

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

clean:
	rm -rf $(VENV) runs .pytest_cache
