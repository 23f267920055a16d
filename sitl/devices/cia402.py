"""Two emulated CiA 402 wheel drives per robot, on canopen's ``LocalNode``, bridged to the robot's CAN channel.

Each :class:`EmulatedDrive` is a CANopen slave of its own (own python-can bus and ``canopen`` network, like a
real device on the wire): the library's SDO server, NMT slave, EMCY producer and object dictionary
(:func:`runtime.drivers.cia402_protocol.object_dictionary`), plus what the library lacks and a drive has:

* the CiA 402 state machine (:class:`~runtime.drivers.cia402_protocol.Drive402`) on every controlword,
  written by SDO or RPDO; statusword 0x6041, modes 0x6060/0x6061 (0x6502 says profile velocity only; another
  mode is refused with SDO abort 0x06090030);
* RPDO reception: ``canopen`` does not write RPDO data into a ``LocalNode``'s objects (canopen-python/canopen
  issue #145), so a callback on each RPDO copies every mapped value out and writes it as an SDO download
  would (same callbacks, same checks), and only in NMT operational;
* TPDOs from the PDO configuration the master wrote (read back from the drive's own objects on NMT start):
  on change of a mapped statusword or mode display (transmission types 254/255), on their event timers, or
  every Nth SYNC (types 1-240); only in NMT operational;
* the heartbeat producer (0x1017; ``canopen``'s NMT slave starts it, on sim time here) and boot-up on reset;
* the heartbeat consumer (0x1016:1): once the master's first heartbeat is heard, silence for longer than the
  consumer time is handled by 0x6007 (1 = FAULT with EMCY 0x8130, 2 = disable voltage, 3 = quick stop) --
  the motor stops when the master goes silent;
* a motor: in OPERATION ENABLED the velocity ramps to the target at the profile acceleration/deceleration
  (0x6083/0x6084), in QUICK STOP and FAULT REACTION to zero at the quick stop deceleration (0x6085), and
  brakes to zero in any other state; leaving NMT operational while enabled is a quick stop;
* test hooks: :meth:`EmulatedDrive.inject_fault` (FAULT with an EMCY) and :meth:`EmulatedDrive.silence`
  (the drive neither hears nor sends, as with a cut cable; its own consumer then stops the motor).

Time: a drive reads its bus in :meth:`EmulatedDrive.pump` (frames in order, one pump at a time): the hub pumps
the drives as soon as a client's frames arrive (so SDO works while the master blocks in its set-up, even in
lock-step), and :meth:`Cia402Device.service` pumps the hub and the drives before and after each step of sim
time.  Everything timed (heartbeats, event timers, ramps, the consumer) moves with the sim time given to
``service``, which also samples the body and drives its wheels.

:class:`Cia402Device` is the SITL device (:mod:`sitl.devices.registry`, ``base.type: cia402``) on a
``"candiff"`` body: its drives join the robot's channel ``can<id>`` of the process's socketcand hub
(:mod:`sitl.can_hub`, started by the first CAN device), and :meth:`Cia402Device.endpoint` names it for the
generated robot config and the manifest.  Given ``bus=`` (python-can arguments) it uses that bus instead
(tests: ``virtual`` in-process, ``socketcan`` on ``vcan0``) and a thread of its own pumps the drives.
"""
from __future__ import annotations

import math
import struct
import threading
from dataclasses import dataclass, field

import can
import canopen
from canopen.sdo import SdoAbortedError

from runtime.drivers import cia402_protocol as P
from runtime.drivers.cia402 import Cia402Config, units
from runtime.log import get_logger

PUMP_IDLE = 0.001           # s the pump thread (no hub) sleeps when no frame waits
ABORT_VALUE_RANGE = 0x06090030
LIVE = (0x1001, 0x603F, 0x6041, 0x6061, 0x6064, 0x606C)   # objects whose value is the drive's state


