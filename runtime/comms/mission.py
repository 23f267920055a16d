"""The MAVLink mission protocol, sans-IO: the vehicle side (:class:`MissionServer`) and the ground-station
side (:class:`MissionClient`).  Neither opens a socket, reads a clock or sleeps: each takes decoded pymavlink
messages with ``now`` (seconds) and returns the messages to send.

Protocol, as the MAVLink developer guide states it (en/services/mission.md, "Upload a Mission",
"Download a Mission", "Clear Missions", "Timeouts and Retries", "Errors/Completion"), with QGroundControl's
timings (src/MissionManager/PlanManager.h: ``_ackTimeoutMilliseconds`` 1500, ``_retryTimeoutMilliseconds``
250, ``_maxRetryCount`` 5):

* upload: GCS MISSION_COUNT -> vehicle MISSION_REQUEST_INT(0) -> GCS MISSION_ITEM_INT(0) -> ... ->
  vehicle MISSION_ACK.  Items are taken in order only: an out-of-sequence item is dropped and the
  expected one re-requested.  A MISSION_ACK with an error ends the transfer and the vehicle keeps the
  mission it had ("A new mission should be fully uploaded and accepted before the old mission is
  replaced").  MISSION_COUNT with count 0 clears, like MISSION_CLEAR_ALL.
* download: GCS MISSION_REQUEST_LIST -> vehicle MISSION_COUNT -> GCS MISSION_REQUEST_INT(seq) ->
  vehicle MISSION_ITEM_INT(seq) ... -> GCS MISSION_ACK.
* deprecated MISSION_REQUEST is answered with MISSION_ITEM_INT; deprecated MISSION_ITEM (float x/y) is
  accepted wherever MISSION_ITEM_INT is ("Protocol implementations must also support MISSION_ITEM and
  MISSION_REQUEST in the same way").
* timeouts: 1.5 s while waiting for a reply, 0.25 s when a GCS re-requests a downloaded item, 5 retries;
  after that the waiting side gives up (the vehicle sends MISSION_ACK MAV_MISSION_OPERATION_CANCELLED).
* one transfer at a time on the vehicle: another requester meanwhile gets MISSION_ACK
  MAV_MISSION_DENIED (common.xml: "Not accepting any mission commands from this communication partner").
* fence and rally "missions" (MAV_MISSION_TYPE_FENCE/RALLY): this vehicle has none; downloads answer
  count 0, uploads of count > 0 are refused with MAV_MISSION_UNSUPPORTED, clears are accepted.
* home: this vehicle (a generic autopilot) keeps no home item, but MAVProxy's ``wp load`` sends a WPL file's
  home line as item 0, as it would to ArduPilot.  An uploaded item 0 that is marked current, is a
  MAV_CMD_NAV_WAYPOINT and is in MAV_FRAME_GLOBAL (absolute altitude, or its _INT twin) is that home line
  (:func:`is_home_item`): it is skipped and the items after it are renumbered from 0, as ``mrta mission upload``
  skips it in a file.  QGroundControl and MAVSDK send no home to a generic autopilot (their waypoints are
  relative-altitude ones), :class:`MissionClient` marks no item current, and downloads mark none either, so a
  mission a station read back and uploads again keeps its item 0.

MISSION_ITEM_INT coordinates (common.xml MISSION_ITEM_INT.x/.y: "local: x position in meters * 1e4,
global: latitude in degrees * 10^7"; devguide "Frames & Positional Information"): in the global frames
(MAV_FRAME_GLOBAL*, with or without _INT, as QGC sends MAV_FRAME_GLOBAL_RELATIVE_ALT in MISSION_ITEM_INT
with degrees * 1e7) x, y = degrees * 1e7; in the local frames (LOCAL_NED, LOCAL_ENU, LOCAL_OFFSET_NED,
BODY_*, LOCAL_FRD/FLU) x, y = metres * 1e4; in MAV_FRAME_MISSION (and unknown frames) x, y are sent as-is.
INT32_MAX means "unset" (common.xml: "NaN or INT32_MAX may be used in float/integer params ... to indicate
optional/default values"): it decodes to NaN and NaN encodes to it.  Note that QGC itself decodes every
frame but MAV_FRAME_MISSION as 1e7 (PlanManager::_handleMissionItem); QGC never plans local frames.

The installed pymavlink (2.4.50) common.xml has no ``opaque_id`` in MISSION_COUNT/MISSION_ACK; the plan id
is set on the wire only when the dialect has the field, and is always reported in :class:`MissionEvent`.
"""
from __future__ import annotations

import math
import re
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import Any, Callable, NamedTuple

from runtime.log import get_logger

