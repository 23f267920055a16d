"""ARCOS (Pioneer 3 / MobileRobots robot server): packet framing, arguments, commands, SIPs, robot geometry.

Pure code, no I/O; shared by the driver (:mod:`runtime.drivers.arcos`) and the SITL emulator
(:mod:`sitl.devices.arcos`).  The facts and their sources are in the project's ARCOS facts file
(AriaCoda ``ArRobotPacket.cpp``, ``ArRobotPacketSender.cpp``, ``ArRobot.cpp`` ``processMotorPacket``,
``ArRobotConfigPacketReader.cpp``, ``ArCommands.h``, ``params/p3dx-sh.p``).

* A packet on the wire is ``FA FB <count> <id> <args...> <ck_hi> <ck_lo>``; ``count`` is the number of
  bytes after it (id, arguments, two checksum bytes).  The checksum (:func:`checksum`) sums the bytes
  from the id on as big-endian 16-bit words, XORs in an odd last byte, and goes out high byte first.
  A *body* below is what lies between the count and the checksum: the id and its arguments.
* :class:`PacketParser`: the receiving side for either end; resynchronises after garbage and counts
  what it drops.  The checksum is compared whole (p2os's check accepts any packet whose last byte
  is non-zero; see :func:`p2os_accepts`).
* Integers travel as INTARG (0x3B) or NINTARG (0x1B, negative) and a little-endian u16 magnitude;
  strings as STRARG (0x2B) with a length byte and a NUL (ARIA) or with the NUL only (Soar).
* :func:`decode_sip` / :func:`encode_sip`: the standard server information packet (ids 0x32, 0x33) with
  the optional tail, read as ARIA reads it (integers little-endian).
"""
from __future__ import annotations

import bisect
import math
import struct
from dataclasses import dataclass, field

from runtime.errors import InputError

HEADER = b"\xfa\xfb"
MAX_COUNT = 255            # the count byte is 8 bits; ARIA's 200-byte cap is commented out

INTARG = 0x3B
NINTARG = 0x1B
STRARG = 0x2B
MAX_STR = 199              # ArRobotPacketSender::comStr

# ----------------------------------------------------------------------------- command ids (ArCommands.h)
SYNC0, SYNC1, SYNC2 = 0, 1, 2
PULSE = 0
OPEN = 1
CLOSE = 2
POLLING = 3                # string: sonar polling sequence (sonar numbers 1..32, one byte each)
ENABLE = 4
SETA = 5
SETV = 6
SETO = 7
MOVE = 8
ROTATE = 9
SETRV = 10
VEL = 11
HEAD = 12
DHEAD = 13
SAY = 15                   # string
CONFIG = 18
ENCODER = 19
RVEL = 21
SETRA = 23
SONAR = 28
STOP = 29
DIGOUT = 30
VEL2 = 32
BUMPSTALL = 44
SONARCYCLE = 48
HOSTBAUD = 50
E_STOP = 55

# ----------------------------------------------------------------------------- packet ids from the robot
SIP_IDS = (0x32, 0x33)     # standard SIP: 0x32 motors stopped, 0x33 moving (MobileSim always sends 0x32)
CONFIG_PAC = 0x20

# STALL_AND_BUMPERS bits (p2os sip.cpp): low byte bit 0 left stall, bits 1-7 rear bumpers;
# high byte bit 0 right stall, bits 1-7 front bumpers (bumper 1 is the leftmost: ArBumpers.cpp).
LEFT_STALL = 0x0001
RIGHT_STALL = 0x0100
# FLAGS bits (ArRobot.h): bit 0 motors enabled, bits 1-4 sonar arrays 1-4 on, bit 5 e-stop pressed.
FLAG_MOTORS = 0x0001
FLAG_SONAR_ARRAYS = (0x0002, 0x0004, 0x0008, 0x0010)
FLAG_ESTOP = 0x0020


