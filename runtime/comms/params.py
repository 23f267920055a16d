"""Onboard parameters a ground station can read and set: :class:`Param` and :class:`ParamTable`.

A :class:`Param` names a value the robot already holds elsewhere: ``get()`` reads it and ``set(v)``
applies it; the table only checks what comes in (known name, finite, integral for ints, within
``lo..hi``) and keeps the order, which gives every parameter its MAVLink ``param_index``.

Wire encoding (PARAM_VALUE / PARAM_SET ``param_value`` is one float32): a float parameter travels as
MAV_PARAM_TYPE_REAL32, an integer one as MAV_PARAM_TYPE_INT32 holding its number C-cast (5 -> 5.0), and
AUTOPILOT_VERSION advertises MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST (:data:`ENCODING_CAPABILITY`), the encoding
ArduPilot uses.  The robot's HEARTBEAT says MAV_AUTOPILOT_ARDUPILOTMEGA (:mod:`runtime.comms.telemetry`), and for
such a vehicle the three stock ground stations read a C-cast INT32 as its number:

* MAVSDK (src/mavsdk/core/mavlink_parameter_client.cpp: ``ParamValue::Conversion::Cast`` and
  ``get_4_float_bytes_cast`` when the autopilot is ArduPilot, both ways), so ``get_param_int`` works;
* QGroundControl (APMFirmwarePlugin::_handleIncomingParamValue converts the casts before ParameterManager reads the
  union);
* MAVProxy (mavproxy_param.handle_px4_param_value unpacks bytes only for MAV_AUTOPILOT_PX4; otherwise
  ``param_value`` is the number).

Integers are kept integral here and limited to +-2**24, where a float32 holds every integer exactly.  Incoming
PARAM_SETs are decoded the way we advertise: the number in ``param_value``, whatever ``param_type`` says.
"""
from __future__ import annotations

import math
import re
import struct
from dataclasses import dataclass
from typing import Callable, Iterator

from runtime.errors import InputError

MAV_PARAM_TYPE_REAL32 = 9                 # MAVLink MAV_PARAM_TYPE_REAL32
MAV_PARAM_TYPE_INT32 = 6                  # MAVLink MAV_PARAM_TYPE_INT32
ENCODING_CAPABILITY = 131072              # MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
MAX_EXACT_INT = 2 ** 24                   # float32 holds every integer of magnitude <= this exactly
NAME_RE = re.compile(r"[A-Z][A-Z0-9_]{0,15}\Z")
MAX_PARAMS = 65535                        # param_count and param_index are uint16


def float32(v: float) -> float:
    """``v`` rounded to the nearest float32, as it travels in ``param_value`` (+-inf beyond its range)."""
    try:
        return struct.unpack("<f", struct.pack("<f", v))[0]
    except OverflowError:
        return math.copysign(math.inf, v)


def _number(v) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise TypeError
    return float(v)


@dataclass(frozen=True)
class Param:
    """One parameter: ``name`` (<= 16 chars, upper case, e.g. ``CTL_CRUISE_SPD``), ``type`` ``float`` or
    ``int``, accepted range ``lo..hi`` (inclusive), a one-line ``description``, and the callables that
    read (``get()``) and apply (``set(value)``) the value where the robot keeps it."""

    name: str
    type: type
    lo: float
    hi: float
    description: str
    get: Callable[[], float]
    set: Callable[[float], None]

    def __post_init__(self) -> None:
        where = f"parameter {self.name!r}"
        if not isinstance(self.name, str) or not NAME_RE.match(self.name):
            raise InputError(f"{where}: expected 1-16 characters A-Z, 0-9, _ starting with a letter")
        if self.type not in (float, int):
            raise InputError(f"{where}: expected type float or int, got {self.type!r}")
        try:
            lo, hi = _number(self.lo), _number(self.hi)
        except TypeError:
            raise InputError(f"{where}: expected numeric lo and hi, got {self.lo!r}, {self.hi!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise InputError(f"{where}: expected finite lo <= hi, got {self.lo!r}..{self.hi!r}")
        if self.type is int and not (lo == int(lo) and hi == int(hi) and -MAX_EXACT_INT <= lo and hi <= MAX_EXACT_INT):
            raise InputError(f"{where}: expected integral lo and hi within +-{MAX_EXACT_INT} (float32-exact)")
        if not isinstance(self.description, str) or "\n" in self.description:
            raise InputError(f"{where}: expected a one-line description")
        if not (callable(self.get) and callable(self.set)):
            raise InputError(f"{where}: expected callable get and set")


class ParamTable:
    """An ordered collection of :class:`Param`; a parameter's position is its MAVLink ``param_index``."""

    def __init__(self, params=()):
        self._params: list[Param] = []
        self._index: dict[str, int] = {}
        for p in params:
            self.add(p)

    def add(self, p: Param) -> None:
        if not isinstance(p, Param):
            raise InputError(f"parameter table: expected a Param, got {type(p).__name__}")
        if p.name in self._index:
            raise InputError(f"parameter {p.name!r}: defined twice")
        if len(self._params) >= MAX_PARAMS:
            raise InputError(f"parameter {p.name!r}: more than {MAX_PARAMS} parameters")
        self._index[p.name] = len(self._params)
        self._params.append(p)

    def __len__(self) -> int:
        return len(self._params)

    def __iter__(self) -> Iterator[Param]:
        return iter(self._params)

    def index(self, name: str) -> int | None:
        """Position of ``name`` (matched upper-cased, as every name is upper case), or None."""
        if not isinstance(name, str):
            return None
        return self._index.get(name.upper())

    def by_index(self, i: int) -> Param | None:
        return self._params[i] if isinstance(i, int) and 0 <= i < len(self._params) else None

    @staticmethod
    def wire_type(p: Param) -> int:
        """``p``'s MAV_PARAM_TYPE: INT32 for an integer parameter, REAL32 for a float one."""
        return MAV_PARAM_TYPE_INT32 if p.type is int else MAV_PARAM_TYPE_REAL32

    def value(self, p: Param) -> float:
        """``p``'s current value as it travels (float32); NaN if its getter fails or returns a non-number."""
        try:
            v = _number(p.get())
        except Exception:          # a getter is the robot's code: report, never raise into the link
            return math.nan
        if p.type is int and math.isfinite(v):
            v = float(round(v))
        return float32(v)

    def set(self, name: str, value) -> tuple[bool, float, str]:
        """Apply ``value`` to ``name`` if acceptable.  Returns ``(ok, value now in force, reason)``;
        ``reason`` is "" on success, else one line saying why nothing changed.  Raises nothing."""
        i = self.index(name)
        if i is None:
            return False, math.nan, f"{name!r}: no such parameter"
        p = self._params[i]
        try:
            v = _number(value)
        except TypeError:
            return False, self.value(p), f"{p.name}: expected a number, got {value!r}"
        if not math.isfinite(v):
            return False, self.value(p), f"{p.name}: expected a finite value, got {v}"
        if p.type is int:
            if abs(v - round(v)) > 1e-6:
                return False, self.value(p), f"{p.name}: expected an integer, got {v:g}"
            v = float(round(v))
        if not p.lo <= v <= p.hi:
            return False, self.value(p), f"{p.name}: {v:g} out of range {p.lo:g}..{p.hi:g}"
        try:
            p.set(int(v) if p.type is int else v)
        except Exception as e:     # the robot refused it: the old value stays
            return False, self.value(p), f"{p.name}: not applied ({type(e).__name__}: {e})"[:200]
        return True, self.value(p), ""
