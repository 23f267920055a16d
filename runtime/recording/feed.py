"""What one robot core did in a cycle, onto a :class:`~runtime.recording.recorder.Recorder`'s channels.

A host calls :meth:`CoreFeed.cycle` after each :meth:`RobotCore.step <runtime.robot.core.RobotCore.step>` (and
:meth:`CoreFeed.frames` after :meth:`RobotCore.service`) with the core's :class:`~runtime.robot.core.Output`.  The
feed reads only what the core returned and its narrow state (pose, commitments, the fleet table, the lead
executor's path); it changes nothing, so a recorded run is the run it would have been.

Allocation events (``/allocation``): every message the robot sent its peers (bids, awards, prices, rounds, coalition
offers ...) as ``sent`` with its type and fields, and with ``received`` those that reached it; ``committed`` and
``released`` when a task enters or leaves the robot's commitments (with its partners: a coalition formed or left);
``progress`` (arrived, done, failed); ``task`` when the robot's copy of the fleet table changes a task's state
(handed in, done, withdrawn, cleared) or who did it; ``peer_lost``.  The ground-station STATUSTEXT lines go to
``/log``.
"""
from __future__ import annotations

import dataclasses
import logging

from runtime.messages import STATE_NAMES
from runtime.recording.recorder import recoverable
from runtime.robot.core import GCS, PEERS, TO

FLUSH_PERIOD = 2.0        # wall s between a daemon recording's chunk flushes: what a killed daemon loses at most


def message_fields(msg) -> dict:
    """A message dataclass's fields as plain data."""
    if dataclasses.is_dataclass(msg):
        return {f.name: getattr(msg, f.name) for f in dataclasses.fields(msg)}
    return {}


class CoreFeed:
    """Records robot ``core``'s cycles on ``rec``.  ``received``: also the peers' messages that reached it (a fleet
    recording has them as the senders' ``sent`` already)."""

    def __init__(self, rec, core, *, received: bool = False, stats=None, stats_period: float = 1.0,
                 scene: bool = False, watch=None):
        self.rec = rec
        self.watch = watch                  # (robot id, message) -> None: told every message the robot sends its
        #                                     peers (a fleet's host learns objects' weights left from them)
        self.scene = scene                  # draw /world (the robot's map and its table's tasks): a robot's own
        #                                     recording; a fleet's host draws the world itself
        self.stats = stats                  # () -> the host's status snapshot, recorded every stats_period s
        self.stats_period = stats_period
        self._next_stats = None
        self.core = core
        self.id = core.id
        self.received = received
        self._path = None
        self._bumpers = None
        self._laser: object = ()
        self._held: dict[int, tuple] = {}
        self._table: dict[int, tuple] = {}
        self._drawn = False
        self._lost = 0

    def cycle(self, now: float, out, inbox=None) -> None:
        """One control cycle's output (``out``, and the ``inbox`` it answered).  A failing recording ends with one
        warning line; the cycle goes on."""
        self._guarded(self._cycle, now, out, inbox)

    def frames(self, now: float, out, inbox=None) -> None:
        """The messages of ``out`` (sent to peers) and, with ``received``, those of ``inbox``; STATUSTEXT to the
        log."""
        self._guarded(self._frames, now, out, inbox)

    def _guarded(self, record, *args) -> None:
        try:
            record(*args)
        except BaseException as exc:
            if not recoverable(exc):
                raise
            self.rec.fail(exc)

    def _cycle(self, now: float, out, inbox) -> None:
        rec, core, rid = self.rec, self.core, self.id
        pose = core.pose()
        if pose is not None:
            rec.pose(rid, now, pose)
        rec.command(rid, now, *out.command)
        lead = core.executive._lead()
        path = None if lead is None else lead.follow.path
        if path is not self._path:
            self._path = path
            rec.path(rid, now, path or ())
        if core.sensors is not None:
            self._sensors(now, core.sensors)
        if out.frames or (self.received and inbox is not None):
            self._frames(now, out, inbox)
        for p in out.progress:
            rec.event(now, rid, "progress", p.event, p.task, (rid,), {"detail": p.detail}, t=p.t)
        self._commitments(now)
        self._fleet_table(now)
        lost = core.stats.peers_lost
        if len(lost) != self._lost:
            for peer in lost[self._lost:]:
                rec.event(now, rid, "peer_lost", "", None, (peer,))
            self._lost = len(lost)
        if self.stats is not None and (self._next_stats is None or now >= self._next_stats):
            self._next_stats = now + self.stats_period
            rec.stats(rid, now, self.stats())
        rec.check()

    def _sensors(self, now: float, sensors) -> None:
        """What the robot senses: every range reading as points (the base's and its lasers'), a laser's revolution
        also as ``/robot_N/scan`` (``foxglove.LaserScan``), its bumpers when they change."""
        rec, rid = self.rec, self.id
        ranges = getattr(sensors, "ranges", ())
        if ranges:
            rec.ranges(rid, now, ranges)
        laser = getattr(self.core, "laser", ())
        if laser and laser != self._laser:           # a new revolution (the sensor repeats its last until then)
            self._laser = laser
            rec.scan(rid, now, laser)
        bump = (sensors.bump_left, sensors.bump_right, sensors.wheel_drop, tuple(getattr(sensors, "faults", ())))
        if bump != self._bumpers:
            self._bumpers = bump
            rec.bumpers(rid, now, *bump)

    def _frames(self, now: float, out, inbox) -> None:
        rec, rid = self.rec, self.id
        if self.received and inbox is not None:
            for msg in inbox.peers:
                rec.event(now, rid, "received", type(msg).__name__, getattr(msg, "task", None),
                          (getattr(msg, "sender", 0),), message_fields(msg))
        for frame in out.frames:
            if frame[0] == PEERS:
                msg = frame[1]
                rec.event(now, rid, "sent", type(msg).__name__, getattr(msg, "task", None), (rid,),
                          message_fields(msg))
                if self.watch is not None:
                    self.watch(rid, msg)
            elif frame[0] in (GCS, TO) and getattr(frame[1], "get_type", lambda: "")() == "STATUSTEXT":
                text = frame[1].text
                text = text.decode(errors="replace") if isinstance(text, bytes) else str(text)
                rec.text(now, logging.INFO, f"statustext robot={rid}", text.rstrip("\0"))

    def _commitments(self, now: float) -> None:
        held = {c.task_id: (tuple(c.partners), c.role) for c in self.core.agent.commitments}
        if held == self._held:
            return
        for tid, (partners, role) in held.items():
            if self._held.get(tid) != (partners, role):
                self.rec.event(now, self.id, "committed", role, tid, (self.id, *partners), {"kind": self._kind(tid)})
        for tid in self._held.keys() - held.keys():
            self.rec.event(now, self.id, "released", "", tid, (self.id,))
        self._held = held

    def _kind(self, tid: int) -> str:
        c = next((c for c in self.core.agent.commitments if c.task_id == tid), None)
        return "" if c is None else c.task.kind

    def _fleet_table(self, now: float) -> None:
        entries = self.core.node.table.entries
        if len(entries) == len(self._table) and all(
                self._table.get(tid) == (e.state, e.done_by) for tid, e in entries.items()) and \
                (self._drawn or not self.scene):
            return
        self._drawn = True
        for tid, e in entries.items():
            if self._table.get(tid) != (e.state, e.done_by):
                self._table[tid] = (e.state, e.done_by)
                self.rec.event(now, self.id, "task", STATE_NAMES.get(e.state, str(e.state)), tid, e.done_by,
                               {"x": e.x, "y": e.y, "command": e.command})
        if self.scene:
            self.rec.scene(now, self.core.planner.world,
                           [(tid, e.x, e.y, f"{tid >> 16}.{tid & 0xFFFF}", STATE_NAMES.get(e.state, "?"))
                            for tid, e in entries.items()])