class SipError(ValueError):
    """A packet that is not a well-formed standard SIP (too short for its fields)."""


# ----------------------------------------------------------------------------- framing
def checksum(body: bytes) -> int:
    """ArRobotPacket::calcCheckSum over ``body`` (id and arguments): big-endian 16-bit words summed
    modulo 2**16; an odd last byte is XORed in."""
    n = len(body)
    words = _WORDS.get(n >> 1)
    if words is None:
        words = _WORDS[n >> 1] = struct.Struct(f">{n >> 1}H")
    c = sum(words.unpack_from(body)) & 0xFFFF
    if n & 1:
        c ^= body[-1]
    return c


_WORDS: dict[int, struct.Struct] = {}


def frame(body: bytes) -> bytes:
    """The wire packet for ``body`` (an id and its arguments, at most 252 bytes)."""
    body = bytes(body)
    if not 1 <= len(body) <= MAX_COUNT - 2:
        raise InputError(f"ARCOS packet body: expected 1..{MAX_COUNT - 2} bytes, got {len(body)}")
    ck = checksum(body)
    return HEADER + bytes([len(body) + 2]) + body + bytes([ck >> 8, ck & 0xFF])


def p2os_accepts(packet: bytes) -> bool:
    """The check p2os_driver (packet.cpp) applies to a whole packet, for tests that show why ours differs:
    ``(chksum == (packet[size-2] << 8)) | packet[size-1]`` with an ``int16_t`` sum -- true whenever the last
    byte is non-zero, whatever the sum."""
    size = len(packet)
    c = checksum(packet[3:size - 2])
    c16 = c - 0x10000 if c >= 0x8000 else c               # int16_t: sums >= 0x8000 sign-extend
    return bool((c16 == (packet[size - 2] << 8)) | packet[size - 1])


class PacketParser:
    """Incremental packet parser for either end: ``feed(bytes) -> [body, ...]`` (id + arguments, checksum off).

    A packet starts at ``FA FB``; a count below 3 cannot be one.  A count that is impossible or a checksum
    that does not match drops only the ``FA`` and the search goes on from the next byte, so a good packet
    that follows (or hides inside) garbage is still found.  So does a count whose packet is not complete yet while
    a complete packet with a good checksum starts after its header (``stale_headers``): a real packet arrives
    whole before the next one starts, so such a header is garbage, and without this rule a stray ``FA FB`` with a
    count of 250 at the end of garbage held the good packets after it back until 253 bytes had come (a
    handshake's six-byte replies: 10 s).  Counters: ``packets``, ``packet_bytes``, ``bad_checksum``,
    ``bad_count``, ``stale_headers``, ``dropped_bytes``; with ``pending`` the bytes add up to ``fed``.
    Never raises on any bytes.
    """

    def __init__(self):
        self._buf = bytearray()
        self.fed = 0
        self.packets = 0
        self.packet_bytes = 0
        self.bad_checksum = 0
        self.bad_count = 0
        self.stale_headers = 0
        self.dropped_bytes = 0

    @staticmethod
    def _good_packet_after(buf: bytearray, i: int, end: int) -> bool:
        """A complete packet with a good checksum starts at a header after the one at ``i``."""
        k = buf.find(HEADER, i + 1)
        while 0 <= k and k + 3 <= end:
            total = buf[k + 2] + 3
            if buf[k + 2] >= 3 and k + total <= end and \
                    checksum(bytes(buf[k + 3:k + total - 2])) == (buf[k + total - 2] << 8 | buf[k + total - 1]):
                return True
            k = buf.find(HEADER, k + 1)
        return False

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a possible packet."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[bytes]:
        self.fed += len(data)
        buf = self._buf
        buf += data
        out: list[bytes] = []
        i, end = 0, len(buf)
        while i < end:
            j = buf.find(HEADER, i)
            if j < 0:
                keep = 1 if buf[end - 1] == 0xFA else 0      # a header split across feeds
                self.dropped_bytes += end - keep - i
                i = end - keep
                break
            self.dropped_bytes += j - i
            i = j
            if end - i < 3:
                break
            count = buf[i + 2]
            if count < 3:
                self.bad_count += 1
                self.dropped_bytes += 1
                i += 1
                continue
            total = count + 3
            if end - i < total:
                if self._good_packet_after(buf, i, end):   # garbage that looked like a long packet's start
                    self.stale_headers += 1
                    self.dropped_bytes += 1
                    i += 1
                    continue
                break
            body = bytes(buf[i + 3:i + total - 2])
            if checksum(body) != (buf[i + total - 2] << 8 | buf[i + total - 1]):
                self.bad_checksum += 1
                self.dropped_bytes += 1
                i += 1
                continue
            out.append(body)
            self.packets += 1
            self.packet_bytes += total
            i += total
        del buf[:i]
        return out


