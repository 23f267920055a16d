"""NMEA 0183 GPS receiver emulator: GGA + RMC at ``rate_hz`` from a simulated body's pose.

The body's local ENU pose (x east, y north, metres from the datum) plus seeded Gaussian noise is
turned into WGS-84 (:class:`runtime.localization.enu.EnuToGeodetic`) and written as a real receiver would:
``ddmm.mmmm`` coordinates with hemisphere letters, UTC time and date from sim time (``utc_start`` + ``now``), fix
quality 1, 9 satellites, hdop 0.9, checksums by pynmea2.  The emulator does not model the geoid: GGA altitude is
the ellipsoidal height and the geoid separation field is 0.0.

I/O goes through a link object with ``path``, ``write(bytes) -> int | None`` (bytes taken; a full
link drops the rest, as a receiver's full UART would), ``read() -> bytes`` and ``close()`` (by
default a pty from :func:`sitl.devices.pty_link.open_pty`).
"""
from __future__ import annotations

import datetime
import math
from dataclasses import dataclass
from typing import Optional

import numpy as np
import pynmea2

from runtime.config import Datum
from runtime.localization.enu import EnuToGeodetic
from runtime.log import get_logger

KNOT = 1852.0 / 3600.0                 # m/s
UTC_START = datetime.datetime(2024, 1, 1, tzinfo=datetime.timezone.utc)
MIN_COURSE_SPEED = 0.1                 # m/s; slower than this the course field is left empty


@dataclass
class GpsDeviceStats:
    epochs: int = 0
    sentences: int = 0
    bytes_written: int = 0
    bytes_received: int = 0            # configuration bytes from the host, read and ignored
    write_errors: int = 0
    dropped_bytes: int = 0             # not taken by a full link (no one reading the pty)


def format_coord(deg: float, lat: bool, decimals: int = 4) -> tuple[str, str]:
    """Signed degrees -> (``ddmm.mmmm`` or ``dddmm.mmmm``, hemisphere letter)."""
    scale = 10 ** decimals
    units = round(abs(deg) * 60.0 * scale)          # integer 10^-decimals minutes: no 60.0000 minutes
    d, m = divmod(units, 60 * scale)
    mi, mf = divmod(m, scale)
    width = 2 if lat else 3
    text = f"{d:0{width}d}{mi:02d}" + (f".{mf:0{decimals}d}" if decimals > 0 else "")
    hemi = ("N" if deg >= 0 else "S") if lat else ("E" if deg >= 0 else "W")
    return text, hemi


def utc_fields(t: float, start: datetime.datetime = UTC_START) -> tuple[str, str]:
    """Sim seconds ``t`` after ``start`` -> (``hhmmss.ss``, ``ddmmyy``)."""
    cs = round(t * 100)                             # centiseconds, carried through days exactly
    stamp = start + datetime.timedelta(milliseconds=10 * cs)
    return stamp.strftime("%H%M%S.") + f"{stamp.microsecond // 10000:02d}", stamp.strftime("%d%m%y")


def gga_sentence(t: float, lat: float, lon: float, alt: float, *, quality: int = 1, sats: int = 9,
                 hdop: float = 0.9, talker: str = "GP", decimals: int = 4,
                 start: datetime.datetime = UTC_START) -> bytes:
    """One GGA sentence, ``$`` to ``\\r\\n``, checksummed."""
    hms, _ = utc_fields(t, start)
    la, ns = format_coord(lat, True, decimals)
    lo, ew = format_coord(lon, False, decimals)
    fields = (hms, la, ns, lo, ew, str(quality), f"{sats:02d}", f"{hdop:.1f}", f"{alt:.1f}", "M",
              "0.0", "M", "", "")
    return pynmea2.GGA(talker, "GGA", fields).render(checksum=True, dollar=True, newline="\r\n").encode()


def rmc_sentence(t: float, lat: float, lon: float, speed: float, course_deg: Optional[float], *,
                 talker: str = "GP", decimals: int = 4, start: datetime.datetime = UTC_START) -> bytes:
    """One RMC sentence (status A, mode A); ``speed`` in m/s, course in degrees true or None."""
    hms, dmy = utc_fields(t, start)
    la, ns = format_coord(lat, True, decimals)
    lo, ew = format_coord(lon, False, decimals)
    fields = (hms, "A", la, ns, lo, ew, f"{speed / KNOT:.2f}",
              "" if course_deg is None else f"{course_deg % 360.0:.1f}", dmy, "", "", "A")
    return pynmea2.RMC(talker, "RMC", fields).render(checksum=True, dollar=True, newline="\r\n").encode()


