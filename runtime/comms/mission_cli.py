"""`mrta mission upload TARGET FILE`, `mrta mission download TARGET [FILE]` and `mrta mission status TARGET`: a
ground station's mission transfer with one robot over UDP, driven by
:class:`~runtime.comms.mission.MissionClient`, and the fleet's tasks as that robot knows them (each with its
holders and state, from the robot's replicated task table: MRTA_TABLE_REQUEST, answered with one
MRTA_TASK_RECORD per task).

TARGET is the robot's MAVLink UDP address ``HOST:PORT`` (``udp:`` or ``udpout:`` in front is accepted),
e.g. the ``mavlink_udp`` of a SITL manifest.  We send from an ephemeral UDP port as system 255, component
190 (MAVProxy's ids) and take answers only from TARGET.  Like a stock GCS we send a MAV_TYPE_GCS HEARTBEAT
once a second, so a robot that answers whoever talks to it learns our address; without ``--system`` the
target system id is the first non-GCS HEARTBEAT heard from TARGET.  With ``--key`` every frame is signed
(MAVLink 2, link id 0) and only frames signed with the same key are accepted.

Missions are not wiped by accident: an upload of no items (a WPL file holding only its header, a .plan with no
items) would withdraw the fleet's open tasks, so ``upload`` refuses a file without items unless ``--clear`` is
given, which sends MISSION_CLEAR_ALL instead (FILE may then be left out).  After an accepted upload the tool says
how many of the items the fleet took as new tasks, from the robot's report (its STATUSTEXT ``mission: N task(s)
added, M already known``, :func:`~runtime.comms.mission.added_report`), which arrives with the MISSION_ACK.

Limits, checked before the robot is asked anything: a mission file of at most 1 MiB and
:data:`~runtime.comms.mission.MAX_ITEMS` items (:mod:`~runtime.comms.mission_files`); ``--timeout`` in
[:data:`MIN_TIMEOUT`, :data:`MAX_TIMEOUT`] s; ``download FILE`` a file that can be written (its folder exists and
takes new files, FILE is not a folder).

Exit codes: 0 done; 1 the robot did not answer, or refused (one line on stderr); 2 bad input (file,
key, address).  :func:`upload`, :func:`clear` and :func:`download` are the same for code (e.g. the SITL launcher).
"""
from __future__ import annotations

import argparse
import socket
import sys
import time
from collections import deque
from dataclasses import dataclass

from runtime import argcheck
from runtime.comms import dialect, mission_files
from runtime.comms.gcs import GCS_SYSTEM, HEARTBEAT_PERIOD, gcs_heartbeat, ground_mav
from runtime.comms.link import MISSION_LINK, load_key, parse_address, signing_timestamp, was_signed
from runtime.comms.mission import (ACCEPTED, MISSION, TIMEOUT, MissionClient, MissionItem,
                                   parse_added_report)
from runtime.errors import InputError
from runtime.log import get_logger

POLL = 0.02                               # s: socket wait per loop turn
MIN_TIMEOUT, MAX_TIMEOUT = 0.1, 3600.0    # s: --timeout (one exchange with a robot; an hour at most)
REPORT_WAIT = 1.0                         # s: after MISSION_ACK, for the robot's report of the tasks added
MAX_TEXTS = 64                            # STATUSTEXT lines kept (a robot also announces awards and arrivals)
log = get_logger("comms.mission_cli")


class NoAnswer(RuntimeError):
    """The robot did not answer or refused; ``str()`` is one line.  The CLI exits 1."""