# ----------------------------------------------------------------------------- arguments
def int_arg(value: int) -> bytes:
    """ArRobotPacketSender::comInt's argument: INTARG or NINTARG, then the magnitude as a little-endian u16 (a short:
    -32768 goes as NINTARG 0x8000, as ARIA's ``-val`` promoted to int gives it; VEL2 with left -128 sends it)."""
    value = int(value)
    if not -32768 <= value <= 32767:
        raise InputError(f"ARCOS integer argument {value}: expected -32768..32767 (a short)")
    return bytes([NINTARG if value < 0 else INTARG]) + abs(value).to_bytes(2, "little")


def str_arg(text: bytes | str, length_byte: bool = True) -> bytes:
    """A string argument: STRARG, a length byte, the characters and a NUL as ARIA's comStr sends it, or
    (``length_byte=False``) the characters and a NUL as Soar's client does."""
    data = text.encode("latin-1") if isinstance(text, str) else bytes(text)
    if len(data) > MAX_STR:
        raise InputError(f"ARCOS string argument: expected at most {MAX_STR} bytes, got {len(data)}")
    return bytes([STRARG]) + (bytes([len(data)]) if length_byte else b"") + data + b"\0"


@dataclass(frozen=True)
class Command:
    """One client command as the robot reads it.  ``kind``: "none" (no argument), "int", "str" or "raw"
    (an argument type byte we do not know, or an integer cut short); ``value`` the integer, the string's
    bytes, or the raw argument bytes."""
    id: int
    kind: str
    value: int | bytes | None = None


def parse_command(body: bytes) -> Command:
    """The command in ``body``, in any of the argument forms ARIA, p2os and Soar send.  Never raises for a
    non-empty body."""
    cid, args = body[0], body[1:]
    if not args:
        return Command(cid, "none")
    kind = args[0]
    if kind in (INTARG, NINTARG) and len(args) >= 3:
        mag = args[1] | args[2] << 8
        return Command(cid, "int", -mag if kind == NINTARG else mag)
    if kind == STRARG:
        rest = args[1:]
        if rest and 1 + rest[0] <= len(rest) and rest[1 + rest[0]:] in (b"", b"\0"):
            return Command(cid, "str", bytes(rest[1:1 + rest[0]]))       # ARIA: length byte (and a NUL)
        nul = rest.find(0)
        return Command(cid, "str", bytes(rest if nul < 0 else rest[:nul]))   # Soar: NUL-terminated
    return Command(cid, "raw", bytes(args))


# ----------------------------------------------------------------------------- client commands (bytes)
def command(cid: int, value: int | None = None) -> bytes:
    """The packet for command ``cid`` with no argument (``value`` None) or an integer argument."""
    return frame(bytes([cid]) + (b"" if value is None else int_arg(value)))


def sync(n: int) -> bytes:
    """SYNC0, SYNC1 or SYNC2: ``FA FB 03 0n 00 0n``."""
    if n not in (0, 1, 2):
        raise InputError(f"ARCOS SYNC{n}: expected 0, 1 or 2")
    return command(n)


