"""Mission files: QGC WPL 110 waypoint files (read and write) and QGroundControl ``.plan`` JSON (read).

QGC WPL 110 (mavlink-devguide en/file_formats/index.md): first line ``QGC WPL 110``, then one line per
item, fields separated by tabs (any whitespace is accepted here)::

    INDEX CURRENT_WP COORD_FRAME COMMAND PARAM1 PARAM2 PARAM3 PARAM4 X/LAT Y/LON Z/ALT AUTOCONTINUE

X/Y are degrees in global frames, metres in local frames.  Blank lines and ``#`` comment lines (as
pymavlink's mavwp writes them) are skipped.

Home: QGC reads line 0 of a WPL 110 file as the planned home ("ArduPilot file, planned home position is
already in position 0", MissionController::_loadTextMissionFile) and MAVProxy saves the vehicle's home
there.  This vehicle (a generic autopilot: QGC sends no home item, seq 0 is the first real item) takes no
home item, so the first data line is read as home and skipped when it has INDEX 0, CURRENT_WP 1 and
COMMAND MAV_CMD_NAV_WAYPOINT (16), which is how QGC and MAVProxy write home; any other first line is a
real item.  Its X, Y, Z are returned as :attr:`MissionFile.home`.  Once home is skipped the items are
renumbered from 0 and MAV_CMD_DO_JUMP targets (param1) move down by one, as QGC does when it drops home.
:func:`write_wpl` writes such a home line first, so the files it writes read back the same here, in QGC
and in MAVProxy.

``.plan`` (QGC): ``fileType`` "Plan"; ``mission.items`` of ``SimpleItem`` (``command``, ``frame``,
``params`` [7 numbers or null = NaN], ``autoContinue``, optional ``doJumpId``); ``ComplexItem`` (survey,
corridor scan, ...) is refused naming its index; ``mission.plannedHomePosition`` [lat, lon, alt] becomes
:attr:`MissionFile.home`; ``geoFence`` and ``rallyPoints`` are ignored.  DO_JUMP param1 holds a
``doJumpId`` in a .plan file and is turned into the target's sequence number.

Every error is an :class:`~runtime.errors.InputError` of one line naming the file and the line number or
JSON key, e.g. ``mission.txt: line 4: expected 12 fields, got 9``.

Damaged files: a file larger than :data:`MAX_FILE_BYTES` is refused before it is read whole, and one of more
than :data:`MAX_ITEMS` items (what a robot takes) as soon as the parser meets item MAX_ITEMS + 1.  A WPL line
cut short or that does not parse is refused naming it; the INDEX column must count up by one from the first
data line (0, or 1 in a file without a home line), so a line lost from the middle or repeated is refused.  WPL
has no item count and no end mark: a file cut exactly at a line end reads as the shorter mission it now holds,
and one cut to its header holds none (``mrta mission upload`` refuses an empty mission unless ``--clear``).
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, replace
from pathlib import Path

from runtime.comms.mission import GLOBAL_FRAMES, MAV_CMD_DO_JUMP, MAX_ITEMS, MISSION, MissionItem
from runtime.errors import InputError

WPL_HEADER = "QGC WPL 110"
MAV_CMD_NAV_WAYPOINT = 16
WPL_FIELDS = ("INDEX", "CURRENT_WP", "COORD_FRAME", "COMMAND", "PARAM1", "PARAM2", "PARAM3", "PARAM4",
              "X", "Y", "Z", "AUTOCONTINUE")
_INT_FIELDS = {0: (0, 0xFFFF), 1: (0, 1), 2: (0, 0xFF), 3: (0, 0xFFFF), 11: (0, 1)}
MAX_FILE_BYTES = 1 << 20      # a mission file (1 MiB; MAX_ITEMS WPL lines take about 100 kB)


@dataclass(frozen=True)
class MissionFile:
    """What a mission file holds: items (mission_type 0, seq from 0) and the planned home, if any."""
    items: list[MissionItem]
    home: tuple[float, float, float] | None = None


# ---------------------------------------------------------------------------------------------- reading

def read_mission(path: str | Path) -> MissionFile:
    """A WPL or .plan file, told apart by its content (``{`` starts a .plan)."""
    text = _read_text(path)
    if text.lstrip("\ufeff \t\r\n").startswith("{"):
        return parse_plan(text, str(path))
    return parse_wpl(text, str(path))


def read_wpl(path: str | Path) -> MissionFile:
    return parse_wpl(_read_text(path), str(path))


def read_plan(path: str | Path) -> MissionFile:
    return parse_plan(_read_text(path), str(path))


def _read_text(path: str | Path) -> str:
    """The file's text; refused without reading it whole if it is larger than MAX_FILE_BYTES (its size first, then
    at most one byte more is read, for a file whose size is not known beforehand, such as a pipe)."""
    too_big = f"{path}: expected a mission file of at most {MAX_FILE_BYTES} bytes (1 MiB)"
    try:
        with open(path, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            if size > MAX_FILE_BYTES:
                raise InputError(f"{too_big}, got {size}")
            raw = fh.read(MAX_FILE_BYTES + 1)
        if len(raw) > MAX_FILE_BYTES:
            raise InputError(f"{too_big}, got more")
        return raw.decode("utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: mission file not found") from None
    except UnicodeDecodeError as e:
        raise InputError(f"{path}: expected UTF-8 text, got byte 0x{e.object[e.start]:02x} "
                         f"at offset {e.start}") from None
    except OSError as e:
        raise InputError(f"{path}: cannot read mission file ({e.strerror})") from None


def parse_wpl(text: str, name: str = "<wpl>") -> MissionFile:
    lines = text.lstrip("\ufeff").splitlines()
    first = lines[0].strip() if lines else ""
    if first != WPL_HEADER:
        raise InputError(f"{name}: line 1: expected {WPL_HEADER!r}, got {first[:40]!r}")
    rows: list[tuple[int, list]] = []
    for number, line in enumerate(lines[1:], start=2):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        where = f"{name}: line {number}"
        row = _wpl_row(line, where)
        _check_index(rows, row[0], where)
        rows.append((number, row))
    home = None
    if rows and rows[0][1][0] == 0 and rows[0][1][1] == 1 and rows[0][1][3] == MAV_CMD_NAV_WAYPOINT:
        f = rows.pop(0)[1]
        home = (f[8], f[9], f[10])
    if len(rows) > MAX_ITEMS:
        raise InputError(f"{name}: line {rows[MAX_ITEMS][0]}: expected at most {MAX_ITEMS} items (what a robot "
                         "takes), got more")
    items = []
    for seq, (number, f) in enumerate(rows):
        p1 = f[4]
        if home is not None and f[3] == MAV_CMD_DO_JUMP:
            p1 -= 1
        item = MissionItem(seq, f[2], f[3], p1, f[5], f[6], f[7], f[8], f[9], f[10], bool(f[11]), MISSION)
        _check_xy(item, f"{name}: line {number}", ("X", "Y"))
        items.append(item)
    return MissionFile(items, home)


def _check_index(rows: list, index: int, where: str) -> None:
    """A data line's INDEX counts up by one from the first (0, or 1 without a home line): a lost or repeated line
    is refused; so is the line that would be item MAX_ITEMS + 2 (parse_wpl counts the items once home is known)."""
    if not rows:
        if index not in (0, 1):
            raise InputError(f"{where}: INDEX: expected 0 (or 1 in a file without a home line), got {index}")
    elif index != rows[-1][1][0] + 1:
        raise InputError(f"{where}: INDEX: expected {rows[-1][1][0] + 1} (a line lost or repeated?), got {index}")
    if len(rows) > MAX_ITEMS:
        raise InputError(f"{where}: expected at most {MAX_ITEMS} items (what a robot takes), got more")


def _wpl_row(line: str, where: str) -> list:
    fields = line.split()
    if len(fields) != len(WPL_FIELDS):
        raise InputError(f"{where}: expected {len(WPL_FIELDS)} fields, got {len(fields)}")
    out: list = []
    for i, (label, text) in enumerate(zip(WPL_FIELDS, fields)):
        if i in _INT_FIELDS:
            lo, hi = _INT_FIELDS[i]
            try:
                v = int(text)
            except ValueError:
                raise InputError(f"{where}: {label}: expected an integer, got {text[:20]!r}") from None
            if not lo <= v <= hi:
                raise InputError(f"{where}: {label}: expected {lo}..{hi}, got {v}")
        else:
            try:
                v = float(text)
            except ValueError:
                raise InputError(f"{where}: {label}: expected a number, got {text[:20]!r}") from None
        out.append(v)
    return out


def parse_plan(text: str, name: str = "<plan>") -> MissionFile:
    try:
        doc = json.loads(text.lstrip("\ufeff"))
    except json.JSONDecodeError as e:
        raise InputError(f"{name}: line {e.lineno}: not valid JSON ({e.msg})") from None
    except RecursionError:
        raise InputError(f"{name}: JSON nested too deeply") from None
    if not isinstance(doc, dict):
        raise InputError(f"{name}: expected a JSON object (a QGC .plan), got {type(doc).__name__}")
    if doc.get("fileType") != "Plan":
        raise InputError(f"{name}: fileType: expected \"Plan\", got {_short(doc.get('fileType'))}")
    mission = doc.get("mission")
    if not isinstance(mission, dict):
        raise InputError(f"{name}: mission: expected an object")
    raw = mission.get("items")
    if not isinstance(raw, list):
        raise InputError(f"{name}: mission.items: expected a list")
    if len(raw) > MAX_ITEMS:
        raise InputError(f"{name}: mission.items: expected at most {MAX_ITEMS} items (what a robot takes), "
                         f"got {len(raw)}")
    items, jump_ids = [], {}
    for i, it in enumerate(raw):
        key = f"{name}: mission.items[{i}]"
        item, jump_id = _plan_item(it, i, key)
        if jump_id is not None:
            jump_ids.setdefault(jump_id, i)
        items.append(item)
    for i, item in enumerate(items):
        if item.command == MAV_CMD_DO_JUMP:
            target = jump_ids.get(item.param1)
            if target is None:
                raise InputError(f"{name}: mission.items[{i}].params[0]: DO_JUMP to doJumpId "
                                 f"{item.param1:g}, which no item has")
            items[i] = replace(item, param1=float(target))
    return MissionFile(items, _plan_home(mission, name))


def _plan_item(it, i: int, key: str) -> tuple[MissionItem, int | None]:
    if not isinstance(it, dict):
        raise InputError(f"{key}: expected an object")
    kind = it.get("type")
    if kind == "ComplexItem":
        raise InputError(f"{key}: ComplexItem {_short(it.get('complexItemType'))} is not supported; "
                         "expected a SimpleItem (split it into waypoints in QGC)")
    if kind != "SimpleItem":
        raise InputError(f"{key}.type: expected \"SimpleItem\", got {_short(kind)}")
    command = _int(it.get("command"), 0, 0xFFFF, f"{key}.command")
    frame = _int(it.get("frame"), 0, 0xFF, f"{key}.frame")
    params = it.get("params")
    if not (isinstance(params, list) and len(params) == 7
            and all(p is None or _is_number(p) for p in params)):
        raise InputError(f"{key}.params: expected 7 numbers or nulls")
    p = [math.nan if v is None else float(v) for v in params]
    auto = it.get("autoContinue", True)
    if not isinstance(auto, bool):
        raise InputError(f"{key}.autoContinue: expected true or false, got {_short(auto)}")
    jump_id = it.get("doJumpId")
    if jump_id is not None and not _is_number(jump_id):
        raise InputError(f"{key}.doJumpId: expected a number, got {_short(jump_id)}")
    item = MissionItem(i, frame, command, *p, autocontinue=auto, mission_type=MISSION)
    _check_xy(item, key, ("params[4]", "params[5]"), sep=".")
    return item, jump_id


def _plan_home(mission: dict, name: str) -> tuple[float, float, float] | None:
    home = mission.get("plannedHomePosition")
    if home is None:
        return None
    if not (isinstance(home, list) and len(home) == 3 and all(_is_number(v) for v in home)):
        raise InputError(f"{name}: mission.plannedHomePosition: expected [lat, lon, alt] numbers")
    return float(home[0]), float(home[1]), float(home[2])


def _check_xy(item: MissionItem, where: str, labels: tuple[str, str], sep: str = ": ") -> None:
    """Latitude/longitude in range in global frames; anything else must fit MISSION_ITEM_INT."""
    checks = ((labels[0], item.x, 90.0, "latitude"), (labels[1], item.y, 180.0, "longitude"))
    for label, v, limit, what in checks:
        if math.isnan(v):
            continue                       # "unset": sent as INT32_MAX
        if item.frame in GLOBAL_FRAMES and not -limit <= v <= limit:
            raise InputError(f"{where}{sep}{label}: expected a {what} in -{limit:g}..{limit:g}, got {v!r}")
    why = item.check_encodable()
    if why:
        raise InputError(f"{where}: {why}")


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _int(v, lo: int, hi: int, key: str) -> int:
    if not (isinstance(v, int) and not isinstance(v, bool)) or not lo <= v <= hi:
        raise InputError(f"{key}: expected an integer {lo}..{hi}, got {_short(v)}")
    return v


def _short(v) -> str:
    text = json.dumps(v) if isinstance(v, (str, int, float, bool, type(None))) else type(v).__name__
    return text if len(text) <= 40 else text[:37] + "..."


# ---------------------------------------------------------------------------------------------- writing

def format_wpl(items, home: tuple[float, float, float] | None = None) -> str:
    """WPL 110 text: a home line first (``home``, else the first global item's lat/lon at altitude 0),
    then the items with INDEX = seq + 1 and DO_JUMP targets moved up by one to match."""
    items = list(items)
    lines = [WPL_HEADER]
    if home is None and items:
        first = next((it for it in items if it.frame in GLOBAL_FRAMES), None)
        home = (first.x, first.y, 0.0) if first else (0.0, 0.0, 0.0)
    if home is not None:
        lines.append(_wpl_line(0, 1, 0, MAV_CMD_NAV_WAYPOINT, (0.0, 0.0, 0.0, 0.0, *home), True))
    for i, it in enumerate(items):
        p1 = it.param1 + 1 if it.command == MAV_CMD_DO_JUMP else it.param1
        lines.append(_wpl_line(i + 1, 0, it.frame, it.command, (p1, *it.params[1:]), it.autocontinue))
    return "\n".join(lines) + "\n"


def _wpl_line(index: int, current: int, frame: int, command: int, params, auto: bool) -> str:
    return "\t".join([str(index), str(current), str(frame), str(command),
                      *(repr(float(v)) for v in params), str(int(bool(auto)))])


def write_wpl(items, path: str | Path, home: tuple[float, float, float] | None = None) -> None:
    """Write ``items`` as a QGC WPL 110 file (see :func:`format_wpl`)."""
    try:
        Path(path).write_text(format_wpl(items, home), encoding="utf-8")
    except OSError as e:
        raise InputError(f"{path}: cannot write mission file ({e.strerror})") from None
