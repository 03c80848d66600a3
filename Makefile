# demoforge: `make evaluate` runs the main job, `make test` the tests. Both set up everything first.
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.demoforge-setup
export MUJOCO_GL ?= egl
export PREFECT_HOME ?= $(CURDIR)/.prefect
# test processes (pytest-xdist, whole files per worker): one per core, up to 4 (the suite now rarely waits:
# on 2 cores 2 workers took 343 s, 3 workers 352 s, docs/results/issue-24-tests.md); 0 runs it in this process
PYTEST_WORKERS ?= $(shell n=$$(nproc 2>/dev/null || echo 2); echo $$(( n < 4 ? n : 4 )))

.PHONY: setup test evaluate bench catalog table3 help check-exports

help:  ## list the targets
	@grep -E '^[a-z0-9-]+:.*##' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-16s %s\n", $$1, $$2}'

setup: $(STAMP)  ## create .venv and install pinned dependencies (fast when nothing changed)

$(STAMP): pyproject.toml setup.py requirements/lock.txt requirements/torch.txt requirements/mediapipe.txt \
          requirements/llm.txt scripts/setup.sh scripts/setup_llm.sh scripts/fetch_mediapipe_model.py
	bash scripts/setup.sh
	@touch $@

# PYTEST_ARGS: e.g. tests/lib/sim to run the tests of demoforge/lib/sim only (tests/ mirrors demoforge/)
test: setup  ## run the test suite
	$(PY) -m pytest -n $(PYTEST_WORKERS) --dist loadfile --durations=25 $(PYTEST_ARGS)

evaluate: setup  ## the main job: synthetic takes -> every flow -> reports/
	$(VENV)/bin/demoforge evaluate $(EVALUATE_ARGS)

table3: setup  ## the thesis's Table 3 grid: 5 pouring takes x 10 scenes x every strategy, both protocols (resumable)
	$(VENV)/bin/demoforge table3 --protocol thesis --protocol novel $(TABLE3_ARGS)

bench: setup  ## run the benchmarks, write warehouse/benchmarks and print a table
	$(VENV)/bin/demoforge bench $(BENCH_ARGS)

catalog: setup  ## rebuild warehouse/catalog.duckdb (views over the Parquet tables)
	$(VENV)/bin/demoforge catalog

check-exports: setup  ## optional: load and train on sample exports with the real lerobot and robomimic (own venvs, GBs)
	bash scripts/check_exports.sh