class UdpTarget:
    """One UDP socket talking to one robot: send pymavlink messages, receive those that come from it."""

    def __init__(self, target: str, key: bytes | None = None):
        self.target = target
        text = target.split(":", 1)[1] if target.startswith(("udp:", "udpout:")) else target
        host, port = parse_address(text, "TARGET")
        try:
            family, _, _, _, self.addr = socket.getaddrinfo(host, port, 0, socket.SOCK_DGRAM)[0]
        except socket.gaierror as e:
            raise InputError(f"TARGET: cannot resolve {target!r} ({e.strerror})") from None
        self.mod, self.mav = ground_mav(key, link_id=MISSION_LINK)
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        self.sock.bind(("::", 0) if family == socket.AF_INET6 else ("0.0.0.0", 0))
        self._next_heartbeat = -float("inf")
        self.keyless = key is None
        self.signed_peer = False                 # the robot signs its frames: a signed fleet
        self.texts: deque[str] = deque(maxlen=MAX_TEXTS)   # the robot's last STATUSTEXT lines (single frames)

    def send(self, msg) -> None:
        if self.mav.signing.sign_outgoing:
            s = self.mav.signing
            s.timestamp = max(s.timestamp, signing_timestamp(time.time()))
        try:
            self.sock.sendto(msg.pack(self.mav), self.addr)
        except OSError as e:
            log.debug("send to %s failed: %s", self.target, e)
        self.mav.seq = (self.mav.seq + 1) % 256

    def heartbeat(self, now: float) -> None:
        """Our GCS HEARTBEAT, once per HEARTBEAT_PERIOD."""
        if now >= self._next_heartbeat:
            self._next_heartbeat = now + HEARTBEAT_PERIOD
            self.send(gcs_heartbeat(self.mod, self.mav))

    def recv(self, wait: float) -> list:
        """Messages from TARGET that arrive within ``wait`` seconds (good frames only)."""
        self.sock.settimeout(max(wait, 1e-4))
        out = []
        while True:
            try:
                data, addr = self.sock.recvfrom(65535)
            except (socket.timeout, BlockingIOError):
                return out
            except OSError as e:             # ICMP port unreachable and the like: nobody there yet
                log.debug("recv: %s", e)
                return out
            self.sock.settimeout(0)
            if addr[:2] != self.addr[:2]:
                continue
            try:
                msgs = self.mav.parse_buffer(data) or []
            except Exception as e:
                log.debug("unparsable datagram: %r", e)
                continue
            self.signed_peer |= was_signed(data)
            out += [m for m in msgs if m.get_type() != "BAD_DATA"]
            self.texts += [_text(m) for m in msgs if m.get_type() == "STATUSTEXT"]

    def close(self) -> None:
        self.sock.close()


def _text(m) -> str:
    text = m.text if isinstance(m.text, str) else bytes(m.text).decode(errors="replace")
    return text.split("\0", 1)[0]


def find_system(link: UdpTarget, deadline: float) -> int:
    """System id of the first non-GCS HEARTBEAT from the target, heartbeating while we wait."""
    while time.monotonic() < deadline:
        link.heartbeat(time.monotonic())
        for m in link.recv(POLL):
            if m.get_type() == "HEARTBEAT" and m.type != link.mod.MAV_TYPE_GCS:
                return m.get_srcSystem()
    raise NoAnswer(f"{link.target}: no HEARTBEAT from a robot (is it running? --system skips the wait)")


def _hint(link: UdpTarget) -> str:
    """Why a robot may ignore us: it signs its frames and we have no key."""
    return "; the robot signs its MAVLink (a signed fleet): pass --key FILE" if link.keyless and link.signed_peer else ""


def run(link: UdpTarget, client: MissionClient, first: list, deadline: float) -> MissionClient:
    """Drive ``client`` over ``link`` until it is done; NoAnswer unless it ends with MAV_MISSION_ACCEPTED."""
    out, started = first, time.monotonic()
    while True:
        for m in out:
            link.send(m)
        if client.done:
            break
        now = time.monotonic()
        if now >= deadline:
            raise NoAnswer(f"{link.target}: mission {client.op} unfinished after {now - started:.1f} s "
                           f"(system {client.target_system}; --timeout reached){_hint(link)}")
        link.heartbeat(now)
        out = []
        for m in link.recv(POLL):
            out += client.handle(m, time.monotonic())
        out += client.tick(time.monotonic())
    if client.result != ACCEPTED:
        raise NoAnswer(f"{link.target}: {client.error}{_hint(link) if client.result == TIMEOUT else ''}")
    return client


def status(target: str, *, system: int | None = None, timeout: float = 10.0, key: bytes | None = None):
    """The fleet's tasks as the robot at ``target`` knows them: its TaskRecords (with holders), by id.  Waits
    for the robot's RobotState (the size of its table) and asks until every record is in."""
    from runtime.comms import codec
    from runtime.messages import RobotState, TableRequest, TaskRecord

    deadline = time.monotonic() + float(timeout)
    link = UdpTarget(target, key)
    try:
        sysid = system if system is not None else find_system(link, deadline)
        records: dict[int, TaskRecord] = {}
        known, asked = None, -float("inf")
        while time.monotonic() < deadline:
            now = time.monotonic()
            link.heartbeat(now)
            if now - asked > HEARTBEAT_PERIOD:
                asked = now
                link.send(codec.to_mavlink(TableRequest(GCS_SYSTEM, sysid, 0), link.mod))
            for m in link.recv(POLL):
                try:
                    msg = codec.from_mavlink(m) if codec.is_agent(m) else None
                except codec.InvalidMessage:
                    continue
                if isinstance(msg, TaskRecord):
                    records[msg.task] = msg
                elif isinstance(msg, RobotState) and msg.sender == sysid:
                    known = msg.known
            if known is not None and len(records) >= known:
                return [records[t] for t in sorted(records)]
        raise NoAnswer(f"{target}: no task table from system {sysid} within {timeout:g} s{_hint(link)} "
                       f"(got {len(records)} of {'?' if known is None else known} tasks)")
    finally:
        link.close()


