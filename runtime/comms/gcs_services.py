"""What a stock ground station asks a vehicle, answered: the robot side of QGC's and MAVProxy's connect.

Sans-IO: :meth:`GcsServices.handle` takes one decoded pymavlink message, the injected time ``now`` and
an opaque, hashable ``source`` (whatever the caller needs to reply, e.g. a UDP address) and returns the
``(message, source)`` pairs to send; :meth:`GcsServices.tick` returns the parameter list still due.
Messages are built with the caller's ``mav`` (``mav.*_encode``), not packed: the caller packs, signs
and sends them.  Nothing here raises out of ``handle``/``tick``; what is dropped is counted in ``stats``.

QGroundControl's connect (src/Vehicle/InitialConnectStateMachine): REQUEST_MESSAGE AUTOPILOT_VERSION ->
[PROTOCOL_VERSION, older QGC] -> AVAILABLE_MODES -> component information -> PARAM_REQUEST_LIST ->
mission -> fence -> rally, each step moving on when answered or after its timeouts and retries.  The
mission protocol (all MISSION_* messages, fence and rally included) is :mod:`runtime.comms.mission`'s;
this module serves the rest and ignores (counts) MISSION_* messages:

* COMMAND_LONG / COMMAND_INT: always a COMMAND_ACK to the sender.  MAV_CMD_REQUEST_MESSAGE(148) and
  MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: ACCEPTED, then AUTOPILOT_VERSION.  REQUEST_MESSAGE of any
  other id: the ``message_providers`` registry (ACCEPTED then the message; TEMPORARILY_REJECTED if the
  provider has nothing yet), else UNSUPPORTED, which ends QGC's wait at once (PROTOCOL_VERSION and
  AVAILABLE_MODES are not in the project dialect, which includes common.xml only).  The deprecated
  MAV_CMD_GET_HOME_POSITION, which MAVProxy sends every 2 s, is served like REQUEST_MESSAGE
  HOME_POSITION (the same provider).  Other commands: the ``commands`` registry
  (:meth:`register_command`), else UNSUPPORTED.  A bad param1 -> DENIED, a handler that raises -> FAILED.
  A command broadcast to system 0 (e.g. a fleet-wide disarm) is served by every robot.
* AUTOPILOT_VERSION capabilities: MAVLINK2 | MISSION_INT | COMMAND_INT | PARAM_ENCODE_C_CAST (see
  :mod:`runtime.comms.params` for the encoding); no FENCE/RALLY bits, so QGC skips those two steps.
  flight_sw_version = the package version (major, minor, patch, FIRMWARE_VERSION_TYPE bytes), uid =
  system id, vendor/product 0; ``version`` overrides any field by name.
* PARAM_REQUEST_LIST: every PARAM_VALUE, at most ``params_per_tick`` per :meth:`tick` (a new request
  from the same source restarts its list; no parameters -> nothing, as the protocol says).
  PARAM_REQUEST_READ: the PARAM_VALUE by index (>= 0) or name; an unknown one gets no PARAM_VALUE but
  a STATUSTEXT, as the parameter protocol recommends.  PARAM_SET: applied if acceptable, and always a
  PARAM_VALUE with the value now in force (plus a STATUSTEXT saying why when refused).
* FILE_TRANSFER_PROTOCOL: answered by :mod:`runtime.comms.ftp_nack` (MAVProxy's parameter download
  over FTP gets FileNotFound and falls back to PARAM_REQUEST_LIST at once).

Addressing: a message is served when its target_system is this robot, or 0 (broadcast) for the
requests MAVLink lets a GCS broadcast (:data:`BROADCAST_OK`: parameter reads and commands); its
target_component must be 0 or ours.  PARAM_SET and FTP sessions need our id.
"""
from __future__ import annotations

import math
import re
import sys
from dataclasses import dataclass, fields
from typing import Callable

from runtime.comms import ftp_nack
from runtime.comms.params import ENCODING_CAPABILITY, ParamTable
from runtime.errors import InputError
from runtime.log import get_logger

