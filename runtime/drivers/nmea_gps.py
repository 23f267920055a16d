"""NMEA 0183 GPS receiver: a pure byte-stream parser (:class:`NmeaParser`) and a polled serial shell
(:class:`NmeaGps`).

Framing: a sentence runs from ``$`` to ``\\n``.  Bytes outside a sentence, a sentence cut short by
the next ``$``, and a sentence longer than ``max_line`` are dropped and counted.  Each complete line
goes through ``pynmea2.parse(check=True)``; GGA and RMC become fixes, other good sentences are
counted by type and ignored.  GGA and RMC of one epoch (same UTC time) merge into one
:class:`GpsFix`; an epoch is emitted when it has both, when the next epoch starts, or when it has
waited ``epoch_timeout`` seconds (receivers that send only one of the two).
"""
from __future__ import annotations

import datetime
import math
import re
from dataclasses import dataclass, field
from typing import Literal, Optional

import pynmea2
import serial

from runtime.config.build import rng
from runtime.errors import InputError
from runtime.log import get_logger

KNOT = 1852.0 / 3600.0             # m/s
MAX_LINE = 164                     # NMEA allows 82 characters; twice that tolerates chatty receivers
VALID_QUALITY = (1, 2, 3, 4, 5)    # GPS, DGPS, PPS, RTK fixed, RTK float (0 none, 6 estimated, ...)
_DM = re.compile(r"^(\d+)(\d\d\.\d+)$")


@dataclass
class GpsFix:
    """One receiver epoch.  ``alt`` is the ellipsoidal height (GGA altitude + geoid separation);
    ``speed`` m/s and ``course`` rad clockwise from true north come from RMC (nan if absent)."""
    t: float                       # the ``now`` at which the epoch's first sentence arrived
    lat: float = math.nan          # degrees, north positive
    lon: float = math.nan          # degrees, east positive
    alt: float = math.nan          # m
    fix_quality: int = 0           # GGA quality indicator (1 when only an RMC with status A was seen)
    num_sats: int = 0
    hdop: float = math.nan
    speed: float = math.nan
    course: float = math.nan
    valid: bool = False
    utc: Optional[float] = None    # seconds since UTC midnight of the epoch, None if not sent


@dataclass
class NmeaStats:
    """What the parser saw.  Every byte fed is in a good sentence, dropped, or still buffered."""
    bytes: int = 0                 # bytes fed
    good_bytes: int = 0            # bytes of sentences that parsed (incl. ignored types)
    dropped_bytes: int = 0         # everything else: noise between sentences and bad sentences
    sentences: int = 0             # good GGA and RMC sentences
    fixes: int = 0                 # GpsFix objects emitted
    ignored: int = 0               # good sentences of other types
    ignored_types: dict = field(default_factory=dict)
    bad_checksum: int = 0
    parse_errors: int = 0          # pynmea2 rejected it, or a field is malformed or out of range
    non_ascii: int = 0
    truncated: int = 0             # cut by the next '$', or no '*hh' checksum
    overlong: int = 0              # no end of line within max_line bytes
    read_errors: int = 0           # serial read failures (driver only)
    outages: int = 0               # episodes of no fix for the driver's ``silence`` seconds (driver only)

    @property
    def bad(self) -> int:
        return self.bad_checksum + self.parse_errors + self.non_ascii + self.truncated + self.overlong


def _opt_float(s: str) -> Optional[float]:
    if s == "":
        return None
    v = float(s)
    if not math.isfinite(v):
        raise ValueError(f"non-finite number {s!r}")
    return v


def _opt_int(s: str) -> Optional[int]:
    return None if s == "" else int(s)


def _coord(value: str, hemi: str, pos: str, neg: str, limit: float) -> Optional[float]:
    """``dddmm.mmmm`` + hemisphere -> signed degrees; None when the receiver left it empty."""
    if value == "" and hemi == "":
        return None
    m = _DM.match(value)
    if not m or hemi not in (pos, neg):
        raise ValueError(f"bad coordinate {value!r} {hemi!r}")
    deg, minutes = int(m.group(1)), float(m.group(2))
    out = deg + minutes / 60.0
    if minutes >= 60.0 or out > limit:
        raise ValueError(f"coordinate out of range {value!r}")
    return out if hemi == pos else -out