# MAV_MISSION_TYPE
MISSION, FENCE, RALLY, ALL = 0, 1, 2, 255
# MAV_MISSION_RESULT (common.xml); names for one-line messages
RESULT_NAMES = {
    0: "MAV_MISSION_ACCEPTED", 1: "MAV_MISSION_ERROR", 2: "MAV_MISSION_UNSUPPORTED_FRAME",
    3: "MAV_MISSION_UNSUPPORTED", 4: "MAV_MISSION_NO_SPACE", 5: "MAV_MISSION_INVALID",
    6: "MAV_MISSION_INVALID_PARAM1", 7: "MAV_MISSION_INVALID_PARAM2", 8: "MAV_MISSION_INVALID_PARAM3",
    9: "MAV_MISSION_INVALID_PARAM4", 10: "MAV_MISSION_INVALID_PARAM5_X", 11: "MAV_MISSION_INVALID_PARAM6_Y",
    12: "MAV_MISSION_INVALID_PARAM7", 13: "MAV_MISSION_INVALID_SEQUENCE", 14: "MAV_MISSION_DENIED",
    15: "MAV_MISSION_OPERATION_CANCELLED",
}
ACCEPTED, ERROR, UNSUPPORTED, NO_SPACE = 0, 1, 3, 4
INVALID_PARAM1, INVALID_PARAM5_X, INVALID_PARAM6_Y, INVALID_PARAM7 = 6, 10, 11, 12   # PARAM2..4: 7..9
INVALID_SEQUENCE, DENIED, CANCELLED = 13, 14, 15
TIMEOUT = -1                   # MissionClient.result when the vehicle stopped answering

DEFAULT_TIMEOUT = 1.5          # s: waiting for any reply
ITEM_TIMEOUT = 0.25            # s: a GCS re-requesting a downloaded item
MAX_RETRIES = 5
IDLE_TIMEOUT = 2 * DEFAULT_TIMEOUT   # s: a download the GCS stopped driving is released
REREQUEST_GAP = ITEM_TIMEOUT   # s: at most one re-request per gap on out-of-sequence items
MAX_ITEMS = 1000               # default vehicle capacity; larger uploads get MAV_MISSION_NO_SPACE

# MAV_FRAME
FRAME_MISSION = 2
GLOBAL_FRAMES = frozenset({0, 3, 5, 6, 10, 11})         # GLOBAL, GLOBAL_RELATIVE_ALT, *_INT, TERRAIN_ALT*
LOCAL_FRAMES = frozenset({1, 4, 7, 8, 9, 12, 20, 21})   # LOCAL_NED/ENU/OFFSET_NED, BODY_*, LOCAL_FRD/FLU
INT32_MAX = 2**31 - 1
MAV_CMD_DO_JUMP = 177
MAV_CMD_NAV_WAYPOINT = 16
HOME_FRAMES = frozenset({0, 5})                         # MAV_FRAME_GLOBAL, MAV_FRAME_GLOBAL_INT

_TRANSFER_KINDS = ("MISSION_COUNT", "MISSION_REQUEST_LIST", "MISSION_CLEAR_ALL")


def result_name(code: int) -> str:
    return "timeout" if code == TIMEOUT else RESULT_NAMES.get(code, f"MAV_MISSION_RESULT {code}")


def xy_scale(frame: int) -> float:
    """Factor from x/y (degrees or metres) to the MISSION_ITEM_INT integer for ``frame``."""
    if frame in GLOBAL_FRAMES:
        return 1e7
    if frame in LOCAL_FRAMES:
        return 1e4
    return 1.0


def encode_xy(value: float, frame: int) -> int:
    """x or y as the MISSION_ITEM_INT integer; NaN -> INT32_MAX ("unset").  ValueError if it cannot fit."""
    value = float(value)
    if math.isnan(value):
        return INT32_MAX
    n = value * xy_scale(frame)
    if not -2**31 <= n < INT32_MAX - 0.5:
        raise ValueError(f"{value!r} does not fit MISSION_ITEM_INT in frame {frame}")
    return int(round(n))


def decode_xy(n: int, frame: int) -> float:
    if n == INT32_MAX:
        return math.nan
    scale = xy_scale(frame)
    return float(n) if scale == 1.0 else n / scale


def is_home_item(msg) -> bool:
    """Whether an uploaded MISSION_ITEM(_INT) is a home line as MAVProxy sends it (module docstring, home): seq 0,
    current, MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL(_INT)."""
    return (int(msg.seq) == 0 and int(msg.current) == 1 and int(msg.command) == MAV_CMD_NAV_WAYPOINT
            and int(msg.frame) in HOME_FRAMES)


def _nan_key(v: float):
    return None if isinstance(v, float) and math.isnan(v) else v