def _session(target: str, system: int | None, timeout: float, key: bytes | None, start, after=None):
    """Run one transfer; ``after(link, client, deadline)`` (if given) then reads what else the robot sent."""
    deadline = time.monotonic() + float(timeout)
    link = UdpTarget(target, key)
    try:
        sysid = system if system is not None else find_system(link, deadline)
        link.texts.clear()                   # from here on, lines about this transfer
        client = MissionClient(link.mav, sysid)
        run(link, client, start(client, time.monotonic()), deadline)
        return client if after is None else after(link, client, deadline)
    finally:
        link.close()


@dataclass(frozen=True)
class Uploaded:
    """An accepted upload: the finished client (``plan_id``, ``target_system``) and what the robot reported of it,
    ``new`` tasks the fleet added and ``known`` items it already had as tasks (both None: no report heard)."""
    client: MissionClient
    items: int
    new: int | None
    known: int | None


def _added(link: UdpTarget, count: int) -> tuple[int, int] | None:
    """The robot's report of an upload of ``count`` items (its numbers add up to ``count``), if it came."""
    for text in reversed(link.texts):
        report = parse_added_report(text)
        if report is not None and sum(report) == count:
            return report
    return None


def upload(target: str, items, *, system: int | None = None, timeout: float = 10.0,
           key: bytes | None = None, mission_type: int = MISSION) -> Uploaded:
    """Upload ``items`` (at least one: an upload of none would withdraw the fleet's open tasks, see :func:`clear`)
    to the robot at ``target``; the result with the robot's report of the tasks added, or NoAnswer."""
    items = list(items)
    if not items:
        raise InputError("expected at least one mission item to upload (clear() withdraws the open tasks)")

    def report(link: UdpTarget, client: MissionClient, deadline: float) -> Uploaded:
        # the robot sends its report before the MISSION_ACK; wait a little if the datagrams were reordered
        until = min(deadline, time.monotonic() + REPORT_WAIT)
        while _added(link, len(items)) is None and time.monotonic() < until:
            link.heartbeat(time.monotonic())
            link.recv(POLL)
        new, known = _added(link, len(items)) or (None, None)
        return Uploaded(client, len(items), new, known)

    return _session(target, system, timeout, key,
                    lambda c, now: c.start_upload(items, mission_type, now=now), report)


def clear(target: str, *, system: int | None = None, timeout: float = 10.0, key: bytes | None = None,
          mission_type: int = MISSION) -> MissionClient:
    """MISSION_CLEAR_ALL to the robot at ``target`` (the fleet withdraws its open tasks); the client, or NoAnswer."""
    return _session(target, system, timeout, key, lambda c, now: c.start_clear(mission_type, now=now))


def download(target: str, *, system: int | None = None, timeout: float = 10.0,
             key: bytes | None = None, mission_type: int = MISSION) -> list[MissionItem]:
    """The robot's mission items, or NoAnswer."""
    client = _session(target, system, timeout, key, lambda c, now: c.start_download(mission_type, now=now))
    return client.items


# ---------------------------------------------------------------------------------------------- CLI

def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("mission", help="upload or download a robot's mission (MAVLink mission protocol)",
                       description="Talk to one robot's MAVLink UDP port the way a ground station does.")
    ms = p.add_subparsers(dest="mission_command", metavar="ACTION", required=True)
    up = ms.add_parser("upload", help="upload a QGC WPL 110 (.waypoints/.txt) or QGC .plan file")
    up.add_argument("target", metavar="TARGET", help="the robot's MAVLink UDP address HOST:PORT")
    up.add_argument("file", metavar="FILE", nargs="?",
                    help="mission file (WPL 110 or .plan, at most 1 MiB and %d items)" % mission_files.MAX_ITEMS)
    up.add_argument("--clear", action="store_true",
                    help="withdraw the fleet's open tasks (MISSION_CLEAR_ALL); FILE, if given, must hold no items")
    down = ms.add_parser("download", help="print the robot's mission, or save it as WPL 110")
    down.add_argument("target", metavar="TARGET", help="the robot's MAVLink UDP address HOST:PORT")
    down.add_argument("file", metavar="FILE", nargs="?", help="write the items here (QGC WPL 110)")
    st = ms.add_parser("status", help="the fleet's tasks as the robot knows them: holders and state")
    st.add_argument("target", metavar="TARGET", help="the robot's MAVLink UDP address HOST:PORT")
    for q in (up, down, st):
        q.add_argument("--system", type=int, default=None,
                       help="target system id (default: from the robot's first HEARTBEAT)")
        q.add_argument("--timeout", type=float, default=10.0,
                       help=f"give up after S seconds ({MIN_TIMEOUT:g}..{MAX_TIMEOUT:g}, default 10)")
        q.add_argument("--key", metavar="FILE", default=None,
                       help="MAVLink 2 signing key file (64 hex characters)")
    up.set_defaults(func=_upload_main)
    down.set_defaults(func=_download_main)
    st.set_defaults(func=_status_main)