def _utc_seconds(msg) -> Optional[float]:
    ts = msg.timestamp
    if ts is None:
        return None
    if not isinstance(ts, datetime.time):      # pynmea2 hands back the raw text when it cannot convert
        raise ValueError(f"bad time {ts!r}")
    return ts.hour * 3600 + ts.minute * 60 + ts.second + ts.microsecond * 1e-6


class _Epoch:
    """GGA and RMC fields of one epoch collected so far."""

    def __init__(self, t: float, utc: Optional[float]):
        self.t, self.utc = t, utc
        self.gga: Optional[dict] = None
        self.rmc: Optional[dict] = None

    def fix(self) -> GpsFix:
        out = GpsFix(t=self.t, utc=self.utc)
        gga, rmc = self.gga, self.rmc
        src = gga if gga is not None and gga["lat"] is not None else rmc
        has_pos = src is not None and src["lat"] is not None and src["lon"] is not None
        if has_pos:
            out.lat, out.lon = src["lat"], src["lon"]
        ok = has_pos
        if gga is not None:
            out.fix_quality = gga["quality"]
            out.num_sats = gga["sats"]
            out.hdop = gga["hdop"]
            out.alt = gga["alt"]
            ok = ok and gga["quality"] in VALID_QUALITY
        if rmc is not None:
            out.speed, out.course = rmc["speed"], rmc["course"]
            ok = ok and rmc["status"] == "A"
            if gga is None and rmc["status"] == "A":
                out.fix_quality = 1
        out.valid = ok
        return out


