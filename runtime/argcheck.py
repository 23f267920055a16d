"""Checks of command-line values, made before a command starts its work: numbers in range, and files and folders
it will write.  Each failure is one :class:`~runtime.errors.InputError` line naming the option."""
from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path

from runtime.errors import InputError


def number(value: float | None, option: str, lo: float | None = None, hi: float | None = None, *,
           lo_open: bool = False) -> None:
    """``value`` (None: not given) is a finite number in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``)."""
    if value is None:
        return
    finite = isinstance(value, int) or math.isfinite(value)         # an int may be too large for a float
    if finite and (lo is None or value > lo or (value == lo and not lo_open)) and (hi is None or value <= hi):
        return
    show = lambda x: str(x) if isinstance(x, int) else f"{x:g}"        # noqa: E731
    if lo is not None and hi is not None:
        want = f"a number in {'(' if lo_open else '['}{show(lo)}, {show(hi)}]"
    elif lo is not None:
        want = f"a number {'>' if lo_open else '>='} {show(lo)}"
    else:
        want = "a finite number" + (f" <= {show(hi)}" if hi is not None else "")
    shown = (f"an integer of {int(value.bit_length() * math.log10(2)) + 1} digits"
             if isinstance(value, int) and abs(value) > 10**20 else repr(value))
    raise InputError(f"{option}: expected {want}, got {shown}")


def _probe(folder: Path, option: str, shown: str) -> None:
    """InputError unless a file can be created in ``folder`` (made and removed at once)."""
    try:
        fd, name = tempfile.mkstemp(prefix=".mrta-probe-", dir=folder)
    except OSError as exc:
        raise InputError(f"{option} {shown}: expected a place this user can write ({exc.strerror} in {folder})") \
            from None
    os.close(fd)
    os.unlink(name)


def _nearest_existing(path: Path) -> Path:
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def output_file(path: str | None, option: str, *, make_parents: bool = False) -> None:
    """``path`` (None: not given) can be written: not a folder, and its folder exists (or, with ``make_parents``,
    can be made) and takes new files."""
    if path is None:
        return
    shown = repr(path) if not path.isprintable() else path
    p = Path(path)
    if not path or p.is_dir():
        raise InputError(f"{option} {shown}: expected a file name, got {'a folder' if path else 'nothing'}")
    folder = p.parent
    if not folder.is_dir():
        if not make_parents:
            raise InputError(f"{option} {shown}: expected a file in an existing folder ({folder} is not one)")
        folder = _nearest_existing(folder)
        if not folder.is_dir():
            raise InputError(f"{option} {shown}: expected a path whose folders can be made ({folder} is a file)")
    _probe(folder, option, shown)


def output_dir(path: str | None, option: str) -> None:
    """``path`` (None: not given) is a folder that takes new files, or one that can be made."""
    if path is None:
        return
    shown = repr(path) if not path.isprintable() else path
    p = Path(path)
    if not path:
        raise InputError(f"{option}: expected a folder, got nothing")
    if p.exists() and not p.is_dir():
        raise InputError(f"{option} {shown}: expected a folder, got a file")
    folder = _nearest_existing(p)
    if not folder.is_dir():
        raise InputError(f"{option} {shown}: expected a path whose folders can be made ({folder} is a file)")
    _probe(folder, option, shown)
