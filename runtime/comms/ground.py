"""A daemon's ground-station side: the mission protocol over the fleet's tasks, parameters, commands, and
what the robot reports (its state, what happened to tasks, the current mission item).

Missions (:class:`~runtime.comms.mission.MissionServer`): an upload to any robot hands the fleet new tasks.
Each MAV_CMD_NAV_WAYPOINT / NAV_LOITER_UNLIM item becomes a ``goto``, MAV_CMD_WAYPOINT_USER_1 a
``rendezvous`` (the kinds say which commands they take); the robot enters them in the replicated task
table, which tells every peer.  Uploads add tasks (a second upload while the fleet is busy adds more); an
uploaded item identical to the task listed at the same ``seq`` is that task, so a ground station that
downloads the mission, appends to it and uploads it again adds only the new items.  An upload of count 0
(or MISSION_CLEAR_ALL) withdraws the tasks not yet done.  The whole upload is refused, with a MISSION_ACK
error and a STATUSTEXT naming the item, if an item is not a task this fleet's method takes, has a frame
that is not global or local (NED/ENU), or lies off the map, in an obstacle or out of reach; the tasks the
fleet had stay as they were.  Downloads from any robot return the fleet's tasks (open and done, by id; an
item's ``seq`` is its place there), in the frame each was uploaded in.

Frames: global (lat, lon) through the datum with pymap3d; MAV_FRAME_LOCAL_ENU (x east, y north);
MAV_FRAME_LOCAL_NED (x north, y east).  Positions are metres in the fleet frame from there on.

Reports: the robot's :class:`~runtime.messages.RobotState` at 1 Hz (the fleet tasks it holds),
MISSION_CURRENT at 1 Hz (the seq of the task it works on, or the task count when idle),
MISSION_ITEM_REACHED when it arrives at a task, and one STATUSTEXT per task awarded, done or failed.

Base faults (``base.sensors.faults``, e.g. ``left_drive_silent``): a STATUSTEXT (CRITICAL) naming each new one;
a base that latches its faults (``latches_faults``: it stands until reset) also disarms the robot, so its tasks go
back to the fleet; SYS_STATUS shows MOTOR_OUTPUTS unhealthy meanwhile (:mod:`runtime.comms.telemetry`).  MAV_CMD_COMPONENT_ARM_DISARM with param1 = 1 while the base reports
faults is the fault reset: the base is asked to reset (``reset_faults``) and the robot arms once the faults have
cleared (a STATUSTEXT says so).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import pymap3d

from runtime import tasks as T
from runtime.comms import mission as M
from runtime.comms.gcs_services import GcsServices
from runtime.comms.params import Param, ParamTable
from runtime.messages import OPEN, TableRequest
from runtime.log import get_logger

if TYPE_CHECKING:
    from runtime.robot.ports import RobotPort

FRAME_LOCAL_NED, FRAME_LOCAL_ENU = 1, 4
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_RESULT_ACCEPTED, MAV_RESULT_DENIED = 0, 2
REPORT_PERIOD = 1.0
SAME_POSITION = 1e-3          # m: an uploaded item this close to a listed task (same seq, command, params) is it
STATUSTEXT_LEN = 50


class GroundServices:
    """``port``: the robot as a ground station may see and ask it (:class:`~runtime.robot.ports.RobotPort`).
    ``radio``: where replies and reports go (``send_to(msg, addr)``, ``send_gcs(msg)``), with the MAVLink
    encoder ``mav`` and dialect ``module``."""

    def __init__(self, port: "RobotPort", radio):
        self.port = port
        self.radio = radio
        self.mav = radio.mav
        self.m = radio.module
        self.log = get_logger("comms.ground", port.robot_id)
        self.mission = M.MissionServer(self.mav, port.robot_id, on_upload=self._on_upload, on_clear=self._on_clear,
                                       items=self._items, plan_id=lambda mission_type: self._plan_id(),
                                       validate=self._validate)
        self.params = ParamTable(_params(port, self._out_extend))
        self.gcs = GcsServices(self.mav, port.robot_id, 1, self.params)
        self.gcs.register_command(MAV_CMD_COMPONENT_ARM_DISARM, self._arm_disarm)
        self.gcs.register_message(self.m.MAVLINK_MSG_ID_HOME_POSITION, self._home)
        self._out: list = []                   # messages to peers produced while serving (new tasks ...)
        self._next_report = -math.inf
        self.reached: list[int] = []           # seqs reported reached (for tests and the trace)
        self._text_id = 0
        self._faults: tuple[str, ...] = ()     # the base's faults as last reported
        self._arm_after_reset = False

    # ------------------------------------------------------------------ requests
    def _out_extend(self, msgs: list) -> None:
        self._out.extend(msgs)

    def serve(self, now: float, inbox) -> list:
        """Answer what ground stations sent since the last cycle (``(message, source address)`` pairs); returns
        messages for the peers."""
        replies = []
        for msg, addr in inbox:
            if isinstance(msg, TableRequest):
                replies += [(r, addr) for r in self.port.answer_table(msg.sender)]
            elif msg.get_type().startswith("MISSION_"):
                replies += self.mission.handle(msg, now, addr)
            else:
                replies += self.gcs.handle(msg, now, addr)
        replies += self.mission.tick(now)
        replies += self.gcs.tick(now)
        for msg, addr in replies:
            self.radio.send_to(msg, addr)
        for ev in self.mission.pop_events():
            if ev.kind == "refused":
                self._text(4, ev.reason)                # MAV_SEVERITY_WARNING
            elif ev.kind == "cancelled":
                self._text(4, ev.reason or "mission upload cancelled")
        out, self._out = self._out, []
        return out

    def _validate(self, items: list[M.MissionItem]) -> tuple[int, str] | None:
        kinds = self.port.task_kinds
        pose = self.port.pose()
        for it in items:
            what = f"item {it.seq}"
            kind = T.kind_of_command(it.command)
            if kind is None or kind.KIND not in kinds:
                takes = sorted(c for k in kinds for c in T.kind(k).COMMANDS)
                return M.UNSUPPORTED, (f"{what}: command {it.command} is not a task for allocation "
                                       f"'{self.port.method_name}' (takes commands {takes})")
            xy = self._to_fleet(it)
            if xy is None:
                return 2, f"{what}: frame {it.frame} not supported (global, LOCAL_NED or LOCAL_ENU)"
            try:
                kind.from_item(it.command, (it.param1, it.param2, it.param3, it.param4), *xy)
            except ValueError as e:
                return 6, f"{what}: {e}"                # MAV_MISSION_INVALID_PARAM1
            why = self.port.refuse(pose, *xy)
            if why:
                return 10, f"{what} refused: {why}"     # MAV_MISSION_INVALID_PARAM5_X
        return None

    def _on_upload(self, items: list[M.MissionItem]) -> int:
        listing = self.port.listing()
        new = []
        for it in items:
            x, y = self._to_fleet(it)
            params = (it.param1, it.param2, it.param3, it.param4)
            same = it.seq < len(listing) and _same(listing[it.seq], it.command, params, x, y)
            if not same:
                new.append((it.command, it.frame, params, x, y))
        now = self.port.now
        if new:
            self._out += self.port.hand_in(new, now)
        home = ", home item 0 skipped" if self.mission.home_skipped else ""
        self._text(6, f"mission: {len(new)} task(s) added, {len(items) - len(new)} already known{home}")
        return self._plan_id()

    def _on_clear(self, mission_type: int) -> None:
        self._out += self.port.clear(self.port.now)

    def _items(self, mission_type: int) -> list[M.MissionItem]:
        if mission_type != M.MISSION:
            return []
        out = []
        for seq, e in enumerate(self.port.listing()):
            x, y = self._from_fleet(e.frame, e.x, e.y)
            out.append(M.MissionItem(seq, e.frame, e.command, *e.params, x, y, 0.0, True, M.MISSION))
        return out

    def _plan_id(self) -> int:
        return self.port.digest

    def _to_fleet(self, it: M.MissionItem) -> tuple[float, float] | None:
        if it.frame in M.GLOBAL_FRAMES:
            d = self.port.datum
            e, n, _ = pymap3d.geodetic2enu(it.x, it.y, d.alt, d.lat, d.lon, d.alt)
            return float(e), float(n)
        if it.frame == FRAME_LOCAL_ENU:
            return float(it.x), float(it.y)
        if it.frame == FRAME_LOCAL_NED:
            return float(it.y), float(it.x)
        return None

    def _from_fleet(self, frame: int, x: float, y: float) -> tuple[float, float]:
        if frame in M.GLOBAL_FRAMES:
            d = self.port.datum
            lat, lon, _ = pymap3d.enu2geodetic(x, y, 0.0, d.lat, d.lon, d.alt)
            return float(lat), float(lon)
        if frame == FRAME_LOCAL_NED:
            return y, x
        return x, y

    def _home(self):
        """HOME_POSITION: the fleet frame's origin (the datum), where a ground station centres its map."""
        d = self.port.datum
        return self.mav.home_position_encode(int(round(d.lat * 1e7)), int(round(d.lon * 1e7)), int(round(d.alt * 1000)),
                                             0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0)

    def _arm_disarm(self, msg, now: float) -> int:
        p1 = float(msg.param1)
        if p1 not in (0.0, 1.0):
            return MAV_RESULT_DENIED
        self._arm_after_reset = p1 == 1.0 and self.port.reset_faults(now)    # arms once the faults clear
        if self._arm_after_reset:
            self._text(4, "base fault reset requested")
        else:
            self._out += self.port.set_armed(p1 == 1.0, now)
        return MAV_RESULT_ACCEPTED

    def _base_faults(self, now: float) -> None:
        faults = self.port.faults()
        if faults == self._faults:
            return
        new = [f for f in faults if f not in self._faults]
        self._faults = faults
        if new:
            self._text(2, "base fault: " + ", ".join(new))                          # MAV_SEVERITY_CRITICAL
            if self.port.base.latches_faults:         # it stands until reset: its tasks go back
                self._out += self.port.set_armed(False, now)
        elif not faults:
            self._text(5, "base faults cleared")
            if self._arm_after_reset:
                self._arm_after_reset = False
                self._out += self.port.set_armed(True, now)

    # ------------------------------------------------------------------ reports
    def report(self, now: float) -> None:
        radio, port = self.radio, self.port
        self._base_faults(now)
        for n in port.pop_notices():
            if n.reached_seq is not None:
                self.reached.append(n.reached_seq)
                radio.send_gcs(self.mav.mission_item_reached_encode(n.reached_seq))
            self._text(n.severity, n.text)
        if now < self._next_report:
            return
        self._next_report = now + REPORT_PERIOD
        radio.send_gcs(port.robot_state())
        listing = port.listing()
        held = port.held()
        seq = next((i for i, e in enumerate(listing) if held and e.id == held[0]), len(listing))
        total = len(listing)
        m = self.m
        if held:
            state = m.MISSION_STATE_ACTIVE
        elif total and all(e.state != OPEN for e in listing):
            state = m.MISSION_STATE_COMPLETE
        elif total:
            state = m.MISSION_STATE_NOT_STARTED
        else:
            state = m.MISSION_STATE_NO_MISSION
        radio.send_gcs(self.mav.mission_current_encode(seq, total, state, 0))

    def _text(self, severity: int, text: str) -> None:
        """One STATUSTEXT, or several chunks of 50 characters with a common ``id`` and their ``chunk_seq``
        (MAVLink 2's way of sending a longer line; a last chunk shorter than 50, or empty, ends it)."""
        data = text.encode()
        if len(data) <= STATUSTEXT_LEN:
            self.radio.send_gcs(self.mav.statustext_encode(severity, data))
        else:
            self._text_id = self._text_id % 0xFFFF + 1
            chunks = [data[i:i + STATUSTEXT_LEN] for i in range(0, len(data), STATUSTEXT_LEN)]
            if len(chunks[-1]) == STATUSTEXT_LEN:
                chunks.append(b"")
            for k, chunk in enumerate(chunks):
                self.radio.send_gcs(self.mav.statustext_encode(severity, chunk, self._text_id, k))
        self.log.info("%s", text)