class NmeaParser:
    """Pure NMEA 0183 stream parser: ``feed(bytes, now) -> list[GpsFix]``; never raises on input."""

    def __init__(self, max_line: int = MAX_LINE, epoch_timeout: float = 0.5, robot_id=None):
        self.max_line = max_line
        self.epoch_timeout = epoch_timeout
        self.stats = NmeaStats()
        self._buf = bytearray()
        self._epoch: Optional[_Epoch] = None
        self._log = get_logger("gps", robot_id)

    @property
    def pending_bytes(self) -> int:
        """Bytes of an unfinished sentence held for the next feed."""
        return len(self._buf)

    def feed(self, data: bytes, now: float = 0.0) -> list[GpsFix]:
        """Consume ``data`` (any split of the stream) received at ``now``; return completed fixes."""
        out: list[GpsFix] = []
        if self._epoch is not None and now - self._epoch.t > self.epoch_timeout:
            out.append(self._emit())
        self.stats.bytes += len(data)
        buf = self._buf
        buf += data
        pos, n = 0, len(buf)
        while pos < n:
            if buf[pos] != 0x24:                       # not '$': noise between sentences
                j = buf.find(b"$", pos)
                end = n if j < 0 else j
                self.stats.dropped_bytes += end - pos
                pos = end
                continue
            lim = min(n, pos + self.max_line)          # a sentence's '\n' must lie before lim
            nl = buf.find(b"\n", pos + 1, lim)
            nd = buf.find(b"$", pos + 1, lim if nl < 0 else nl)
            if nd >= 0:                                # the next sentence began before this one ended
                self._bad("truncated", nd - pos, buf[pos:nd])
                pos = nd
                continue
            if nl < 0:
                if n - pos < self.max_line:            # incomplete: wait for more bytes
                    break
                self._bad("overlong", lim - pos, buf[pos:lim])   # its tail is noise until the next '$'
                pos = lim
                continue
            end = nl + 1
            out.extend(self._line(bytes(buf[pos:end]), now))
            pos = end
        del buf[:pos]
        return out

    def flush(self) -> list[GpsFix]:
        """Emit the epoch still waiting for its partner sentence, if any."""
        return [self._emit()] if self._epoch is not None else []

    # ------------------------------------------------------------------ internals
    def _bad(self, kind: str, nbytes: int, sample: bytes | bytearray) -> None:
        setattr(self.stats, kind, getattr(self.stats, kind) + 1)
        self.stats.dropped_bytes += nbytes
        self._log.debug("dropped %s sentence (%d bytes): %r", kind, nbytes, bytes(sample[:60]))

    def _emit(self) -> GpsFix:
        fix = self._epoch.fix()
        self._epoch = None
        self.stats.fixes += 1
        return fix

    def _line(self, raw: bytes, now: float) -> list[GpsFix]:
        try:
            text = raw.decode("ascii")
        except UnicodeDecodeError:
            self._bad("non_ascii", len(raw), raw)
            return []
        if "*" not in text:
            self._bad("truncated", len(raw), raw)
            return []
        try:
            msg = pynmea2.parse(text, check=True)
        except pynmea2.ChecksumError:
            self._bad("bad_checksum", len(raw), raw)
            return []
        except pynmea2.SentenceTypeError:           # checksum fine, a type pynmea2 does not know
            self._ignore(text[1:].split(",", 1)[0][-3:], raw)
            return []
        except Exception:                            # ParseError and anything else pynmea2 throws
            self._bad("parse_errors", len(raw), raw)
            return []
        if isinstance(msg, (pynmea2.GGA, pynmea2.RMC)):
            try:
                kind, fields, utc = self._fields(msg)
            except Exception:
                self._bad("parse_errors", len(raw), raw)
                return []
        else:
            self._ignore(getattr(msg, "sentence_type", None) or type(msg).__name__, raw)
            return []
        self.stats.sentences += 1
        self.stats.good_bytes += len(raw)
        out = []
        ep = self._epoch
        if ep is not None and (ep.utc != utc or getattr(ep, kind) is not None):
            out.append(self._emit())
            ep = None
        if ep is None:
            ep = self._epoch = _Epoch(now, utc)
        setattr(ep, kind, fields)
        if ep.gga is not None and ep.rmc is not None:
            out.append(self._emit())
        return out

    def _ignore(self, kind: str, raw: bytes) -> None:
        self.stats.ignored += 1
        self.stats.good_bytes += len(raw)
        self.stats.ignored_types[kind] = self.stats.ignored_types.get(kind, 0) + 1

    @staticmethod
    def _fields(msg) -> tuple[str, dict, Optional[float]]:
        utc = _utc_seconds(msg)
        if isinstance(msg, pynmea2.GGA):
            d = msg.data + [""] * (11 - len(msg.data))
            lat = _coord(d[1], d[2], "N", "S", 90.0)
            lon = _coord(d[3], d[4], "E", "W", 180.0)
            quality = _opt_int(d[5]) or 0
            sats = _opt_int(d[6]) or 0
            hdop = _opt_float(d[7])
            alt = _opt_float(d[8])
            sep = _opt_float(d[10]) or 0.0
            if quality < 0 or sats < 0 or (hdop is not None and hdop < 0):
                raise ValueError("negative quality, satellites or hdop")
            return "gga", {"lat": lat, "lon": lon, "quality": quality, "sats": sats,
                           "hdop": math.nan if hdop is None else hdop,
                           "alt": math.nan if alt is None else alt + sep}, utc
        d = msg.data + [""] * (8 - len(msg.data))
        status = d[1]
        lat = _coord(d[2], d[3], "N", "S", 90.0)
        lon = _coord(d[4], d[5], "E", "W", 180.0)
        speed = _opt_float(d[6])
        course = _opt_float(d[7])
        if status not in ("A", "V") or (speed is not None and speed < 0):
            raise ValueError("bad RMC status or speed")
        return "rmc", {"lat": lat, "lon": lon, "status": status,
                       "speed": math.nan if speed is None else speed * KNOT,
                       "course": math.nan if course is None else math.radians(course % 360.0)}, utc