def pulse() -> bytes:
    return command(PULSE)


def open_() -> bytes:
    """OPEN as ARIA sends it (``comInt(OPEN, 1)``); the emulator also takes it bare, as p2os sends it."""
    return command(OPEN, 1)


def close() -> bytes:
    """CLOSE as ARIA sends it (``comInt(CLOSE, 1)``)."""
    return command(CLOSE, 1)


def enable(on: bool) -> bytes:
    return command(ENABLE, 1 if on else 0)


def vel(mm_s: int) -> bytes:
    """Forward velocity, mm/s."""
    return command(VEL, mm_s)


def rvel(deg_s: int) -> bytes:
    """Turn rate, degrees/s counter-clockwise."""
    return command(RVEL, deg_s)


def vel2_value(left: int, right: int) -> int:
    """The integer ARIA's ``com2Bytes(VEL2, left, right)`` hands to comInt: ``(short)((left & 0xff) << 8) +
    (right & 0xff)``; each wheel in Vel2Divisor units (-128..127)."""
    for name, v in (("left", left), ("right", right)):
        if not -128 <= int(v) <= 127:
            raise InputError(f"ARCOS VEL2 {name} {v}: expected -128..127 (units of Vel2Divisor mm/s)")
    high = (int(left) & 0xFF) << 8
    return (high - 0x10000 if high >= 0x8000 else high) + (int(right) & 0xFF)


def vel2_wheels(value: int) -> tuple[int, int]:
    """(left, right) from a VEL2 integer argument: high byte left, low byte right, each signed."""
    u = int(value) & 0xFFFF
    left, right = u >> 8, u & 0xFF
    return (left - 256 if left > 127 else left), (right - 256 if right > 127 else right)


def vel2(left: int, right: int) -> bytes:
    """Independent wheel velocities in Vel2Divisor units (20 mm/s on a P3-DX)."""
    return command(VEL2, vel2_value(left, right))


def sonar(on: bool) -> bytes:
    return command(SONAR, 1 if on else 0)


def seto() -> bytes:
    """Reset the robot's odometry to (0, 0, 0)."""
    return command(SETO)


def stop() -> bytes:
    return command(STOP)


def e_stop() -> bytes:
    return command(E_STOP)


def config() -> bytes:
    """Ask for a CONFIGpac (ARIA: ``comInt(CONFIG, 1)``)."""
    return command(CONFIG, 1)


# ----------------------------------------------------------------------------- robot replies
def _strings(data: bytes, n: int) -> tuple[list[str], int]:
    """``n`` NUL-terminated strings from ``data`` (a missing NUL ends the last one at the end); and where
    reading stopped."""
    out, i = [], 0
    for _ in range(n):
        j = data.find(0, i)
        j = len(data) if j < 0 else j
        out.append(data[i:j].decode("latin-1"))
        i = min(len(data), j + 1)
    return out, i


def sync2_reply(name: str, robot_class: str, subclass: str) -> bytes:
    """The robot's answer to SYNC2: id 2 and three NUL-terminated strings."""
    return bytes([SYNC2]) + b"".join(s.encode("latin-1") + b"\0" for s in (name, robot_class, subclass))


def parse_sync2(body: bytes) -> tuple[str, str, str]:
    """(name, class, subclass) of a SYNC2 reply body; ARIA lower-cases the subclass, so do we."""
    (name, cls, sub), _ = _strings(body[1:], 3)
    return name, cls, sub.lower()


