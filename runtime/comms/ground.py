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

Reports: the robot's :class:`~runtime.messages.RobotState` at 1 Hz (the fleet tasks it holds), and the fleet's
mission progress as every robot knows it: MISSION_CURRENT with ``seq`` = the items done (by any robot of the fleet)
and the fleet mission's state (COMPLETE once no item is open: MAVSDK's ``is_mission_finished``), at 1 Hz and at
once when the count changes; MISSION_ITEM_REACHED once per item done, by any robot, sent only once ``seq`` + 1
items are done (MAVSDK shows seq + 1 as the progress, so it never runs ahead of the truth); one STATUSTEXT per task
awarded, reached, done or failed.

Modes (ArduPilot Rover numbers, as MAVSDK and MAVProxy send them: MAV_CMD_DO_SET_MODE with CUSTOM_MODE_ENABLED in
param1 and the mode in param2, or the SET_MODE message): AUTO (10) takes tasks (the default; also
MAV_CMD_MISSION_START and DO_PAUSE_CONTINUE 1), HOLD (4) pauses the robot: it stops and its tasks go back to the
fleet, which goes on without it (also DO_PAUSE_CONTINUE 0), RTL (11) hands its tasks back and drives to its home,
where it started (also MAV_CMD_NAV_RETURN_TO_LAUNCH).  Other modes are DENIED with a STATUSTEXT.

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
from runtime.comms.gcs_services import GcsServices, _whole
from runtime.comms.params import Param, ParamTable
from runtime.comms.telemetry import STREAMS
from runtime.messages import DONE, OPEN, TableRequest
from runtime.log import get_logger

if TYPE_CHECKING:
    from runtime.robot.ports import RobotPort

