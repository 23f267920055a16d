"""Read a JSON input file for a CLI: any failure is one InputError line naming the file."""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from runtime.errors import InputError


def read_json(path: str | Path, what: str = "JSON file") -> Any:
    """Parsed JSON from ``path`` (``-`` reads stdin); ``what`` names the expected file in errors."""
    name = str(path)
    try:
        text = sys.stdin.read() if name == "-" else Path(path).read_text()
    except OSError as exc:
        raise InputError(f"{name}: expected a readable {what} ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise InputError(f"{name}: expected a {what} in UTF-8 text") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{name}: expected JSON ({exc.msg} at line {exc.lineno} column {exc.colno})") from None
    except RecursionError:
        raise InputError(f"{name}: expected JSON (nested too deeply)") from None