@dataclass(frozen=True, eq=False)
class MissionItem:
    """One mission item with x, y decoded: degrees in global frames, metres in local frames, raw otherwise.

    Equality treats NaN parameters as equal (NaN means "default" in MAV_CMD parameters).
    """
    seq: int
    frame: int
    command: int
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    autocontinue: bool = True
    mission_type: int = MISSION

    def _key(self) -> tuple:
        return (self.seq, self.frame, self.command, *(_nan_key(float(v)) for v in self.params),
                bool(self.autocontinue), self.mission_type)

    def __eq__(self, other) -> bool:
        return isinstance(other, MissionItem) and self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    @property
    def params(self) -> tuple[float, ...]:
        """The seven MAV_CMD parameters: param1..4, x, y, z."""
        return (self.param1, self.param2, self.param3, self.param4, self.x, self.y, self.z)

    @classmethod
    def from_mavlink(cls, msg) -> "MissionItem":
        """From a MISSION_ITEM_INT (x, y decoded per frame) or a legacy MISSION_ITEM (float x, y as-is)."""
        frame = int(msg.frame)
        if msg.get_type() == "MISSION_ITEM_INT":
            x, y = decode_xy(int(msg.x), frame), decode_xy(int(msg.y), frame)
        else:
            x, y = float(msg.x), float(msg.y)
        return cls(int(msg.seq), frame, int(msg.command), float(msg.param1), float(msg.param2),
                   float(msg.param3), float(msg.param4), x, y, float(msg.z), bool(msg.autocontinue),
                   int(getattr(msg, "mission_type", MISSION)))

    def check_encodable(self) -> str | None:
        """None if the item fits MISSION_ITEM_INT, else a short reason."""
        for name, v in (("x", self.x), ("y", self.y)):
            try:
                encode_xy(v, self.frame)
            except (ValueError, TypeError, OverflowError):
                return f"{name} {v!r} does not fit an int32 in frame {self.frame}"
        if not (0 <= self.seq <= 0xFFFF and 0 <= self.frame <= 0xFF and 0 <= self.command <= 0xFFFF
                and 0 <= self.mission_type <= 0xFF):
            return "seq, frame, command or mission_type out of range"
        return None

    def to_mavlink_int(self, mav, target_system: int, target_component: int, current: bool = False):
        """This item as a MISSION_ITEM_INT built by ``mav`` (a generated ``MAVLink`` instance)."""
        return mav.mission_item_int_encode(
            target_system, target_component, self.seq, self.frame, self.command, int(bool(current)),
            int(bool(self.autocontinue)), self.param1, self.param2, self.param3, self.param4,
            encode_xy(self.x, self.frame), encode_xy(self.y, self.frame), self.z, self.mission_type)


def check_task_values(item: MissionItem) -> tuple[int, str] | None:
    """Values no task can work with, as ``(MAV_MISSION_RESULT, reason)``, else None: x or y NaN or infinite (a task
    needs a position, and NaN, the protocol's "unset", gives none: MAV_MISSION_INVALID_PARAM5_X / PARAM6_Y); an
    infinite param1..4 or z (MAV_MISSION_INVALID_PARAM1..4 / PARAM7).  NaN in param1..4 and z is the protocol's
    "default" (common.xml: "NaN ... may be used in float ... params to indicate optional/default values"; QGC
    sends NaN yaw in param4) and is left to the task kind.  A legacy MISSION_ITEM carries x, y as floats, so only
    it can bring infinities; MISSION_ITEM_INT brings NaN as INT32_MAX."""
    for code, name, v in ((INVALID_PARAM5_X, "x", item.x), (INVALID_PARAM6_Y, "y", item.y)):
        if not math.isfinite(v):
            return code, f"item {item.seq}: {name} {v!r}: expected a finite number (a task needs a position)"
    checks = [(INVALID_PARAM1 + i, f"param{i + 1}", v) for i, v in enumerate(item.params[:4])]
    for code, name, v in checks + [(INVALID_PARAM7, "z", item.z)]:
        if math.isinf(v):
            return code, f"item {item.seq}: {name} {v!r}: expected a finite number (or NaN: the default)"
    return None


def param_result(reason: str) -> int:
    """MAV_MISSION_INVALID_PARAM1..4 for a task kind's refusal that starts with the param it names ("param2 (value):
    ..."), else MAV_MISSION_INVALID_PARAM1."""
    m = re.match(r"param([1-4])\b", reason)
    return INVALID_PARAM1 + (int(m.group(1)) - 1 if m else 0)


ADDED_REPORT = "mission: {new} task(s) added, {known} already known"
_ADDED = re.compile(r"mission: (\d+) task\(s\) added, (\d+) already known(, .*)?")   # then a note, if any


def added_report(new: int, known: int) -> str:
    """The STATUSTEXT a robot sends when it has taken an upload: how many of its items were new tasks (the robot may
    add a note after a comma, e.g. that it skipped a home item)."""
    return ADDED_REPORT.format(new=new, known=known)


