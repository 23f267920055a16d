"""Test-wide settings: generated MAVLink bindings go to a per-run temp cache, not ~/.cache; hypothesis has no
per-example deadline (an absolute-time assert: one example that took 277 ms, against the default 200, failed a
run on a loaded 2-core machine; tests that want a time budget set their own). Under `make test`'s work stealing the
files run heavy first in every worker's block (tests/xdist_order.py)."""
from __future__ import annotations

import os

import pytest
from hypothesis import settings

settings.register_profile("mrta", deadline=None)
settings.load_profile("mrta")


def pytest_collection_modifyitems(config, items):
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT") or 0)
    if workers > 1 and getattr(config.option, "dist", "no") == "worksteal":
        from tests import xdist_order
        items[:] = xdist_order.order(items, workers, xdist_order.load_table())


@pytest.fixture(scope="session", autouse=True)
def _mrta_cache(tmp_path_factory):
    os.environ.setdefault("MRTA_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "mrta-cache"))
    yield
