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

Exit codes: 0 done; 1 the robot did not answer, or refused (one line on stderr); 2 bad input (file,
key, address).  :func:`upload` and :func:`download` are the same for code (e.g. the SITL launcher).
"""
from __future__ import annotations

import argparse
import socket
import sys
import time
from pathlib import Path

from runtime.comms import dialect, mission_files
from runtime.comms.gcs import GCS_SYSTEM, HEARTBEAT_PERIOD, gcs_heartbeat, ground_mav
from runtime.comms.link import MISSION_LINK, load_key, parse_address, signing_timestamp, was_signed
from runtime.comms.mission import ACCEPTED, MISSION, TIMEOUT, MissionClient, MissionItem
from runtime.errors import InputError
from runtime.log import get_logger

POLL = 0.02                               # s: socket wait per loop turn
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

    def close(self) -> None:
        self.sock.close()


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


def _session(target: str, system: int | None, timeout: float, key: bytes | None, start) -> MissionClient:
    deadline = time.monotonic() + float(timeout)
    link = UdpTarget(target, key)
    try:
        sysid = system if system is not None else find_system(link, deadline)
        client = MissionClient(link.mav, sysid)
        return run(link, client, start(client, time.monotonic()), deadline)
    finally:
        link.close()


def upload(target: str, items, *, system: int | None = None, timeout: float = 10.0,
           key: bytes | None = None, mission_type: int = MISSION) -> MissionClient:
    """Upload ``items`` to the robot at ``target``; the finished client (``plan_id``), or NoAnswer."""
    items = list(items)
    return _session(target, system, timeout, key,
                    lambda c, now: c.start_upload(items, mission_type, now=now))


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
    up.add_argument("file", metavar="FILE", help="mission file (WPL 110 or .plan)")
    down = ms.add_parser("download", help="print the robot's mission, or save it as WPL 110")
    down.add_argument("target", metavar="TARGET", help="the robot's MAVLink UDP address HOST:PORT")
    down.add_argument("file", metavar="FILE", nargs="?", help="write the items here (QGC WPL 110)")
    st = ms.add_parser("status", help="the fleet's tasks as the robot knows them: holders and state")
    st.add_argument("target", metavar="TARGET", help="the robot's MAVLink UDP address HOST:PORT")
    for q in (up, down, st):
        q.add_argument("--system", type=int, default=None,
                       help="target system id (default: from the robot's first HEARTBEAT)")
        q.add_argument("--timeout", type=float, default=10.0, help="give up after S seconds (default 10)")
        q.add_argument("--key", metavar="FILE", default=None,
                       help="MAVLink 2 signing key file (64 hex characters)")
    up.set_defaults(func=_upload_main)
    down.set_defaults(func=_download_main)
    st.set_defaults(func=_status_main)


def _common(args) -> dict:
    if args.system is not None and not 1 <= args.system <= 255:
        raise InputError(f"--system {args.system}: expected a system id 1..255")
    if not args.timeout > 0:
        raise InputError(f"--timeout {args.timeout}: expected a positive number of seconds")
    key = load_key(args.key) if args.key else None
    return {"system": args.system, "timeout": args.timeout, "key": key}


def _upload_main(args) -> int:
    mf = mission_files.read_mission(args.file)
    kw = _common(args)
    try:
        client = upload(args.target, mf.items, **kw)
    except NoAnswer as e:
        print(f"mrta: {e}", file=sys.stderr)
        return 1
    print(f"uploaded {len(mf.items)} items to system {client.target_system} at {args.target}")
    return 0


def _download_main(args) -> int:
    kw = _common(args)
    if args.file and Path(args.file).is_dir():
        raise InputError(f"{args.file}: expected a file name, got a directory")
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