def _same(entry, command: int, params, x: float, y: float) -> bool:
    return (entry.command == command and all(_eq(a, b) for a, b in zip(entry.params, params))
            and math.hypot(entry.x - x, entry.y - y) <= SAME_POSITION)


def _eq(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or abs(a - b) <= 1e-6 * max(1.0, abs(a))


def _params(port: "RobotPort", out) -> list[Param]:
    """The robot's tunables a ground station may read and set; each takes effect at once.  ``out`` takes the
    messages for the peers that arming or disarming makes."""
    t = port.tunables
    vmax = port.base.max_speed

    def tune(name):
        return lambda v: port.tune(**{name: float(v)})

    return [
        Param("CTL_CRUISE_SPD", float, 0.01, vmax, "cruise speed (m/s)", lambda: t.cruise_speed, tune("cruise_speed")),
        Param("CTL_GOAL_TOL", float, 0.005, 5.0, "a goal is reached within this distance (m)",
              lambda: t.goal_tolerance, tune("goal_tolerance")),
        Param("CTL_LOOKAHEAD", float, 0.05, 10.0, "pure pursuit lookahead (m)", lambda: t.lookahead,
              tune("lookahead")),
        Param("CTL_MAX_TURN", float, 0.1, 10.0, "turn rate limit (rad/s)", lambda: t.max_turn_rate,
              tune("max_turn_rate")),
        Param("SYS_ARMED", int, 0, 1, "1: may drive and take tasks (MAV_CMD_COMPONENT_ARM_DISARM does the same)",
              lambda: int(port.armed), lambda v: out(port.set_armed(bool(v), port.now))),
    ] + _option_params(port.allocation_options)


def _option_params(opts) -> list[Param]:
    """The allocation method's numeric options, read-only here: the agent is built with them (ALLOC_*)."""
    import dataclasses

    out = []
    for f in dataclasses.fields(opts):
        v = getattr(opts, f.name)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            continue
        name = ("ALC_" + f.name.upper())[:16]
        out.append(Param(name, type(v), v, v, f"allocation option {f.name} (set it in the robot config)",
                         lambda v=v: v, lambda _v: None))
    return out