def parse_added_report(text: str) -> tuple[int, int] | None:
    """(new, already known) from a robot's :func:`added_report` line, or None if ``text`` is not one."""
    m = _ADDED.fullmatch(text.strip())
    return (int(m.group(1)), int(m.group(2))) if m else None


class Reply(NamedTuple):
    """A message for the transport to send, and the requester (``source`` key) it goes to."""
    msg: Any
    dest: Any


@dataclass(frozen=True)
class MissionEvent:
    """Something the daemon may report (e.g. as STATUSTEXT).

    ``kind``: "accepted" (a new mission is in place; ``plan_id`` set), "refused" (an upload or clear ended
    with error ``result``; the old mission is kept; ``reason`` is one line), "cleared", or "cancelled"
    (an upload ended without a mission: the GCS went silent or sent an error MISSION_ACK).
    """
    kind: str
    mission_type: int
    source: Any
    count: int = 0
    result: int = ACCEPTED
    plan_id: int | None = None
    reason: str = ""


@dataclass
class _Transfer:
    source: Any
    sysid: int           # the requester's MAVLink address, for target_system/component of replies
    compid: int
    mission_type: int


@dataclass
class _Upload(_Transfer):
    count: int = 0
    items: list = field(default_factory=list)
    deadline: float = 0.0
    retries: int = 0
    requested_at: float = -math.inf
    home: bool = False            # item 0 was a home line: skipped


@dataclass
class _Download(_Transfer):
    items: list = field(default_factory=list)
    last_heard: float = 0.0


# what MissionServer.handle does with each message: stats[outcome] += 1, exactly one outcome per message
HANDLED = "handled"
DROPS = ("bad_data", "ignored", "not_for_us", "other_source", "denied", "out_of_sequence",
         "wrong_mission_type", "stray", "bad_seq", "unsupported_type", "errors")