class _SimTask:
    """A periodic message on sim time (``canopen``'s own runs on a wall-clock thread)."""

    def __init__(self, net: "SimNetwork", can_id: int, data, period: float):
        self.net, self.can_id, self.data, self.period = net, can_id, bytes(data or b""), period
        self.next: float | None = None

    def update(self, data) -> None:
        self.data = bytes(data)

    def stop(self) -> None:
        with self.net.task_lock:
            if self in self.net.tasks:
                self.net.tasks.remove(self)

    def due(self, now: float) -> bool:
        fire, self.next = _due(self.next, now, self.period)
        return fire


def _due(nxt: float | None, now: float, period: float) -> tuple[bool, float | None]:
    """Whether a periodic event scheduled at ``nxt`` fires at ``now``, and when it is next due (on its grid;
    after a stall, from now: no bursts)."""
    if nxt is not None and now + 1e-9 < nxt:
        return False, nxt
    return True, (now if nxt is None or nxt + period < now else nxt) + period


class SimNetwork(canopen.Network):
    """A ``canopen`` network whose periodic messages follow sim time (:meth:`tick`), that is fed by
    :meth:`EmulatedDrive.pump` (no receive thread), and that a test can cut off (``silent``: nothing in, nothing
    out)."""

    def __init__(self, bus: can.BusABC):
        super().__init__(bus)
        self.tasks: list[_SimTask] = []
        self.task_lock = threading.Lock()
        self.silent = False
        self.frames_out = 0
        self.send_errors = 0

    def send_periodic(self, can_id, data, period, remote=False):
        task = _SimTask(self, can_id, data, period)
        with self.task_lock:
            self.tasks.append(task)
        return task

    def send_message(self, can_id, data, remote=False):
        if self.silent:
            return
        try:
            super().send_message(can_id, data, remote)
        except can.CanError:
            self.send_errors += 1
            return
        self.frames_out += 1

    def notify(self, can_id, data, timestamp):
        if not self.silent:
            super().notify(can_id, data, timestamp)

    def tick(self, now: float) -> None:
        with self.task_lock:
            due = [t for t in self.tasks if t.due(now)]
        for t in due:
            self.send_message(t.can_id, t.data)


@dataclass
class DriveStats:
    frames_in: dict = field(default_factory=dict)   # by CANopen kind (runtime.drivers.cia402_protocol.classify)
    malformed: int = 0              # frames no CANopen service sends, RPDOs shorter than their map, frames
                                    # canopen could not take (an SDO request it cannot parse ...)
    controlwords: int = 0
    faults: int = 0
    consumer_timeouts: int = 0
    rpdos_ignored: int = 0          # RPDOs outside NMT operational


