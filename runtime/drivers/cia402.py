"""A differential base of two CiA 402 drives on one CAN bus, through ``canopen`` as master.

Each wheel has its own drive (``left_node``, ``right_node``), run by ``canopen``'s ``BaseNode402`` in profile
velocity mode.  :meth:`Cia402Base._open` (blocking, once; SDO needs the drives' answers):

1. python-can bus from the config (any interface: ``socketcan``, ``socketcand``, ``slcan``, ``virtual`` ...);
2. per drive: NMT pre-operational; 0x1000 must name profile 402; 0x1017 = the heartbeat period; 0x1016:1 =
   this master's node id and 3 heartbeat periods (the drive stops its motor when the master goes silent);
   0x6083/0x6084/0x6085 accelerations; PDOs: RPDO1 = controlword 0x6040 + target velocity 0x60FF + mode 0x6060,
   TPDO1 = statusword 0x6041 + mode display 0x6061 (on change and every heartbeat period), TPDO2 = position
   actual 0x6064 + velocity actual 0x606C (every ``pdo_period``), the rest disabled; profile velocity: the
   library checks bit 2 of 0x6502 (``is_op_mode_supported``), then 0x6060 = 3, and 0x6061 must read 3;
3. per drive: NMT start; ``state = 'OPERATION ENABLED'`` (the library's state setter: controlword 0x06, 0x07,
   0x0F, each confirmed by the statusword TPDO).

Then :meth:`_read` (non-blocking, every cycle, time injected) reads every frame waiting on the bus and hands it
to ``canopen`` -- the driver is polled like every base; python-can's receive thread runs only while
:meth:`_open` and :meth:`_close` block on SDO answers -- then sends this master's heartbeat (0x700 + ``master_node``,
state 5) every ``heartbeat`` seconds; odometry from the position actual values (velocities from velocity actual);
and the heartbeat consumer ``canopen`` lacks: a drive not heard for 3 heartbeat periods, or reporting FAULT
(statusword), an EMCY, or an NMT state other than operational, is a fault.  On a fault both drives get a
quick stop (controlword 0x02, target 0) in the same cycle, the faults go to ``sensors.faults``
(``"left_drive_silent"``, ``"right_drive_emcy_2310"``, ``"left_drive_fault"``, ``"left_drive_pre-operational"``)
and stay there until :meth:`reset_faults`: NMT start where needed, then per drive the 402 transitions towards
OPERATION ENABLED (fault reset 0x80, then 0x06, 0x07, 0x0F) one per cycle as the statuswords confirm them,
without blocking; the faults clear when both drives are enabled and healthy, or the reset gives up after
``RESET_TIMEOUT`` seconds.  Heartbeat and fault times are in the injected clock's seconds (simulated in the SITL).
"""
from __future__ import annotations

import contextlib
import logging
import math
from dataclasses import dataclass, field
from typing import Literal, Optional

import can
import canopen
import yaml
from canopen.emcy import EmcyError
from canopen.profiles.p402 import BaseNode402, State402
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from runtime.config.build import rng
from runtime.drivers import cia402_protocol as P
from runtime.drivers.base import Footprint, MobileBase
from runtime.errors import InputError
from runtime.log import get_logger

SILENT_PERIODS = 3             # heartbeat periods without a heartbeat before a drive counts as silent
RESET_TIMEOUT = 2.0            # s a fault reset may take before it gives up
NOTIFIER_CYCLE = 0.02          # s: how long stopping the receive thread (after open, at close) waits at most
MAX_FRAMES_PER_POLL = 4096
ENABLE_ATTEMPTS = 3
STALE_PDOS = 3                 # TPDO periods after which a drive's last speed no longer counts
_CAN_ERRORS = (can.CanError, OSError, RuntimeError, ValueError)