class LogTap(logging.Handler):
    """Every record of the runtime's loggers (``mrta.*``) onto ``rec``'s ``/log``, at the recording's time, with
    the robot id the record carries.  While attached, the ``mrta`` logger passes INFO records (the recording wants
    them) and the handlers that were there print only what they printed before."""

    def __init__(self, rec, level: int = logging.INFO):
        super().__init__(level)
        self.rec = rec
        self._restore: list = []

    def attach(self) -> "LogTap":
        logger = logging.getLogger("mrta")
        effective = logger.getEffectiveLevel()
        if effective > self.level:
            for h in logging.getLogger().handlers:         # what stderr showed, it still shows
                if h.level < effective:
                    self._restore.append((h, h.level))
                    h.setLevel(effective)
            self._restore.append((logger, logger.level))
            logger.setLevel(self.level)
        logger.addHandler(self)
        return self

    def detach(self) -> None:
        logging.getLogger("mrta").removeHandler(self)
        for thing, level in reversed(self._restore):
            thing.setLevel(level)
        self._restore = []

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.rec.text(self.rec.ns / 1e9 if not self.rec.wall else 0.0, record.levelno,
                          f"{record.name} robot={getattr(record, 'robot', '-')}", record.getMessage(),
                          record.pathname, record.lineno)
        except Exception:       # a log line must never stop the robot
            self.handleError(record)


class Recording:
    """One daemon's recording (``mrta daemon --record/--live``): the recorder, the feed on the core, the log tap
    and (``mavlink``) the link's tap.  :meth:`close` finishes the file."""

    def __init__(self, rec, tap: LogTap):
        self.rec = rec
        self.tap = tap

    @classmethod
    def of_daemon(cls, daemon, path, *, wall: bool = True, limit: int | None = None, rotate: bool = False,
                  live=None, mavlink: bool = False, relay=None) -> "Recording":
        from runtime.recording.recorder import Recorder

        rec = Recorder(path, wall=wall, limit=limit, rotate=rotate, live=live, mavlink=mavlink, robot_id=daemon.id,
                       name=f"mrta robot {daemon.id}", flush_period=FLUSH_PERIOD, relay=relay)
        rec.metadata("robot", {"id": str(daemon.id), "base": daemon.cfg.base.type,
                               "allocation": daemon.cfg.allocation.method, "clock": "system" if wall else "sim"})
        daemon.feed = CoreFeed(rec, daemon.core, received=True, stats=daemon.snapshot, scene=True)
        if mavlink:
            daemon.link.tap = rec.frame_tap(daemon.id)
        return cls(rec, LogTap(rec).attach())

    def close(self) -> None:
        self.tap.detach()
        self.rec.close()
