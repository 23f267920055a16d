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

# The installer: uv, which downloads in parallel and byte-compiles on every core (a fresh .venv in 24.9 s against
# pip's 50.7 s, both with empty caches, measured 2026-12-04; the same packages at the same versions). pip remains the
# fallback, and `make INSTALLER=pip` chooses it: uv reads UV_INDEX_URL, not pip.conf, so a site whose packages come
# from a mirror named only in pip.conf falls back to pip when uv cannot reach an index.
INSTALLER ?= uv
UV := $(VENV)/bin/uv pip install -q --python $(PY) --compile-bytecode

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@if [ "$(INSTALLER)" = uv ] && $(PY) -m pip install -q 'uv>=0.5' && $(UV) -e '.[test]' && \
	    $(UV) --no-deps $(MAVPROXY); then echo "installed with uv"; else \
	  echo "installing with pip"; $(PY) -m pip install -q --upgrade pip && $(PY) -m pip install -q -e '.[test]' && \
	  $(PY) -m pip install -q --no-deps $(MAVPROXY); fi
	@touch $(STAMP)

# The project's own modules compiled to bytecode once, on every core, before the processes that import them: where
# PYTHONDONTWRITEBYTECODE is set (this machine, and CI) nothing else writes them, and every daemon, CLI and pytest
# worker process would compile its imports from source again (about 0.3 s of CPU a process; the process-heavy test
# files take a third less CPU with them: docs/benchmarks.md). A stale file is never used: Python checks the source's
# time and size.
BYTECODE := $(PY) -m compileall -q -j 0 runtime sitl tests

run: $(STAMP)
	@$(BYTECODE)
	$(VENV)/bin/mrta sitl run configs/fleets/create2_4.yaml --manifest $(VENV)/manifest.json

# pytest-xdist: one worker more than the cores (about a fifth of the suite is daemon processes waiting on the wall
# clock, and the extra worker keeps the cores busy meanwhile), work stealing so the slow SITL runs do not queue on one
# worker; the 15 slowest tests are printed at the end (docs/benchmarks.md#the-test-suite)
WORKERS ?= $(shell echo $$(( $$(nproc) + 1 )))
XDIST := -n $(WORKERS) --dist worksteal --durations=15

# PYTHONDONTWRITEBYTECODE is cleared for the suite alone so that pytest keeps the test modules it rewrites for its
# assertions: every worker collects the whole suite, 11 s of CPU each with the rewriting redone, 4 s with it kept.
PYTEST := PYTHONDONTWRITEBYTECODE= $(PY) -m pytest

test: $(STAMP)
	@$(BYTECODE)
	$(PYTEST) -q $(XDIST) $(PYTEST_ARGS)

test-fast: $(STAMP)
	@$(BYTECODE)
	$(PYTEST) -q -m 'not slow' $(XDIST) $(PYTEST_ARGS)

bench: $(STAMP)
	$(PY) benchmarks/sitl_speedup.py

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
