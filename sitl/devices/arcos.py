"""Emulated ARCOS robot server (a Pioneer 3-DX's microcontroller) on a pty or a TCP port.

The device stands in for the robot's serial port, or for MobileSim's TCP port, byte for byte: a driver
or a third-party client opens :attr:`ArcosDevice.path` and speaks ARCOS.  What it does, after the
facts file and MobileSim's ``EmulatePioneer.cc``:

* handshake: SYNC0 starts it from idle; each SYNC is echoed, an out-of-order one within a handshake is
  answered with the number received (MobileSim's default); SYNC2 is answered with the name, class and
  subclass.  OPEN (bare, as p2os sends it, or with an argument, as ARIA does) starts the session: a
  standard SIP every 100 ms of sim time with every field a P3-DX sends, the optional tail included;
* commands: PULSE, OPEN, CLOSE (ends the session and stops), ENABLE, VEL, RVEL, VEL2 (high byte left,
  low byte right, x Vel2Divisor), SETA/SETRA (accelerations), SETV/SETRV (speed limits), HOSTBAUD (noted), SONAR (bit 0 on/off, bits 1-3 the array,
  0 = all; FLAGS bits 1-2 report the arrays), POLLING (string), SETO, STOP (decelerates), E_STOP (at
  once), CONFIG (a CONFIGpac), SAY; strings with or without a length byte.  Others are counted;
* motion: VEL/RVEL targets reached at the robot's accelerations (300 mm/s^2, 100 deg/s^2), converted to
  wheel speeds on the DiffConvFactor track; motors disabled until ENABLE 1;
* watchdog: 2 s after the last packet received the robot stops (MobileSim only logs it: the stop there
  is commented out; a real ARCOS stops, and so does this one) until the next motion command;
* sonar: each array fires one transducer every 40 ms in its polling order (the ring refreshes every
  320 ms, as on the robot); a SIP carries the readings fired since the one before;
* stall: a wheel driven at 50 mm/s or more that turns at less than a fifth of that for 0.25 s stalls
  (STALL_AND_BUMPERS bit 0 left, bit 8 right); contacts in the front/rear 135 degrees set the bumper bits.

``body`` is a :class:`sitl.bodies.pioneer3dx.SimPioneer3DX` or anything with ``set_wheel_speeds``,
``wheel_travel``, ``wheel_rates``, ``bumper_segments`` and ``sonar_ranges``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from urllib.parse import urlsplit

from runtime.drivers import arcos_protocol as P
from runtime.errors import InputError
from runtime.log import get_logger

SIP_PERIOD = 0.100             # s (MobileSim DEFAULT_SIP_FREQ)
WATCHDOG = 2.0                 # s (MobileSim DEFAULT_WATCHDOG_TIME)
SONAR_CYCLE = 0.040            # s per transducer firing in each array
TRANS_ACCEL = 300.0            # mm/s^2, accel and decel (ARCOS defaults)
ROT_ACCEL = 100.0              # deg/s^2
STALL_MIN = 50.0               # mm/s commanded before a wheel can stall
STALL_FRACTION = 0.2
STALL_TIME = 0.25              # s
DEFAULT_TCP_PORT = 8101        # ArTcpConnection / MobileSim's first robot
NAME = "mrta-sitl"             # the robot name in the SYNC2 reply (MobileSim sends "MobileSim")
FIRMWARE = "sim"


@dataclass
class ArcosDeviceStats:
    bytes_in: int = 0
    bytes_out: int = 0
    tx_dropped: int = 0
    packets: int = 0               # packets with a good checksum
    bad_packets: int = 0           # bad checksum or count (from the parser)
    dropped_bytes: int = 0
    handshakes: int = 0
    sessions: int = 0              # OPENs that started SIPs
    ignored: int = 0               # packets not valid in the current state (e.g. CLOSE while idle)
    unsupported: int = 0           # commands this emulator does not carry out
    bad_arguments: int = 0
    sips: int = 0
    watchdog_stops: int = 0
    sonar_firings: int = 0


class _Battery:
    """Three 12 V 7.2 Ah lead-acid packs in parallel (the P3-DX takes up to three): charge, terminal voltage."""
    CAPACITY_AH = 21.6
    IDLE_A = 1.2                   # microcontroller, sonar, onboard electronics
    A_PER_M_S = 2.0                # drive current per m/s of wheel speed (both wheels)
    R_INTERNAL = 0.05

    def __init__(self, soc: float = 0.9):
        self.charge = soc * self.CAPACITY_AH
        self.current = self.IDLE_A

    def step(self, dt: float, wheel_speeds_m_s: tuple[float, float]) -> None:
        self.current = self.IDLE_A + self.A_PER_M_S * sum(abs(v) for v in wheel_speeds_m_s)
        self.charge = max(0.0, self.charge - self.current * dt / 3600.0)

    @property
    def soc(self) -> float:
        return self.charge / self.CAPACITY_AH

    @property
    def volts(self) -> float:
        return 11.8 + 1.2 * self.soc - self.current * self.R_INTERNAL


class ArcosDevice:
    """One emulated ARCOS robot on a link (a pty, or a TCP port); call :meth:`service` with the sim time."""

    @classmethod
    def from_config(cls, body, cfg, robot_id=None) -> "ArcosDevice":
        """The device a robot with ``base:`` config ``cfg`` (an ``ArcosConfig``) talks to: on a TCP port on
        127.0.0.1 (the first free one from the template's, 8101 by default) if ``cfg.port`` is a
        ``socket://`` URL, else on a new pty."""
        link = None
        if str(cfg.port).startswith("socket://"):
            from sitl.devices.tcp_link import open_tcp
            try:
                port = urlsplit(cfg.port).port or DEFAULT_TCP_PORT
            except ValueError:
                raise InputError(f"ARCOS port {cfg.port!r}: expected socket://HOST:PORT") from None
            link = open_tcp(port)
        return cls(body, subclass=cfg.subclass, robot_id=robot_id, link=link, baudrate=cfg.baudrate)

    @staticmethod
    def body_kind(cfg) -> str:
        return "pioneer3dx"

    def __init__(self, body, subclass: str = "p3dx-sh", robot_id=None, link=None, baudrate: int = 9600):
        self.params = P.robot_params(subclass)
        self.body = body
        self.baudrate = baudrate
        self.log = get_logger("sitl.arcos", robot_id)
        if link is None:
            from sitl.devices.pty_link import open_pty
            link = open_pty()
        self.link = link
        self.parser = P.PacketParser()
        self.stats = ArcosDeviceStats()
        self.battery = _Battery()
        self.fault_flags = 0                    # tests may set FAULTFLAGS bits
        self.estop_pressed = False              # tests may press the e-stop button (FLAGS bit 5)
        self.sync_seq = 0                       # next SYNC expected; 3 = synced
        self.open = False                       # SIPs flowing
        self.motors = False
        self.sonar_on = [True, True]            # front, rear array (ARIA assumes sonar on at start)
        self.polling: list[int] | None = None   # a POLLING sequence (0-based sonar numbers), else per array
        self.limits = [self.params.max_vel_mm_s, self.params.max_rvel_deg_s]   # SETV, SETRV
        self.host_baud: int | None = None
        self.trans_accel = self.trans_decel = TRANS_ACCEL
        self.rot_accel = self.rot_decel = ROT_ACCEL
        self.target = (0.0, 0.0)                # (mm/s, deg/s) asked for
        self.command = (0.0, 0.0)               # (mm/s, deg/s) after the acceleration limits
        self.watchdog_tripped = False
        self.last_rx: float | None = None
        self.commands: list[int] = []           # ids of the commands carried out, in order (tests read it)
        self.said: list[bytes] = []
        self._disconnects = getattr(link, "disconnects", 0)
        self._last_now: float | None = None
        self._next_sip = 0.0
        self._next_fire = 0.0
        self._fire_index = [0, 0]
        self._fired: dict[int, int] = {}        # sonar -> range mm, since the last SIP
        self._stall_since: list[float | None] = [None, None]
        self._stalled = [False, False]
        self._travel = tuple(body.wheel_travel())
        self._rates = (0.0, 0.0)
        self.x_mm = self.y_mm = self.th = 0.0   # the robot's own odometry (SETO zeroes it)

    @property
    def path(self) -> str:
        """Where a driver opens the robot: the pty slave, or socket://127.0.0.1:PORT."""
        return self.link.path

    def endpoint(self) -> dict:
        """The ``base:`` keys that point the driver at this device."""
        return {"port": self.path, "baudrate": self.baudrate}

    # ------------------------------------------------------------------ main loop
    def service(self, now: float) -> None:
        dt = 0.0 if self._last_now is None else max(0.0, now - self._last_now)
        self._last_now = now
        self._sample(dt)
        data = self.link.read()
        if data:
            self.stats.bytes_in += len(data)
            for body in self.parser.feed(data):
                self._on_packet(body, now)
            self._parser_stats()
        if getattr(self.link, "disconnects", 0) != self._disconnects:
            self._disconnects = self.link.disconnects
            if self.sync_seq or self.open:
                self.log.info("client disconnected: session ended")
                self._end_session()
        self._watchdog(now)
        self._drive(dt)
        self._sonar(now)
        self._sip(now)

    def close(self) -> None:
        self.link.close()

    # ------------------------------------------------------------------ body
    def _sample(self, dt: float) -> None:
        travel = tuple(self.body.wheel_travel())
        dl = (travel[0] - self._travel[0]) * 1000.0
        dr = (travel[1] - self._travel[1]) * 1000.0
        self._travel = travel
        mid = self.th + (dr - dl) / self.params.track_mm / 2.0
        self.x_mm += (dl + dr) / 2.0 * math.cos(mid)
        self.y_mm += (dl + dr) / 2.0 * math.sin(mid)
        self.th = math.remainder(self.th + (dr - dl) / self.params.track_mm, math.tau)
        rates = getattr(self.body, "wheel_rates", None)
        self._rates = tuple(rates()) if callable(rates) else ((dl / 1000.0 / dt, dr / 1000.0 / dt) if dt else
                                                                self._rates)
        self.battery.step(dt, self._rates)

    def _wheel_targets(self) -> tuple[float, float]:
        """(left, right) mm/s for the present command."""
        v, rv = self.command
        half = math.radians(rv) * self.params.track_mm / 2.0
        return v - half, v + half

    def _drive(self, dt: float) -> None:
        """Ramp the command to the target at the accelerations, drive the wheels, watch for stalls."""
        if not self.motors:
            self.command = (0.0, 0.0)
        else:
            v = _ramp(self.command[0], self.target[0], self.trans_accel, self.trans_decel, dt)
            w = _ramp(self.command[1], self.target[1], self.rot_accel, self.rot_decel, dt)
            self.command = (v, w)
        left, right = self._wheel_targets()
        self.body.set_wheel_speeds(left / 1000.0, right / 1000.0)
        for k, (want, got) in enumerate(zip((left, right), self._rates)):
            if abs(want) >= STALL_MIN and abs(got * 1000.0) < STALL_FRACTION * abs(want):
                if self._stall_since[k] is None:
                    self._stall_since[k] = self._last_now
                self._stalled[k] = self._last_now - self._stall_since[k] >= STALL_TIME
            else:
                self._stall_since[k] = None
                self._stalled[k] = False

    def _halt(self) -> None:
        """Stop at once (E_STOP, watchdog, disabled motors)."""
        self.target = self.command = (0.0, 0.0)

    # ------------------------------------------------------------------ packets
    def _on_packet(self, body: bytes, now: float) -> None:
        self.last_rx = now
        if self.watchdog_tripped:
            self.watchdog_tripped = False
            self.log.info("packets again: watchdog reset")
        cmd = P.parse_command(body)
        if self.sync_seq < 3:
            self._handshake(cmd)
        else:
            self._execute(cmd)

    def _handshake(self, cmd: P.Command) -> None:
        n = cmd.id
        if n not in (0, 1, 2) or (self.sync_seq == 0 and n != 0):
            self.stats.ignored += 1                 # only SYNC0 starts a handshake
            return
        if n != self.sync_seq:
            self.log.warning("SYNC%d out of sequence (expected SYNC%d): answered as received", n, self.sync_seq)
        self.sync_seq = n
        if n < 2:
            self._write(P.sync(n))
        else:
            self._write(P.frame(P.sync2_reply(NAME, self.params.robot_class, self.params.subclass)))
            self.stats.handshakes += 1
            self.log.info("handshake done")
        self.sync_seq += 1

    def _int(self, cmd: P.Command) -> int | None:
        if cmd.kind == "int":
            return cmd.value
        self.stats.bad_arguments += 1
        return None

    def _execute(self, cmd: P.Command) -> None:
        c = cmd.id
        self.commands.append(c)
        if c == P.PULSE:
            return
        if c == P.OPEN:
            if not self.open:
                self.open = True
                self.stats.sessions += 1
                self._next_sip = self._last_now or 0.0
                self.log.info("OPEN: SIPs every %.0f ms", SIP_PERIOD * 1000)
        elif c == P.CLOSE:
            self.log.info("CLOSE: session ended")
            self._end_session()
        elif c == P.ENABLE:
            value = self._int(cmd)
            if value is not None:
                self.motors = bool(value)
                if not self.motors:
                    self._halt()
        elif c in (P.VEL, P.RVEL, P.VEL2):
            value = self._int(cmd)
            if value is not None:
                self._motion(c, value)
        elif c in (P.SETA, P.SETRA):
            value = self._int(cmd)
            if value:
                attr = ("trans" if c == P.SETA else "rot") + ("_accel" if value > 0 else "_decel")
                setattr(self, attr, float(abs(value)))
        elif c in (P.SETV, P.SETRV):
            value = self._int(cmd)
            if value is not None and value > 0:
                top = self.params.max_vel_mm_s if c == P.SETV else self.params.max_rvel_deg_s
                self.limits[0 if c == P.SETV else 1] = min(float(value), top)
        elif c == P.HOSTBAUD:
            self.host_baud = self._int(cmd)             # a pty or a socket has no baud rate to change
        elif c == P.SONAR:
            value = self._int(cmd)
            if value is not None:
                array = (value >> 1) & 0x7
                for k in range(2):
                    if array in (0, k + 1):
                        self.sonar_on[k] = bool(value & 1)
        elif c == P.POLLING:
            if cmd.kind != "str":
                self.stats.bad_arguments += 1
            else:
                seq = [b - 1 for b in cmd.value if 1 <= b <= len(self.params.sonar_units)]
                self.polling = seq or None
                self._fire_index = [0, 0]
        elif c == P.SETO:
            self.x_mm = self.y_mm = self.th = 0.0
        elif c == P.STOP:
            self.target = (0.0, 0.0)
        elif c == P.E_STOP:
            self._halt()
        elif c == P.CONFIG:
            self._write(P.frame(P.encode_config(self._config_values())))
        elif c == P.SAY:
            self.said.append(cmd.value if cmd.kind == "str" else b"")
        else:
            self.stats.unsupported += 1
            self.commands.pop()

    def _motion(self, c: int, value: int) -> None:
        pr = self.params
        v, rv = self.target
        if c == P.VEL:
            v = float(value)
        elif c == P.RVEL:
            rv = float(value)
        else:
            left, right = (k * pr.vel2_divisor for k in P.vel2_wheels(value))
            v, rv = (left + right) / 2.0, math.degrees((right - left) / pr.track_mm)
        vmax, rmax = self.limits
        self.target = (_clamp(v, -vmax, vmax), _clamp(rv, -rmax, rmax))

    def _end_session(self) -> None:
        self._halt()
        self.motors = False
        self.open = False
        self.sync_seq = 0
        self._fired.clear()

    def _watchdog(self, now: float) -> None:
        if (self.open and not self.watchdog_tripped and self.last_rx is not None
                and now - self.last_rx >= WATCHDOG):
            self.watchdog_tripped = True
            self.stats.watchdog_stops += 1
            self._halt()
            self.log.warning("watchdog: nothing received for %.1f s, robot stopped", now - self.last_rx)

    # ------------------------------------------------------------------ sonar and SIPs
    def _sonar(self, now: float) -> None:
        if now + 1e-9 < self._next_fire:
            return
        fire = []
        if self.polling is not None:
            num = self.polling[self._fire_index[0] % len(self.polling)]
            self._fire_index[0] += 1
            if self.sonar_on[0 if num in P.FRONT_SONARS else 1]:
                fire.append(num)
        else:
            for k, array in enumerate((P.FRONT_SONARS, P.REAR_SONARS)):
                if self.sonar_on[k]:
                    fire.append(array[self._fire_index[k] % len(array)])
                    self._fire_index[k] += 1
        if fire and self.open:
            for num, r in self.body.sonar_ranges(fire).items():
                self._fired[num] = int(round(min(r * 1000.0, self.params.sonar_max_range_mm) / self.params.range_conv))
                self.stats.sonar_firings += 1
        self._next_fire += SONAR_CYCLE
        if self._next_fire + 1e-9 < now:
            self._next_fire = now + SONAR_CYCLE

    def _sip(self, now: float) -> None:
        if not self.open or now + 1e-9 < self._next_sip:
            return
        self._write(P.frame(P.encode_sip(self.sip())))
        self._fired.clear()
        self.stats.sips += 1
        self._next_sip += SIP_PERIOD
        if self._next_sip + 1e-9 < now:
            self._next_sip = now

    def sip(self) -> P.Sip:
        """The standard SIP this robot would send now."""
        pr = self.params
        front, rear = self.body.bumper_segments()
        stall = (P.LEFT_STALL if self._stalled[0] else 0) | (P.RIGHT_STALL if self._stalled[1] else 0)
        flags = ((P.FLAG_MOTORS if self.motors else 0) | (P.FLAG_SONAR_ARRAYS[0] if self.sonar_on[0] else 0)
                 | (P.FLAG_SONAR_ARRAYS[1] if self.sonar_on[1] else 0) | (P.FLAG_ESTOP if self.estop_pressed else 0))
        th = int(round(self.th / pr.angle_conv)) % 4096
        left, right = (int(round(_clamp(r * 1000.0 / pr.vel_conv, -32767, 32767))) for r in self._rates)
        rot = math.degrees((self._rates[1] - self._rates[0]) * 1000.0 / pr.track_mm)
        volts = self.battery.volts
        return P.Sip(
            x=int(round(self.x_mm / pr.dist_conv)) & 0x7FFF, y=int(round(self.y_mm / pr.dist_conv)) & 0x7FFF,
            th=th, left_vel=left, right_vel=right, battery_dv=int(_clamp(round(volts * 10), 0, 255)),
            stall_bumpers=stall | (front & 0x7F) << 9 | (rear & 0x7F) << 1, control=th, flags=flags, compass=0,
            sonars=tuple(sorted(self._fired.items())), moving=abs(left) + abs(right) > 0,
            grip_anport=0, analog=0, digin=0, digout=0, battery_x10=int(_clamp(round(volts * 10), 0, 65535)),
            charge_state=0, rot_vel_x10=int(_clamp(round(rot * 10), -32767, 32767)), fault_flags=self.fault_flags,
            lat_vel=0, temperature=25, state_of_charge=int(_clamp(round(self.battery.soc * 100), 0, 100)),
            uc_time_us=int((self._last_now or 0.0) * 1e6) & 0xFFFFFFFF, flags3=0)

    def _config_values(self) -> dict:
        pr = self.params
        return {
            "robot_class": pr.robot_class, "subclass": pr.subclass, "serial": "SIM", "rot_vel_top": pr.max_rvel_deg_s,
            "trans_vel_top": pr.max_vel_mm_s, "rot_accel_top": 300, "trans_accel_top": 1000, "pwm_max": 1000,
            "name": NAME, "sip_cycle_ms": int(SIP_PERIOD * 1000), "front_sonar": 1, "rear_sonar": 1,
            "watchdog_ms": int(WATCHDOG * 1000), "rot_vel_max": pr.max_rvel_deg_s, "trans_vel_max": pr.max_vel_mm_s,
            "rot_accel": self.rot_accel, "rot_decel": self.rot_decel, "trans_accel": self.trans_accel,
            "trans_decel": self.trans_decel, "sonar_cycle_ms": int(SONAR_CYCLE * 1000), "firmware": FIRMWARE,
        }

    # ------------------------------------------------------------------ output
    def _write(self, data: bytes) -> None:
        n = self.link.write(data)
        self.stats.bytes_out += n
        if n < len(data):
            self.stats.tx_dropped += len(data) - n

    def _parser_stats(self) -> None:
        p = self.parser
        self.stats.packets = p.packets
        self.stats.bad_packets = p.bad_checksum + p.bad_count
        self.stats.dropped_bytes = p.dropped_bytes


def _ramp(value: float, target: float, accel: float, decel: float, dt: float) -> float:
    """``value`` moved towards ``target`` by at most accel*dt (speeding up) or decel*dt (slowing down)."""
    if value == target:
        return value
    speeding_up = abs(target) > abs(value) and (value == 0 or (target > 0) == (value > 0))
    step = (accel if speeding_up else decel) * dt
    return target if abs(target - value) <= step else value + math.copysign(step, target - value)


def _clamp(v: float, lo: float, hi: float) -> float:
    return max(lo, min(hi, v))