class EmulatedDrive:
    """One CiA 402 drive: a ``LocalNode`` on its own bus, fed by :meth:`pump`; :meth:`sample` and
    :meth:`service` from the sim's thread.  ``wheel_rate`` is what the motor drives the wheel at (rad/s, forward
    positive)."""

    def __init__(self, node_id: int, bus_kwargs: dict, cfg: Cia402Config, sign: int = 1, robot_id=None,
                 name: str = "drive"):
        self.id, self.sign, self.name = node_id, sign, name
        self.units = units(cfg)
        self.log = get_logger(f"sitl.cia402.{name}", robot_id)
        self.stats = DriveStats()
        self.lock = threading.RLock()
        self.drive = P.Drive402()
        self.motor = 0.0              # motor velocity now, drive units
        self.target = 0
        self.mode = 0
        self.error_code = 0
        self.accel = self.decel = 10000
        self.qs_decel = 20000
        self.angle = 0.0              # wheel angle, rate (rad, rad/s) as last sampled from the body
        self.rate = 0.0
        self.wheel_rate = 0.0
        self._consumer: tuple[int, float] | None = None     # (producer node id, timeout s)
        self._heard = 0               # consumer heartbeats received (receive thread)
        self._heard_seen = 0
        self._heard_at: float | None = None                 # sim time; None: not monitoring yet
        self.clock_lag = 0.0          # s of sim time the world may run ahead of the master's view of its clock
        self._last: float | None = None
        self._event_due: dict[int, float] = {}              # TPDO COB-ID -> next event-timer time
        self._syncs = 0
        self.bus = can.Bus(**bus_kwargs)
        self.net = SimNetwork(self.bus)
        self.node = self.net.create_node(node_id, P.object_dictionary(node_id))
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        self.net.subscribe(P.COB_NMT, self._on_nmt)
        self.net.subscribe(P.COB_SYNC, self._on_sync)
        for m in self.node.rpdo.map.values():
            m.add_callback(self._on_rpdo)
        self._boot()

    # ------------------------------------------------------------------ test hooks
    def inject_fault(self, code: int = P.EMCY_OVERCURRENT) -> None:
        """The drive detects a fault: FAULT REACTION ACTIVE, EMCY ``code``, then FAULT once the motor stopped."""
        with self.lock:
            self._fault(code)

    def silence(self, on: bool = True) -> None:
        """Cut the drive off the bus (``on``) or reconnect it."""
        self.net.silent = on
        self.log.warning("drive %d %s", self.id, "silenced" if on else "back on the bus")

    @property
    def state(self) -> str:
        return self.drive.state

    @property
    def nmt_state(self) -> str:
        return self.node.nmt.state

    # ------------------------------------------------------------------ reception
    def pump(self) -> int:
        """Handle every frame waiting on the bus, in order; returns how many."""
        n = 0
        with self.lock:
            while True:
                try:
                    msg = self.bus.recv(0)
                except can.CanError:
                    break
                if msg is None:
                    break
                n += 1
                self._dispatch(msg)
        return n

    def _dispatch(self, msg: can.Message) -> None:
        """Count the frame by kind, then hand it to canopen (SDO server, NMT, PDOs, our subscriptions).  Nothing
        a frame holds gets out of here: a bad one is counted and dropped."""
        s = self.stats
        kind = None if msg.is_error_frame or msg.is_remote_frame else \
            P.classify(msg.arbitration_id, bytes(msg.data), msg.is_extended_id)
        if kind is None:
            s.malformed += 1
            return
        s.frames_in[kind[0]] = s.frames_in.get(kind[0], 0) + 1
        try:
            self.net.notify(msg.arbitration_id, msg.data, msg.timestamp)
        except Exception as exc:       # noqa: BLE001 - as canopen's own listener: log, count, go on
            s.malformed += 1
            self.log.debug("drive %d: frame 0x%03X %s: %s", self.id, msg.arbitration_id, bytes(msg.data).hex(), exc)

    # ------------------------------------------------------------------ boot and NMT
    def _boot(self) -> None:
        """Power-up or NMT reset: boot-up message, then pre-operational (heartbeat from 0x1017)."""
        with self.lock:
            self.node.nmt.send_command(P.NMT_RESET_NODE)       # state 0: sends the boot-up message
            self.node.nmt.send_command(P.NMT_PRE_OPERATIONAL)

    def _on_nmt(self, can_id, data, timestamp) -> None:
        if len(data) != 2 or data[1] not in (0, self.id):
            return
        with self.lock:
            cmd = data[0]
            if cmd in (P.NMT_RESET_NODE, P.NMT_RESET_COMMUNICATION):
                keep = (lambda i: i >= 0x2000) if cmd == P.NMT_RESET_COMMUNICATION else (lambda i: False)
                self.node.data_store = {i: v for i, v in self.node.data_store.items() if keep(i)}
                for t in list(self.net.tasks):
                    t.stop()
                self._consumer, self._heard_at = None, None
                if cmd == P.NMT_RESET_NODE:
                    self.drive, self.target, self.mode, self.error_code = P.Drive402(), 0, 0, 0
                self._boot()
            elif cmd == P.NMT_START:
                self.node.tpdo.read()
                self.node.rpdo.read()
                self._event_due.clear()
                self._emit_events()
            elif self.drive.enabled:                       # leaving operational: quick stop (transition 11)
                before = self.drive.state
                self.drive.command(P.CW_QUICK_STOP)
                self._state_changed(before)

    def _on_sync(self, can_id, data, timestamp) -> None:
        with self.lock:
            self._syncs += 1
            if self.node.nmt.state != "OPERATIONAL":
                return
            for m in self.node.tpdo.map.values():
                if m.enabled and m.trans_type and 1 <= m.trans_type <= 240 and self._syncs % m.trans_type == 0:
                    self._transmit(m)

    def _on_heartbeat(self, can_id, data, timestamp) -> None:
        self._heard += 1

    # ------------------------------------------------------------------ objects
    def _on_read(self, index, subindex, od):
        if index not in LIVE:
            return None
        with self.lock:
            if index == 0x6041:
                return self.drive.statusword(self._target_reached())
            if index == 0x6061:
                return self.mode
            if index == 0x6064:
                return _int32(round(self.sign * self.angle * self.units.counts_per_rad))
            if index == 0x606C:
                return _clamp32(round(self.sign * self.rate * self.units.unit_per_rad_s))
            if index == 0x603F:
                return self.error_code
            return P.error_register(self.error_code)

    def _on_write(self, index, subindex, od, data) -> None:
        value = od.decode_raw(data)
        with self.lock:
            if index == 0x6040:
                self.stats.controlwords += 1
                before = self.drive.state
                if self.drive.command(value):
                    self._state_changed(before)
            elif index == 0x6060:
                if value not in (0, P.MODE_PROFILE_VELOCITY):
                    raise SdoAbortedError(ABORT_VALUE_RANGE)
                if value != self.mode:
                    self.mode = value
                    self._emit_events()
            elif index == 0x60FF:
                self.target = value
            elif index in (0x6083, 0x6084, 0x6085):
                setattr(self, {0x6083: "accel", 0x6084: "decel", 0x6085: "qs_decel"}[index], max(1, value))
            elif index == 0x1016 and subindex == 1:
                self._set_consumer(value)

    def _set_consumer(self, value: int) -> None:
        if self._consumer is not None:
            self.net.unsubscribe(P.COB_HEARTBEAT + self._consumer[0], self._on_heartbeat)
        producer, ms = value >> 16 & 0x7F, value & 0xFFFF
        self._consumer, self._heard_at = None, None
        if producer and ms:
            self._consumer = (producer, ms / 1000.0)
            self.net.subscribe(P.COB_HEARTBEAT + producer, self._on_heartbeat)

    def _on_rpdo(self, pdo) -> None:
        """Copy an RPDO's values out and write them as an SDO download would (canopen issue #145)."""
        with self.lock:
            if self.node.nmt.state != "OPERATIONAL":
                self.stats.rpdos_ignored += 1
                return
            if len(pdo.data) * 8 < pdo.length:
                self.stats.malformed += 1
                return
            for var in pdo.map:
                if var.length:
                    try:
                        self.node.set_data(var.index, var.subindex, var.get_data(), check_writable=True)
                    except SdoAbortedError:
                        self.stats.malformed += 1

    # ------------------------------------------------------------------ state
    def _state_changed(self, before: str) -> None:
        after = self.drive.state
        self.log.debug("drive %d: %s -> %s", self.id, before, after)
        if before == P.FAULT and after != P.FAULT:
            self.error_code = 0
            self.node.emcy.reset()
        self._emit_events()

    def _fault(self, code: int) -> None:
        before = self.drive.state
        if not self.drive.fault():
            return
        self.stats.faults += 1
        self.error_code = code
        self.log.warning("drive %d: fault 0x%04X", self.id, code)
        self.node.emcy.send(code, P.error_register(code))
        self._state_changed(before)

    def _target_reached(self) -> bool:
        return self.drive.enabled and abs(self.motor - self.target) <= max(1.0, 0.01 * abs(self.target))

    def _emit_events(self) -> None:
        """TPDOs with transmission type 254/255 that map the statusword or mode display, when either changed."""
        if self.node.nmt.state != "OPERATIONAL":
            return
        for m in self.node.tpdo.map.values():
            if m.enabled and (m.trans_type or 0) >= 254 and any(v.index in (0x6041, 0x6061) for v in m.map):
                self._transmit(m)

    def _transmit(self, m) -> None:
        for var in m.map:
            if var.length:
                var.set_data(self.node.get_data(var.index, var.subindex))
        m.transmit()

    # ------------------------------------------------------------------ sim thread
    def sample(self, angle: float, rate: float) -> None:
        """The body's wheel angle (rad) and rate (rad/s) now."""
        with self.lock:
            self.angle, self.rate = angle, rate

    def service(self, now: float) -> None:
        """Consumer, motor ramp, fault reaction, heartbeats and event-timer TPDOs, at sim time ``now``."""
        with self.lock:
            dt = 0.0 if self._last is None else max(0.0, now - self._last)
            self._last = now
            self._watch_master(now)
            self._ramp(dt)
            self.net.tick(now)
            if self.node.nmt.state == "OPERATIONAL":
                for m in self.node.tpdo.map.values():
                    if m.enabled and (m.trans_type or 0) >= 254 and m.event_timer:
                        fire, self._event_due[m.cob_id] = _due(self._event_due.get(m.cob_id), now,
                                                               m.event_timer / 1000.0)
                        if fire:
                            self._transmit(m)

    def _watch_master(self, now: float) -> None:
        if self._consumer is None:
            return
        if self._heard != self._heard_seen:
            self._heard_seen = self._heard
            self._heard_at = now                     # monitoring starts with the first heartbeat
        if self._heard_at is None or now - self._heard_at <= self._consumer[1] + self.clock_lag:
            return
        self._heard_at = None                        # re-armed by the next heartbeat
        self.stats.consumer_timeouts += 1
        option = struct.unpack("<h", self.node.get_data(0x6007, 0))[0]
        self.log.warning("drive %d: master (node %d) silent for more than %.2f s: abort connection option %d",
                         self.id, self._consumer[0], self._consumer[1] + self.clock_lag, option)
        before = self.drive.state
        if option == P.ABORT_FAULT:
            self._fault(P.EMCY_HEARTBEAT)
        elif option == P.ABORT_DISABLE_VOLTAGE and self.drive.command(P.CW_DISABLE_VOLTAGE):
            self._state_changed(before)
        elif option == P.ABORT_QUICK_STOP and self.drive.command(P.CW_QUICK_STOP):
            self._state_changed(before)

    def _ramp(self, dt: float) -> None:
        d = self.drive
        if d.enabled and self.mode == P.MODE_PROFILE_VELOCITY:
            goal = float(self.target)
            rate = self.accel if abs(goal) > abs(self.motor) and goal * self.motor >= 0 else self.decel
        else:
            goal, rate = 0.0, self.qs_decel
        step = rate * dt
        self.motor = goal if abs(goal - self.motor) <= step else self.motor + math.copysign(step, goal - self.motor)
        if d.state == P.FAULT_REACTION and self.motor == 0.0:
            before = d.state
            d.reaction_done()
            self._state_changed(before)
        self.wheel_rate = self.sign * self.motor / self.units.unit_per_rad_s

    def close(self) -> None:
        try:
            self.net.disconnect()
        except Exception as exc:         # noqa: BLE001 - closing goes on
            self.log.warning("close drive %d: %s", self.id, exc)