@dataclass(frozen=True)
class Cia402Config:
    """The robot config's ``base:`` section for ``type: cia402``."""
    type: Literal["cia402"] = "cia402"
    interface: str = "socketcan"          # any python-can interface
    channel: str = "can0"
    host: Optional[str] = None            # socketcand server
    port: Optional[int] = field(default=None, metadata=rng(1, 65535))
    bitrate: Optional[int] = field(default=None, metadata=rng(10000, 1000000))
    options: tuple[str, ...] = ()         # further python-can bus arguments, "name=value" (value read as YAML)
    eds: Optional[str] = None             # the drives' EDS file; null: the objects this base needs
    left_node: int = field(default=1, metadata=rng(1, 127))
    right_node: int = field(default=2, metadata=rng(1, 127))
    master_node: int = field(default=127, metadata=rng(1, 127))   # this master's heartbeat id (0x1016 of the drives)
    invert_left: bool = False             # the motor turns the wheel backwards for a positive velocity
    invert_right: bool = True             # (the right motor of a base is usually mounted mirrored)
    wheel_radius: float = field(default=0.075, metadata=rng(0.01, 1.0))     # m
    track: float = field(default=0.34, metadata=rng(0.05, 3.0))             # m between the wheels
    radius: float = field(default=0.30, metadata=rng(0.05, 3.0))            # m: the circle holding the base
    gear_ratio: float = field(default=24.0, metadata=rng(0.01, 1000.0))     # motor turns per wheel turn
    counts_per_rev: int = field(default=4096, metadata=rng(1, 2 ** 24))     # encoder increments per motor turn
    velocity_unit: Literal["rpm", "counts_per_s"] = "rpm"                    # of 0x60FF and 0x606C
    acceleration: float = field(default=1.0, metadata=rng(0.05, 20.0))      # m/s^2 (0x6083, 0x6084)
    quick_stop_deceleration: float = field(default=3.0, metadata=rng(0.1, 50.0))   # m/s^2 (0x6085)
    heartbeat: float = field(default=0.1, metadata=rng(0.01, 10.0))         # s, drives' and this master's
    pdo_period: float = field(default=0.02, metadata=rng(0.001, 1.0))       # s between position/velocity TPDOs
    watchdog: float = field(default=0.5, metadata=rng(0.05, 10.0))
    max_speed: float = field(default=1.0, metadata=rng(0.01, 10.0))         # m/s per wheel
    max_turn_rate: Optional[float] = field(default=None, metadata=rng(0.01, 50.0))   # rad/s; null: the wheels'


def bus_kwargs(cfg: Cia402Config) -> dict:
    """The ``can.Bus`` arguments the config names: interface, channel, host, port, bitrate and ``options``."""
    kw = {"interface": cfg.interface, "channel": cfg.channel}
    for name in ("host", "port", "bitrate"):
        if getattr(cfg, name) is not None:
            kw[name] = getattr(cfg, name)
    for i, opt in enumerate(cfg.options):
        name, sep, text = opt.partition("=")
        if not sep or not name.strip().isidentifier():
            raise InputError(f"base.options[{i}] {opt!r}: expected name=value (a python-can bus argument)")
        try:
            kw[name.strip()] = yaml.safe_load(text)
        except yaml.YAMLError:
            raise InputError(f"base.options[{i}] {opt!r}: expected a YAML scalar after '='") from None
    return kw


def units(cfg: Cia402Config) -> P.WheelUnits:
    return P.WheelUnits(cfg.wheel_radius, cfg.counts_per_rev, cfg.gear_ratio, cfg.velocity_unit)