class MissionServer:
    """Vehicle side of the mission protocol for one robot (one transfer at a time).

    ``handle(msg, now, source)`` and ``tick(now)`` return :class:`Reply` s; ``source`` is any hashable key
    for the requester (the daemon passes the UDP address) and is where each reply goes.  ``stats`` counts
    every message handled: ``received``, then exactly one of ``handled`` or a :data:`DROPS` reason.
    ``events`` collects :class:`MissionEvent` s; drain it with :meth:`pop_events`.

    Callbacks: ``validate(items) -> (MAV_MISSION_RESULT, reason) | None``; ``on_upload(items) -> plan id``
    (after a validated upload of count > 0); ``on_clear(mission_type)`` (MISSION, or ALL for
    MISSION_CLEAR_ALL(ALL)); ``items(MISSION)`` and ``plan_id(MISSION)`` for downloads.  A callback that
    raises is answered with MAV_MISSION_ERROR and the mission stays as it was.
    """

    def __init__(self, mav, system_id: int, *, on_upload: Callable[[list], int],
                 on_clear: Callable[[int], None], items: Callable[[int], list],
                 plan_id: Callable[[int], int] = lambda mission_type: 0,
                 validate: Callable[[list], tuple[int, str] | None] = lambda items: None,
                 component_id: int = 1, max_items: int = MAX_ITEMS):
        self.mav = mav
        self.system_id = int(system_id)
        self.component_id = int(component_id)
        self.max_items = int(max_items)
        self._validate, self._on_upload, self._on_clear = validate, on_upload, on_clear
        self._items, self._plan_id = items, plan_id
        self.stats: Counter = Counter()
        self.events: list[MissionEvent] = []
        self.log = get_logger("comms.mission", self.system_id)
        self._xfer: _Upload | _Download | None = None
        self._last_upload: tuple | None = None   # (source, mission_type, count, final ack) to repeat it
        self.home_skipped = False                 # the last upload's item 0 was a home line (is_home_item)

    # ------------------------------------------------------------------ public
    @property
    def busy(self) -> bool:
        return self._xfer is not None

    def pop_events(self) -> list[MissionEvent]:
        out, self.events = self.events, []
        return out

    def handle(self, msg, now: float, source) -> list[Reply]:
        """Answer one decoded message from ``source``.  Never raises; counts what it drops."""
        self.stats["received"] += 1
        try:
            self._expire_download(now)
            outcome, replies = self._dispatch(msg, now, source)
        except Exception as e:               # a field that will not convert, a value that will not encode
            self.log.debug("dropped %s from %s: %r", _kind(msg), source, e)
            outcome, replies = "errors", []
        self.stats[outcome] += 1
        return replies

    def tick(self, now: float) -> list[Reply]:
        """Re-request an overdue item; cancel an upload after MAX_RETRIES; release an idle download."""
        self._expire_download(now)
        x = self._xfer
        if not isinstance(x, _Upload) or now < x.deadline:
            return []
        x.retries += 1
        seq = len(x.items)
        if x.retries > MAX_RETRIES:
            self._xfer = None
            reason = f"upload cancelled: no item {seq} of {x.count} after {MAX_RETRIES} retries"
            self._event("cancelled", x, result=CANCELLED, reason=reason)
            return [self._ack(x, CANCELLED)]
        return [self._request(x, now)]

    # ------------------------------------------------------------------ dispatch
    def _dispatch(self, msg, now: float, source) -> tuple[str, list[Reply]]:
        kind = _kind(msg)
        handler = self._HANDLERS.get(kind)
        if handler is None:
            return ("bad_data" if kind == "BAD_DATA" else "ignored"), []
        if int(msg.target_system) not in (0, self.system_id) or \
                int(msg.target_component) not in (0, self.component_id):
            return "not_for_us", []
        return handler(self, msg, now, source)

    def _start(self, msg, source) -> tuple[str, list[Reply]] | None:
        """Common entry of COUNT / REQUEST_LIST / CLEAR_ALL: deny a second requester, drop our own
        unfinished transfer (the GCS restarted), refuse unknown mission types."""
        x = self._xfer
        if x is not None and x.source != source:
            self.log.info("%s from %s denied: busy with %s", _kind(msg), source, x.source)
            return "denied", [self._reply_to(msg, source, DENIED)]
        self._xfer = None
        mt = int(msg.mission_type)
        if mt not in (MISSION, FENCE, RALLY) and not (mt == ALL and _kind(msg) == "MISSION_CLEAR_ALL"):
            return "unsupported_type", [self._reply_to(msg, source, UNSUPPORTED)]
        return None

    def _on_count(self, msg, now: float, source):
        early = self._start(msg, source)
        if early:
            return early
        x = _Upload(source, msg.get_srcSystem(), msg.get_srcComponent(), int(msg.mission_type),
                    count=int(msg.count), deadline=now)
        if x.count == 0:
            return HANDLED, [self._clear(x)]
        if x.mission_type != MISSION:
            return HANDLED, [self._refuse(x, UNSUPPORTED, "this vehicle keeps no fence or rally points")]
        if x.count > self.max_items:
            return HANDLED, [self._refuse(x, NO_SPACE, f"{x.count} items; this vehicle takes at most "
                                                        f"{self.max_items}")]
        self._xfer = x
        self._last_upload = None
        return HANDLED, [self._request(x, now)]

    def _on_clear_all(self, msg, now: float, source):
        early = self._start(msg, source)
        if early:
            return early
        x = _Transfer(source, msg.get_srcSystem(), msg.get_srcComponent(), int(msg.mission_type))
        return HANDLED, [self._clear(x)]

    def _on_request_list(self, msg, now: float, source):
        early = self._start(msg, source)
        if early:
            return early
        x = _Download(source, msg.get_srcSystem(), msg.get_srcComponent(), int(msg.mission_type),
                      last_heard=now)
        plan = 0
        if x.mission_type == MISSION:
            try:
                x.items = [replace(it, seq=i, mission_type=MISSION)
                           for i, it in enumerate(self._items(MISSION))]
                plan = int(self._plan_id(MISSION))
            except Exception as e:
                self.log.error("items callback failed: %r", e)
                return HANDLED, [self._ack(x, ERROR)]
        self._xfer = x
        reply = self.mav.mission_count_encode(x.sysid, x.compid, len(x.items), x.mission_type)
        _set_opaque(reply, plan)
        return HANDLED, [Reply(reply, source)]

    def _on_request(self, msg, now: float, source):
        x = self._xfer
        if not isinstance(x, _Download) or x.source != source:
            return ("other_source" if x is not None and x.source != source else "stray"), []
        if int(msg.mission_type) != x.mission_type:
            return "wrong_mission_type", []
        x.last_heard = now
        seq = int(msg.seq)
        if seq >= len(x.items):
            self._xfer = None
            return "bad_seq", [self._ack(x, INVALID_SEQUENCE)]
        item = x.items[seq].to_mavlink_int(self.mav, x.sysid, x.compid)
        return HANDLED, [Reply(item, source)]

    def _on_item(self, msg, now: float, source):
        x = self._xfer
        if not isinstance(x, _Upload) or x.source != source:
            if x is not None and x.source != source:
                return "other_source", []
            last = self._last_upload        # the GCS repeats the final item: our ACK was lost
            if last and last[:3] == (source, int(msg.mission_type), int(msg.seq) + 1):
                return "stray", [Reply(last[3], source)]
            return "stray", []
        if int(msg.mission_type) != x.mission_type:
            return "wrong_mission_type", []
        if int(msg.seq) != len(x.items):
            replies = [self._request(x, now)] if now - x.requested_at >= REREQUEST_GAP else []
            return "out_of_sequence", replies
        x.items.append(MissionItem.from_mavlink(msg))
        x.home = x.home or is_home_item(msg)
        x.retries = 0
        if len(x.items) < x.count:
            return HANDLED, [self._request(x, now)]
        self._xfer = None
        reply = self._finish_upload(x)
        self._last_upload = (source, x.mission_type, x.count, reply.msg)
        return HANDLED, [reply]

    def _on_ack(self, msg, now: float, source):
        x = self._xfer
        if x is None or x.source != source:
            return ("other_source" if x is not None else "stray"), []
        if int(msg.mission_type) != x.mission_type:
            return "wrong_mission_type", []
        self._xfer = None
        if isinstance(x, _Upload):
            code = int(msg.type)
            self._event("cancelled", x, result=code,
                        reason=f"upload cancelled by the ground station ({result_name(code)})")
        return HANDLED, []

    _HANDLERS = {
        "MISSION_COUNT": _on_count, "MISSION_CLEAR_ALL": _on_clear_all,
        "MISSION_REQUEST_LIST": _on_request_list, "MISSION_REQUEST_INT": _on_request,
        "MISSION_REQUEST": _on_request, "MISSION_ITEM_INT": _on_item, "MISSION_ITEM": _on_item,
        "MISSION_ACK": _on_ack,
    }

    # ------------------------------------------------------------------ outcomes
    def _finish_upload(self, x: _Upload) -> Reply:
        items = list(x.items)
        self.home_skipped = x.home
        if x.home:
            self.log.info("mission item 0 from %s is a home line (current, NAV_WAYPOINT, global frame): skipped",
                          x.source)
            items = [replace(it, seq=it.seq - 1) for it in items[1:]]
        try:
            verdict = self._validate(items)
            if verdict is not None:
                code, reason = verdict
                return self._refuse(x, int(code) or ERROR, str(reason))
            plan = int(self._on_upload(items))
        except Exception as e:
            self.log.error("mission callback failed: %r", e)
            return self._refuse(x, ERROR, f"internal error: {type(e).__name__}")
        self.log.info("mission of %d items accepted from %s (plan %d)", x.count, x.source, plan)
        self._event("accepted", x, plan_id=plan)
        reply = self._ack(x, ACCEPTED)
        _set_opaque(reply.msg, plan)
        return reply

    def _clear(self, x: _Transfer) -> Reply:
        if x.mission_type in (MISSION, ALL):
            try:
                self._on_clear(x.mission_type)
            except Exception as e:
                self.log.error("clear callback failed: %r", e)
                return self._refuse(x, ERROR, f"clear failed: internal error: {type(e).__name__}")
            self.log.info("mission cleared by %s", x.source)
            self._event("cleared", x)
        return self._ack(x, ACCEPTED)

    def _refuse(self, x: _Transfer, code: int, reason: str) -> Reply:
        self.log.info("mission from %s refused (%s): %s", x.source, result_name(code), reason)
        self._event("refused", x, result=code, reason=reason)
        return self._ack(x, code)

    def _event(self, kind: str, x: _Transfer, **kw) -> None:
        self.events.append(MissionEvent(kind, x.mission_type, x.source, getattr(x, "count", 0), **kw))

    # ------------------------------------------------------------------ messages
    def _ack(self, x: _Transfer, code: int) -> Reply:
        return Reply(self.mav.mission_ack_encode(x.sysid, x.compid, code, x.mission_type), x.source)

    def _reply_to(self, msg, source, code: int) -> Reply:
        return self._ack(_Transfer(source, msg.get_srcSystem(), msg.get_srcComponent(),
                                   int(msg.mission_type)), code)

    def _request(self, x: _Upload, now: float) -> Reply:
        x.deadline = now + DEFAULT_TIMEOUT
        x.requested_at = now
        msg = self.mav.mission_request_int_encode(x.sysid, x.compid, len(x.items), x.mission_type)
        return Reply(msg, x.source)

    def _expire_download(self, now: float) -> None:
        x = self._xfer
        if isinstance(x, _Download) and now - x.last_heard >= IDLE_TIMEOUT:
            self.log.debug("download by %s released after %.1f s of silence", x.source, IDLE_TIMEOUT)
            self._xfer = None