def _common(args) -> dict:
    if args.system is not None and not 1 <= args.system <= 255:
        raise InputError(f"--system {args.system}: expected a system id 1..255")
    argcheck.number(args.timeout, "--timeout", MIN_TIMEOUT, MAX_TIMEOUT)
    key = load_key(args.key) if args.key else None
    return {"system": args.system, "timeout": args.timeout, "key": key}


def _upload_main(args) -> int:
    if args.file is None and not args.clear:
        raise InputError("upload: expected FILE, a mission file (or --clear to withdraw the fleet's open tasks)")
    items = mission_files.read_mission(args.file).items if args.file is not None else []
    if args.clear and items:
        raise InputError(f"{args.file}: --clear withdraws the fleet's open tasks and uploads nothing: expected a "
                         f"file with no items (or no FILE), got {len(items)}")
    if not args.clear and not items:
        raise InputError(f"{args.file}: expected at least one mission item, got none (an empty or cut mission "
                         "file; uploading no items withdraws the fleet's open tasks: pass --clear to do that)")
    kw = _common(args)
    try:
        if args.clear:
            client = clear(args.target, **kw)
            print(f"cleared: system {client.target_system} at {args.target} accepted MISSION_CLEAR_ALL "
                  "(the fleet withdraws its open tasks)")
            return 0
        up = upload(args.target, items, **kw)
    except NoAnswer as e:
        print(f"mrta: {e}", file=sys.stderr)
        return 1
    where = f"uploaded {up.items} items to system {up.client.target_system} at {args.target}"
    if up.new is None:
        print(f"{where}: accepted; the robot did not report how many were new tasks")
    else:
        print(f"{where}: {up.new} new tasks, {up.known} already known")
    return 0


def _download_main(args) -> int:
    kw = _common(args)
    argcheck.output_file(args.file, "FILE")
    try:
        items = download(args.target, **kw)
    except NoAnswer as e:
        print(f"mrta: {e}", file=sys.stderr)
        return 1
    if args.file:
        mission_files.write_wpl(items, args.file)
        print(f"wrote {len(items)} items to {args.file}")
    else:
        print(format_table(items, dialect.load()))
    return 0


def _status_main(args) -> int:
    from runtime import tasks as T
    from runtime.messages import STATE_NAMES

    kw = _common(args)
    try:
        records = status(args.target, **kw)
    except NoAnswer as e:
        print(f"mrta: {e}", file=sys.stderr)
        return 1
    rows = [("seq", "task", "kind", "position (m)", "state", "holders")]
    seq = 0
    for r in records:
        listed = STATE_NAMES[r.state] in ("open", "done")
        kind = T.kind_of_command(r.command)
        rows.append((str(seq) if listed else "-", f"{r.task >> 16}.{r.task & 0xFFFF}",
                     kind.KIND if kind else str(r.command), f"({r.x:6.2f}, {r.y:6.2f})", STATE_NAMES[r.state],
                     "+".join(f"R{h}" for h in r.holders) or "-"))
        seq += listed
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    print("\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows))
    print(f"{len(records)} task(s), {sum(r.state == 1 for r in records)} done")
    return 0


def format_table(items, mod) -> str:
    """The items as a fixed-width table; frames and commands by their MAVLink names."""
    def name(enum: str, value: int, prefix: str) -> str:
        entry = mod.enums.get(enum, {}).get(value)
        return entry.name.removeprefix(prefix) if entry is not None else str(value)

    rows = [("seq", "frame", "command", "param1", "param2", "param3", "param4", "x", "y", "z", "auto")]
    for it in items:
        rows.append((str(it.seq), name("MAV_FRAME", it.frame, "MAV_FRAME_"),
                     name("MAV_CMD", it.command, "MAV_CMD_"), *(f"{v:g}" for v in it.params[:4]),
                     f"{it.x:.7f}", f"{it.y:.7f}", f"{it.z:g}", str(int(it.autocontinue))))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows)