@dataclass(frozen=True)
class NmeaGpsConfig:
    """A ``sensors:`` entry of ``type: nmea_gps`` (what the top-level ``gps:`` section of older configs says)."""
    type: Literal["nmea_gps"] = "nmea_gps"
    port: str = "loop://"                          # any pyserial URL
    baudrate: int = field(default=9600, metadata=rng(300, 921600))


class NmeaGps:
    """Polled NMEA GPS on any pyserial URL (device, pty, ``socket://``, ``loop://``).

    A receiver that babbles or goes silent: what does not parse is counted (``stats``), never logged per sentence;
    once fixes have come and then none for ``silence`` seconds, one warning opens the outage (``stats.outages``)
    and one closes it when fixes return.  The robot drives on: the pose filter dead-reckons on odometry meanwhile
    and gates the first fixes after."""

    Config = NmeaGpsConfig
    kind = "gps"               # what the robot can offer (an allocation's sensor view)
    reports = "fixes"          # the daemon hands what poll() returns to the pose estimate

    @classmethod
    def from_config(cls, cfg: NmeaGpsConfig, robot_id=None) -> "NmeaGps":
        return cls(cfg.port, baudrate=cfg.baudrate, robot_id=robot_id)

    def __init__(self, port: str, baudrate: int = 9600, robot_id=None, silence: float = 2.0):
        self.port = port
        self.log = get_logger("gps", robot_id)
        self.parser = NmeaParser(robot_id=robot_id)
        self.last_fix: Optional[GpsFix] = None
        self.silence = float(silence)
        self._fix_t: Optional[float] = None      # the last poll that completed a fix
        self._out_since: Optional[float] = None  # an outage was logged, counted from this fix time
        try:
            self.ser = serial.serial_for_url(port, baudrate=baudrate, timeout=0)
        except (serial.SerialException, ValueError, OSError) as exc:
            raise InputError(f"gps port {port!r}: expected a serial device or pyserial URL that opens "
                             f"({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None

    @property
    def stats(self) -> NmeaStats:
        return self.parser.stats

    @property
    def usable(self) -> bool:
        """A valid fix has come and no outage is open (no fix for ``silence`` s); the port opens when built."""
        return self.last_fix is not None and bool(self.last_fix.valid) and self._out_since is None

    def open(self, now: float = 0.0) -> None:
        """Nothing: the port opened when the driver was built (an InputError naming it if it did not)."""

    def poll(self, now: float) -> list[GpsFix]:
        """Read what has arrived (non-blocking) and return the fixes it completed; never raises."""
        fixes: list[GpsFix] = []
        try:
            for _ in range(64):                       # bounded: at most 256 KiB per poll
                data = self.ser.read(4096)
                if not data:
                    break
                fixes += self.parser.feed(data, now)
        except Exception as exc:                      # unplugged device, closed pty ...
            self.parser.stats.read_errors += 1
            if self.parser.stats.read_errors in (1, 10, 100) or self.parser.stats.read_errors % 1000 == 0:
                self.log.warning("gps read on %s failed (%d so far): %s", self.port,
                                 self.parser.stats.read_errors, exc)
        if not fixes:
            fixes = self.parser.feed(b"", now)        # lets a lone sentence's epoch time out
        if fixes:
            self.last_fix = fixes[-1]
        self._outage(now, bool(fixes))
        return fixes

    def _outage(self, now: float, fixed: bool) -> None:
        st = self.parser.stats
        if fixed:
            if self._out_since is not None:
                self.log.warning("gps fixes again on %s after %.2f s", self.port, now - self._out_since)
                self._out_since = None
            self._fix_t = now
        elif self._fix_t is not None and self._out_since is None and now - self._fix_t >= self.silence:
            self._out_since = self._fix_t
            st.outages += 1
            self.log.warning("no gps fix on %s for %.2f s (%d bytes dropped, %d bad sentences so far): "
                             "dead-reckoning on odometry", self.port, now - self._fix_t, st.dropped_bytes, st.bad)

    def close(self) -> None:
        try:
            self.ser.close()
        except Exception as exc:
            self.log.debug("closing %s: %s", self.port, exc)
