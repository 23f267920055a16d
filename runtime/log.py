"""Logging with the robot id in every record.

``get_logger("driver", robot_id=3)`` returns a LoggerAdapter whose records carry ``robot``; the
format set by :func:`setup` prints it.  Records from code that has no robot show ``robot=-``.
"""
from __future__ import annotations

import logging
import sys

FORMAT = "%(asctime)s %(levelname)s robot=%(robot)s %(name)s: %(message)s"


class _RobotDefault(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        if not hasattr(record, "robot"):
            record.robot = "-"
        return True


class RobotAdapter(logging.LoggerAdapter):
    def process(self, msg, kwargs):
        extra = dict(kwargs.get("extra") or {})
        extra.setdefault("robot", self.extra["robot"])
        kwargs["extra"] = extra
        return msg, kwargs


def get_logger(name: str, robot_id: int | str | None = None) -> logging.LoggerAdapter:
    return RobotAdapter(logging.getLogger(f"mrta.{name}"), {"robot": "-" if robot_id is None else robot_id})


class _Stderr(logging.StreamHandler):
    """Writes to whatever ``sys.stderr`` is at the time of the record, not the one at setup (a host that swaps
    stderr, as pytest's capture does, and closes the old one then gets no 'I/O operation on closed file')."""

    def __init__(self):
        logging.Handler.__init__(self)

    @property
    def stream(self):
        return sys.stderr


def setup(level: int | str = logging.INFO, stream=None) -> None:
    root = logging.getLogger()
    handler = logging.StreamHandler(stream) if stream is not None else _Stderr()
    handler.setFormatter(logging.Formatter(FORMAT))
    handler.addFilter(_RobotDefault())
    root.handlers[:] = [handler]
    root.setLevel(level)
