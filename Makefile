# The two commands: `make run` and `make test`. Both create .venv on demand.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp

.PHONY: run test test-fast bench clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	@touch $(STAMP)

run: $(STAMP)
	$(VENV)/bin/mrta sitl run configs/fleets/create2_4.yaml --manifest $(VENV)/manifest.json

# one pytest-xdist worker per core, work stealing (the slow SITL runs do not all end up on one worker); the 15
# slowest tests are printed at the end (docs/benchmarks.md#the-test-suite)
XDIST := -n auto --dist worksteal --durations=15

test: $(STAMP)
	$(PY) -m pytest -q $(XDIST) $(PYTEST_ARGS)

test-fast: $(STAMP)
	$(PY) -m pytest -q -m 'not slow' $(XDIST) $(PYTEST_ARGS)

bench: $(STAMP)
	$(PY) benchmarks/sitl_speedup.py

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
