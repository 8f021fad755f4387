# Every target sets itself up: a virtual environment in .venv with the package installed.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
WARM   := $(VENV)/.warm
# every source file: an edit to a numba kernel's module invalidates its compiled cache, so
# the warm-up reruns after any edit (a few seconds when nothing needs compiling)
SOURCES := $(shell find touchloc -name '*.py')

.PHONY: demo test bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[test]"
	touch $(STAMP)

# compile the numba kernels now, not in the first timed command (the suite's hang limits)
$(WARM): $(STAMP) $(SOURCES)
	$(VENV)/bin/touchloc warmup
	touch $(WARM)

demo: $(WARM)
	$(VENV)/bin/touchloc demo

# the suite on a worker process per core (at most 4; numba's threads share the cores); each
# test file runs whole in one worker, in order, as its module-level fixtures expect;
# PYTEST_ARGS="-n 0" runs it in one process
test: $(WARM)
	$(PY) -m pytest -q -n auto --maxprocesses 4 --dist loadfile $(PYTEST_ARGS)

# the localisation, planning, identification and DNF sweeps run on a process pool, one worker
# per core (BENCH_ARGS="--executor dask --workers 8" to move them; --resume after an interrupt)
bench: $(WARM)
	$(PY) benchmarks/run.py $(BENCH_ARGS)

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
