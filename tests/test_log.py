"""runtime.log: the robot id in every record, and a handler that follows sys.stderr."""
from __future__ import annotations

import io
import logging
import sys

import pytest

from runtime import log


@pytest.fixture(autouse=True)
def _root_logger_restored():
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    yield
    root.handlers[:] = handlers
    root.setLevel(level)


def test_records_carry_the_robot_id_and_go_to_the_stderr_of_the_moment(monkeypatch):
    first = io.StringIO()
    monkeypatch.setattr(sys, "stderr", first)
    log.setup("INFO")
    second = io.StringIO()
    monkeypatch.setattr(sys, "stderr", second)
    first.close()                       # as a host that swapped stderr does with the old one
    log.get_logger("test.log", 4).warning("wheel %d slipped", 2)
    logging.getLogger("mrta.test.plain").warning("no robot here")
    lines = second.getvalue().splitlines()
    assert "robot=4 mrta.test.log: wheel 2 slipped" in lines[0]
    assert "robot=- mrta.test.plain: no robot here" in lines[1]


def test_an_explicit_stream_is_kept():
    out = io.StringIO()
    log.setup("INFO", out)
    log.get_logger("test.log", 9).info("ready")
    assert "robot=9 mrta.test.log: ready" in out.getvalue()