# CONFIGpac fields in ArRobotConfigPacketReader order: "s" NUL-terminated string, "B" u8, "H" u16, "h" s16.
CONFIG_FIELDS: tuple[tuple[str, str], ...] = (
    ("robot_class", "s"), ("subclass", "s"), ("serial", "s"), ("four_motors", "B"), ("rot_vel_top", "H"),
    ("trans_vel_top", "H"), ("rot_accel_top", "H"), ("trans_accel_top", "H"), ("pwm_max", "H"), ("name", "s"),
    ("sip_cycle_ms", "B"), ("host_baud", "B"), ("aux1_baud", "B"), ("has_gripper", "H"), ("front_sonar", "H"),
    ("rear_sonar", "B"), ("low_battery_dv", "H"), ("rev_count", "H"), ("watchdog_ms", "H"), ("normal_mpacs", "B"),
    ("stall_val", "H"), ("stall_count", "H"), ("joy_vel", "H"), ("joy_rot_vel", "H"), ("rot_vel_max", "H"),
    ("trans_vel_max", "H"), ("rot_accel", "H"), ("rot_decel", "H"), ("rot_kp", "H"), ("rot_kv", "H"),
    ("rot_ki", "H"), ("trans_accel", "H"), ("trans_decel", "H"), ("trans_kp", "H"), ("trans_kv", "H"),
    ("trans_ki", "H"), ("front_bumps", "B"), ("rear_bumps", "B"), ("charger", "B"), ("sonar_cycle_ms", "B"),
    ("reset_baud", "B"), ("gyro_type", "B"), ("drift_factor", "h"), ("aux2_baud", "B"), ("aux3_baud", "B"),
    ("ticks_mm", "H"), ("shutdown_volts", "H"), ("firmware", "s"), ("gyro_cw", "H"), ("gyro_ccw", "H"),
    ("kinematics_delay", "B"), ("lat_vel_top", "H"), ("lat_accel_top", "H"), ("lat_vel_max", "H"),
    ("lat_accel", "H"), ("lat_decel", "H"), ("charge_threshold", "H"),
)


def encode_config(values: dict) -> bytes:
    """A CONFIGpac body (id 0x20) from ``values`` (missing fields are 0 or empty)."""
    out = bytearray([CONFIG_PAC])
    for name, kind in CONFIG_FIELDS:
        v = values.get(name, "" if kind == "s" else 0)
        if kind == "s":
            out += str(v).encode("latin-1") + b"\0"
        else:
            out += struct.pack("<" + kind, int(v))
    return bytes(out)


def decode_config(body: bytes) -> dict:
    """The CONFIGpac fields present in ``body`` (a short packet gives the leading ones)."""
    data, i, out = body[1:], 0, {}
    for name, kind in CONFIG_FIELDS:
        if i >= len(data):
            break
        if kind == "s":
            (out[name],), n = _strings(data[i:], 1)
            i += n
            continue
        size = struct.calcsize(kind)
        if i + size > len(data):
            break
        out[name] = struct.unpack_from("<" + kind, data, i)[0]
        i += size
    return out


# ----------------------------------------------------------------------------- standard SIP
_SIP_HEAD = struct.Struct("<HHhhhBHhHBB")       # x, y, th, lvel, rvel, battery, stall, control, flags, compass, n
_SONAR = struct.Struct("<BH")
# The optional tail, read while bytes remain (processMotorPacket): (name, struct code).
SIP_TAIL: tuple[tuple[str, str], ...] = (
    ("grip_anport", "H"), ("analog", "B"), ("digin", "B"), ("digout", "B"), ("battery_x10", "H"),
    ("charge_state", "B"), ("rot_vel_x10", "h"), ("fault_flags", "H"), ("lat_vel", "h"), ("temperature", "b"),
    ("state_of_charge", "B"), ("uc_time_us", "I"), ("flags3", "I"),
)


_TAIL_NAMES = tuple(name for name, _ in SIP_TAIL)
_TAIL_PREFIX = [struct.Struct("<" + "".join(code for _, code in SIP_TAIL[:k])) for k in range(len(SIP_TAIL) + 1)]
_TAIL_SIZES = [st.size for st in _TAIL_PREFIX]        # bytes the first k tail fields take