FRAME_LOCAL_NED, FRAME_LOCAL_ENU = 1, 4
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_RESULT_ACCEPTED, MAV_RESULT_DENIED = 0, 2
REPORT_PERIOD = 1.0
SAME_POSITION = 1e-3          # m: an uploaded item this close to a listed task (same seq, command, params) is it
STATUSTEXT_LEN = 50
ROVER_MODES = {10: "auto", 4: "hold", 11: "rtl"}     # ArduPilot Rover custom_mode -> the robot's mode
MODE_NAMES = {"auto": "AUTO", "hold": "HOLD", "rtl": "RTL"}
CUSTOM_MODE_ENABLED = 1       # MAV_MODE_FLAG_CUSTOM_MODE_ENABLED


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
        m = self.m
        self.gcs.register_command(MAV_CMD_COMPONENT_ARM_DISARM, self._arm_disarm)
        self.gcs.register_command(m.MAV_CMD_DO_SET_MODE, self._do_set_mode)
        self.gcs.register_command(m.MAV_CMD_MISSION_START, lambda msg, now: self._mode("auto", now))
        self.gcs.register_command(m.MAV_CMD_NAV_RETURN_TO_LAUNCH, lambda msg, now: self._mode("rtl", now))
        self.gcs.register_command(m.MAV_CMD_DO_PAUSE_CONTINUE, self._pause_continue)
        self.gcs.register_command(m.MAV_CMD_SET_MESSAGE_INTERVAL, self._set_interval)
        self.gcs.register_command(m.MAV_CMD_GET_MESSAGE_INTERVAL, self._get_interval)
        for name in STREAMS:
            msg_id = getattr(m, "MAVLINK_MSG_ID_" + name)
            self.gcs.register_message(msg_id, lambda msg_id=msg_id: port.stream_message(msg_id))
        self._out: list = []                   # messages to peers produced while serving (new tasks ...)
        self._next_report = -math.inf
        self.reached: list[int] = []           # seqs reported reached (for tests and the trace)
        self._reached_ids: set[int] = set()    # tasks whose MISSION_ITEM_REACHED went out
        self._done_reported = 0                # the items done that the last MISSION_CURRENT counted
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
            elif msg.get_type() == "SET_MODE":
                self._set_mode_message(msg, now)
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
            bad = M.check_task_values(it)
            if bad:
                return bad
            try:
                kind.from_item(it.command, (it.param1, it.param2, it.param3, it.param4), *xy)
            except ValueError as e:
                return M.param_result(str(e)), f"{what}: {e}"      # MAV_MISSION_INVALID_PARAM1..4
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
        self._text(6, M.added_report(len(new), len(items) - len(new)) + home)
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

    def _mode(self, mode: str, now: float) -> int:
        if mode == "rtl" and self.port.home is None:
            self._text(4, "RTL refused: no home yet (not localized)")
            return self.m.MAV_RESULT_TEMPORARILY_REJECTED
        self._out += self.port.set_mode(mode, now)
        return MAV_RESULT_ACCEPTED

    def _rover_mode(self, base_mode, custom_mode, now: float) -> int:
        """A mode change as DO_SET_MODE and SET_MODE carry it: CUSTOM_MODE_ENABLED and a Rover mode number."""
        base, custom = _whole(base_mode), _whole(custom_mode)
        mode = ROVER_MODES.get(custom)
        if base is None or not base & CUSTOM_MODE_ENABLED or mode is None:
            self._text(4, f"mode {float(custom_mode):g} refused: the robot takes AUTO 10, HOLD 4, RTL 11 "
                          "(custom modes)")
            return MAV_RESULT_DENIED
        return self._mode(mode, now)

    def _do_set_mode(self, msg, now: float) -> int:
        return self._rover_mode(msg.param1, msg.param2, now)

    def _set_mode_message(self, msg, now: float) -> None:
        """SET_MODE (no ack; the HEARTBEAT shows the result), as QGroundControl's mode menu sends it."""
        try:
            if int(msg.target_system) == self.port.robot_id:
                self._rover_mode(msg.base_mode, msg.custom_mode, now)
        except (TypeError, ValueError) as e:
            self.log.debug("SET_MODE dropped: %r", e)

    def _pause_continue(self, msg, now: float) -> int:
        p1 = float(msg.param1)
        if p1 not in (0.0, 1.0):
            return MAV_RESULT_DENIED
        return self._mode("auto" if p1 == 1.0 else "hold", now)

    def _set_interval(self, msg, now: float) -> int:
        msg_id = _whole(msg.param1)
        if msg_id is None or self.port.message_interval(msg_id) is None:
            return self.m.MAV_RESULT_UNSUPPORTED
        return MAV_RESULT_ACCEPTED if self.port.set_message_interval(msg_id, float(msg.param2)) else MAV_RESULT_DENIED

    def _get_interval(self, msg, now: float):
        msg_id = _whole(msg.param1)
        us = None if msg_id is None else self.port.message_interval(msg_id)
        if us is None:
            return self.m.MAV_RESULT_UNSUPPORTED
        return MAV_RESULT_ACCEPTED, [self.mav.message_interval_encode(msg_id, us)]

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
            self._text(n.severity, n.text)
        listing = port.listing()
        done = sum(e.state == DONE for e in listing)
        # MISSION_ITEM_REACHED once per item done, by any robot; MAVSDK takes seq + 1 as the progress, so an item
        # goes out only once that many are done (no progress shown beyond the truth), in seq order, and
        # MISSION_CURRENT (seq = the items done) follows at once
        new = [i for i, e in enumerate(listing[:done]) if e.state == DONE and e.id not in self._reached_ids]
        for seq in new:
            self._reached_ids.add(listing[seq].id)
            self.reached.append(seq)
            radio.send_gcs(self.mav.mission_item_reached_encode(seq))
        if now < self._next_report and done == self._done_reported:
            return
        self._done_reported = done
        self._next_report = now + REPORT_PERIOD
        radio.send_gcs(port.robot_state())
        radio.send_gcs(self._mission_current(listing))

    def _mission_current(self, listing):
        """MISSION_CURRENT of the fleet's mission: ``seq`` = the items done by any robot (MAVSDK shows it as the
        progress, ``seq``/``total``), the state COMPLETE once none is open."""
        m, total = self.m, len(listing)
        done = sum(e.state == DONE for e in listing)
        if not total:
            state = m.MISSION_STATE_NO_MISSION
        elif all(e.state != OPEN for e in listing):
            state = m.MISSION_STATE_COMPLETE
        elif self.port.mode != "auto":
            state = m.MISSION_STATE_PAUSED            # this robot takes no part in it now
        else:
            state = m.MISSION_STATE_ACTIVE
        return self.mav.mission_current_encode(done, total, state, 1 if self.port.mode == "auto" else 0)

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