class _Drive:
    """One wheel's drive as the master sees it.  The callbacks run in the bus's receive thread and only set
    counters and values; :meth:`Cia402Base._read` turns them into times of the injected clock."""

    def __init__(self, side: str, node_id: int, sign: int):
        self.side, self.id, self.sign = side, node_id, sign
        self.node: BaseNode402 | None = None
        self.heartbeats = 0            # received (receive thread)
        self.seen = 0                  # heartbeats counted by the last _read
        self.nmt = None                # NMT state of the last heartbeat
        self.not_operational = 0       # heartbeats in a row reporting another state than operational
        self.last_heard: float | None = None   # injected time of the last _read that found a new heartbeat
        self.pdos = 0                  # position/velocity TPDOs received
        self.pdos_seen = 0             # ... counted by the last _read
        self.pdo_at: float | None = None   # injected time of the last _read that found a new one
        self.position = 0
        self.velocity = 0
        self.emcy: list[int] = []      # EMCY codes received, in order
        self.last_cw: int | None = None

    @property
    def name(self) -> str:
        return f"{self.side} drive (node {self.id})"

    def on_heartbeat(self, state: int) -> None:
        self.nmt = state
        self.not_operational = 0 if state == P.HB_OPERATIONAL else self.not_operational + 1
        self.heartbeats += 1

    def on_emcy(self, entry) -> None:
        self.emcy.append(entry.code)

    def on_motion(self, pdo) -> None:
        if len(pdo.data) * 8 < pdo.length:
            return                     # counted as malformed by the frame monitor
        self.position, self.velocity = pdo[0x6064].raw, pdo[0x606C].raw
        self.pdos += 1


class _FrameMonitor(can.Listener):
    """Counts every received frame by CANopen kind, and the frames no service sends (bad id or length).
    Never raises: an exception here would end python-can's receive thread.  :meth:`on_error` takes what the bus
    raised in that thread (while ``_open`` and ``_close`` run it), so the thread goes on and the driver reports it
    once."""

    def __init__(self):
        self.kinds: dict[str, int] = {}
        self.malformed = 0
        self.lengths: dict[int, int] = {}      # COB-ID -> data length its configured PDO has
        self.thread_errors: list[str] = []     # what the receive thread raised (the first few), for the driver

    def on_error(self, exc: Exception) -> None:
        if len(self.thread_errors) < 10:
            self.thread_errors.append(_first_line(exc))
        self.malformed += 1

    def on_message_received(self, msg: can.Message) -> None:
        try:
            kind = None if msg.is_error_frame or msg.is_remote_frame else \
                P.classify(msg.arbitration_id, bytes(msg.data), msg.is_extended_id)
            expected = self.lengths.get(msg.arbitration_id)
            if kind is None or (expected is not None and len(msg.data) != expected):
                self.malformed += 1
            else:
                self.kinds[kind[0]] = self.kinds.get(kind[0], 0) + 1
        except Exception:              # noqa: BLE001 - whatever a frame holds, counting goes on
            self.malformed += 1


