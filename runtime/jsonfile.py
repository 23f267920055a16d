"""Read a JSON input file for a CLI (any failure is one InputError line naming the file); write one whole."""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

from runtime.errors import InputError


MAX_BYTES = 64 << 20        # a JSON input's size


def read_json(path: str | Path, what: str = "JSON file") -> Any:
    """Parsed JSON from ``path`` (``-`` reads stdin); ``what`` names the expected file in errors."""
    name = str(path) if str(path).isprintable() else repr(str(path))
    try:
        if str(path) == "-":
            text = sys.stdin.read(MAX_BYTES + 1)
        else:
            with open(path, "rb") as fh:
                text = fh.read(MAX_BYTES + 1).decode("utf-8")
    except OSError as exc:
        raise InputError(f"{name}: expected a readable {what} ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise InputError(f"{name}: expected a {what} in UTF-8 text") from None
    if len(text) > MAX_BYTES:
        raise InputError(f"{name}: expected a {what} of at most {MAX_BYTES} bytes")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{name}: expected JSON ({exc.msg} at line {exc.lineno} column {exc.colno})") from None
    except RecursionError:
        raise InputError(f"{name}: expected JSON (nested too deeply)") from None
    except ValueError as exc:           # an integer of more digits than Python converts (4300)
        raise InputError(f"{name}: expected JSON numbers Python can read ({str(exc).split(':')[0]})") from None


def write_json(path: str | Path, data: Any) -> None:
    """``data`` as JSON at ``path``, replaced whole (a reader never sees half a file: a daemon's --stats)."""
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as fh:
        json.dump(data, fh, default=str)
    os.replace(tmp, path)
