# The two commands: `make run` and `make test`. Both create .venv on demand.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
# tests/test_mavproxy_station.py drives the real MAVProxy, headless. Installed without its requirements: they include
# vtk (565 MB) and opencv (288 MB) for its 3D map and camera modules, which a headless station never imports, and
# which cost about 12 s of every fresh make test; what its core imports (pymavlink, pyserial, numpy) is in the base.
MAVPROXY := 'MAVProxy>=1.8.75'

.PHONY: run test test-fast bench clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	$(PY) -m pip install -q --no-deps $(MAVPROXY)
	@touch $(STAMP)

run: $(STAMP)
	$(VENV)/bin/mrta sitl run configs/fleets/create2_4.yaml --manifest $(VENV)/manifest.json

# pytest-xdist: one worker more than the cores (about a fifth of the suite is daemon processes waiting on the wall
# clock, and the extra worker keeps the cores busy meanwhile), work stealing so the slow SITL runs do not queue on one
# worker; the 15 slowest tests are printed at the end (docs/benchmarks.md#the-test-suite)
WORKERS ?= $(shell echo $$(( $$(nproc) + 1 )))
XDIST := -n $(WORKERS) --dist worksteal --durations=15

test: $(STAMP)
	$(PY) -m pytest -q $(XDIST) $(PYTEST_ARGS)

test-fast: $(STAMP)
	$(PY) -m pytest -q -m 'not slow' $(XDIST) $(PYTEST_ARGS)

bench: $(STAMP)
	$(PY) benchmarks/sitl_speedup.py

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
