"""The robot daemon: the I/O shell around one robot core.  poll -> core -> send.

One :class:`Daemon` per robot.  It opens the base (chosen by ``base.type``), the sensors the config lists (each
chosen by its ``type``: a GPS, a laser scanner) and the MAVLink link, and each control cycle (:meth:`Daemon.step`,
never blocking) polls them, hands what it read to the robot's
:class:`~runtime.robot.core.RobotCore` (the robot's logic, sans-IO: allocation, execution, pose estimate, ground
services), then gives the base the core's command and sends the core's frames on the link.  The same object runs
in its own process against real devices (:func:`run`, wall or scaled clock) or lock-stepped inside the SITL
process.
"""
from __future__ import annotations

import signal
import time
from dataclasses import dataclass

from runtime import config as C
from runtime.clock import Clock, ClockStalled, SharedClock
from runtime.jsonfile import write_json
from runtime.log import get_logger
from runtime.robot.core import GCS, PEERS, Inbox, RobotCore, Sensed
from runtime.robot.ports import BaseFacts


@dataclass
class ShellStats:
    cycles: int = 0
    missed_deadlines: int = 0      # cycles that started after the next cycle was due
    worst_lateness: float = 0.0    # s (clock time)
    cpu_seconds: float = 0.0
    wall_seconds: float = 0.0


class Daemon:
    def __init__(self, cfg: C.RobotConfig, *, base=None, gps=None, link=None, listen_socket=None):
        """``listen_socket``: a UDP socket already bound to ``comms.listen`` for the link (the SITL launcher's,
        held since it checked the port), else the link binds one."""
        self.cfg = cfg
        self.id = cfg.robot.id
        self.log = get_logger("daemon", self.id)
        self.stats = ShellStats()
        if base is None:
            from runtime.drivers.registry import open_base
            base = open_base(cfg.base, self.id)
        self.base = base
        from runtime.drivers.registry import open_sensor, sensor_class
        # the sensors: entries (and an older config's gps: section); ``gps`` given stands for those giving fixes
        self.sensor_entries = cfg.sensor_list()
        self.sensor_parts = [gps if gps is not None and sensor_class(e.type).reports == "fixes"
                             else open_sensor(e, self.id) for e in self.sensor_entries]
        self.gps = next((s for s in self.sensor_parts if s.reports == "fixes"), None)
        if link is None:
            from runtime.comms.link import open_link
            from runtime.errors import InputError
            try:
                link = open_link(cfg.comms, self.id, sock=listen_socket)
            except InputError as exc:            # a socket that will not bind, no Zenoh router answering
                raise InputError(f"{cfg.source or '<config>'}: {exc}") from None
        self.link = link
        self.guard = None                 # the base's stop guard (start_guard), in a daemon of its own process
        self.core = RobotCore(cfg, BaseFacts.of(base, self.sensor_parts),
                              mavlink=(link.mav, link.module, link.counters))
        self.period = self.core.period
        self.feed = None                  # a recording's CoreFeed (runtime.recording.feed): told every cycle
        self._mode()

    # ------------------------------------------------------------------ lifecycle
    def open(self, now: float) -> None:
        self.core.prepare()               # before the base runs: its watchdogs start with it
        self.base.open(now)
        for part in self.sensor_parts:
            if hasattr(part, "open"):
                part.open(now)
        self.log.info("open: base %s, sensors %s, listening %s, peers over %s, allocation %s%s", self.cfg.base.type,
                      ", ".join(f"{e.type} {e.port}" for e in self.sensor_entries) or "none",
                      self.cfg.comms.listen, self.cfg.comms.transport, self.core.method.name,
                      "" if self.core.node.armed else " (disarmed)")

    def start_guard(self) -> None:
        """Start the base's stop guard (:mod:`runtime.drivers.guard`): a process that stops the base when this
        one dies or stops stepping.  Only a daemon with a process of its own has one (``run``)."""
        from runtime.drivers.guard import start
        self.guard = start(self.base, self.id, self.log)

    def close(self) -> None:
        stopped = False
        try:
            self.base.close()
            stopped = True
        finally:
            if self.guard is not None:
                self.guard.close(goodbye=stopped)      # no goodbye: the guard stops the base itself
                self.guard = None
            for part in (*self.sensor_parts, self.link):
                if part is not None and hasattr(part, "close"):
                    part.close()

    # ------------------------------------------------------------------ one cycle
    def step(self, now: float) -> None:
        self.stats.cycles += 1
        base, link = self.base, self.link
        odometry = (base.odometry.v, base.odometry.w) if base.poll(now) else None
        fixes, ranges = [], []
        for part in self.sensor_parts:
            got = part.poll(now)
            if part.reports == "fixes":
                fixes += got
            else:
                ranges += part.ranges()          # empty while the sensor is unusable (stalled, failed, lost)
        peers = link.poll(now)
        lost = link.peers_lost(now)
        inbox = self._inbox(peers, lost)
        out = self.core.step(now, Sensed(odometry, fixes, base.sensors, ranges=ranges), inbox)
        if out.reset_faults:
            base.reset_faults(now)
        base.set_velocity(*out.command, now)
        self._send(out, now)
        if self.feed is not None:
            self.feed.cycle(now, out, inbox)
        if self.guard is not None:
            self.guard.beat()

    def service(self, now: float) -> None:
        """Messages only, no control cycle: peers' task tables and ground-station requests (a SITL operator
        hands tasks in before the first cycle this way).  Peer messages for the agent wait for the next step."""
        inbox = self._inbox(self.link.poll(now), ())
        out = self.core.service(now, inbox)
        self._send(out, now)
        if self.feed is not None:
            self.feed.frames(now, out, inbox)

    def _inbox(self, peers: list, lost: list) -> Inbox:
        link = self.link
        ground, link.gcs_inbox = link.gcs_inbox, []
        return Inbox(peers, ground, lost, getattr(link, "peers_alive", ()), bool(link.gcs_addresses()))

    def _send(self, out, now: float) -> None:
        """The core's frames on the link, in the order it made them."""
        link, batch = self.link, []
        for frame in out.frames:
            if frame[0] == PEERS:
                batch.append(frame[1])
                continue
            if batch:
                link.send_agent(batch, now)
                batch = []
            if frame[0] == GCS:
                link.send_gcs(frame[1])
            else:
                link.send_to(frame[1], frame[2])
        if batch:
            link.send_agent(batch, now)
        self._mode()

    def _mode(self) -> None:
        """The HEARTBEAT fields the core's telemetry chose, onto the link (it heartbeats the peers too)."""
        r = self.core.radio
        self.link.base_mode, self.link.custom_mode, self.link.system_status = r.base_mode, r.custom_mode, \
            r.system_status

    def snapshot(self) -> dict:
        s = self.stats
        snap = self.core.snapshot()
        snap.update({
            "missed_deadlines": s.missed_deadlines, "worst_lateness": s.worst_lateness,
            "cpu_seconds": s.cpu_seconds, "wall_seconds": s.wall_seconds,
            "base": vars(self.base.stats) if hasattr(self.base, "stats") else {},
            "sensors": [{"type": e.type, "usable": bool(getattr(p, "usable", False))}
                        for e, p in zip(self.sensor_entries, self.sensor_parts)],
            "link": self.link.counters.as_dict() if hasattr(self.link, "counters") else {},
        })
        return snap


