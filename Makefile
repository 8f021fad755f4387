# Every target sets itself up: a virtual environment in .venv with the package installed.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[test]"
	$(VENV)/bin/touchloc warmup   # compile the numba kernels now, once, not in the first command
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/touchloc demo

# the suite on a worker process per core (at most 4; numba's threads share the cores); each
# test file runs whole in one worker, in order, as its module-level fixtures expect;
# PYTEST_ARGS="-n 0" runs it in one process
test: $(STAMP)
	$(PY) -m pytest -q -n auto --maxprocesses 4 --dist loadfile $(PYTEST_ARGS)

# the localisation, planning, identification and DNF sweeps run on a process pool, one worker
# per core (BENCH_ARGS="--executor dask --workers 8" to move them; --resume after an interrupt)
bench: $(STAMP)
	$(PY) benchmarks/run.py $(BENCH_ARGS)

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