class NmeaGpsDevice:
    """Emulated GPS receiver on a link; call :meth:`service` with the sim time."""

    @classmethod
    def from_config(cls, body, cfg, robot_id=None, datum: Datum = Datum(), noise_sigma: float = 0.3,
                    seed: int | None = None) -> "NmeaGpsDevice":
        """The device for a ``sensors:`` entry ``cfg`` (:class:`runtime.drivers.nmea_gps.NmeaGpsConfig`); the
        launcher gives the world's ``datum``, the fleet's GPS noise and the run's seed."""
        return cls(body, datum, noise_sigma=noise_sigma, seed=int(robot_id or 0) if seed is None else seed,
                   robot_id=robot_id)

    def endpoint(self) -> dict:
        return {"port": self.link.path, "baudrate": 9600}

    def __init__(self, body, datum: Datum, noise_sigma: float = 0.3, rate_hz: float = 5.0, seed: int = 0,
                 robot_id=None, link=None, *, speed_sigma: float = 0.05, talker: str = "GP",
                 decimals: int = 4, utc_start: datetime.datetime = UTC_START):
        if rate_hz <= 0 or noise_sigma < 0 or speed_sigma < 0:
            raise ValueError("rate_hz must be > 0, noise_sigma and speed_sigma >= 0")
        if link is None:
            from sitl.devices.pty_link import open_pty
            link = open_pty()
        self.body, self.datum, self.link = body, datum, link
        self._geodetic = EnuToGeodetic(datum)
        self.noise_sigma, self.speed_sigma = noise_sigma, speed_sigma
        self.period = 1.0 / rate_hz
        self.talker, self.decimals, self.utc_start = talker, decimals, utc_start
        self.rng = np.random.default_rng(seed)
        self.stats = GpsDeviceStats()
        self.log = get_logger("sitl.gps", robot_id)
        self._next: Optional[float] = None

    @property
    def path(self) -> str:
        """Where the daemon opens the receiver (the pty slave)."""
        return self.link.path

    def epoch(self, now: float) -> bytes:
        """GGA + RMC for the body's state at ``now``, with fresh noise."""
        x, y, _ = self.body.pose()
        vx, vy = self.body.velocity()
        s = self.noise_sigma
        de, dn, du = self.rng.normal(0.0, 1.0, 3) * (s, s, 1.5 * s)
        lat, lon, alt = self._geodetic(x + de, y + dn, du)
        ve, vn = np.array([vx, vy], dtype=float) + self.rng.normal(0.0, self.speed_sigma, 2)
        speed = math.hypot(ve, vn)
        course = math.degrees(math.atan2(ve, vn)) % 360.0 if speed >= MIN_COURSE_SPEED else None
        kw = dict(talker=self.talker, decimals=self.decimals, start=self.utc_start)
        return (gga_sentence(now, float(lat), float(lon), float(alt), **kw)
                + rmc_sentence(now, float(lat), float(lon), speed, course, **kw))

    def service(self, now: float) -> int:
        """Drain host input; write an epoch if one is due.  Returns bytes written."""
        try:
            got = self.link.read()
            self.stats.bytes_received += len(got or b"")
        except OSError as exc:
            self.log.debug("gps link read: %s", exc)
        if self._next is not None and now < self._next - 1e-9:
            return 0
        # keep a fixed grid; after a stall emit once and resume the grid (no burst of stale epochs)
        self._next = now + self.period if self._next is None or now >= self._next + self.period \
            else self._next + self.period
        data = self.epoch(now)
        try:
            n = self.link.write(data)
        except OSError as exc:
            self.stats.write_errors += 1
            if self.stats.write_errors in (1, 10, 100) or self.stats.write_errors % 1000 == 0:
                self.log.warning("gps link write failed (%d so far): %s", self.stats.write_errors, exc)
            return 0
        n = len(data) if n is None else n
        self.stats.dropped_bytes += len(data) - n
        self.stats.epochs += 1
        self.stats.sentences += 2
        self.stats.bytes_written += n
        return n

    def close(self) -> None:
        self.link.close()
