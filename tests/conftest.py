"""Test-wide settings: generated MAVLink bindings go to a per-run temp cache, not ~/.cache."""
from __future__ import annotations

import os

import pytest


@pytest.fixture(scope="session", autouse=True)
def _mrta_cache(tmp_path_factory):
    os.environ.setdefault("MRTA_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "mrta-cache"))
    yield