class Cia402Base(MobileBase):
    """Two CiA 402 drives in profile velocity mode; non-blocking after :meth:`open`, polled with ``now``."""

    Config = Cia402Config
    latches_faults = True

    @classmethod
    def from_config(cls, cfg: Cia402Config, robot_id=None) -> "Cia402Base":
        return cls(cfg, robot_id)

    def __init__(self, cfg: Cia402Config = Cia402Config(), robot_id=None):
        ids = (cfg.left_node, cfg.right_node, cfg.master_node)
        if len(set(ids)) != 3:
            raise InputError(f"base left_node, right_node, master_node {ids}: expected three different node ids")
        self.units = units(cfg)
        self.bus_kwargs = bus_kwargs(cfg)
        turn = cfg.max_turn_rate if cfg.max_turn_rate is not None else 2.0 * cfg.max_speed / cfg.track
        super().__init__(Footprint(cfg.radius, cfg.track, cfg.max_speed, turn), cfg.watchdog,
                         get_logger("cia402", robot_id))
        self.cfg = cfg
        self.input_period = cfg.pdo_period
        self.drives = (_Drive("left", cfg.left_node, -1 if cfg.invert_left else 1),
                       _Drive("right", cfg.right_node, -1 if cfg.invert_right else 1))
        self.network: canopen.Network | None = None
        self.monitor = _FrameMonitor()
        self.stats.extra.update({"frames_out": 0, "send_errors": 0, "receive_errors": 0, "malformed": 0, "heartbeats": 0, "emcy": 0,
                                 "fault_stops": 0, "resets": 0, "undecodable": 0, "bus_log_lines": 0})
        self._muffle = _Muffle()
        self._muffled: logging.Logger | None = None
        self._garbled_since: float | None = None   # an episode of undecodable input was logged at this time
        self._thread_errors_seen = 0
        self._next_heartbeat = -math.inf
        self._latched: dict[str, str] = {}     # fault name -> description, until a reset clears it
        self._resetting: float | None = None   # the reset's deadline
        self._ref: tuple[int, int] | None = None
        self._last_now = 0.0                   # the latest poll's time
        self._current: dict[str, str] = {}     # the faults the drives show now

    def _where(self) -> str:
        kw = self.bus_kwargs
        at = f" at {kw['host']}:{kw.get('port', '')}" if "host" in kw else ""
        return f"{kw['interface']} channel {kw['channel']!r}{at}"

    # ------------------------------------------------------------------ lifecycle
    def _open(self, now: float) -> None:
        try:
            bus = can.Bus(**self.bus_kwargs)
        except Exception as exc:       # noqa: BLE001 - each interface raises its own kinds
            raise InputError(f"CiA 402 base: cannot open the CAN bus {self._where()} ({exc}); expected a "
                             "python-can interface and channel that exist") from None
        self._muffled = logging.getLogger(type(bus).__module__)
        self._muffled.addFilter(self._muffle)
        net = canopen.Network(bus)
        net.listeners.append(self.monitor)
        self.network = net
        drive = None
        try:
            with self._receiving():
                for drive in self.drives:
                    self._add(drive)
                for drive in self.drives:
                    self._configure(drive)
                for drive in self.drives:
                    self._enable(drive)
        except (SdoCommunicationError, SdoAbortedError, *_CAN_ERRORS) as exc:
            self._shutdown()
            raise InputError(f"CiA 402 base: {drive.name} on {self._where()} did not come up ({exc}); expected "
                             "a CiA 402 drive with that node id answering on the bus") from None
        except InputError:
            self._shutdown()
            raise
        for d in self.drives:
            d.last_heard = None                # silence is counted from the first poll (open may take a while)
            d.not_operational = 0
        self._last_now = now
        self._next_heartbeat = -math.inf       # the first master heartbeat goes with the first poll
        self.odometry.t = now
        self.log.info("opened %s: drives %d (left) and %d (right) operation enabled, profile velocity",
                      self._where(), self.cfg.left_node, self.cfg.right_node)

    def _add(self, d: _Drive) -> None:
        od = self.cfg.eds if self.cfg.eds else P.object_dictionary(d.id)
        d.node = BaseNode402(d.id, od)
        self.network.add_node(d.node)
        d.node.nmt.add_heartbeat_callback(d.on_heartbeat)
        d.node.emcy.add_callback(d.on_emcy)

    def _configure(self, d: _Drive) -> None:
        """Pre-operational; check the profile; heartbeats both ways; ramps; the PDO maps; profile velocity mode
        (0x6060 = 3 once the library has found bit 2 in 0x6502; 0x6061 must confirm it)."""
        n, cfg, u = d.node, self.cfg, self.units
        n.nmt.state = "PRE-OPERATIONAL"
        device_type = n.sdo[0x1000].raw
        if device_type & 0xFFFF != 402:
            raise InputError(f"CiA 402 base: {d.name} device type 0x{device_type:08X} (0x1000): expected profile 402")
        n.sdo[0x1017].raw = max(1, round(cfg.heartbeat * 1000))
        n.sdo[0x1016][1].raw = P.consumer_entry(cfg.master_node, SILENT_PERIODS * cfg.heartbeat)
        accel = max(1, round(cfg.acceleration * u.unit_per_mps))
        n.sdo[0x6083].raw = accel
        n.sdo[0x6084].raw = accel
        n.sdo[0x6085].raw = max(1, round(cfg.quick_stop_deceleration * u.unit_per_mps))
        for maps in (n.rpdo, n.tpdo):
            for m in maps.map.values():
                m.clear()
                m.enabled = False
                m.cob_id = m.predefined_cob_id
        self._map(n.rpdo[1], (0x6040, 0x60FF, 0x6060), 0)
        self._map(n.tpdo[1], (0x6041, 0x6061), round(cfg.heartbeat * 1000))
        self._map(n.tpdo[2], (0x6064, 0x606C), max(1, round(cfg.pdo_period * 1000)))
        for maps in (n.rpdo, n.tpdo):
            for m in maps.map.values():
                if m.enabled:
                    m.save()
                elif m.cob_id is not None:
                    m.com_record[1].raw = m.cob_id | 0x80000000        # invalid: the drive sends/takes nothing
        n.rpdo[1][0x6060].raw = P.MODE_PROFILE_VELOCITY         # (save() cleared the map's data)
        n.tpdo[2].add_callback(d.on_motion)
        self.monitor.lengths[n.tpdo[2].cob_id] = len(n.tpdo[2].data)
        self.monitor.lengths[n.tpdo[1].cob_id] = len(n.tpdo[1].data)
        n.setup_402_state_machine(read_pdos=False)
        if not n.is_op_mode_supported("PROFILED VELOCITY"):            # the library reads 0x6502
            raise InputError(f"CiA 402 base: {d.name} supported drive modes 0x{n.sdo[0x6502].raw:04X} (0x6502): "
                             "expected profile velocity (bit 2)")
        n.sdo[0x6060].raw = P.MODE_PROFILE_VELOCITY
        mode = n.sdo[0x6061].raw
        if mode != P.MODE_PROFILE_VELOCITY:
            raise InputError(f"CiA 402 base: {d.name} modes of operation display {mode} (0x6061): expected 3 "
                             "(profile velocity)")

    @staticmethod
    def _map(m, indices: tuple[int, ...], event_ms: int) -> None:
        for index in indices:
            m.add_variable(index)
        m.trans_type = 255
        m.event_timer = event_ms
        m.enabled = True

    def _enable(self, d: _Drive) -> None:
        """NMT start, then controlwords 0x06, 0x07, 0x0F to OPERATION ENABLED (the library's state setter)."""
        n = d.node
        n.nmt.state = "OPERATIONAL"
        n.rpdo[1][0x60FF].raw = 0
        n.tpdo_values[0x6041] = n.sdo[0x6041].raw      # the library starts from 0 until a TPDO came: read it
        for _ in range(ENABLE_ATTEMPTS):
            try:
                n.state = P.ENABLED
                break
            except RuntimeError:       # a statusword TPDO missed by the library's wait; look again
                if n.state == P.ENABLED:
                    break
        else:
            raise InputError(f"CiA 402 base: {d.name} stays {n.state}: expected OPERATION ENABLED after "
                             "controlwords 0x06, 0x07, 0x0F")
        d.last_cw = P.CW_ENABLE_OPERATION

    def _close(self) -> None:
        """Target 0 and Shutdown (power stage off), the drives' heartbeat consumer off, NMT pre-operational."""
        with self._receiving():
            for d in self.drives:
                if d.node is None or self._silent(d):
                    continue
                self._transmit(d, P.CW_SHUTDOWN, 0)
                try:
                    d.node.sdo[0x1016][1].raw = 0
                    d.node.nmt.state = "PRE-OPERATIONAL"
                except (SdoCommunicationError, SdoAbortedError, *_CAN_ERRORS) as exc:
                    self.log.warning("close %s: %s", d.name, exc)
        self._shutdown()

    @contextlib.contextmanager
    def _receiving(self):
        """python-can's receive thread feeds canopen while SDO calls block for their answers."""
        net = self.network
        net.notifier = can.Notifier(net.bus, net.listeners, NOTIFIER_CYCLE)
        try:
            yield
        finally:
            net.notifier.stop(1.0)
            if net.notifier.exception is None:
                net.notifier = None

    def _shutdown(self) -> None:
        self._thread_report()
        if self._muffled is not None:
            self._muffled.removeFilter(self._muffle)
            self._muffled = None
        if self.network is not None:
            try:
                self.network.disconnect()
            except Exception as exc:       # noqa: BLE001 - closing goes on
                self.log.warning("close %s: %s", self._where(), exc)
        self.network = None

    # ------------------------------------------------------------------ polling
    def _read(self, now: float) -> bool:
        self._receive()
        if now >= self._next_heartbeat:
            self._send(P.COB_HEARTBEAT + self.cfg.master_node, bytes([P.HB_OPERATIONAL]))
            self._next_heartbeat = now + self.cfg.heartbeat
        fresh = self._odometry(now)
        self._watch(now)
        if self._resetting is not None:
            self._sequence(now)
        self._sync_stats()
        return fresh

    def _receive(self) -> None:
        """Every frame waiting on the bus, in order, to canopen (which catches what its callbacks raise) and the
        frame monitor.  A bus that fails LOST_AFTER polls in a row is lost; input that does not decode (garbage
        on a socketcand or slcan stream) is counted in ``undecodable``, one line per episode, and reading goes on
        (the drives' heartbeats fall silent meanwhile: a latched fault, the base stopped)."""
        net = self.network
        self._thread_report()
        garbled = got = False
        try:
            for _ in range(MAX_FRAMES_PER_POLL):
                try:
                    msg = net.bus.recv(0)
                except can.CanError as exc:
                    if not _undecodable(exc):
                        raise
                    garbled = True
                    self.stats.extra["undecodable"] += 1
                    continue
                if msg is None:
                    break
                got = True
                for listener in net.listeners:
                    listener.on_message_received(msg)
        except (can.CanError, OSError) as exc:
            self._link_failed("receive_errors", exc, f"CiA 402 base: reads from {self._where()}")
            return
        self._link_ok("receive_errors")
        self._garbled(garbled, got)

    def _garbled(self, now_garbled: bool, got: bool) -> None:
        x = self.stats.extra
        x["bus_log_lines"] = self._muffle.count
        if now_garbled and self._garbled_since is None:
            self._garbled_since = self._last_now
            self.log.warning("CiA 402 base: undecodable input from %s (counted in 'undecodable', not logged per "
                             "frame)", self._where())
        elif got and not now_garbled and self._garbled_since is not None:
            self.log.warning("CiA 402 base: input from %s decodes again after %.2f s (%d undecodable reads)",
                             self._where(), self._last_now - self._garbled_since, x["undecodable"])
            self._garbled_since = None

    def _thread_report(self) -> None:
        """What python-can's receive thread raised (during open or close), reported once."""
        errors = self.monitor.thread_errors
        if len(errors) > self._thread_errors_seen:
            if self._thread_errors_seen == 0:
                self.log.warning("CiA 402 base: python-can's receive thread on %s: %s (further ones counted in "
                                 "'malformed')", self._where(), errors[0])
            self._thread_errors_seen = len(errors)

    def _odometry(self, now: float) -> bool:
        """Dead reckoning from the position actual values; wheel speeds from velocity actual, taken as 0 for a
        drive whose TPDO has not come for STALE_PDOS periods (silent or stopped sending: a stale speed would
        move the pose estimate of a base that stands)."""
        left, right = self.drives
        fresh = False
        for d in self.drives:
            if d.pdos != d.pdos_seen:
                d.pdos_seen, d.pdo_at, fresh = d.pdos, now, True
        if not fresh or not (left.pdos and right.pdos):
            return False
        positions = (left.position, right.position)
        previous, self._ref = self._ref, positions
        if previous is None:                   # the first pair only sets the reference
            return False
        u = self.units
        dl, dr = (u.metres(P.delta32(p, q)) * d.sign for p, q, d in zip(positions, previous, self.drives))
        ds, dth = (dl + dr) / 2.0, (dr - dl) / self.cfg.track
        o = self.odometry
        o.advance(ds, dth)
        stale = STALE_PDOS * self.cfg.pdo_period
        vl, vr = (u.mps(d.velocity) * d.sign if now - d.pdo_at <= stale else 0.0 for d in self.drives)
        o.v, o.w = (vl + vr) / 2.0, (vr - vl) / self.cfg.track
        o.t = now
        return True

    def _silent(self, d: _Drive) -> bool:
        return d.last_heard is not None and self._last_now - d.last_heard > SILENT_PERIODS * self.cfg.heartbeat

    def _faults_now(self, d: _Drive) -> dict[str, str]:
        """The faults drive ``d`` shows now, by name, with a line saying what was seen."""
        if self._silent(d):
            return {f"{d.side}_drive_silent": f"{d.name} not heard for "
                                              f"{self._last_now - d.last_heard:.2f} s"}
        out = {}
        state = d.node.state
        if state in (P.FAULT, P.FAULT_REACTION):
            out[f"{d.side}_drive_fault"] = f"{d.name} statusword: {state}"
        for code in {e.code for e in d.node.emcy.active}:
            out[f"{d.side}_drive_emcy_{code:04x}"] = f"{d.name} EMCY 0x{code:04X} ({_emcy_text(code)})"
        if d.not_operational >= 2:          # two in a row: not one sent just before the NMT start arrived
            what = P.NMT_NAMES.get(d.nmt, str(d.nmt))
            out[f"{d.side}_drive_{what}"] = f"{d.name} NMT {what}"
        return out

    def _watch(self, now: float) -> None:
        self._last_now = now
        for d in self.drives:
            if d.heartbeats != d.seen or d.last_heard is None:
                d.seen = d.heartbeats
                d.last_heard = now
        current: dict[str, str] = {}
        for d in self.drives:
            current.update(self._faults_now(d))
        new = {k: v for k, v in current.items() if k not in self._latched}
        if new:
            stopping = not self._latched
            self._latched.update(new)
            for text in new.values():
                self.log.error("base fault: %s", text)
            if stopping:
                self._stop_drives()
        self._current = current
        self.sensors.faults = tuple(sorted(self._latched))

    def _stop_drives(self) -> None:
        """Quick stop (0x02, target 0) to both drives, in the cycle the fault was seen."""
        self.stats.extra["fault_stops"] += 1
        self._resetting = None
        for d in self.drives:           # a silent drive too: it may be running, unheard (garbage on the bus)
            self._transmit(d, P.CW_QUICK_STOP, 0)
        self._moving = False

    # ------------------------------------------------------------------ fault reset
    def reset_faults(self, now: float) -> bool:
        """Start a fault reset (non-blocking; :meth:`poll` carries it on).  False if there is nothing to reset."""
        if not self._latched or not self.is_open:
            return False
        self._resetting = now + RESET_TIMEOUT
        for d in self.drives:              # acknowledged; what persists shows again as FAULT or a new EMCY
            d.node.emcy.active = []
        self.stats.extra["resets"] += 1
        self.log.warning("fault reset requested: %s", ", ".join(sorted(self._latched)))
        return True

    def _sequence(self, now: float) -> None:
        """One step towards OPERATION ENABLED per drive per cycle, as the statuswords confirm them."""
        ready = True
        for d in self.drives:
            if self._silent(d):
                ready = False
                continue
            if d.nmt is not None and d.nmt != P.HB_OPERATIONAL:
                d.node.nmt.state = "OPERATIONAL"
                ready = False
                continue
            state = d.node.state
            if state == P.ENABLED:
                continue
            ready = False
            if state == P.FAULT:                   # a rising edge of bit 7 each time: 0x00 between
                cw = P.CW_DISABLE_VOLTAGE if d.last_cw == P.CW_FAULT_RESET else P.CW_FAULT_RESET
            elif (state, P.ENABLED) in State402.TRANSITIONTABLE:
                cw = State402.TRANSITIONTABLE[(state, P.ENABLED)]
            else:
                nxt = State402.next_state_indirect(state)
                cw = State402.TRANSITIONTABLE.get((state, nxt))
                if cw is None or nxt == P.FAULT:   # automatic transitions: wait for them
                    continue
            self._transmit(d, cw, 0)
        if ready and not self._current:
            self.log.warning("fault reset done: %s cleared", ", ".join(sorted(self._latched)))
            self._latched.clear()
            self._resetting = None
            self.sensors.faults = ()
        elif now > self._resetting:
            self.log.error("fault reset gave up after %.1f s: %s", RESET_TIMEOUT,
                           "; ".join(self._current.values()) or "drives not enabled")
            self._resetting = None

    # ------------------------------------------------------------------ commands
    def _command(self, v: float, w: float, now: float) -> bool:
        """Wheel speeds as target velocities by RPDO1 (controlword 0x0F); a quick stop while faulted; nothing
        while a reset runs (its controlwords go instead)."""
        if self._resetting is not None:
            return False
        if self._latched:
            for d in self.drives:
                self._transmit(d, P.CW_QUICK_STOP, 0)
            return False
        half = self._footprint.track / 2.0
        targets = [self.units.velocity((v + s * w * half) * d.sign) for s, d in zip((-1, 1), self.drives)]
        for d, target in zip(self.drives, targets):
            self._transmit(d, P.CW_ENABLE_OPERATION, target)
        return any(targets)

    def _transmit(self, d: _Drive, cw: int, target: int) -> None:
        pdo = d.node.rpdo[1]
        pdo[0x6040].raw = cw
        pdo[0x60FF].raw = target
        d.last_cw = cw
        self._send(pdo.cob_id, bytes(pdo.data))

    def _send(self, can_id: int, data: bytes) -> None:
        try:
            self.network.send_message(can_id, data)
        except _CAN_ERRORS as exc:
            self._link_failed("send_errors", exc, f"CiA 402 base: sends on {self._where()}")
            return
        self._link_ok("send_errors")
        self.stats.extra["frames_out"] += 1

    def _sync_stats(self) -> None:
        m = self.monitor
        self.stats.frames = sum(m.kinds.values())
        self.stats.extra["malformed"] = m.malformed
        self.stats.extra["heartbeats"] = sum(d.heartbeats for d in self.drives)
        self.stats.extra["emcy"] = sum(len(d.emcy) for d in self.drives)


def _first_line(exc: BaseException) -> str:
    """``exc`` in one line (python-can's messages may carry a whole traceback)."""
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}"


def _undecodable(exc: BaseException) -> bool:
    """A receive error caused by the bytes, not by the link: a socketcand or slcan line that does not parse."""
    cause = exc.__cause__ or exc.__context__
    return isinstance(cause, (ValueError, UnicodeError, IndexError, TypeError))


class _Muffle(logging.Filter):
    """On a python-can interface's logger: what it says per bad frame or failed receive (warnings, errors with a
    traceback each) is counted, not printed; the driver reports the episode in one line."""

    def __init__(self):
        super().__init__()
        self.count = 0

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno >= logging.WARNING:
            self.count += 1
            return False
        return True


def _emcy_text(code: int) -> str:
    return EmcyError(code, 0, b"", 0.0).get_desc() or "vendor specific"
