"""Emulated iRobot Create 2 (or Create 1) speaking the Open Interface on a pty.

The device stands in for the robot's serial port byte for byte: a driver or a third-party library
opens :attr:`CreateOIDevice.path` and talks OI.  It runs the OI mode machine (Off -> Passive on Start;
Safe, Full; Stop -> Off; a wheel drop or cliff in Safe drops to Passive and stops the wheels), drives
the body's wheels (Drive, Drive Direct, Drive PWM), answers Sensors and Query List for every packet id
and group of the model, and streams frames every 15 ms of sim time.

``body`` is any object with ``set_wheel_speeds(left_mps, right_mps)``, ``wheel_travel() -> (left_m,
right_m)``, ``bumps() -> (left, right)`` and ``wheel_drop() -> (left, right)``.  Optional extras are
used when present: ``battery() -> dict`` (charge_mah, capacity_mah, voltage_mv, current_ma,
temperature_c), ``motor_currents_ma() -> (left, right)``, ``cliffs() -> (left, front_left,
front_right, right)``.  Without ``battery()`` the device drains its own simulated pack.

In a SITL fleet it is built by :func:`sitl.devices.registry.make_device` for ``base.type: create_oi``
on a ``"create2"`` body (for either model: :mod:`sitl.bodies.registry`), and :meth:`endpoint` is what
goes into the generated robot config's ``base:`` section.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from runtime.drivers import create_oi_protocol as P
from runtime.log import get_logger

CLIFF_SIGNAL_FLOOR = 1800        # cliff sensor reading over a floor (0..4095)
CAPACITY_MAH = {"create2": 2696.0, "create1": 3000.0}
NOMINAL_MV = 14400.0             # pack voltage at half charge
SOC_SLOPE_MV = 1200.0            # mV from empty to full around the nominal voltage
R_INTERNAL = 0.15                # ohm
IDLE_MA = 180.0                  # electronics and sensors
MA_PER_MM_S = 0.8                # drive motor draw per wheel, mA per mm/s of wheel speed
SONG_SLOTS = {"create2": 5, "create1": 16}


@dataclass
class CreateDeviceStats:
    bytes_in: int = 0
    bytes_out: int = 0
    tx_dropped: int = 0              # bytes the client's queue would not take
    commands: int = 0                # commands parsed
    ignored: int = 0                 # commands not allowed in the current mode
    unknown_opcodes: int = 0         # opcode bytes the model does not know (skipped)
    bad_packet_ids: int = 0          # unknown ids in Sensors / Query List / Stream (skipped)
    bad_arguments: int = 0           # e.g. Pause/Resume with a value other than 0 or 1
    not_emulated: int = 0            # cleaning, demos, scripts played, waits
    frames: int = 0                  # stream frames sent
    stream_overflow: int = 0         # packets left out of a frame that would pass 255 bytes
    safety_stops: int = 0            # Safe -> Passive on wheel drop or cliff


class _Battery:
    """A pack that drains with the wheel speeds: charge, current and terminal voltage."""

    def __init__(self, capacity_mah: float):
        self.capacity = capacity_mah
        self.charge = 0.9 * capacity_mah
        self.current_ma = -IDLE_MA

    def step(self, dt: float, left_mm_s: float, right_mm_s: float) -> None:
        draw = IDLE_MA + MA_PER_MM_S * (abs(left_mm_s) + abs(right_mm_s))
        self.current_ma = -draw if self.charge > 0 else 0.0
        self.charge = max(0.0, self.charge - draw * dt / 3600.0)

    def reading(self) -> dict:
        soc = self.charge / self.capacity
        mv = NOMINAL_MV + SOC_SLOPE_MV * (soc - 0.5) + self.current_ma * R_INTERNAL
        return {"charge_mah": self.charge, "capacity_mah": self.capacity, "voltage_mv": mv,
                "current_ma": self.current_ma, "temperature_c": 25.0}


class CreateOIDevice:
    """One emulated Create on a link (a pty by default); call :meth:`service` with the sim time."""

    @classmethod
    def from_config(cls, body, cfg, robot_id=None) -> "CreateOIDevice":
        """The device a robot with ``base:`` config ``cfg`` (a ``CreateOIConfig``) talks to, on a new pty."""
        return cls(body, model=cfg.model, robot_id=robot_id, baudrate=cfg.baudrate)

    @staticmethod
    def body_kind(cfg) -> str:
        """The body this device drives: a Create 2 for either model.  A Create 1 is the same size but its
        wheels are 258 mm apart, not 235 mm: on this body it turns 10 % faster than commanded and the
        angle it reports (packet 20, from its own 258 mm) is 9 % short of the body's turn."""
        return "create2"

    def __init__(self, body, model: str = "create2", robot_id=None, link=None, baudrate: int | None = None):
        self.model = P.check_model(model)
        self.body = body
        self.geometry = P.GEOMETRY[model]
        self.log = get_logger("sitl.create_oi", robot_id)
        if link is None:
            from sitl.devices.pty_link import open_pty
            link = open_pty()
        self.link = link
        self.parser = P.CommandParser(model)
        self.stats = CreateDeviceStats()
        self._ids = set(P.packet_ids(model))
        self.mode = P.MODE_OFF
        self.baud_code = P.baud_code(self.geometry.default_baud if baudrate is None else baudrate)
        self.wheels_mm_s = (0.0, 0.0)           # (left, right) the motors are driving
        self.requested = {"requested_velocity": 0, "requested_radius": 0,
                          "requested_right_velocity": 0, "requested_left_velocity": 0}
        self.stream_ids: list[int] = []
        self.streaming = False
        self._next_frame = 0.0
        self._encoder_zero = (0.0, 0.0)        # wheel travel (m) where the counts read 0
        self._travel = tuple(body.wheel_travel())
        self._distance_mm = 0.0                 # since last reported (packet 19)
        self._angle_deg = 0.0                   # since last reported (packet 20)
        self._own_battery = None if callable(getattr(body, "battery", None)) else _Battery(CAPACITY_MAH[model])
        self._songs: dict[int, bytes] = {}
        self._song_number = 0
        self._song_until = -math.inf
        self.script = b""
        self.actuators: dict[int, bytes] = {}  # last data of commands with no effect on motion
        self._last_now: float | None = None
        self._values: dict | None = None

    @property
    def path(self) -> str:
        """Where a driver opens the robot (the pty slave)."""
        return self.link.path

    def endpoint(self) -> dict:
        """Where and how the driver reaches this device: the ``base:`` keys of the robot config."""
        return {"port": self.path, "baudrate": P.BAUD_RATES[self.baud_code]}

    @property
    def mode_name(self) -> str:
        return P.MODE_NAMES[self.mode]

    # ------------------------------------------------------------------ main loop
    def service(self, now: float) -> None:
        """Sample the body, act on waiting command bytes, enforce Safe mode, send a due stream frame."""
        self._sample(now)
        data = self.link.read()
        if data:
            self.stats.bytes_in += len(data)
            before = self.parser.unknown_opcodes
            for op, args in self.parser.feed(data):
                self.stats.commands += 1
                self._execute(op, args, now)
            self.stats.unknown_opcodes += self.parser.unknown_opcodes - before
        self._safety()
        self._stream(now)

    def close(self) -> None:
        self.link.close()

    # ------------------------------------------------------------------ body
    def _sample(self, now: float) -> None:
        travel = tuple(self.body.wheel_travel())
        dl = (travel[0] - self._travel[0]) * 1000.0
        dr = (travel[1] - self._travel[1]) * 1000.0
        self._travel = travel
        self._distance_mm += (dl + dr) / 2.0
        self._angle_deg += math.degrees((dr - dl) / self.geometry.track_mm)
        dt = 0.0 if self._last_now is None else max(0.0, now - self._last_now)
        self._last_now = now
        if self._own_battery is not None:
            self._own_battery.step(dt, *self.wheels_mm_s)

    def _set_wheels(self, left_mm_s: float, right_mm_s: float) -> None:
        self.wheels_mm_s = (float(left_mm_s), float(right_mm_s))
        self.body.set_wheel_speeds(left_mm_s / 1000.0, right_mm_s / 1000.0)

    def _stop_wheels(self) -> None:
        if self.wheels_mm_s != (0.0, 0.0):
            self._set_wheels(0.0, 0.0)

    def _cliffs(self) -> tuple[bool, bool, bool, bool]:
        fn = getattr(self.body, "cliffs", None)
        return tuple(bool(c) for c in fn()) if callable(fn) else (False, False, False, False)

    def _safety(self) -> None:
        if self.mode != P.MODE_SAFE:
            return
        if any(self.body.wheel_drop()) or any(self._cliffs()):
            self.mode = P.MODE_PASSIVE
            self._stop_wheels()
            self.stats.safety_stops += 1
            self.log.warning("safe mode: wheel drop or cliff, motors stopped, now passive")

    # ------------------------------------------------------------------ commands
    def _execute(self, op: int, args: bytes, now: float) -> None:
        self._values = None
        c2 = self.model == "create2"
        mode = self.mode
        if mode == P.MODE_OFF and op != P.START and not (c2 and op == P.RESET):
            self.stats.ignored += 1
            return
        if op == P.START:
            self._enter(P.MODE_PASSIVE)
        elif c2 and op == P.RESET:
            self._enter(P.MODE_OFF)
            self._clear_stream()
            self._songs.clear()
            self._encoder_zero = self._travel
            self.log.info("reset")
        elif c2 and op == P.STOP:
            self._enter(P.MODE_OFF)
            self._clear_stream()
        elif op == P.BAUD:
            if args[0] < len(P.BAUD_RATES):
                self.baud_code = args[0]
            else:
                self.stats.bad_arguments += 1
        elif op == P.SAFE or (not c2 and op == P.CONTROL):
            self._enter(P.MODE_SAFE)
        elif op == P.FULL:
            self._enter(P.MODE_FULL)
        elif op in ((P.POWER, P.SPOT, P.CLEAN, P.MAX, P.SEEK_DOCK) if c2 else
                    (P.SPOT, P.COVER, P.DEMO, P.COVER_AND_DOCK)):
            self._enter(P.MODE_PASSIVE)       # cleaning and demos change to Passive; not emulated
            self.stats.not_emulated += 1
        elif op == P.SENSORS:
            self._reply([args[0]])
        elif op == P.QUERY_LIST:
            self._reply(list(args[1:]))
        elif op == P.STREAM:
            self._start_stream(list(args[1:]), now)
        elif op == P.PAUSE_RESUME_STREAM:
            if args[0] == 0:
                self.streaming = False
            elif args[0] == 1:
                self.streaming = bool(self.stream_ids)
                self._next_frame = now
            else:
                self.stats.bad_arguments += 1
        elif op == P.SONG:
            self._song(args)
        elif not c2 and op == P.SCRIPT:
            self.script = bytes(args[1:])
        elif not c2 and op == P.SHOW_SCRIPT:
            self.streaming = False               # the spec: Show Script halts the stream
            self._write(bytes([len(self.script)]) + self.script)
        elif not c2 and op in (P.PLAY_SCRIPT, P.WAIT_TIME, P.WAIT_DISTANCE, P.WAIT_ANGLE, P.WAIT_EVENT):
            self.stats.not_emulated += 1
            self.log.warning("opcode %d (scripts and waits) is not emulated", op)
        elif mode in (P.MODE_SAFE, P.MODE_FULL):
            self._actuate(op, args, now)
        else:
            self.stats.ignored += 1              # an actuator command in Passive

    def _enter(self, mode: int) -> None:
        if mode in (P.MODE_OFF, P.MODE_PASSIVE):
            self._stop_wheels()
        if mode != self.mode:
            self.log.info("OI mode %s -> %s", P.MODE_NAMES[self.mode], P.MODE_NAMES[mode])
        self.mode = mode

    def _actuate(self, op: int, args: bytes, now: float) -> None:
        """Commands available in Safe and Full only."""
        if op == P.DRIVE:
            v = int.from_bytes(args[0:2], "big", signed=True)
            radius = int.from_bytes(args[2:4], "big")
            self.requested["requested_velocity"] = v
            self.requested["requested_radius"] = radius - 0x10000 if radius >= 0x8000 else radius
            self._set_wheels(*P.drive_to_wheels(v, radius, self.geometry.track_mm))
        elif op == P.DRIVE_DIRECT:
            right = _clamp(int.from_bytes(args[0:2], "big", signed=True), -P.MAX_WHEEL_MM_S, P.MAX_WHEEL_MM_S)
            left = _clamp(int.from_bytes(args[2:4], "big", signed=True), -P.MAX_WHEEL_MM_S, P.MAX_WHEEL_MM_S)
            self.requested["requested_right_velocity"] = right
            self.requested["requested_left_velocity"] = left
            self._set_wheels(left, right)
        elif op == P.DRIVE_PWM and self.model == "create2":
            # approximation: wheel speed proportional to duty, full duty = 500 mm/s
            right = _clamp(int.from_bytes(args[0:2], "big", signed=True), -P.MAX_PWM, P.MAX_PWM)
            left = _clamp(int.from_bytes(args[2:4], "big", signed=True), -P.MAX_PWM, P.MAX_PWM)
            scale = P.MAX_WHEEL_MM_S / P.MAX_PWM
            self._set_wheels(left * scale, right * scale)
        elif op == P.PLAY:
            self._play(args[0], now)
        else:                                    # LEDs, brushes, outputs, IR, schedule: recorded only
            self.actuators[op] = bytes(args)

    def _song(self, args: bytes) -> None:
        number, n = args[0], args[1]
        if number >= SONG_SLOTS[self.model] or not 1 <= n <= 16:
            self.stats.bad_arguments += 1
            return
        self._songs[number] = bytes(args[2:])

    def _play(self, number: int, now: float) -> None:
        notes = self._songs.get(number)
        if notes is None:
            self.stats.bad_arguments += 1
            return
        if now < self._song_until:               # the spec: Play does nothing while a song plays
            return
        self._song_number = number
        self._song_until = now + sum(notes[1::2]) / 64.0

    # ------------------------------------------------------------------ sensors
    def values(self) -> dict:
        """Every named sensor value of the model as a reply sent now would carry it."""
        return self._snapshot(-math.inf if self._last_now is None else self._last_now)

    def _reply_values(self) -> dict:
        """:meth:`values`, computed once per command or frame."""
        if self._values is None:
            self._values = self.values()
        return self._values

    def _snapshot(self, now: float) -> dict:
        body = self.body
        bl, br = (bool(b) for b in body.bumps())
        dl, dr = (bool(d) for d in body.wheel_drop())
        c_l, c_fl, c_fr, c_r = self._cliffs()
        bat = body.battery() if self._own_battery is None else self._own_battery.reading()
        v: dict = {
            "bumps_wheel_drops": br | bl << 1 | dr << 2 | dl << 3,
            "wall": 0, "cliff_left": int(c_l), "cliff_front_left": int(c_fl),
            "cliff_front_right": int(c_fr), "cliff_right": int(c_r), "virtual_wall": 0,
            "distance": _clamp(int(self._distance_mm), -32768, 32767),
            "angle": _clamp(int(self._angle_deg), -32768, 32767),
            "charging_state": 0,
            "voltage": _clamp(round(bat["voltage_mv"]), 0, 65535),
            "current": _clamp(round(bat["current_ma"]), -32768, 32767),
            "temperature": _clamp(round(bat["temperature_c"]), -128, 127),
            "battery_charge": _clamp(round(bat["charge_mah"]), 0, 65535),
            "battery_capacity": _clamp(round(bat["capacity_mah"]), 0, 65535),
            "wall_signal": 0,
            "cliff_left_signal": 0 if c_l else CLIFF_SIGNAL_FLOOR,
            "cliff_front_left_signal": 0 if c_fl else CLIFF_SIGNAL_FLOOR,
            "cliff_front_right_signal": 0 if c_fr else CLIFF_SIGNAL_FLOOR,
            "cliff_right_signal": 0 if c_r else CLIFF_SIGNAL_FLOOR,
            "charging_sources": 0, "oi_mode": self.mode, "song_number": self._song_number,
            "song_playing": int(now < self._song_until), "stream_packets": len(self.stream_ids),
            "buttons": 0,
            **self.requested,
        }
        if self.model == "create2":
            mpc = self.geometry.mm_per_count
            counts = [_wrap16(round((t - z) * 1000.0 / mpc)) for t, z in zip(self._travel, self._encoder_zero)]
            fn = getattr(body, "motor_currents_ma", None)
            if callable(fn):
                ml, mr = fn()
            else:
                ml, mr = (MA_PER_MM_S * abs(w) for w in self.wheels_mm_s)
            v.update({
                "wheel_overcurrents": 0, "dirt_detect": 0, "unused_16": 0, "infrared_character_omni": 0,
                "unused_32": 0, "unused_33": 0,
                "left_encoder_counts": counts[0], "right_encoder_counts": counts[1],
                "light_bumper": 0, "light_bump_left_signal": 0, "light_bump_front_left_signal": 0,
                "light_bump_center_left_signal": 0, "light_bump_center_right_signal": 0,
                "light_bump_front_right_signal": 0, "light_bump_right_signal": 0,
                "infrared_character_left": 0, "infrared_character_right": 0,
                "left_motor_current": _clamp(round(ml), -32768, 32767),
                "right_motor_current": _clamp(round(mr), -32768, 32767),
                "main_brush_motor_current": 0, "side_brush_motor_current": 0, "stasis": 0,
            })
        else:
            v.update({"low_side_driver_and_wheel_overcurrents": 0, "unused_15": 0, "unused_16": 0,
                      "infrared_byte": 255, "cargo_bay_digital_inputs": 0, "cargo_bay_analog_signal": 0})
        return v

    def _packet(self, pid: int) -> bytes:
        """Data bytes of one packet id; reading distance/angle restarts them (they are 'since last')."""
        values = self._reply_values()
        data = P.encode_packet(pid, values, self.model)
        members = P.packet_members(pid, self.model)
        if 19 in members:                        # keep the fraction; past +-32767 the excess is lost
            self._distance_mm = math.fmod(self._distance_mm, 1.0)
            values["distance"] = 0
        if 20 in members:
            self._angle_deg = math.fmod(self._angle_deg, 1.0)
            values["angle"] = 0
        return data

    def _valid(self, ids: list[int]) -> list[int]:
        good = [i for i in ids if i in self._ids]
        self.stats.bad_packet_ids += len(ids) - len(good)
        return good

    def _reply(self, ids: list[int]) -> None:
        ids = self._valid(ids)
        if ids:
            self._write(b"".join(self._packet(pid) for pid in ids))

    # ------------------------------------------------------------------ stream
    def _start_stream(self, ids: list[int], now: float) -> None:
        self.stream_ids = self._valid(ids)
        self.streaming = bool(self.stream_ids)
        self._next_frame = now

    def _clear_stream(self) -> None:
        self.stream_ids = []
        self.streaming = False

    def _stream(self, now: float) -> None:
        """One frame when due; after a stall, at most one catch-up frame per call, then the grid resumes."""
        if not self.streaming or self.mode == P.MODE_OFF or now + 1e-9 < self._next_frame:
            return
        self._values = None
        chunks, size = [], 0
        for pid in self.stream_ids:
            n = 1 + P.packet_size(pid, self.model)
            if size + n > 255:
                self.stats.stream_overflow += 1
                continue
            chunks.append((pid, self._packet(pid)))
            size += n
        self._write(P.build_stream_frame(chunks))
        self.stats.frames += 1
        self._next_frame += P.STREAM_PERIOD
        if self._next_frame + 1e-9 < now:
            self._next_frame = now

    def _write(self, data: bytes) -> None:
        n = self.link.write(data)
        self.stats.bytes_out += n
        if n < len(data):
            self.stats.tx_dropped += len(data) - n


def _clamp(v: int, lo: int, hi: int) -> int:
    return max(lo, min(hi, v))


def _wrap16(counts: int) -> int:
    return (counts + 0x8000) % 0x10000 - 0x8000