@dataclass(slots=True)
class Sip:
    """A standard SIP in robot units: position in the robot's 15-bit counters (DistConvFactor mm), heading
    in 4096ths of a turn, wheel velocities in mm/s (VelConvFactor), battery in 0.1 V, sonar ranges in
    RangeConvFactor mm.  Tail fields are None when the packet ended before them."""
    x: int = 0
    y: int = 0
    th: int = 0
    left_vel: int = 0
    right_vel: int = 0
    battery_dv: int = 0
    stall_bumpers: int = 0
    control: int = 0
    flags: int = 0
    compass: int = 0
    sonars: tuple[tuple[int, int], ...] = ()
    moving: bool = False            # id 0x33 rather than 0x32
    grip_anport: int | None = None
    analog: int | None = None
    digin: int | None = None
    digout: int | None = None
    battery_x10: int | None = None
    charge_state: int | None = None
    rot_vel_x10: int | None = None  # 0.1 deg/s
    fault_flags: int | None = None
    lat_vel: int | None = None
    temperature: int | None = None
    state_of_charge: int | None = None
    uc_time_us: int | None = None
    flags3: int | None = None


def decode_sip(body: bytes) -> Sip:
    """The standard SIP in ``body`` (id 0x32 or 0x33), with ARIA's signs: XPOS and YPOS masked to 15 bits,
    THPOS, wheel velocities and CONTROL signed.  Raises :class:`SipError` if a field is cut short."""
    if not body or body[0] not in SIP_IDS:
        raise SipError(f"not a standard SIP (id {body[0] if body else None!r})")
    if len(body) < 1 + _SIP_HEAD.size:
        raise SipError(f"standard SIP of {len(body)} bytes: shorter than its {1 + _SIP_HEAD.size}-byte head")
    x, y, th, lv, rv, bat, stall, control, flags, compass, n = _SIP_HEAD.unpack_from(body, 1)
    i = 1 + _SIP_HEAD.size
    j = i + n * _SONAR.size
    if j > len(body):
        raise SipError(f"standard SIP says {n} sonar readings but has room for {(len(body) - i) // _SONAR.size}")
    sonars = tuple(_SONAR.iter_unpack(body[i:j])) if n else ()
    sip = Sip(x & 0x7FFF, y & 0x7FFF, th, lv, rv, bat, stall, control, flags, compass, sonars, body[0] == 0x33)
    left = len(body) - j
    if left:
        k = bisect.bisect_right(_TAIL_SIZES, left) - 1        # how many tail fields fit
        for name, v in zip(_TAIL_NAMES, _TAIL_PREFIX[k].unpack_from(body, j)):
            setattr(sip, name, v)
    return sip


def encode_sip(sip: Sip) -> bytes:
    """The body of ``sip``: the tail up to its last field that is not None (fields before it must be set)."""
    out = bytearray([0x33 if sip.moving else 0x32])
    out += _SIP_HEAD.pack(sip.x & 0xFFFF, sip.y & 0xFFFF, sip.th, sip.left_vel, sip.right_vel, sip.battery_dv,
                          sip.stall_bumpers, sip.control, sip.flags, sip.compass, len(sip.sonars))
    for num, rng in sip.sonars:
        out += _SONAR.pack(num, rng)
    values = [getattr(sip, name) for name, _ in SIP_TAIL]
    last = max((k for k, v in enumerate(values) if v is not None), default=-1)
    for (name, code), v in zip(SIP_TAIL[:last + 1], values):
        if v is None:
            raise InputError(f"SIP field {name}: expected a value (a later tail field is set)")
        out += struct.pack("<" + code, v)
    return bytes(out)


def wrap15(delta: int) -> int:
    """An XPOS/YPOS difference across the 15-bit wrap, as ARIA unwraps it (beyond +-0x1000 it wrapped)."""
    if delta > 0x1000:
        delta -= 0x8000
    if delta < -0x1000:
        delta += 0x8000
    return delta


