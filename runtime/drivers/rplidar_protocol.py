"""Slamtec RPLIDAR A1/A2 serial protocol: pure encode/decode and incremental parsers for both directions.

The subset here is what the standard (legacy) scan needs, per Slamtec's "RPLIDAR Interface Protocol and Application
Notes" (A1 & A2, rev 1.1) and its SDK header ``rplidar_protocol.h`` / ``rplidar_cmd.h``:

* a request is ``A5 cmd``; a command with the 0x80 bit set carries ``size payload checksum`` after it, the checksum
  the XOR of every byte before it (``A5`` and ``cmd`` included);
* a response starts with a 7-byte descriptor ``A5 5A`` + a little-endian 32-bit word (low 30 bits: the length of one
  data response; high 2 bits: the send mode, 0 single, 1 multiple) + a data-type byte;
* GET_INFO (0x50) answers type 0x04, 20 bytes: model, firmware minor, firmware major, hardware, 16-byte serial;
* GET_HEALTH (0x52) answers type 0x06, 3 bytes: status (0 good, 1 warning, 2 error) and a little-endian 16-bit error
  code (the SDK's packed ``_u16``; the PyPI clients ``rplidar`` 0.9.2 and ``pyrplidar`` 0.1.2 read it big-endian);
* STOP (0x25) and RESET (0x40) have no answer; SCAN (0x20) and FORCE_SCAN (0x21) answer type 0x81, length 5, send
  mode multiple, then 5-byte measurement nodes until STOP: byte 0 = quality << 2 | !S << 1 | S (S: first node of
  a new revolution), byte 1 bit 0 the check bit C = 1 and bits 1-7 with byte 2 the angle in 1/64 degree
  (``angle_q6``), bytes 3-4 the distance in 1/4 mm (``distance_q2``, 0: no measurement), little-endian;
* MOTOR_PWM (0xF0, payload: little-endian 16-bit duty 0-1023) drives an A2's motor through its accessory board;
  an A1's motor runs while the host holds DTR low (the MOTOCTL line), which no byte carries.

Angles grow clockwise seen from above, 0 along the scanner's forward mark (the datasheets' left-handed frame).

:class:`ResponseParser` (host side) and :class:`RequestParser` (device side) take the byte stream in any split,
never raise on input, and count every byte they drop: garbage between frames, a mid-frame start, a failed check bit.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import NamedTuple

SYNC = 0xA5
SYNC2 = 0x5A
HAS_PAYLOAD = 0x80

CMD_STOP = 0x25
CMD_RESET = 0x40
CMD_SCAN = 0x20
CMD_FORCE_SCAN = 0x21
CMD_GET_INFO = 0x50
CMD_GET_HEALTH = 0x52
CMD_MOTOR_PWM = 0xF0

TYPE_INFO = 0x04
TYPE_HEALTH = 0x06
TYPE_SCAN = 0x81

MODE_SINGLE = 0
MODE_MULTIPLE = 1

DESCRIPTOR_LEN = 7
INFO_LEN = 20
HEALTH_LEN = 3
NODE_LEN = 5
MAX_PWM = 1023
DEFAULT_PWM = 660                # the SDK's and the ``rplidar`` client's default A2 duty
FULL_TURN_Q6 = 360 * 64

HEALTH_GOOD, HEALTH_WARNING, HEALTH_ERROR = 0, 1, 2
HEALTH_NAMES = {HEALTH_GOOD: "good", HEALTH_WARNING: "warning", HEALTH_ERROR: "error"}

# response types this module decodes -> (length, send mode) they must come with
KNOWN_RESPONSES = {TYPE_INFO: (INFO_LEN, MODE_SINGLE), TYPE_HEALTH: (HEALTH_LEN, MODE_SINGLE),
                   TYPE_SCAN: (NODE_LEN, MODE_MULTIPLE)}
_NODES = struct.Struct("<BHH")
RUN_NODES = 512                  # nodes decoded per pass over the buffer
LOCK_NODES = 3                   # good nodes in a row that (re)gain the node stream after a loss


# ------------------------------------------------------------------ requests

def checksum(data: bytes) -> int:
    """XOR of every byte."""
    c = 0
    for b in data:
        c ^= b
    return c


def request(cmd: int, payload: bytes | None = None) -> bytes:
    """A request: ``A5 cmd`` and, for a payload command, ``size payload checksum``."""
    if not 0 <= cmd <= 0xFF:
        raise ValueError(f"command: expected a byte, got {cmd!r}")
    out = bytes((SYNC, cmd))
    if payload is None:
        return out
    if len(payload) > 0xFF:
        raise ValueError(f"payload: expected at most 255 bytes, got {len(payload)}")
    out += bytes((len(payload),)) + bytes(payload)
    return out + bytes((checksum(out),))


def motor_pwm(pwm: int) -> bytes:
    """MOTOR_PWM with duty ``pwm`` (0 stops the A2's motor, 1023 full)."""
    if not 0 <= pwm <= MAX_PWM:
        raise ValueError(f"motor pwm: expected 0..{MAX_PWM}, got {pwm!r}")
    return request(CMD_MOTOR_PWM, struct.pack("<H", pwm))


@dataclass(frozen=True)
class Request:
    """One request the device received; ``payload`` is None for a command without one."""
    cmd: int
    payload: bytes | None = None

    @property
    def pwm(self) -> int | None:
        """The duty of a well-formed MOTOR_PWM, else None."""
        if self.cmd == CMD_MOTOR_PWM and self.payload is not None and len(self.payload) == 2:
            return struct.unpack("<H", self.payload)[0]
        return None


# ------------------------------------------------------------------ responses

def descriptor(length: int, mode: int, dtype: int) -> bytes:
    """``A5 5A`` + 30-bit length | 2-bit send mode << 30 (little-endian) + data type."""
    if not 0 <= length < 1 << 30 or mode not in (0, 1, 2, 3) or not 0 <= dtype <= 0xFF:
        raise ValueError(f"descriptor: bad length {length!r}, mode {mode!r} or type {dtype!r}")
    return bytes((SYNC, SYNC2)) + struct.pack("<I", length | mode << 30) + bytes((dtype,))


def parse_descriptor(raw: bytes) -> tuple[int, int, int] | None:
    """(length, send mode, data type) of a 7-byte descriptor, or None if it does not start ``A5 5A``."""
    if len(raw) != DESCRIPTOR_LEN or raw[0] != SYNC or raw[1] != SYNC2:
        return None
    word = struct.unpack_from("<I", raw, 2)[0]
    return word & 0x3FFFFFFF, word >> 30, raw[6]


@dataclass(frozen=True)
class DeviceInfo:
    model: int                     # high nibble the series (1: A1, 2: A2), low nibble the sub-model (8: M8)
    firmware: tuple[int, int]      # (major, minor)
    hardware: int
    serial: bytes                  # 16 bytes

    def encode(self) -> bytes:
        if len(self.serial) != 16:
            raise ValueError("serial: expected 16 bytes")
        return bytes((self.model, self.firmware[1], self.firmware[0], self.hardware)) + bytes(self.serial)

    @classmethod
    def decode(cls, raw: bytes) -> "DeviceInfo":
        return cls(raw[0], (raw[2], raw[1]), raw[3], bytes(raw[4:20]))

    @property
    def name(self) -> str:
        """As the SDK names it, e.g. ``A1M8``."""
        return f"A{self.model >> 4}M{self.model & 0xF}"


@dataclass(frozen=True)
class Health:
    status: int                    # HEALTH_GOOD, HEALTH_WARNING, HEALTH_ERROR
    error_code: int = 0

    def encode(self) -> bytes:
        return bytes((self.status,)) + struct.pack("<H", self.error_code)

    @classmethod
    def decode(cls, raw: bytes) -> "Health":
        return cls(raw[0], struct.unpack_from("<H", raw, 1)[0])

    @property
    def name(self) -> str:
        return HEALTH_NAMES.get(self.status, f"status {self.status}")


class Node(NamedTuple):
    """One measurement: ``angle`` degrees clockwise, ``distance`` mm (0: none), ``quality`` 0-63."""
    start: bool
    quality: int
    angle_q6: int
    distance_q2: int

    @property
    def angle(self) -> float:
        return self.angle_q6 / 64.0

    @property
    def distance(self) -> float:
        return self.distance_q2 / 4.0


def encode_node(start: bool, quality: int, angle_q6: int, distance_q2: int) -> bytes:
    """The 5 bytes of one measurement node."""
    if not (0 <= quality < 64 and 0 <= angle_q6 < 1 << 15 and 0 <= distance_q2 < 1 << 16):
        raise ValueError(f"node: quality {quality!r}, angle_q6 {angle_q6!r} or distance_q2 {distance_q2!r} out of range")
    s = 1 if start else 0
    return struct.pack("<BHH", quality << 2 | (s ^ 1) << 1 | s, angle_q6 << 1 | 1, distance_q2)


def decode_node(raw: bytes | bytearray, pos: int = 0) -> Node | None:
    """The node at ``raw[pos:pos + 5]``, or None when its start flags agree, its check bit is 0 or its angle is not
    below a full turn."""
    b0, b1 = raw[pos], raw[pos + 1]
    if (b0 ^ (b0 >> 1)) & 1 == 0 or b1 & 1 == 0:
        return None
    angle = (b1 >> 1) | raw[pos + 2] << 7
    if angle >= FULL_TURN_Q6:
        return None
    return Node(bool(b0 & 1), b0 >> 2, angle, raw[pos + 3] | raw[pos + 4] << 8)


# ------------------------------------------------------------------ parsers

@dataclass
class ParserStats:
    """Every byte fed is in a good frame, dropped, or still pending."""
    bytes: int = 0
    good_bytes: int = 0
    dropped_bytes: int = 0
    frames: int = 0                # descriptors + single responses + nodes (host); requests (device)
    nodes: int = 0
    bad_nodes: int = 0             # a node position that failed its checks (the stream then resynchronises)
    bad_checksum: int = 0
    unknown: int = 0               # descriptors of a type this parser does not decode; unknown commands
    resyncs: int = 0               # times the node stream was regained after a loss
    kinds: dict = field(default_factory=dict)


class ResponseParser:
    """Host side: ``feed(bytes) -> list`` of :class:`DeviceInfo`, :class:`Health` and :class:`Node` in stream order.

    Outside a node stream it hunts for a descriptor of a known type (:data:`KNOWN_RESPONSES`) and then takes that
    response's bytes.  In a node stream it takes a node at a time; a node that fails its checks drops one byte and
    the stream must then show :data:`LOCK_NODES` good nodes in a row before any is handed on (a misaligned start
    passes the checks by chance about once in eleven tries), unless a known descriptor starts there (the answer to a
    new request).  Never raises on input."""

    def __init__(self):
        self.stats = ParserStats()
        self._buf = bytearray()
        self._single: int | None = None       # data type of the single response whose body comes next
        self._streaming = False                # after a SCAN descriptor
        self._locked = False

    @property
    def pending_bytes(self) -> int:
        return len(self._buf)

    @property
    def streaming(self) -> bool:
        return self._streaming

    def reset(self) -> None:
        """Forget any stream in progress (the host sent STOP or RESET): pending bytes count as dropped."""
        self.stats.dropped_bytes += len(self._buf)
        self._buf.clear()
        self._single = None
        self._streaming = self._locked = False

    def feed(self, data: bytes) -> list:
        st = self.stats
        st.bytes += len(data)
        buf = self._buf
        buf += data
        out: list = []
        pos, n = 0, len(buf)
        while pos < n:
            if self._single is not None:
                size = KNOWN_RESPONSES[self._single][0]
                if n - pos < size:
                    break
                raw = bytes(buf[pos:pos + size])
                out.append(DeviceInfo.decode(raw) if self._single == TYPE_INFO else Health.decode(raw))
                st.frames += 1
                st.good_bytes += size
                pos += size
                self._single = None
                continue
            if buf[pos] == SYNC:
                if n - pos < DESCRIPTOR_LEN and (n - pos < 2 or buf[pos + 1] == SYNC2):
                    break                           # perhaps a descriptor: wait for the rest
                got = parse_descriptor(bytes(buf[pos:pos + DESCRIPTOR_LEN]))
                if got is not None and KNOWN_RESPONSES.get(got[2]) == got[:2]:
                    st.frames += 1
                    st.good_bytes += DESCRIPTOR_LEN
                    st.kinds[got[2]] = st.kinds.get(got[2], 0) + 1
                    pos += DESCRIPTOR_LEN
                    if got[2] == TYPE_SCAN:
                        self._streaming, self._locked = True, False
                    else:
                        self._streaming, self._single = False, got[2]
                    continue
                if got is not None and not self._streaming:
                    st.unknown += 1
            if self._streaming:
                k = self._nodes(buf, pos, n, out)
                if k is None:
                    break
                if k > pos:
                    pos = k
                    continue
                st.bad_nodes += 1
            st.dropped_bytes += 1
            pos += 1
        del buf[:pos]
        return out

    def _nodes(self, buf: bytearray, pos: int, n: int, out: list) -> int | None:
        """Take good nodes from ``pos``: the position after them, ``pos`` if the one there is bad, None to wait."""
        need = NODE_LEN if self._locked else NODE_LEN * LOCK_NODES
        if n - pos < need:
            return None
        if not self._locked:
            if any(decode_node(buf, pos + k * NODE_LEN) is None for k in range(LOCK_NODES)):
                return pos
            self._locked = True
            self.stats.resyncs += 1
        first, make = pos, Node._make
        end = pos + min((n - pos) // NODE_LEN, RUN_NODES) * NODE_LEN        # bounded copies, whatever the input
        for b0, word, dist in _NODES.iter_unpack(bytes(buf[pos:end])):   # decode_node, unrolled over the run
            angle = word >> 1
            if (b0 ^ (b0 >> 1)) & 1 == 0 or word & 1 == 0 or angle >= FULL_TURN_Q6:
                self._locked = False
                break
            out.append(make((b0 & 1 == 1, b0 >> 2, angle, dist)))
            pos += NODE_LEN
        k = (pos - first) // NODE_LEN
        self.stats.nodes += k
        self.stats.frames += k
        self.stats.good_bytes += pos - first
        return pos


class RequestParser:
    """Device side: ``feed(bytes) -> list[Request]``.  Bytes before an ``A5`` are dropped; a payload request whose
    checksum fails is dropped and counted.  Never raises on input."""

    def __init__(self):
        self.stats = ParserStats()
        self._buf = bytearray()

    @property
    def pending_bytes(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes) -> list[Request]:
        st = self.stats
        st.bytes += len(data)
        buf = self._buf
        buf += data
        out: list[Request] = []
        pos, n = 0, len(buf)
        while pos < n:
            if buf[pos] != SYNC:
                j = buf.find(bytes((SYNC,)), pos)
                end = n if j < 0 else j
                st.dropped_bytes += end - pos
                pos = end
                continue
            if n - pos < 2:
                break
            cmd = buf[pos + 1]
            if not cmd & HAS_PAYLOAD:
                out.append(Request(cmd))
                size = 2
            else:
                if n - pos < 3 or n - pos < 4 + buf[pos + 2]:
                    break
                size = 4 + buf[pos + 2]
                frame = bytes(buf[pos:pos + size])
                if checksum(frame[:-1]) != frame[-1]:
                    st.bad_checksum += 1
                    st.dropped_bytes += 1          # the A5 only: a real request may start inside
                    pos += 1
                    continue
                out.append(Request(cmd, frame[3:-1]))
            st.frames += 1
            st.good_bytes += size
            st.kinds[cmd] = st.kinds.get(cmd, 0) + 1
            pos += size
        del buf[:pos]
        return out