# ---------------------------------------------------------------------- process main loop

class _Stop(BaseException):
    """SIGTERM or SIGINT arrived: leave the loop wherever it is, then stop the motors.  A BaseException, as
    KeyboardInterrupt is: the signal can land inside any ``except Exception`` (every parser loop has one, to count
    what it drops), which must not swallow it."""


def run(daemon: Daemon, clock: Clock, duration: float | None = None, stats_path: str | None = None) -> int:
    """Run ``daemon`` at its control rate until ``duration`` (clock seconds) or SIGTERM/SIGINT; 0, or 3 when the
    base's device vanished.  Whatever ends the loop (a signal, an exception, a lost device), the base is told to
    stop and the final status snapshot is written."""
    from runtime.drivers.base import DeviceLost

    def _stop(signum, frame):
        raise _Stop(signal.Signals(signum).name)

    before = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    t0 = clock.now()
    wall0, cpu0 = time.monotonic(), time.process_time()
    next_t = t0
    last_dump = t0
    code = 0
    try:
        daemon.open(t0)
        daemon.start_guard()
        if isinstance(clock, SharedClock) and daemon.guard is not None:
            clock.on_wait = daemon.guard.beat      # a SITL world paused (drawing, stalled) is not a frozen daemon
        while duration is None or clock.now() - t0 < duration:
            now = clock.now()
            late = now - next_t
            if late > daemon.period:       # whole periods late: every cycle that should have run is missed
                daemon.stats.missed_deadlines += int(late // daemon.period)
                next_t = now
            daemon.stats.worst_lateness = max(daemon.stats.worst_lateness, late)
            daemon.step(now)
            next_t += daemon.period
            if stats_path and now - last_dump > 1.0:
                last_dump = now
                daemon.stats.cpu_seconds = time.process_time() - cpu0
                daemon.stats.wall_seconds = time.monotonic() - wall0
                write_json(stats_path, daemon.snapshot())
            try:
                clock.sleep_until(next_t)
            except ClockStalled as exc:
                daemon.log.error("%s: stopping", exc)
                break
    except _Stop as exc:
        daemon.log.info("%s: stopping", exc)
    except DeviceLost as exc:
        daemon.log.error("%s: stopping (the base cannot be told to stop any more)", exc)
        code = 3
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)     # a second signal must not cut the clean-up short
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        daemon.close()
        daemon.stats.cpu_seconds = time.process_time() - cpu0
        daemon.stats.wall_seconds = time.monotonic() - wall0
        if stats_path:
            write_json(stats_path, daemon.snapshot())
        daemon.log.info("stopped after %d cycles, %d missed deadlines", daemon.stats.cycles,
                        daemon.stats.missed_deadlines)
        for s, handler in before.items():      # ignored signals would be inherited by every later child process
            signal.signal(s, handler)
    return code