# ----------------------------------------------------------------------------- robot parameters
@dataclass(frozen=True)
class SonarUnit:
    """One sonar's position (mm, robot frame: x ahead, y left) and heading (degrees, counter-clockwise)."""
    x: float
    y: float
    heading: float


@dataclass(frozen=True)
class RobotParams:
    """An ARIA robot parameter file's numbers that the driver, the emulator and the body use.

    ``angle_conv`` is exactly 2 pi / 4096 (the file rounds it to 0.00153; p2os uses 0.001534).  ``track_mm``
    is the wheel base implied by DiffConvFactor as ARIA uses it (rotational velocity = (right - left) / 2 *
    DiffConvFactor rad/s, i.e. DiffConvFactor = 1 / half the track: 2 / 0.0056 = 357 mm).  ``wheel_diameter_mm``
    is not in the parameter file: 195 mm (Webots' Pioneer 3-DX documentation says 19 cm wheels; a Webots
    Pioneer 3-DX model uses a 97.5 mm radius)."""
    robot_class: str
    subclass: str
    radius_mm: float
    width_mm: float
    length_mm: float
    length_front_mm: float
    length_rear_mm: float
    max_vel_mm_s: float
    max_rvel_deg_s: float
    angle_conv: float
    dist_conv: float
    vel_conv: float
    range_conv: float
    diff_conv: float
    vel2_divisor: float
    wheel_diameter_mm: float
    sonar_units: tuple[SonarUnit, ...] = field(default=())
    sonar_max_range_mm: float = 5000.0     # ARIA's sonar range device: beyond this a reading means no echo

    @property
    def track_mm(self) -> float:
        return 2.0 / self.diff_conv

    def sonar_point(self, num: int, range_mm: float) -> tuple[float, float]:
        """(bearing rad, distance m) from the robot centre of a ``range_mm`` reading of sonar ``num``: the
        echo lies ``range_mm`` along the sonar's heading from the sonar (as ARIA places sonar readings)."""
        u = self.sonar_units[num]
        h = math.radians(u.heading)
        px = u.x + range_mm * math.cos(h)
        py = u.y + range_mm * math.sin(h)
        return math.atan2(py, px), math.hypot(px, py) / 1000.0


# params/p3dx-sh.p (AriaCoda), SonarUnit lines 0-15: x mm, y mm, heading deg.
P3DX_SH = RobotParams(
    robot_class="Pioneer", subclass="p3dx-sh", radius_mm=250.0, width_mm=425.0, length_mm=511.0,
    length_front_mm=210.0, length_rear_mm=301.0, max_vel_mm_s=2200.0, max_rvel_deg_s=500.0,
    angle_conv=2.0 * math.pi / 4096.0, dist_conv=1.0, vel_conv=1.0, range_conv=1.0, diff_conv=0.0056,
    vel2_divisor=20.0, wheel_diameter_mm=195.0,
    sonar_units=tuple(SonarUnit(*u) for u in (
        (69, 136, 90), (114, 119, 50), (148, 78, 30), (166, 27, 10), (166, -27, -10), (148, -78, -30),
        (114, -119, -50), (69, -136, -90), (-157, -136, -90), (-203, -119, -130), (-237, -78, -150),
        (-255, -27, -170), (-255, 27, 170), (-237, 78, 150), (-203, 119, 130), (-157, 136, 90))),
)
FRONT_SONARS = tuple(range(8))       # the P3-DX's two sonar arrays (ARCOS array 1 and 2)
REAR_SONARS = tuple(range(8, 16))
SUBCLASSES = {P3DX_SH.subclass: P3DX_SH}


def robot_params(subclass: str) -> RobotParams:
    if subclass not in SUBCLASSES:
        raise InputError(f"ARCOS robot subclass {subclass!r}: expected one of {', '.join(SUBCLASSES)}")
    return SUBCLASSES[subclass]

