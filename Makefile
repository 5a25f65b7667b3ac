# Two commands on a fresh machine: `make demo` and `make test`. Each builds the venv it needs.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip install --quiet
TORCH_VERSION := 2.13.0
# torchvision: only BenchMARL's videos use it (the marl extra pulls it); the build made for torch.
TORCHVISION_VERSION := 0.28.0
# The PyTorch CPU wheel index. On an ordinary Linux machine a plain `pip install torch` pulls
# the CUDA build (several GB); the networks here are tiny and run on the CPU.
TORCH_CPU_INDEX := https://download.pytorch.org/whl/cpu
# What `make test` installs: everything the test suite imports.
TEST_EXTRAS := rl,bridge,render,bench,dev,ray,docs,marl,camera

# Stamps: each step reruns only when the project's dependency list changes.
CORE := $(VENV)/.core
TORCH := $(VENV)/.torch
FULL := $(VENV)/.full

.PHONY: setup demo test bench lint docs results clean

setup: $(FULL)

# The demo's install: the core dependencies only (no torch, Ray or Stone Soup).
$(CORE): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) --upgrade pip
	$(PIP) -e .
	touch $@

# The CPU build of torch (and torchvision): the PyTorch CPU index first, with a short timeout;
# where that index cannot be reached, the plain torch pin (a machine with the CPU wheel on disk
# takes that; the marl extra then brings the registry's torchvision, which nothing here imports).
$(TORCH): $(CORE)
	$(PY) -c "import torch, sys; sys.exit(torch.__version__.split('+')[0] != '$(TORCH_VERSION)')" 2>/dev/null \
	  || timeout 300 $(PIP) --timeout 15 --retries 1 torch==$(TORCH_VERSION) torchvision==$(TORCHVISION_VERSION) \
	       --index-url $(TORCH_CPU_INDEX) \
	  || $(PIP) torch==$(TORCH_VERSION)
	touch $@

# Training, the bridge, benchmarks, docs and the test tools; torch is already satisfied.
$(FULL): $(TORCH) pyproject.toml
	$(PIP) -e ".[$(TEST_EXTRAS)]"
	$(PY) -m pip check
	touch $@

demo: $(CORE)
	$(VENV)/bin/swarm-phd demo

test: $(FULL)
	$(PY) -m pytest

# Figures go to benchmarks/RESULTS.md by hand, with the date and the machine.
bench: $(FULL)
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

# The docs site (MkDocs + Material, strict: a warning fails it) into build/docs/; needs the
# `docs` extra. The API, CLI and config references are generated during the build.
docs: $(FULL)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --site-dir build/docs

# docs/results.md from the result files under experiments/results/ (tests/test_docs.py checks
# that the page is exactly what this writes).
results: $(FULL)
	$(PY) experiments/results_page.py

lint: $(FULL)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

clean:
	rm -rf $(VENV) runs .pytest_cache