def _int32(v: int) -> int:
    return (v + 0x80000000) % 0x100000000 - 0x80000000


def _clamp32(v: int) -> int:
    return max(-0x80000000, min(0x7FFFFFFF, v))


class Cia402Device:
    """A robot's two drives on ``body`` (with ``set_wheel_rates``, ``wheel_angles``, ``wheel_rates``); call
    :meth:`service` with the sim time."""

    @classmethod
    def from_config(cls, body, cfg: Cia402Config, robot_id=None) -> "Cia402Device":
        """The drives a robot with ``base:`` config ``cfg`` talks to, on channel ``can<robot_id>`` of the hub."""
        return cls(body, cfg, robot_id)

    @staticmethod
    def body_kind(cfg) -> str:
        return "candiff"

    def __init__(self, body, cfg: Cia402Config = Cia402Config(), robot_id=None, bus: dict | None = None):
        self.body = body
        self.cfg = cfg
        self.log = get_logger("sitl.cia402", robot_id)
        self.hub = None
        self.channel = f"can{robot_id if robot_id is not None else 0}"
        self.drives: dict[str, EmulatedDrive] = {}
        self._stop = threading.Event()
        self._thread = None
        if bus is None:
            from sitl import can_hub
            self.hub = can_hub.acquire()
            bus = {"interface": "virtual", "channel": self.hub.add_channel(self.channel, on_input=self.pump)}
        self.bus = dict(bus)
        try:
            for side, node_id, invert in (("left", cfg.left_node, cfg.invert_left),
                                          ("right", cfg.right_node, cfg.invert_right)):
                self.drives[side] = EmulatedDrive(node_id, self.bus, cfg, -1 if invert else 1, robot_id, side)
        except Exception:
            self.close()
            raise
        if self.hub is None:
            self._thread = threading.Thread(target=self._pump_loop, name=f"cia402-{self.channel}", daemon=True)
            self._thread.start()

    def allow_clock_lag(self, seconds: float) -> None:
        """The world may run ``seconds`` of sim time ahead of the master's view of its clock (daemons in their own
        processes read it from a file while the world catches up on a lag): the drives' heartbeat consumers
        wait that much longer before they call the master silent, so a world catching up is no master fault."""
        for d in self.drives.values():
            d.clock_lag = seconds

    def pump(self) -> int:
        """Let both drives handle what waits on their buses."""
        return sum(d.pump() for d in list(self.drives.values()))

    def _pump_loop(self) -> None:
        while not self._stop.is_set():
            if not self.pump():
                self._stop.wait(PUMP_IDLE)

    def endpoint(self) -> dict:
        """The ``base:`` keys that point the driver at these drives."""
        if self.hub is not None:
            return {"interface": "socketcand", "host": self.hub.host, "port": self.hub.port, "channel": self.channel}
        return {k: v for k, v in self.bus.items() if k in ("interface", "channel", "host", "port", "bitrate")}

    def service(self, now: float) -> None:
        """Frames sent so far reach the drives; the drives step to sim time ``now`` (what they send then goes
        out at once); the body's wheels follow the motors."""
        self._move_frames()
        angles, rates = self.body.wheel_angles(), self.body.wheel_rates()
        for d, angle, rate in zip(self.drives.values(), angles, rates):
            d.sample(angle, rate)
            d.service(now)
        self._move_frames()
        left, right = self.drives["left"], self.drives["right"]
        self.body.set_wheel_rates(left.wheel_rate, right.wheel_rate)

    def _move_frames(self) -> None:
        if self.hub is not None:
            self.hub.pump(self.channel)      # clients' frames to the drives, the drives' frames to the clients
        self.pump()                          # what the drives sent each other

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(1.0)
        for d in self.drives.values():
            d.close()
        self.drives = {}
        if self.hub is not None:
            from sitl import can_hub
            self.hub.remove_channel(self.channel)
            can_hub.release()
            self.hub = None
