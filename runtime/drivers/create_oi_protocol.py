"""iRobot Create 2 / Create (1) Open Interface: opcodes, sensor packet table, encoders and parsers.

Pure code, no I/O; shared by the driver (:mod:`runtime.drivers.create_oi`) and the SITL emulator
(:mod:`sitl.devices.create_oi`).  Every opcode, packet id, size, sign, range and unit below is from
the iRobot Create 2 Open Interface Specification (based on the Roomba 600, 2016/2018 editions) and
the iRobot Create Open Interface Specification v2 (Create 1).  Multi-byte values are big-endian
("high byte first").

* :func:`decode_packet` / :func:`encode_packet`: one packet id (a sensor or a group) <-> named values.
* :class:`StreamParser`: the host side, stream frames ``[19][n][id][data]...[checksum]``.
* :class:`CommandParser`: the robot side, ``opcode + data bytes`` with each opcode's length.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

from runtime.errors import InputError

MODELS = ("create1", "create2")

# ----------------------------------------------------------------------------- opcodes
RESET = 7                 # Create 2
START = 128
BAUD = 129
CONTROL = 130             # Create 1: same as Safe
SAFE = 131
FULL = 132
POWER = 133               # Create 2
SPOT = 134
CLEAN = 135               # Create 2 (Create 1: Cover demo)
COVER = 135               # Create 1
MAX = 136                 # Create 2
DEMO = 136                # Create 1 (+1 byte)
DRIVE = 137
MOTORS = 138              # Create 2 (Create 1: Low Side Drivers)
LOW_SIDE_DRIVERS = 138    # Create 1
LEDS = 139
SONG = 140
PLAY = 141
SENSORS = 142
SEEK_DOCK = 143           # Create 2 (Create 1: Cover and Dock)
COVER_AND_DOCK = 143      # Create 1
PWM_MOTORS = 144          # Create 2 (Create 1: PWM Low Side Drivers)
PWM_LOW_SIDE_DRIVERS = 144
DRIVE_DIRECT = 145
DRIVE_PWM = 146           # Create 2
DIGITAL_OUTPUTS = 147     # Create 1
STREAM = 148
QUERY_LIST = 149
PAUSE_RESUME_STREAM = 150
SEND_IR = 151             # Create 1
SCRIPT = 152              # Create 1
PLAY_SCRIPT = 153         # Create 1
SHOW_SCRIPT = 154         # Create 1
WAIT_TIME = 155           # Create 1
WAIT_DISTANCE = 156       # Create 1
WAIT_ANGLE = 157          # Create 1
WAIT_EVENT = 158          # Create 1
SCHEDULING_LEDS = 162     # Create 2
DIGIT_LEDS_RAW = 163      # Create 2
DIGIT_LEDS_ASCII = 164    # Create 2
BUTTONS = 165             # Create 2
SCHEDULE = 167            # Create 2
SET_DAY_TIME = 168        # Create 2
STOP = 173                # Create 2

# Data bytes after the opcode: an int, or "song" ([number][N] then 2N), "list" ([N] then N ids),
# "script" ([N] then N bytes).
_C2_COMMANDS: dict[int, int | str] = {
    RESET: 0, START: 0, BAUD: 1, SAFE: 0, FULL: 0, POWER: 0, SPOT: 0, CLEAN: 0, MAX: 0, DRIVE: 4,
    MOTORS: 1, LEDS: 3, SONG: "song", PLAY: 1, SENSORS: 1, SEEK_DOCK: 0, PWM_MOTORS: 3, DRIVE_DIRECT: 4,
    DRIVE_PWM: 4, STREAM: "list", QUERY_LIST: "list", PAUSE_RESUME_STREAM: 1, SCHEDULING_LEDS: 2,
    DIGIT_LEDS_RAW: 4, DIGIT_LEDS_ASCII: 4, BUTTONS: 1, SCHEDULE: 15, SET_DAY_TIME: 3, STOP: 0,
}
_C1_COMMANDS: dict[int, int | str] = {
    START: 0, BAUD: 1, CONTROL: 0, SAFE: 0, FULL: 0, SPOT: 0, COVER: 0, DEMO: 1, DRIVE: 4,
    LOW_SIDE_DRIVERS: 1, LEDS: 3, SONG: "song", PLAY: 1, SENSORS: 1, COVER_AND_DOCK: 0,
    PWM_LOW_SIDE_DRIVERS: 3, DRIVE_DIRECT: 4, DIGITAL_OUTPUTS: 1, STREAM: "list", QUERY_LIST: "list",
    PAUSE_RESUME_STREAM: 1, SEND_IR: 1, SCRIPT: "script", PLAY_SCRIPT: 0, SHOW_SCRIPT: 0, WAIT_TIME: 1,
    WAIT_DISTANCE: 2, WAIT_ANGLE: 2, WAIT_EVENT: 1,
}
COMMAND_LENGTHS = {"create1": _C1_COMMANDS, "create2": _C2_COMMANDS}

# ----------------------------------------------------------------------------- constants
STREAM_HEADER = 19
STREAM_PERIOD = 0.015                  # s: the OI sends a stream frame every 15 ms
MAX_WHEEL_MM_S = 500                   # Drive / Drive Direct velocity range
MAX_RADIUS_MM = 2000
RADIUS_STRAIGHT = 0x8000               # also 0x7FFF
RADIUS_STRAIGHT_ALT = 0x7FFF
RADIUS_CW = -1                         # 0xFFFF: turn in place clockwise
RADIUS_CCW = 1                         # turn in place counter-clockwise
MAX_PWM = 255
BAUD_RATES = (300, 600, 1200, 2400, 4800, 9600, 14400, 19200, 28800, 38400, 57600, 115200)  # by code
MODE_OFF, MODE_PASSIVE, MODE_SAFE, MODE_FULL = 0, 1, 2, 3
MODE_NAMES = {MODE_OFF: "off", MODE_PASSIVE: "passive", MODE_SAFE: "safe", MODE_FULL: "full"}


@dataclass(frozen=True)
class Geometry:
    """Size, drive geometry and serial default of one model: the one table of these numbers, which the
    driver's footprint, the planner's default inflation and the SITL body all read."""
    model: str
    track_mm: float                    # distance between the wheels' contact points
    radius_mm: float                   # the round shell about the centre between the wheels
    default_baud: int
    wheel_diameter_mm: float | None = None
    counts_per_rev: float | None = None   # None: no encoder packets (Create 1)
    max_wheel_mm_s: int = MAX_WHEEL_MM_S  # Drive / Drive Direct take -500..500 mm/s per wheel

    @property
    def mm_per_count(self) -> float | None:
        if self.counts_per_rev is None or self.wheel_diameter_mm is None:
            return None
        return math.pi * self.wheel_diameter_mm / self.counts_per_rev


# Track and wheels: the Create 2 OI spec (235 mm between the wheels, 72 mm wheels, 508.8 counts per
# revolution) and libcreate's model table (Create 1: 258 mm).  Neither OI spec gives the shell diameter.
# 340 mm (radius 170) is within the 338-353 mm of Roomba shells (the Create 2 is a Roomba 600 without
# the cleaning parts); the ROS create_description draws the Create 2 at 348.5 mm and the Create 1 at
# 330.2 mm.  The Create 1 uses 170 mm too: slightly over-inflated (safe), and the SITL runs either
# model on the same Create 2 body.
GEOMETRY = {
    "create2": Geometry("create2", track_mm=235.0, radius_mm=170.0, default_baud=115200,
                        wheel_diameter_mm=72.0, counts_per_rev=508.8),
    "create1": Geometry("create1", track_mm=258.0, radius_mm=170.0, default_baud=57600),
}


def check_model(model: str) -> str:
    if model not in MODELS:
        raise InputError(f"Create OI model {model!r}: expected one of {', '.join(MODELS)}")
    return model


# ----------------------------------------------------------------------------- sensor packets
@dataclass(frozen=True)
class PacketSpec:
    """One single-value sensor packet."""
    id: int
    name: str
    size: int                          # data bytes
    signed: bool
    lo: int                            # range given by the spec
    hi: int
    unit: str = ""
    bits: tuple[tuple[int, str], ...] = ()   # bit-mapped packets: (bit, flag name)


def _u1(pid, name, hi=255, bits=(), lo=0):
    return PacketSpec(pid, name, 1, False, lo, hi, "", tuple(bits))


def _flag(pid, name):
    return PacketSpec(pid, name, 1, False, 0, 1)


def _u2(pid, name, hi=65535, unit=""):
    return PacketSpec(pid, name, 2, False, 0, hi, unit)


def _s2(pid, name, lo=-32768, hi=32767, unit=""):
    return PacketSpec(pid, name, 2, True, lo, hi, unit)


_CREATE2_PACKETS = (
    _u1(7, "bumps_wheel_drops", 15, ((0, "bump_right"), (1, "bump_left"), (2, "wheel_drop_right"),
                                     (3, "wheel_drop_left"))),
    _flag(8, "wall"), _flag(9, "cliff_left"), _flag(10, "cliff_front_left"), _flag(11, "cliff_front_right"),
    _flag(12, "cliff_right"), _flag(13, "virtual_wall"),
    _u1(14, "wheel_overcurrents", 29, ((0, "side_brush_overcurrent"), (2, "main_brush_overcurrent"),
                                       (3, "right_wheel_overcurrent"), (4, "left_wheel_overcurrent"))),
    _u1(15, "dirt_detect"), _u1(16, "unused_16"), _u1(17, "infrared_character_omni"),
    _u1(18, "buttons", 255, ((0, "button_clean"), (1, "button_spot"), (2, "button_dock"),
                             (3, "button_minute"), (4, "button_hour"), (5, "button_day"),
                             (6, "button_schedule"), (7, "button_clock"))),
    _s2(19, "distance", unit="mm"), _s2(20, "angle", unit="deg"),
    _u1(21, "charging_state", 5), _u2(22, "voltage", unit="mV"), _s2(23, "current", unit="mA"),
    PacketSpec(24, "temperature", 1, True, -128, 127, "degC"),
    _u2(25, "battery_charge", unit="mAh"), _u2(26, "battery_capacity", unit="mAh"),
    _u2(27, "wall_signal", 1023), _u2(28, "cliff_left_signal", 4095), _u2(29, "cliff_front_left_signal", 4095),
    _u2(30, "cliff_front_right_signal", 4095), _u2(31, "cliff_right_signal", 4095),
    _u1(32, "unused_32"), _u2(33, "unused_33"),
    _u1(34, "charging_sources", 3, ((0, "internal_charger"), (1, "home_base"))),
    _u1(35, "oi_mode", 3), _u1(36, "song_number", 4), _flag(37, "song_playing"), _u1(38, "stream_packets", 108),
    _s2(39, "requested_velocity", -500, 500, "mm/s"), _s2(40, "requested_radius", unit="mm"),
    _s2(41, "requested_right_velocity", -500, 500, "mm/s"), _s2(42, "requested_left_velocity", -500, 500, "mm/s"),
    _s2(43, "left_encoder_counts"), _s2(44, "right_encoder_counts"),
    _u1(45, "light_bumper", 127, ((0, "light_bumper_left"), (1, "light_bumper_front_left"),
                                  (2, "light_bumper_center_left"), (3, "light_bumper_center_right"),
                                  (4, "light_bumper_front_right"), (5, "light_bumper_right"))),
    _u2(46, "light_bump_left_signal", 4095), _u2(47, "light_bump_front_left_signal", 4095),
    _u2(48, "light_bump_center_left_signal", 4095), _u2(49, "light_bump_center_right_signal", 4095),
    _u2(50, "light_bump_front_right_signal", 4095), _u2(51, "light_bump_right_signal", 4095),
    _u1(52, "infrared_character_left"), _u1(53, "infrared_character_right"),
    _s2(54, "left_motor_current", unit="mA"), _s2(55, "right_motor_current", unit="mA"),
    _s2(56, "main_brush_motor_current", unit="mA"), _s2(57, "side_brush_motor_current", unit="mA"),
    _u1(58, "stasis", 3, ((0, "stasis_toggling"), (1, "stasis_disabled"))),
)

_CREATE1_OVERRIDES = (
    _u1(7, "bumps_wheel_drops", 31, ((0, "bump_right"), (1, "bump_left"), (2, "wheel_drop_right"),
                                     (3, "wheel_drop_left"), (4, "wheel_drop_caster"))),
    _u1(14, "low_side_driver_and_wheel_overcurrents", 31,
        ((0, "ld1_overcurrent"), (1, "ld0_overcurrent"), (2, "ld2_overcurrent"),
         (3, "right_wheel_overcurrent"), (4, "left_wheel_overcurrent"))),
    _u1(15, "unused_15", 0), _u1(16, "unused_16", 0), _u1(17, "infrared_byte"),
    _u1(18, "buttons", 5, ((0, "button_play"), (2, "button_advance"))),
    _u2(27, "wall_signal", 4095),
    _u1(32, "cargo_bay_digital_inputs", 31, ((0, "digital_input_0"), (1, "digital_input_1"),
                                             (2, "digital_input_2"), (3, "digital_input_3"),
                                             (4, "baud_rate_change"))),
    _u2(33, "cargo_bay_analog_signal", 1023),
    _u1(36, "song_number", 15), _u1(38, "stream_packets", 43),
)


def _create1_packets():
    over = {p.id: p for p in _CREATE1_OVERRIDES}
    return tuple(over.get(p.id, p) for p in _CREATE2_PACKETS if p.id <= 42)


_GROUPS_COMMON = {0: range(7, 27), 1: range(7, 17), 2: range(17, 21), 3: range(21, 27), 4: range(27, 35),
                  5: range(35, 43), 6: range(7, 43)}
_GROUPS_CREATE2 = {**_GROUPS_COMMON, 100: range(7, 59), 101: range(43, 59), 106: range(46, 52),
                   107: range(54, 59)}


class _Model:
    """Precomputed tables of one model: specs, members, sizes and a struct per packet id."""

    def __init__(self, name: str, packets: Sequence[PacketSpec], groups: Mapping[int, range]):
        self.name = name
        self.specs = {p.id: p for p in packets}
        self.members: dict[int, tuple[int, ...]] = {pid: (pid,) for pid in self.specs}
        self.members.update({g: tuple(r) for g, r in groups.items()})
        self.groups = frozenset(groups)
        self.sizes = {pid: sum(self.specs[m].size for m in mem) for pid, mem in self.members.items()}
        self.structs: dict[int, struct.Struct] = {}
        for pid, mem in self.members.items():
            fmt = ">" + "".join(_fmt(self.specs[m]) for m in mem)
            self.structs[pid] = struct.Struct(fmt)
        self.ids = tuple(sorted(self.members))


def _fmt(spec: PacketSpec) -> str:
    return {(1, False): "B", (1, True): "b", (2, False): "H", (2, True): "h"}[(spec.size, spec.signed)]


_MODELS = {"create2": _Model("create2", _CREATE2_PACKETS, _GROUPS_CREATE2),
           "create1": _Model("create1", _create1_packets(), _GROUPS_COMMON)}


def _model(model: str) -> _Model:
    try:
        return _MODELS[model]
    except (KeyError, TypeError):
        raise InputError(f"Create OI model {model!r}: expected one of {', '.join(MODELS)}") from None


def packet_specs(model: str = "create2") -> dict[int, PacketSpec]:
    """Single-value packets of ``model`` by id (7..58 for Create 2, 7..42 for Create 1)."""
    return dict(_model(model).specs)


def packet_ids(model: str = "create2") -> tuple[int, ...]:
    """Every valid packet id of ``model``: groups and single packets, ascending."""
    return _model(model).ids


def group_ids(model: str = "create2") -> tuple[int, ...]:
    return tuple(sorted(_model(model).groups))


def packet_members(pid: int, model: str = "create2") -> tuple[int, ...]:
    """The single packets a packet id stands for, in the order their bytes are sent."""
    m = _model(model)
    if pid not in m.members:
        raise InputError(f"Create OI packet id {pid!r}: expected one of {_ranges(m.ids)} ({model})")
    return m.members[pid]


def packet_size(pid: int, model: str = "create2") -> int | None:
    """Data bytes of a packet id, or None if ``model`` does not have it."""
    return _model(model).sizes.get(pid)


def _ranges(ids: Iterable[int]) -> str:
    ids = sorted(ids)
    out, start, prev = [], None, None
    for i in ids + [None]:
        if start is None:
            start = prev = i
        elif i is not None and i == prev + 1:
            prev = i
        else:
            out.append(f"{start}" if start == prev else f"{start}-{prev}")
            start = prev = i
    return ", ".join(out)


def decode_packet(pid: int, data: bytes, model: str = "create2") -> dict:
    """Data bytes of packet ``pid`` -> named values.

    Single values come as ints under the packet's name; bit-mapped packets also give one bool per
    named bit.  A group gives the values of all its members.
    """
    m = _model(model)
    st = m.structs.get(pid)
    if st is None:
        raise InputError(f"Create OI packet id {pid!r}: expected one of {_ranges(m.ids)} ({model})")
    if len(data) != st.size:
        raise InputError(f"Create OI packet {pid}: expected {st.size} data bytes, got {len(data)}")
    out: dict = {}
    _decode_into(m, pid, st.unpack(data), out)
    return out


def _decode_into(m: _Model, pid: int, raw: tuple, out: dict) -> None:
    specs = m.specs
    for member, value in zip(m.members[pid], raw):
        spec = specs[member]
        out[spec.name] = value
        for bit, flag in spec.bits:
            out[flag] = bool(value >> bit & 1)


def encode_packet(pid: int, values: Mapping, model: str = "create2") -> bytes:
    """Named values -> data bytes of packet ``pid`` (the inverse of :func:`decode_packet`).

    Bit-mapped packets take the raw value under the packet's name if present, else their flags.
    Values are clamped to what the field's bytes can hold.
    """
    m = _model(model)
    if pid not in m.members:
        raise InputError(f"Create OI packet id {pid!r}: expected one of {_ranges(m.ids)} ({model})")
    raw = []
    for member in m.members[pid]:
        spec = m.specs[member]
        if spec.name in values:
            v = values[spec.name]
        elif spec.bits:
            v = sum(1 << bit for bit, flag in spec.bits if values.get(flag))
        else:
            raise InputError(f"Create OI packet {member} ({spec.name}): expected a value, none given")
        lo, hi = (-(1 << (8 * spec.size - 1)), (1 << (8 * spec.size - 1)) - 1) if spec.signed \
            else (0, (1 << (8 * spec.size)) - 1)
        raw.append(min(hi, max(lo, int(v))))
    return m.structs[pid].pack(*raw)


# ----------------------------------------------------------------------------- commands (host -> robot)
def _check(name: str, value, lo: int, hi: int, unit: str = "") -> int:
    if isinstance(value, bool) or not isinstance(value, int) and not (isinstance(value, float) and value.is_integer()):
        raise InputError(f"Create OI {name}: expected an integer {lo}..{hi}{unit}, got {value!r}")
    value = int(value)
    if not lo <= value <= hi:
        raise InputError(f"Create OI {name}: expected {lo}..{hi}{unit}, got {value}")
    return value


def _s16(v: int) -> bytes:
    return struct.pack(">h", v)


def start() -> bytes:
    """Start (128): open the OI, Passive mode."""
    return bytes([START])


def baud(code: int) -> bytes:
    """Baud (129) with a baud code 0..11 (see :data:`BAUD_RATES`)."""
    return bytes([BAUD, _check("baud code", code, 0, len(BAUD_RATES) - 1)])


def baud_code(rate: int) -> int:
    """The OI baud code of a rate in bit/s."""
    if rate not in BAUD_RATES:
        raise InputError(f"Create OI baud rate {rate!r}: expected one of {', '.join(map(str, BAUD_RATES))}")
    return BAUD_RATES.index(rate)


def safe() -> bytes:
    """Safe (131)."""
    return bytes([SAFE])


def full() -> bytes:
    """Full (132)."""
    return bytes([FULL])


def stop() -> bytes:
    """Stop (173, Create 2): close the OI, Off mode."""
    return bytes([STOP])


def reset() -> bytes:
    """Reset (7, Create 2): as if the battery were removed and reinserted; Off mode."""
    return bytes([RESET])


def drive(velocity_mm_s: int, radius_mm: int) -> bytes:
    """Drive (137): velocity -500..500 mm/s, radius -2000..2000 mm or a special radius.

    Special radii: 32768 (0x8000) or 32767 (0x7FFF) straight, -1 (0xFFFF) turn in place clockwise,
    1 turn in place counter-clockwise.  Positive radius turns left.
    """
    v = _check("Drive velocity", velocity_mm_s, -MAX_WHEEL_MM_S, MAX_WHEEL_MM_S, " mm/s")
    if radius_mm in (RADIUS_STRAIGHT, RADIUS_STRAIGHT_ALT, 0xFFFF):
        r = int(radius_mm)
    else:
        r = _check("Drive radius", radius_mm, -MAX_RADIUS_MM, MAX_RADIUS_MM,
                   " mm (or 32768/32767 straight, -1/65535 clockwise, 1 counter-clockwise)")
    return bytes([DRIVE]) + _s16(v) + struct.pack(">H", r & 0xFFFF)


def drive_direct(right_mm_s: int, left_mm_s: int) -> bytes:
    """Drive Direct (145): RIGHT wheel velocity first, then left, each -500..500 mm/s."""
    r = _check("Drive Direct right velocity", right_mm_s, -MAX_WHEEL_MM_S, MAX_WHEEL_MM_S, " mm/s")
    left = _check("Drive Direct left velocity", left_mm_s, -MAX_WHEEL_MM_S, MAX_WHEEL_MM_S, " mm/s")
    return bytes([DRIVE_DIRECT]) + _s16(r) + _s16(left)


def drive_pwm(right_pwm: int, left_pwm: int) -> bytes:
    """Drive PWM (146, Create 2): right then left duty, -255..255."""
    r = _check("Drive PWM right", right_pwm, -MAX_PWM, MAX_PWM)
    left = _check("Drive PWM left", left_pwm, -MAX_PWM, MAX_PWM)
    return bytes([DRIVE_PWM]) + _s16(r) + _s16(left)


def _ids(name: str, ids: Sequence[int], model: str) -> list[int]:
    m = _model(model)
    out = []
    for pid in ids:
        if pid not in m.members:
            raise InputError(f"Create OI {name} packet id {pid!r}: expected one of {_ranges(m.ids)} ({model})")
        out.append(int(pid))
    if len(out) > 255:
        raise InputError(f"Create OI {name}: expected at most 255 packet ids, got {len(out)}")
    return out


def sensors(pid: int, model: str = "create2") -> bytes:
    """Sensors (142): ask once for one packet id."""
    return bytes([SENSORS] + _ids("Sensors", [pid], model))


def query_list(ids: Sequence[int], model: str = "create2") -> bytes:
    """Query List (149): ask once for several packet ids; the reply is their data back to back."""
    ids = _ids("Query List", ids, model)
    return bytes([QUERY_LIST, len(ids)] + ids)


def stream(ids: Sequence[int], model: str = "create2") -> bytes:
    """Stream (148): a frame of these packets every 15 ms until paused or stopped."""
    ids = _ids("Stream", ids, model)
    return bytes([STREAM, len(ids)] + ids)


def pause_resume_stream(resume: bool) -> bytes:
    """Pause/Resume Stream (150): [150][0] stops the stream, [150][1] resumes it."""
    return bytes([PAUSE_RESUME_STREAM, 1 if resume else 0])


def song(number: int, notes: Sequence[tuple[int, int]], model: str = "create2") -> bytes:
    """Song (140): song number, then (MIDI note, duration in 1/64 s) pairs, 1..16 notes."""
    n = _check("Song number", number, 0, 4 if model == "create2" else 15)
    _check("Song length", len(notes), 1, 16, " notes")
    body = []
    for note, dur in notes:
        body += [_check("Song note", note, 0, 255), _check("Song duration", dur, 0, 255, " /64 s")]
    return bytes([SONG, n, len(notes)] + body)


def play(number: int) -> bytes:
    """Play (141) a stored song."""
    return bytes([PLAY, _check("Play song number", number, 0, 15)])


def leds(bits: int, color: int, intensity: int) -> bytes:
    """LEDs (139): LED bits, power LED colour (0 green .. 255 red) and intensity."""
    return bytes([LEDS, _check("LED bits", bits, 0, 255), _check("power LED colour", color, 0, 255),
                  _check("power LED intensity", intensity, 0, 255)])


def drive_to_wheels(velocity_mm_s: float, radius_raw: int, track_mm: float) -> tuple[float, float]:
    """Drive (137) arguments -> (left, right) wheel velocities in mm/s, as the spec defines them.

    ``radius_raw`` is the 16-bit field as sent (0..65535).  The velocity is the average of the two
    wheels; the radius runs from the turning centre to the robot's centre, positive to the left.
    A wheel over 500 mm/s scales both down, keeping the radius.  Radius 0, which the spec leaves
    undefined, drives straight.
    """
    v = max(-MAX_WHEEL_MM_S, min(MAX_WHEEL_MM_S, float(velocity_mm_s)))
    raw = radius_raw & 0xFFFF
    if raw in (RADIUS_STRAIGHT, RADIUS_STRAIGHT_ALT) or raw == 0:
        return v, v
    if raw == 0xFFFF:                       # clockwise in place
        return v, -v
    if raw == 1:                            # counter-clockwise in place
        return -v, v
    r = raw - 0x10000 if raw >= 0x8000 else raw
    r = max(-MAX_RADIUS_MM, min(MAX_RADIUS_MM, r))
    half = track_mm / 2.0
    left, right = v * (r - half) / r, v * (r + half) / r
    peak = max(abs(left), abs(right))
    if peak > MAX_WHEEL_MM_S:
        left, right = left * MAX_WHEEL_MM_S / peak, right * MAX_WHEEL_MM_S / peak
    return left, right


# ----------------------------------------------------------------------------- stream frames (robot -> host)
def checksum(data: bytes) -> int:
    """The byte that makes the low byte of the sum of ``data`` plus itself zero."""
    return -sum(data) & 0xFF


def build_stream_frame(chunks: Iterable[tuple[int, bytes]]) -> bytes:
    """``[19][n-bytes][id 1][data 1]...[checksum]`` from (packet id, data bytes) pairs."""
    payload = b"".join(bytes([pid]) + bytes(data) for pid, data in chunks)
    if len(payload) > 255:
        raise InputError(f"Create OI stream frame: expected at most 255 bytes of packets, got {len(payload)}")
    head = bytes([STREAM_HEADER, len(payload)]) + payload
    return head + bytes([checksum(head)])


class StreamParser:
    """Incremental stream-frame parser: ``feed(bytes) -> [dict of named values, ...]``.

    A frame is ``19, n, (packet id, data)*, checksum`` with the low byte of the sum of all its bytes
    zero, and its packets must fill exactly ``n`` bytes with ids the model knows.  Anything else is
    skipped one byte at a time until the next 19, so a real frame after garbage is still found.
    Counters: ``frames``, ``frame_bytes`` (bytes in good frames), ``bad_checksum``, ``malformed``
    (checksum right, packets wrong), ``dropped_bytes``; with ``pending`` they add up to every byte fed.
    Never raises on any bytes.
    """

    def __init__(self, model: str = "create2"):
        self._m = _model(model)
        self.model = model
        self._buf = bytearray()
        self.frames = 0
        self.frame_bytes = 0
        self.bad_checksum = 0
        self.malformed = 0
        self.dropped_bytes = 0
        self.fed = 0

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a possible frame."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[dict]:
        self.fed += len(data)
        buf = self._buf
        buf += data
        sizes = self._m.sizes
        out: list[dict] = []
        i, end = 0, len(buf)
        while i < end:
            j = buf.find(STREAM_HEADER, i)
            if j < 0:
                self.dropped_bytes += end - i
                i = end
                break
            self.dropped_bytes += j - i
            i = j
            if end - i < 2:
                break
            n = buf[i + 1]
            if n and end - i >= 3 and buf[i + 2] not in sizes:   # cannot be a frame: first id unknown
                self.dropped_bytes += 1
                i += 1
                continue
            total = n + 3
            if end - i < total:
                break
            if sum(buf[i:i + total]) & 0xFF:
                self.bad_checksum += 1
                self.dropped_bytes += 1
                i += 1
                continue
            frame = self._packets(buf, i + 2, i + 2 + n)
            if frame is None:
                self.malformed += 1
                self.dropped_bytes += 1
                i += 1
                continue
            out.append(frame)
            self.frames += 1
            self.frame_bytes += total
            i += total
        del buf[:i]
        return out

    def _packets(self, buf: bytearray, p: int, stop: int) -> dict | None:
        m = self._m
        frame: dict = {}
        while p < stop:
            pid = buf[p]
            st = m.structs.get(pid)
            if st is None or p + 1 + st.size > stop:
                return None
            _decode_into(m, pid, st.unpack_from(buf, p + 1), frame)
            p += 1 + st.size
        return frame


# ----------------------------------------------------------------------------- command parser (robot side)
class CommandParser:
    """Incremental OI command parser for the robot side: ``feed(bytes) -> [(opcode, data bytes), ...]``.

    Knows each opcode's data length for its model, including Song (140), Stream (148), Query List (149)
    and Script (152).  An unknown opcode byte is counted and skipped.  Counters: ``commands``,
    ``command_bytes``, ``unknown_opcodes``, ``dropped_bytes``; with ``pending`` they add up to every
    byte fed.  Never raises on any bytes.
    """

    def __init__(self, model: str = "create2"):
        self.model = check_model(model)
        self._lengths = COMMAND_LENGTHS[model]
        self._buf = bytearray()
        self.commands = 0
        self.command_bytes = 0
        self.unknown_opcodes = 0
        self.dropped_bytes = 0
        self.fed = 0

    @property
    def pending(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        self.fed += len(data)
        buf = self._buf
        buf += data
        lengths = self._lengths
        out: list[tuple[int, bytes]] = []
        i, end = 0, len(buf)
        while i < end:
            op = buf[i]
            spec = lengths.get(op)
            if spec is None:
                self.unknown_opcodes += 1
                self.dropped_bytes += 1
                i += 1
                continue
            if spec == "song":
                need = 3 + 2 * buf[i + 2] if end - i >= 3 else None
            elif spec == "list" or spec == "script":
                need = 2 + buf[i + 1] if end - i >= 2 else None
            else:
                need = 1 + spec
            if need is None or end - i < need:
                break
            out.append((op, bytes(buf[i + 1:i + need])))
            self.commands += 1
            self.command_bytes += need
            i += need
        del buf[:i]
        return out