BROADCAST_OK = frozenset({"PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "COMMAND_LONG", "COMMAND_INT"})
MAX_LIST_STREAMS = 8              # sources with a parameter list in flight; the oldest is dropped beyond
STATUSTEXT_LEN = 50
PACKAGE = "mrta-runtime"


@dataclass
class GcsServiceStats:
    received: int = 0             # messages given to handle()
    served: int = 0               # messages for us that were answered (or deliberately not, e.g. 0 params)
    not_for_us: int = 0           # target_system / target_component not this robot (or broadcast not allowed)
    ignored: int = 0              # message types this module does not serve (MISSION_* included)
    errors: int = 0               # messages whose fields could not be used (logged at debug)
    command_acks: int = 0
    commands_unsupported: int = 0
    param_values: int = 0         # PARAM_VALUEs returned
    param_sets_refused: int = 0
    param_unknown: int = 0        # reads or sets of a parameter that does not exist
    ftp_replies: int = 0

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def _dialect_of(mav):
    """The generated module whose ``MAVLink`` class ``mav`` is (or derives from)."""
    for cls in type(mav).__mro__:
        if cls.__name__ == "MAVLink" and hasattr(sys.modules.get(cls.__module__), "MAV_RESULT_ACCEPTED"):
            return sys.modules[cls.__module__]
    from runtime.comms import dialect
    return dialect.load()


def sw_version(text: str | None, mod) -> int:
    """``"1.2.3"``-style version -> AUTOPILOT_VERSION.flight_sw_version (major, minor, patch, type bytes).

    The type byte is FIRMWARE_VERSION_TYPE: OFFICIAL without a suffix (or ``.postN``), ALPHA, BETA or
    RC for a PEP 440 pre-release, DEV for ``.devN`` or anything else.  0 (unknown) if ``text`` is not
    a version."""
    m = re.match(r"\s*(\d+)\.(\d+)(?:\.(\d+))?(.*)", text or "")
    if not m:
        return 0
    major, minor, patch = (min(int(x or 0), 255) for x in m.group(1, 2, 3))
    rest = m.group(4).lower()
    pre = re.match(r"[._-]?(alpha|a|beta|b|rc|c|preview|pre)\d*", rest)
    if "dev" in rest:
        kind = mod.FIRMWARE_VERSION_TYPE_DEV
    elif not rest or re.fullmatch(r"[._-]?post\d*", rest):
        kind = mod.FIRMWARE_VERSION_TYPE_OFFICIAL
    elif pre and pre.group(1) in ("alpha", "a"):
        kind = mod.FIRMWARE_VERSION_TYPE_ALPHA
    elif pre and pre.group(1) in ("beta", "b"):
        kind = mod.FIRMWARE_VERSION_TYPE_BETA
    elif pre:
        kind = mod.FIRMWARE_VERSION_TYPE_RC
    else:
        kind = mod.FIRMWARE_VERSION_TYPE_DEV      # e.g. a +local build
    return (major << 24) | (minor << 16) | (patch << 8) | kind


def package_version() -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(PACKAGE)
    except PackageNotFoundError:
        return None


def _text(v) -> str:
    """A MAVLink char[] field as str, cut at the first NUL."""
    if isinstance(v, (bytes, bytearray)):
        v = bytes(v).decode("ascii", errors="replace")
    return str(v).split("\0", 1)[0]


def _whole(v) -> int | None:
    """A float command parameter holding an integer (e.g. a message id), or None."""
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    if not math.isfinite(f) or f != int(f) or not 0 <= f < 2 ** 32:
        return None
    return int(f)


class GcsServices:
    """Answers a ground station's requests for one robot (MAVLink system ``system_id``, component
    ``component_id``) from its parameter table and command registry."""

    def __init__(self, mav, system_id: int, component_id: int, params: ParamTable, version: dict | None = None,
                 *, params_per_tick: int = 10):
        if not isinstance(params, ParamTable):
            raise InputError(f"gcs services: expected a ParamTable, got {type(params).__name__}")
        if not 1 <= int(params_per_tick) <= 1000:
            raise InputError(f"gcs services: params_per_tick expected 1..1000, got {params_per_tick!r}")
        self.mav = mav
        self.m = _dialect_of(mav)
        self.system_id = int(system_id)
        self.component_id = int(component_id)
        self.params = params
        self.params_per_tick = int(params_per_tick)
        self.commands: dict[int, Callable] = {}
        self.message_providers: dict[int, Callable] = {}
        self.stats = GcsServiceStats()
        self.log = get_logger("comms.gcs_services", self.system_id)
        self._version = self._version_fields(version)
        self._streams: dict = {}              # source -> next param_index of its PARAM_REQUEST_LIST
        m = self.m
        self._builtin_commands = {m.MAV_CMD_REQUEST_MESSAGE: self._request_message,
                                  m.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: self._request_capabilities,
                                  m.MAV_CMD_GET_HOME_POSITION: self._get_home_position}
        self._results = frozenset(k for k, e in m.enums["MAV_RESULT"].items() if not e.name.endswith("ENUM_END"))
        self._handlers = {
            "COMMAND_LONG": self._command, "COMMAND_INT": self._command,
            "PARAM_REQUEST_LIST": self._param_list, "PARAM_REQUEST_READ": self._param_read,
            "PARAM_SET": self._param_set,
            "FILE_TRANSFER_PROTOCOL": self._ftp,
        }

    # ------------------------------------------------------------------ registries
    def register_command(self, cmd_id: int, handler: Callable) -> None:
        """Serve MAV_CMD ``cmd_id``: ``handler(msg, now) -> MAV_RESULT`` or ``(MAV_RESULT, [messages])`` (msg is
        the COMMAND_LONG or COMMAND_INT; the messages follow the COMMAND_ACK).  A handler that raises is acked
        FAILED."""
        if int(cmd_id) in self._builtin_commands:
            raise ValueError(f"MAV_CMD {cmd_id} is served by GcsServices itself")
        self.commands[int(cmd_id)] = handler

    def register_message(self, msg_id: int, provider: Callable) -> None:
        """Answer MAV_CMD_REQUEST_MESSAGE for ``msg_id`` with ``provider()`` (a message built with ``mav``,
        or None when there is nothing to send yet)."""
        if int(msg_id) == self.m.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            raise ValueError("AUTOPILOT_VERSION is served by GcsServices itself")
        self.message_providers[int(msg_id)] = provider

    # ------------------------------------------------------------------ entry points
    def handle(self, msg, now: float, source) -> list[tuple]:
        """The replies to one decoded message, each paired with ``source``."""
        self.stats.received += 1
        try:
            kind = msg.get_type()
            handler = self._handlers.get(kind)
            if handler is None:
                self.stats.ignored += 1
                return []
            if not self._for_us(msg, kind):
                self.stats.not_for_us += 1
                return []
            out = handler(msg, now, source)
        except Exception as e:        # garbage field values from a valid frame: count, never raise
            self.stats.errors += 1
            self.log.debug("dropped %s: %r", getattr(msg, "get_type", lambda: "?")(), e)
            return []
        self.stats.served += 1
        return [(reply, source) for reply in out]

    def tick(self, now: float) -> list[tuple]:
        """PARAM_VALUEs of lists in flight, at most ``params_per_tick`` in all."""
        out: list[tuple] = []
        n = len(self.params)
        for source in list(self._streams):
            i = self._streams.pop(source)
            while i < n and len(out) < self.params_per_tick:
                out.append((self._param_value(i), source))
                i += 1
            if i < n:
                self._streams[source] = i
                break
        return out

    def autopilot_version(self):
        """The AUTOPILOT_VERSION message this robot answers with."""
        return self.mav.autopilot_version_encode(**self._version)

    # ------------------------------------------------------------------ addressing
    def _for_us(self, msg, kind: str) -> bool:
        ts, tc = int(msg.target_system), int(msg.target_component)
        if ts != self.system_id and not (ts == 0 and kind in BROADCAST_OK):
            return False
        return tc in (0, self.component_id)

    # ------------------------------------------------------------------ commands
    def _command(self, msg, now: float, source) -> list:
        cmd = int(msg.command)
        result, extra = self._run_command(cmd, msg, now)
        self.stats.command_acks += 1
        if result == self.m.MAV_RESULT_UNSUPPORTED:
            self.stats.commands_unsupported += 1
        ack = self.mav.command_ack_encode(cmd, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        return [ack] + extra

    def _run_command(self, cmd: int, msg, now: float) -> tuple[int, list]:
        m = self.m
        builtin = self._builtin_commands.get(cmd)
        if builtin is not None:
            return builtin(msg)
        handler = self.commands.get(cmd)
        if handler is None:
            return m.MAV_RESULT_UNSUPPORTED, []
        try:
            result = handler(msg, now)
        except Exception as e:
            self.log.warning("MAV_CMD %d handler failed: %r", cmd, e)
            return m.MAV_RESULT_FAILED, []
        extra = []
        if isinstance(result, tuple) and len(result) == 2 and isinstance(result[1], list):
            result, extra = result                   # a MAV_RESULT and the messages that follow the ack
        if isinstance(result, bool) or not isinstance(result, int) or result not in self._results:
            self.log.warning("MAV_CMD %d handler returned %r, not a MAV_RESULT", cmd, result)
            return m.MAV_RESULT_FAILED, []
        return result, extra

    def _request_capabilities(self, msg) -> tuple[int, list]:
        return self.m.MAV_RESULT_ACCEPTED, [self.autopilot_version()]

    def _get_home_position(self, msg) -> tuple[int, list]:
        return self._provide(self.m.MAVLINK_MSG_ID_HOME_POSITION)

    def _request_message(self, msg) -> tuple[int, list]:
        m = self.m
        msg_id = _whole(msg.param1)
        if msg_id is None:
            return m.MAV_RESULT_DENIED, []
        if msg_id == m.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return m.MAV_RESULT_ACCEPTED, [self.autopilot_version()]
        return self._provide(msg_id)

    def _provide(self, msg_id: int) -> tuple[int, list]:
        m = self.m
        provider = self.message_providers.get(msg_id)
        if provider is None:
            return m.MAV_RESULT_UNSUPPORTED, []
        try:
            reply = provider()
        except Exception as e:
            self.log.warning("provider of message %d failed: %r", msg_id, e)
            return m.MAV_RESULT_FAILED, []
        if reply is None:
            return m.MAV_RESULT_TEMPORARILY_REJECTED, []
        return m.MAV_RESULT_ACCEPTED, [reply]

    def _version_fields(self, version: dict | None) -> dict:
        m = self.m
        out = dict(
            capabilities=(m.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | m.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                          | m.MAV_PROTOCOL_CAPABILITY_COMMAND_INT | ENCODING_CAPABILITY),
            flight_sw_version=sw_version(package_version(), m), middleware_sw_version=0, os_sw_version=0,
            board_version=0, flight_custom_version=[0] * 8, middleware_custom_version=[0] * 8,
            os_custom_version=[0] * 8, vendor_id=0, product_id=0, uid=self.system_id, uid2=[0] * 18)
        for key, value in (version or {}).items():
            if key not in out:
                raise InputError(f"AUTOPILOT_VERSION: unknown field {key!r} (expected one of {', '.join(out)})")
            out[key] = value
        return out

    # ------------------------------------------------------------------ parameters
    def _param_value(self, i: int):
        p = self.params.by_index(i)
        self.stats.param_values += 1
        return self.mav.param_value_encode(p.name.encode("ascii"), self.params.value(p), self.params.wire_type(p),
                                           len(self.params), i)

    def _status(self, severity: int, text: str):
        return self.mav.statustext_encode(severity, text.encode("ascii", errors="replace")[:STATUSTEXT_LEN])

    def _param_list(self, msg, now: float, source) -> list:
        if len(self.params):
            self._streams.pop(source, None)
            self._streams[source] = 0
            while len(self._streams) > MAX_LIST_STREAMS:
                del self._streams[next(iter(self._streams))]
        return []

    def _param_read(self, msg, now: float, source) -> list:
        index = int(msg.param_index)
        if index >= 0:
            if self.params.by_index(index) is not None:
                return [self._param_value(index)]
            what = f"index {index}"
        else:
            name = _text(msg.param_id)
            i = self.params.index(name)
            if i is not None:
                return [self._param_value(i)]
            what = repr(name)
        self.stats.param_unknown += 1
        return [self._status(self.m.MAV_SEVERITY_INFO, f"no parameter {what}")]

    def _param_set(self, msg, now: float, source) -> list:
        name = _text(msg.param_id)
        i = self.params.index(name)
        if i is None:
            self.stats.param_unknown += 1
            return [self._status(self.m.MAV_SEVERITY_WARNING, f"set refused: no parameter {name!r}")]
        ok, value, reason = self.params.set(name, msg.param_value)
        out = [self._param_value(i)]
        if ok:
            self.log.info("parameter %s set to %g by %d/%d", self.params.by_index(i).name, value,
                          msg.get_srcSystem(), msg.get_srcComponent())
        else:
            self.stats.param_sets_refused += 1
            self.log.warning("parameter set refused: %s", reason)
            out.append(self._status(self.m.MAV_SEVERITY_WARNING, reason))
        return out

    # ------------------------------------------------------------------ FTP (no files)
    def _ftp(self, msg, now: float, source) -> list:
        payload = ftp_nack.reply_payload(msg.payload)
        if payload is None:
            return []
        self.stats.ftp_replies += 1
        return [self.mav.file_transfer_protocol_encode(0, msg.get_srcSystem(), msg.get_srcComponent(), payload)]
