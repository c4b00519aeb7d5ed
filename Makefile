# kpioed-drake. `make demo` and `make test` set everything up on a fresh machine.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
# one BLAS thread a process: the tests run a process per core, and the small dense problems of a
# fit gain nothing from more threads (several processes with several threads each spin-wait)
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1
STAMP  := $(VENV)/.installed-stamp

.PHONY: setup demo test test-slow lint format bench tables tables-quick models clean

setup: $(STAMP)

# Idempotent and fast when nothing changed: reinstalls only when pyproject.toml is newer.
$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev,dask]'
	touch $(STAMP)

demo: setup   ## KPI design for kr16 in the default cell: heuristic vs standard vs KPI, CSV + picture
	$(PY) -c "from kpioed_drake.design import demo; demo('out/demo')"

test: setup   ## the default test run (slow studies excluded), one worker per core (pytest-xdist)
	$(PY) -m pytest -q -n auto

test-slow: setup   ## the slow tests only (full-size checks)
	$(PY) -m pytest -q -m slow

lint: setup   ## ruff, and the type checker (mypy) on the modules pyproject.toml lists
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy

format: setup
	$(VENV)/bin/ruff format .
	$(VENV)/bin/ruff check --fix .

bench: setup   ## benchmark report (ratios within one run) -> bench/results.md; certificate -> bench/bound_results.md; first runs -> bench/cold_results.md
	$(PY) bench/run_bench.py
	$(PY) bench/bound_bench.py
	$(PY) bench/cold_bench.py

tables: setup   ## full study: paper Tables 6-8, Figures 7-8 -> studies/results
	$(VENV)/bin/kpioed study --out studies/results

tables-quick: setup   ## quick study (3 KUKA + 6 notional robots) -> out/tables-quick
	$(VENV)/bin/kpioed study --quick --out out/tables-quick

models: setup   ## re-author the robot model files (q_work by Drake IK)
	$(PY) studies/make_models.py

clean:
	rm -rf out .pytest_cache .ruff_cache