def _kind(msg) -> str:
    try:
        return str(msg.get_type())
    except Exception:
        return "BAD_DATA"


def _set_opaque(msg, plan_id: int) -> None:
    """Put the plan id in ``opaque_id`` when the dialect's message has that field (newer common.xml)."""
    if "opaque_id" in getattr(msg, "fieldnames", ()):
        msg.opaque_id = int(plan_id) & 0xFFFFFFFF


class MissionClient:
    """Ground-station side of the mission protocol (one operation at a time), with QGC's timings.

    ``start_upload`` / ``start_download`` / ``start_clear`` return the first messages to send; feed every
    message from the vehicle to :meth:`handle` and call :meth:`tick` often; both return what to send.
    The retry clock starts at ``now`` if given to ``start_*``, else at the first ``tick``/``handle``.
    When :attr:`done`: :attr:`result` is the MAV_MISSION_RESULT (or :data:`TIMEOUT`), :attr:`error` one
    line or None, :attr:`items` the downloaded items, :attr:`plan_id` the vehicle's opaque id if sent.
    ``stats`` counts the messages dropped (other systems, wrong mission type, out of sequence, ...).

    Retries: MISSION_COUNT, MISSION_REQUEST_LIST and MISSION_CLEAR_ALL are resent every ``timeout``
    (1.5 s); a downloaded item is re-requested every ``item_timeout`` (0.25 s); during an upload a silent
    vehicle gets the item it last requested again every 1.5 s (a duplicate it drops, answering with a
    request for what it needs; a repeated last item gets the final MISSION_ACK again).  After
    ``retries`` resends the operation ends with :data:`TIMEOUT`; a timed-out download sends
    MISSION_ACK MAV_MISSION_OPERATION_CANCELLED so the vehicle is free for others at once.
    """

    def __init__(self, mav, target_system: int, target_component: int = 1, *,
                 timeout: float = DEFAULT_TIMEOUT, item_timeout: float = ITEM_TIMEOUT,
                 retries: int = MAX_RETRIES):
        self.mav = mav
        self.target_system = int(target_system)
        self.target_component = int(target_component)
        self.timeout, self.item_timeout, self.retries = float(timeout), float(item_timeout), int(retries)
        self.stats: Counter = Counter()
        self._reset(None, MISSION)
        self.done = True

    # ------------------------------------------------------------------ starting
    def _reset(self, op: str | None, mission_type: int) -> None:
        self.op, self.mission_type = op, int(mission_type)
        self.done, self.result, self.error, self.plan_id = False, None, None, None
        self.items: list[MissionItem] = []
        self._upload: list[MissionItem] = []
        self._phase = "start"
        self._count = 0
        self._last_sent = -1           # upload: highest item seq sent
        self._sent_seq = 0             # upload: the item last requested (resent on timeout)
        self._retry = 0
        self._deadline: float | None = None
        self._pending_wait = self.timeout
        self._requested_at = -math.inf

    def _arm(self, now: float | None, wait: float) -> None:
        self._pending_wait = wait
        self._deadline = None if now is None else now + wait

    def start_upload(self, items, mission_type: int = MISSION, *, now: float | None = None) -> list:
        items = [replace(it, seq=i, mission_type=int(mission_type)) for i, it in enumerate(items)]
        for it in items:
            why = it.check_encodable()
            if why:
                raise ValueError(f"mission item {it.seq}: {why}")
        self._reset("upload", mission_type)
        self._upload, self._count, self._phase = items, len(items), "count"
        self._arm(now, self.timeout)
        return [self._count_msg()]

    def start_download(self, mission_type: int = MISSION, *, now: float | None = None) -> list:
        self._reset("download", mission_type)
        self._phase = "count"
        self._arm(now, self.timeout)
        return [self._request_list()]

    def start_clear(self, mission_type: int = MISSION, *, now: float | None = None) -> list:
        self._reset("clear", mission_type)
        self._phase = "ack"
        self._arm(now, self.timeout)
        return [self._clear_all()]

    # ------------------------------------------------------------------ input
    def handle(self, msg, now: float) -> list:
        """One decoded message from the vehicle link; returns what to send.  Never raises."""
        try:
            if self._deadline is None and not self.done:
                self._arm(now, self._pending_wait)
            outcome, out = self._dispatch(msg, now)
        except Exception:
            outcome, out = "errors", []
        if outcome:
            self.stats[outcome] += 1
        return out

    def _dispatch(self, msg, now: float) -> tuple[str | None, list]:
        kind = _kind(msg)
        if not kind.startswith("MISSION_"):
            return None, []
        if msg.get_srcSystem() != self.target_system:
            return "other_system", []
        if int(getattr(msg, "target_system", 0)) not in (0, self.mav.srcSystem):
            return "not_for_us", []
        if self.done:
            return "after_done", []
        if int(getattr(msg, "mission_type", MISSION)) != self.mission_type:
            return "wrong_mission_type", []
        if kind == "MISSION_ACK":
            return self._on_ack(msg)
        if self.op == "upload" and kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            return self._on_request(msg, now)
        if self.op == "download" and kind == "MISSION_COUNT":
            return self._on_count(msg, now)
        if self.op == "download" and kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            return self._on_item(msg, now)
        return "unexpected", []

    def _on_ack(self, msg) -> tuple[str | None, list]:
        code = int(msg.type)
        if code == ACCEPTED:
            if self.op != "upload" and self.op != "clear":
                return "unexpected", []
            if self.op == "upload" and self._last_sent < self._count - 1:
                return "early_ack", []     # stale ACK of an earlier transfer
            self.plan_id = getattr(msg, "opaque_id", None)
            self._finish(ACCEPTED)
            return None, []
        self._finish(code, f"system {self.target_system} refused the mission {self.op}: {result_name(code)}")
        return None, []

    def _on_request(self, msg, now: float) -> tuple[str | None, list]:
        seq = int(msg.seq)
        if seq >= self._count:
            return "bad_seq", []
        self._phase = "items"
        self._last_sent = max(self._last_sent, seq)
        self._sent_seq = seq
        self._retry = 0
        self._arm(now, self.timeout)
        return None, [self._item_msg(seq)]

    def _on_count(self, msg, now: float) -> tuple[str | None, list]:
        if self._phase != "count":
            return "duplicate", []
        self._count = int(msg.count)
        self.plan_id = getattr(msg, "opaque_id", None)
        self._retry = 0
        if self._count == 0:
            self._finish(ACCEPTED)
            return None, [self._ack_msg(ACCEPTED)]
        self._phase = "items"
        return None, [self._request_item(now)]

    def _on_item(self, msg, now: float) -> tuple[str | None, list]:
        if self._phase != "items":
            return "unexpected", []
        if int(msg.seq) != len(self.items):
            out = [self._request_item(now)] if now - self._requested_at >= REREQUEST_GAP else []
            return "out_of_sequence", out
        self.items.append(MissionItem.from_mavlink(msg))
        self._retry = 0
        if len(self.items) < self._count:
            return None, [self._request_item(now)]
        self._finish(ACCEPTED)
        return None, [self._ack_msg(ACCEPTED)]

    # ------------------------------------------------------------------ time
    def tick(self, now: float) -> list:
        """Resend whatever is overdue; give up after ``retries`` resends."""
        if self.done:
            return []
        if self._deadline is None:
            self._arm(now, self._pending_wait)
            return []
        if now < self._deadline:
            return []
        self._retry += 1
        if self._retry > self.retries:
            return self._give_up()
        if self.op == "upload":
            self._arm(now, self.timeout)
            return [self._count_msg() if self._phase == "count" else self._item_msg(self._sent_seq)]
        if self.op == "download":
            if self._phase == "count":
                self._arm(now, self.timeout)
                return [self._request_list()]
            return [self._request_item(now)]
        self._arm(now, self.timeout)
        return [self._clear_all()]

    def _give_up(self) -> list:
        waited = {"count": "MISSION_COUNT" if self.op == "upload" else "MISSION_REQUEST_LIST",
                  "items": "the mission items", "ack": "MISSION_CLEAR_ALL"}[self._phase]
        if self.op == "upload" and self._phase == "items":
            why = f"stopped requesting items after item {self._last_sent} of {self._count}"
        elif self.op == "download" and self._phase == "items":
            why = f"sent no item {len(self.items)} of {self._count}"
        else:
            why = f"did not answer {waited}"
        self._finish(TIMEOUT, f"system {self.target_system} {why} ({self.retries} retries)")
        if self.op == "download" and self._phase == "items":
            return [self._ack_msg(CANCELLED)]     # frees the vehicle for other ground stations
        return []

    def _finish(self, result: int, error: str | None = None) -> None:
        self.done, self.result, self.error, self._deadline = True, result, error, None

    # ------------------------------------------------------------------ messages
    def _count_msg(self):
        return self.mav.mission_count_encode(self.target_system, self.target_component, self._count,
                                             self.mission_type)

    def _item_msg(self, seq: int):
        # no item marked current: the vehicle would take a current global waypoint at seq 0 for a home line
        return self._upload[seq].to_mavlink_int(self.mav, self.target_system, self.target_component)

    def _request_list(self):
        return self.mav.mission_request_list_encode(self.target_system, self.target_component,
                                                    self.mission_type)

    def _request_item(self, now: float):
        self._requested_at = now
        self._arm(now, self.item_timeout)
        return self.mav.mission_request_int_encode(self.target_system, self.target_component,
                                                   len(self.items), self.mission_type)

    def _clear_all(self):
        return self.mav.mission_clear_all_encode(self.target_system, self.target_component,
                                                 self.mission_type)

    def _ack_msg(self, code: int):
        return self.mav.mission_ack_encode(self.target_system, self.target_component, code,
                                           self.mission_type)
