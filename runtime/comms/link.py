"""MAVLink between robots (over a transport: UDP unicast by default) and to the ground station (UDP).

One non-blocking UDP socket per robot, bound to ``listen``, for ground stations, and for the peers too under the
default ``udp`` transport.  The link keeps framing, signing, replay windows, counters and the loss model; a
transport (:mod:`runtime.comms.transport`: ``udp``, or ``zenoh`` publishing each frame once through a router) only
moves bytes.  Agent messages are encoded once and sent to every peer address (UDP) or published once (Zenoh);
receivers keep those whose ``target_system`` is 0 or their own id.  Frames are
parsed with the generated pymavlink parser (robust mode), one datagram at a time: garbage, bad CRCs,
truncated frames and refused signatures are counted in :class:`LinkCounters`, never raised.

Ground stations: frames that are not ours (MISSION_*, PARAM_*, COMMAND_*, FILE_TRANSFER_PROTOCOL ...) and
not HEARTBEATs, and ours from a system id above 250 (no robot's: a ground station asking for the task
table), are queued in :attr:`MavlinkLink.gcs_inbox` with the UDP address they came from, for the
daemon's ground-station services, which answer with :meth:`MavlinkLink.send_to`.  Telemetry goes to the
configured ground station and to every address a GCS HEARTBEAT or request came from in the last
``GCS_TIMEOUT`` seconds (a ground station that is not the configured one sees the robot once it talks).

Liveness: :meth:`MavlinkLink.poll` sends a HEARTBEAT to every peer once per ``heartbeat_period`` and
records the HEARTBEATs it hears; :meth:`MavlinkLink.peers_lost` names peers silent for more than
``heartbeat_timeout`` (once per silence).

Loss injection (``peer_loss``, for tests and SITL): each datagram to each peer is left unsent with that
probability (a seeded draw per copy, counted in ``loss_injected``), as a lossy radio drops a broadcast for one
receiver and not another; ground-station traffic is not touched.  0 (the default) sends everything.  With
``loss_burst`` > 0 the losses come in bursts, as fading and interference bring them (a Gilbert-Elliott channel in
time, per peer): bad spells of a mean ``loss_burst`` s lose every copy, good spells between them lose none, both of
exponential length, the good ones long enough (``loss_burst (1 - peer_loss) / peer_loss`` on average) that the
share lost is still ``peer_loss``.

Signing (MAVLink 2, pymavlink's implementation): with a key, every frame sent is signed (timestamp in 10 us
units since 2015-01-01 UTC, never behind the wall clock).  Incoming frames must be signed with the same key, with
one exception: an *unsigned* HEARTBEAT whose type is MAV_TYPE_GCS is accepted, so a stock ground station without
the key can still be seen; it never counts as peer liveness.  Unsigned robot HEARTBEATs and any wrongly signed
frame are dropped and counted.  A refused frame cannot advance pymavlink's per-stream replay window (see
:func:`signing_guard`).

Ground stations that cannot sign (``unsigned_gcs``, the config's ``comms.unsigned_gcs``: networks in CIDR form): an
unsigned frame from an address in one of those networks is taken if it is ground-station traffic: a standard message
whose system id is no robot's of this fleet (``fleet``: the configured peers, and this robot; QGroundControl and
MAVProxy use 255, a MAVSDK app 245) from an address that is no peer's.  Anything else unsigned (a fleet robot's id,
a robot's own MRTA message, a peer's address) stays refused (``unsigned_dropped``) whatever the list says: peers
always sign.  Unsigned frames taken this
way are counted in ``unsigned_gcs_taken``.  The robot signs everything it sends either way.

Keys never come from the network: a SETUP_SIGNING (MAVProxy's ``signing setup``, a peer, anyone) is refused
whether it is signed with the fleet key or unsigned (``setup_signing_refused``; one with a wrong signature is
``bad_signature_dropped`` like any other), the key stays as it is, and the sender's address gets one STATUSTEXT
saying why (:data:`KEY_REFUSAL_TEXT`), at most once per ``KEY_REFUSAL_PERIOD`` seconds per address and to at most
``MAX_KEY_REFUSAL_SENDERS`` addresses per period, so it cannot be used to flood anyone (``setup_signing_replies``
counts them).  The key is set on the robot: ``comms.signing_key``, a file `mrta key` writes.

Link ids (the signature's ``link_id`` byte; pymavlink keeps one replay window per link id, system and
component): a frame's link id says where it was sent, so a signed frame cannot be replayed to another kind of
destination.

* ``PEER_LINK`` (0): a robot to its peers (agent messages to every robot, peer HEARTBEATs);
* ``PEER_DIRECT_LINK`` (4): a robot to one peer (agent messages with a ``dest``).  A stream of its own: a
  publish/subscribe transport delivers a robot's broadcast and addressed frames through two subscriptions, whose
  order between them is not kept (zenoh-python runs each subscriber's callback in a thread of its own), and one
  replay window for both refused the older as a replay (848 of 2,000 alternating frames through one router);
* ``GCS_LINK`` (1): a robot to ground stations (telemetry, HEARTBEAT, RobotState, STATUSTEXT, answers);
* ``OPERATOR_LINK`` (2): the SITL operator's ground station (:class:`runtime.comms.gcs.GroundStation`);
* ``MISSION_LINK`` (3): ``mrta mission``.  Stock ground stations choose their own (pymavlink counts from 0, a
  link per connection in the process).

A robot takes a frame from a robot system id (1..250) only if it is signed on a peer link id: a frame a robot
sent to a ground station and replayed to its peers is dropped and counted (``replayed_dropped``); so is a
peer frame replayed to :class:`~runtime.comms.gcs.GroundStation`, which takes robot frames on ``GCS_LINK``
only.  Frames from ground-station system ids (above 250) are taken on any link id.  Two ground stations that
sign with the same system id, component id and link id share one replay window: the one whose timestamps are
older has every frame dropped as a replay (``bad_signature_dropped``).  That happens to a stock station on 255/190
beside the SITL operator when pymavlink gave it link id 2 (its third connection in the process); the robot logs
one warning per such address, naming both stations (at most ``MAX_GCS_STREAMS`` of them).

Counters (:class:`LinkCounters`): every datagram read ends in exactly one outcome, ``received`` (it gave at
least one frame that was taken: an agent message for us, a HEARTBEAT, a ground-station request) or one drop
reason (:data:`DROP_REASONS`, the reason of its first refused frame or run of junk), so
``datagrams == received + sum of the drop counters`` at any time.  Datagrams the kernel dropped before we read
them (receive buffer full under a flood) are ``kernel_dropped`` (:mod:`runtime.comms.udp`).  The frame
counters (``agent_received``, ``heartbeats``, ``gcs_requests``, ``frames_dropped``) count frames: a datagram
may carry several.
"""
from __future__ import annotations

import hashlib
import ipaddress
import math
import os
import random
import socket
import time
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Callable, Iterable

from runtime.comms import codec, dialect, udp
from runtime.comms.networks import Networks
from runtime.comms.liveness import Silence
from runtime.errors import InputError
from runtime.log import get_logger

COMPONENT_ID = 1                       # MAV_COMP_ID_AUTOPILOT1
SIGNING_EPOCH = 1420070400             # 2015-01-01T00:00:00Z as a Unix time
MAX_DATAGRAMS_PER_POLL = 1024          # bounds one poll's work under a flood
MAX_ROBOT_ID = 250                     # system ids above are ground stations (QGC, MAVProxy use 255)
MAX_GCS_INBOX = 256                    # ground-station requests kept between two daemon cycles
GCS_TIMEOUT = 10.0                     # s a ground station that talked to us keeps getting telemetry
PEER_LINK, GCS_LINK, OPERATOR_LINK, MISSION_LINK, PEER_DIRECT_LINK = 0, 1, 2, 3, 4   # signing link ids (docstring)
PEER_LINKS = frozenset((PEER_LINK, PEER_DIRECT_LINK))
KERNEL_DROPS_PERIOD = 1.0              # s between reads of the kernel's drop count when no datagram brings it
KEY_REFUSAL_TEXT = "SETUP_SIGNING refused: key is set on the robot"      # one STATUSTEXT (<= 50 characters)
KEY_REFUSAL_PERIOD = 10.0              # s between two refusal STATUSTEXTs to one address
MAX_KEY_REFUSAL_SENDERS = 64           # addresses told within one period; beyond, refusals go unanswered
MAX_GCS_STREAMS = 64                   # ground-station signing streams whose address is kept (to name a clash)
MAV_SEVERITY_WARNING = 4
_IFLAG_SIGNED = 0x01


def signing_timestamp(unix_time: float) -> int:
    """MAVLink 2 signing timestamp: 10 us units since 2015-01-01 00:00 UTC."""
    return max(0, int((unix_time - SIGNING_EPOCH) * 100_000))


def new_key(path: str | Path) -> Path:
    """Write a fresh 32-byte signing key to ``path`` (:func:`write_key`)."""
    import secrets

    return write_key(path, secrets.token_bytes(32))


def passphrase_key(passphrase: str, what: str = "passphrase") -> bytes:
    """The 32-byte signing key a ground station derives from ``passphrase``: SHA-256 of its bytes, as MAVProxy's
    ``signing key P`` and ``signing setup P`` do (MAVProxy/modules/mavproxy_signing.py, ``passphrase_to_key``:
    ``hashlib.sha256(P.encode('ascii'))``).  Refused (InputError naming ``what``) unless MAVProxy can take it as
    typed: not empty, ASCII only (MAVProxy cannot encode anything else), and no whitespace, quotes or ``;``
    (its command line splits on those, so ``signing key P`` would hash something else)."""
    expected = (f"{what}: expected printable ASCII without spaces, quotes or ';' "
                "(as MAVProxy's `signing key P` takes it)")
    if not passphrase:
        raise InputError(f"{what}: expected a passphrase, got an empty one")
    bad = next((c for c in passphrase if not (c.isascii() and c.isprintable()) or c in " \"';"), None)
    if bad is not None:
        raise InputError(f"{expected}, got {bad!r}")
    import hashlib

    return hashlib.sha256(passphrase.encode("ascii")).digest()


def write_key(path: str | Path, key: bytes) -> Path:
    """Write the 32-byte signing ``key`` (64 hex characters and a newline) to ``path``: created with mode 0600 under
    a temporary name and renamed into place, so the key is never readable by others, not even for a moment, and a
    reader never sees half a key.  Refuses to replace an existing file."""
    if len(key) != 32:
        raise InputError(f"signing key: expected 32 bytes, got {len(key)}")
    path = Path(path)
    if path.exists():
        raise InputError(f"{path}: a file is already there (a signing key is never overwritten)")
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w") as fh:
            fh.write(key.hex() + "\n")
        os.replace(tmp, path)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise InputError(f"{path}: cannot write a signing key ({e.strerror})") from None
    return path


def load_key(path: str | Path, what: str | None = None) -> bytes:
    """The 32-byte signing key in ``path`` (64 hex characters; surrounding whitespace ignored).  Errors name the
    file, after ``what`` if given (the option that named it, e.g. ``--key``)."""
    expected = "expected 64 hex characters (a 32-byte MAVLink signing key)"
    name = f"{what} {path}" if what else str(path)
    try:
        text = Path(path).read_text(encoding="ascii")
    except FileNotFoundError:
        raise InputError(f"{name}: signing key file not found") from None
    except UnicodeDecodeError:
        raise InputError(f"{name}: {expected}, got non-ASCII data") from None
    except OSError as e:
        raise InputError(f"{name}: cannot read signing key ({e.strerror})") from None
    s = text.strip()
    if len(s) != 64:
        raise InputError(f"{name}: {expected}, got {len(s)} characters")
    try:
        return bytes.fromhex(s)
    except ValueError:
        raise InputError(f"{name}: {expected}, got a non-hex character") from None


def parse_address(text: str, what: str, *, allow_port_zero: bool = False) -> tuple[str, int]:
    """``"host:port"`` (IPv6 as ``"[::1]:port"``) -> ``(host, port)``; InputError naming ``what``."""
    expected = f"{what}: expected host:port"
    if not isinstance(text, str) or ":" not in text:
        raise InputError(f"{expected}, got {text!r}")
    host, _, port_s = text.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    try:
        port = int(port_s)
    except ValueError:
        raise InputError(f"{expected} with a numeric port, got {text!r}") from None
    lo = 0 if allow_port_zero else 1
    if not host or not lo <= port <= 65535:
        raise InputError(f"{expected} with port {lo}..65535, got {text!r}")
    return host, port


def _resolve(text: str, what: str, family: int | None = None, *, listen: bool = False):
    host, port = parse_address(text, what, allow_port_zero=listen)
    try:
        infos = socket.getaddrinfo(host, port, family or 0, socket.SOCK_DGRAM)
    except socket.gaierror as e:
        raise InputError(f"{what}: cannot resolve {text!r} ({e.strerror})") from None
    fam, _, _, _, sockaddr = infos[0]
    if not listen:
        ip = ipaddress.ip_address(sockaddr[0].split("%")[0])
        if ip.is_multicast or ip.is_unspecified or str(ip) == "255.255.255.255":
            raise InputError(f"{what}: expected a unicast address, got {text!r}")
    return fam, sockaddr



DROP_REASONS = ("parse_errors", "bad_crc", "unsigned_dropped", "bad_signature_dropped", "replayed_dropped",
                "unknown", "invalid", "not_for_us", "ignored", "gcs_overflow", "setup_signing_refused")


@dataclass
class LinkCounters:
    datagrams: int = 0              # UDP datagrams read
    # the outcome of each datagram: received, or the first reason one of its frames was refused (DROP_REASONS)
    received: int = 0               # datagrams that gave at least one frame taken
    parse_errors: int = 0           # nothing but junk bytes, bad lengths or flags, a frame cut short
    bad_crc: int = 0                # a frame with a wrong checksum
    unsigned_dropped: int = 0       # an unsigned frame, refused because signing is on
    bad_signature_dropped: int = 0  # a signed frame whose signature is wrong or whose timestamp is old (a replay)
    replayed_dropped: int = 0       # a robot's frame signed for another kind of destination (see Link ids)
    unknown: int = 0                # a message id the dialect does not define
    invalid: int = 0                # one of our messages with values the protocol does not allow
    not_for_us: int = 0             # an agent message for another robot, or claiming our own id
    ignored: int = 0                # a valid frame of a message the link has no use for
    gcs_overflow: int = 0           # a ground-station request dropped: the inbox was full
    setup_signing_refused: int = 0  # a SETUP_SIGNING: the key is never changed from the network
    kernel_dropped: int = 0         # datagrams the kernel dropped before we read them (receive buffer full)
    queue_dropped: int = 0          # frames a publish/subscribe transport (zenoh) dropped unread (its queue full)
    # frames (a datagram may carry several)
    agent_received: int = 0         # agent messages returned by poll
    heartbeats: int = 0             # HEARTBEATs taken (peers and ground stations)
    gcs_requests: int = 0           # ground-station frames queued for the services
    unsigned_gcs_taken: int = 0     # of which unsigned, taken from a network in ``unsigned_gcs``
    frames_dropped: int = 0         # frames and runs of junk refused, in any datagram
    # sending
    sent: int = 0                   # datagrams sent (one per message and destination)
    peer_sent: int = 0              # of which to peers (agent messages, peer HEARTBEATs)
    send_errors: int = 0
    encode_errors: int = 0          # agent messages whose values do not fit the wire types
    loss_injected: int = 0          # datagrams to peers not sent: ``peer_loss`` (a lossy radio, for testing)
    setup_signing_replies: int = 0  # STATUSTEXTs telling a SETUP_SIGNING's sender why it was refused

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @property
    def dropped(self) -> int:
        """Datagrams read and dropped, whatever the reason: ``datagrams == received + dropped``."""
        return sum(getattr(self, k) for k in DROP_REASONS)


def parse_datagram(mav, module, data: bytes) -> tuple[list, list[str]]:
    """The frames of one datagram (pymavlink's robust parser, its state reset before and after, so nothing
    carries over between datagrams), and the refusals met outside frames: the parser raising, a frame cut
    short at the end."""
    mav.buf, mav.buf_index = bytearray(), 0
    mav.expected_length = module.HEADER_LEN_V1 + 2
    refused = []
    try:
        msgs = mav.parse_buffer(data) or []
    except Exception:                     # robust parsing should not raise; count it if it does
        refused.append("parse_errors")
        msgs = []
    if mav.buf_len() > 0:
        refused.append("parse_errors")
    mav.buf, mav.buf_index = bytearray(), 0
    mav.expected_length = module.HEADER_LEN_V1 + 2
    return msgs, refused


def count_datagram(c: LinkCounters, taken: bool, refused: list[str]) -> None:
    """One datagram's outcome into ``c``: ``received`` if a frame of it was taken, else the first reason in
    ``refused`` (junk, if nothing at all was parsed); every refused frame also counts in ``frames_dropped``."""
    c.datagrams += 1
    c.frames_dropped += len(refused)
    if taken:
        c.received += 1
    else:
        why = refused[0] if refused else "parse_errors"
        setattr(c, why, getattr(c, why) + 1)


def refusal(bad) -> str:
    """The counter for a pymavlink BAD_DATA message: its frame's signature (unsigned or bad), CRC, or junk."""
    reason = str(getattr(bad, "reason", ""))
    if "signature" in reason:
        return "bad_signature_dropped" if was_signed(getattr(bad, "data", b"")) else "unsigned_dropped"
    if "CRC" in reason:
        return "bad_crc"
    return "parse_errors"


_guarded: dict[type, type] = {}


def signing_guard(base: type) -> type:
    """Subclass of a generated ``MAVLink`` class whose refused signatures leave the replay window alone.

    pymavlink records a stream's timestamp before it checks the signature, so a forged frame with a
    large timestamp would make every later genuine frame of that stream look like a replay.
    """
    cls = _guarded.get(base)
    if cls is None:
        class _SigningGuard(base):
            def check_signature(self, msgbuf, srcSystem, srcComponent):
                key = (msgbuf[-13], srcSystem, srcComponent)
                before = self.signing.stream_timestamps.get(key)
                ok = super().check_signature(msgbuf, srcSystem, srcComponent)
                if not ok:
                    if before is None:
                        self.signing.stream_timestamps.pop(key, None)
                    else:
                        self.signing.stream_timestamps[key] = before
                return ok

        cls = _guarded[base] = _SigningGuard
    return cls


class MavlinkLink:
    """UDP MAVLink endpoint of one robot: agent messages to peers, common messages to the GCS."""

    def __init__(self, robot_id: int, listen: str, peers: Iterable[str], gcs: str | None = None,
                 signing_key: bytes | None = None, heartbeat_timeout: float = 3.0, *,
                 heartbeat_period: float = 1.0, wallclock: Callable[[], float] = time.time,
                 peer_loss: float = 0.0, loss_burst: float = 0.0, loss_seed: int | None = None,
                 unsigned_gcs: Iterable[str] = (), fleet: Iterable[int] = (), sock: socket.socket | None = None,
                 transport=None):
        """``sock``: a UDP socket already bound to ``listen`` (held for this robot since its port was checked, as
        the SITL launcher does, or inherited: ``mrta daemon --listen-fd``) instead of binding one here.
        ``transport``: what carries peer frames (:mod:`runtime.comms.transport`; None: UDP on ``sock``/``listen``)."""
        if not 1 <= int(robot_id) <= 250:
            raise InputError(f"robot id: expected 1..250, got {robot_id!r}")
        if signing_key is not None and len(signing_key) != 32:
            raise InputError(f"signing key: expected 32 bytes, got {len(signing_key)}")
        self.robot_id = int(robot_id)
        self.heartbeat_timeout = float(heartbeat_timeout)
        self.heartbeat_period = float(heartbeat_period)
        if not 0.0 <= float(peer_loss) <= 1.0:
            raise InputError(f"comms.peer_loss: expected a share of datagrams 0..1, got {peer_loss!r}")
        if not (math.isfinite(loss_burst) and loss_burst >= 0.0):
            raise InputError(f"comms.loss_burst: expected a mean burst length >= 0 s, got {loss_burst!r}")
        self.peer_loss = float(peer_loss)
        self.loss_burst = float(loss_burst)
        self._loss_rng = random.Random(self.robot_id if loss_seed is None else loss_seed)
        self._spells: dict[tuple, tuple[bool, float]] = {}      # peer -> (in a bad spell, until when)
        self.counters = LinkCounters()
        self.log = get_logger("comms.link", self.robot_id)
        self._wallclock = wallclock

        self.module = dialect.load()
        codec.check(self.module)
        self._hb_id = self.module.MAVLINK_MSG_ID_HEARTBEAT
        self._unsigned_ok = frozenset({self._hb_id, self.module.MAVLINK_MSG_ID_SETUP_SIGNING})
        self._gcs_type = self.module.MAV_TYPE_GCS
        self.mav = signing_guard(self.module.MAVLink)(None, srcSystem=self.robot_id,
                                                        srcComponent=COMPONENT_ID)
        self.mav.robust_parsing = True
        self.signing = signing_key is not None
        try:
            self.unsigned_gcs = Networks(unsigned_gcs)
        except ValueError as e:
            raise InputError(f"comms.unsigned_gcs: expected a network in CIDR form ({e})") from None
        self._unsigned_net = False        # the datagram being parsed comes from a network in unsigned_gcs
        if self.unsigned_gcs and self.signing:
            self.log.warning("accepting unsigned ground-station frames from %s (comms.unsigned_gcs; peers must "
                             "sign)", self.unsigned_gcs)
        elif self.unsigned_gcs:
            self.log.info("comms.unsigned_gcs (%s) changes nothing: signing is off, every frame is taken",
                          self.unsigned_gcs)
        self._fleet = frozenset(int(r) for r in fleet) | {self.robot_id}    # system ids that must always sign
        if self.signing:
            s = self.mav.signing
            s.secret_key = bytes(signing_key)
            s.sign_outgoing = True
            s.link_id = PEER_LINK
            s.timestamp = signing_timestamp(self._wallclock())
            s.allow_unsigned_callback = self._allow_unsigned

        family, self._listen_addr = _resolve(listen, "comms.listen", listen=True)
        self._peers = [_resolve(p, f"comms.peers[{i}]", family)[1] for i, p in enumerate(peers)]
        self._gcs = _resolve(gcs, "comms.gcs", family)[1] if gcs else None
        # ground stations are always on UDP at the robot; peers too unless another transport is given
        self.udp = udp.UdpTransport(family, self._listen_addr, () if transport is not None else self._peers,
                                    sock=sock, listen=listen)
        self.transport = self.udp if transport is None else transport
        self._next_kernel_check = -math.inf
        self._left: set[int] = set()          # peers the transport said left, not reported lost yet

        # what the peer HEARTBEAT says; GcsTelemetry keeps these current
        self.base_mode = self.module.MAV_MODE_FLAG_AUTO_ENABLED
        self.custom_mode = 0
        self.system_status = self.module.MAV_STATE_STANDBY

        self._next_heartbeat: float | None = None
        self._beats = Silence(None, self.heartbeat_timeout)     # peers' HEARTBEATs: the one liveness rule
        self._now = float("-inf")
        self.tap = None          # tap(direction "tx" | "rx", datagram, address, now): a recording's raw frames
        self.gcs_last_heartbeat: float | None = None
        self.gcs_inbox: list[tuple[object, tuple]] = []       # (pymavlink message, source address)
        self._gcs_seen: dict[tuple, float] = {}               # ground-station addresses -> last heard
        self._key_refusals: dict[tuple, float] = {}           # addresses told KEY_REFUSAL_TEXT -> when
        self._gcs_streams: dict[tuple, tuple] = {}            # (link id, system, component) -> the address it came from
        self._clashes: set[tuple] = set()                     # (stream, address) pairs already warned of

    # ------------------------------------------------------------------ addresses
    @property
    def address(self) -> tuple[str, int]:
        """The bound (host, port); the port is the real one when ``listen`` asked for port 0."""
        return self.udp.address

    @property
    def sock(self) -> socket.socket:
        """The UDP socket (ground stations; peers too over the ``udp`` transport)."""
        return self.udp.sock

    @property
    def peers(self) -> list[tuple]:
        return list(self._peers)

    # ------------------------------------------------------------------ sending
    def _stamp(self, link_id: int) -> None:
        if self.signing:
            s = self.mav.signing
            s.timestamp = max(s.timestamp, signing_timestamp(self._wallclock()))
            s.link_id = link_id

    def _pack(self, mavmsg, link_id: int) -> bytes:
        self._stamp(link_id)
        frame = mavmsg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        return frame

    def _sendto(self, frame: bytes, addr, transport=None) -> bool:
        if self.tap is not None:
            self.tap("tx", frame, addr, self._now)
        try:
            (transport or self.udp).send(frame, addr)
        except OSError as e:
            self.counters.send_errors += 1
            self.log.debug("send to %s failed: %s", addr, e)
            return False
        self.counters.sent += 1
        return True

    def send_agent(self, msgs: Iterable, now: float) -> None:
        """Encode each agent message once and send it to every peer (the wire sender is our id)."""
        for msg in msgs:
            dest = getattr(msg, "dest", 0)
            self._stamp(PEER_DIRECT_LINK if dest else PEER_LINK)
            try:
                frame = codec.encode(msg, self.mav)
            except (ValueError, TypeError) as e:
                self.counters.encode_errors += 1
                self.log.error("not sent: %s", e)
                continue
            self._to_peers(frame, now, dest)

    def _to_peers(self, frame: bytes, now: float, dest: int = 0) -> None:
        """Send ``frame`` to the peers (``dest``: the robot it is addressed to, 0 every robot) over the transport.
        With ``peer_loss``, a copy is lost with that probability (or, with ``loss_burst``, while that peer's channel
        is in a bad spell), as a lossy radio loses it for one receiver and not another: drawn here per copy when the
        transport sends copies (UDP), on receipt per sender when it publishes once (:meth:`_lost_on_receipt`)."""
        t = self.transport
        for where in t.destinations(dest):
            if self.peer_loss and t.copies and self._loses(where, now):
                self.counters.loss_injected += 1
                continue
            self.counters.peer_sent += self._sendto(frame, where, t)

    def _lost_on_receipt(self, origin, now: float) -> bool:
        """A published frame from ``origin`` (the sender's key) lost here with the loss model; counted."""
        if origin is None or not self.peer_loss or not self._loses(origin, now):
            return False
        self.counters.loss_injected += 1
        return True

    def _loses(self, addr, now: float) -> bool:
        if not self.loss_burst or self.peer_loss >= 1.0:
            return self._loss_rng.random() < self.peer_loss
        if addr not in self._spells:                # the first copy finds the channel as it is on average
            bad = self._loss_rng.random() < self.peer_loss
            self._spells[addr] = (bad, now + self._spell(bad))
        bad, until = self._spells[addr]
        while until <= now:
            bad = not bad
            until += self._spell(bad)
        self._spells[addr] = (bad, until)
        return bad

    def _spell(self, bad: bool) -> float:
        """A spell's length: exponential, of mean ``loss_burst`` bad and ``loss_burst (1 - p) / p`` good."""
        p, b = self.peer_loss, self.loss_burst
        return self._loss_rng.expovariate(1.0 / b if bad else p / (b * (1.0 - p)))

    def gcs_addresses(self) -> list[tuple]:
        """Where telemetry goes: the configured ground station and those heard within GCS_TIMEOUT."""
        out = [self._gcs] if self._gcs is not None else []
        for addr, t in list(self._gcs_seen.items()):
            if self._now - t > GCS_TIMEOUT:
                del self._gcs_seen[addr]
            elif addr not in out:
                out.append(addr)
        return out

    def send_gcs(self, mavmsg) -> bool:
        """Send a message built from ``self.mav``'s dialect (or one of our dataclasses) to the ground
        stations; True if it went to at least one."""
        addrs = self.gcs_addresses()
        if not addrs:
            return False
        frame = self._frame(mavmsg)
        return frame is not None and any([self._sendto(frame, a) for a in addrs])

    def send_to(self, mavmsg, addr) -> bool:
        """Send one message (pymavlink or our dataclass) to ``addr`` (a ground station's request source)."""
        frame = self._frame(mavmsg)
        return frame is not None and self._sendto(frame, addr)

    def _frame(self, mavmsg) -> bytes | None:
        try:
            if not hasattr(mavmsg, "pack"):
                mavmsg = codec.to_mavlink(mavmsg, self.module)
            return self._pack(mavmsg, GCS_LINK)
        except Exception as e:            # struct.error / ValueError: a value outside its wire type
            self.counters.encode_errors += 1
            self.log.error("not sent: %s %s", getattr(mavmsg, "get_type", lambda: type(mavmsg).__name__)(), e)
            return None

    def heartbeat(self):
        """The HEARTBEAT this robot sends: ground rover, generic autopilot, current mode and state."""
        m = self.module
        return self.mav.heartbeat_encode(m.MAV_TYPE_GROUND_ROVER, m.MAV_AUTOPILOT_GENERIC,
                                         self.base_mode, self.custom_mode, self.system_status)

    def _heartbeat_peers(self, now: float) -> None:
        if self._next_heartbeat is not None and now < self._next_heartbeat:
            return
        self._to_peers(self._pack(self.heartbeat(), PEER_LINK), now)
        nxt = (now if self._next_heartbeat is None else self._next_heartbeat) + self.heartbeat_period
        self._next_heartbeat = nxt if nxt > now else now + self.heartbeat_period

    # ------------------------------------------------------------------ receiving
    def poll(self, now: float) -> list:
        """Heartbeat the peers when due, drain the socket, return the messages for us from peers (ground-station
        requests go to :attr:`gcs_inbox`)."""
        self._now = max(self._now, now)
        self._heartbeat_peers(now)
        out: list = []
        for t in self._transports():
            for data, addr, origin in t.receive(self.counters, MAX_DATAGRAMS_PER_POLL):
                if not self._lost_on_receipt(origin, now):
                    out += self.feed(data, now, addr)
        for robot, joined in self.transport.membership():
            self._member(robot, joined, now)
        if now >= self._next_kernel_check:
            self._next_kernel_check = now + KERNEL_DROPS_PERIOD
            self.check_kernel_drops()
        return out

    def _transports(self) -> tuple:
        return (self.udp,) if self.transport is self.udp else (self.udp, self.transport)

    def _member(self, robot: int, joined: bool, now: float) -> None:
        """The transport saw ``robot`` join (a session's liveliness token appeared: it counts as heard now) or
        leave (its session died: reported lost at the next :meth:`peers_lost`, without waiting for the
        heartbeats' timeout; the core still waits for its messages to be silent that long)."""
        if robot == self.robot_id or not 1 <= robot <= MAX_ROBOT_ID:
            return
        if joined:
            self._left.discard(robot)
            self._beats.hear(robot, now)
        elif robot not in self._beats.lost:
            self._left.add(robot)

    def check_kernel_drops(self) -> int:
        """Bring ``kernel_dropped`` up to the kernel's count now (datagrams carry it only once more arrive), and
        ``queue_dropped`` up to a publish/subscribe transport's."""
        for t in self._transports():
            t.check_drops(self.counters)
        return self.counters.kernel_dropped

    def feed(self, data: bytes, now: float, addr: tuple | None = None) -> list:
        """Parse one datagram; return the agent messages addressed to us.  Never raises.  The datagram is
        counted once: ``received`` if a frame in it was taken, else the first reason a frame was refused."""
        self._unsigned_net = self.signing and addr in self.unsigned_gcs
        if self.tap is not None:
            self.tap("rx", data, addr, now)
        msgs, after = parse_datagram(self.mav, self.module, data)
        refused: list[str] = []
        out: list = []
        taken = False
        for m in msgs:
            try:
                why, agent = self._dispatch(m, now, addr)
            except codec.InvalidMessage as e:
                why, agent = "invalid", None
                self.log.debug("dropped: %s", e)
            except Exception as e:        # a field that will not convert; count, keep going
                why, agent = "parse_errors", None
                self.log.debug("dropped %s: %r", m.get_type(), e)
            if why is None:
                taken = True
            else:
                refused.append(why)
            if agent is not None:
                out.append(agent)
        count_datagram(self.counters, taken, refused + after)
        return out

    def _allow_unsigned(self, mav, msg_id: int) -> bool:
        # only HEARTBEAT and SETUP_SIGNING get past pymavlink unsigned (anything, from an unsigned_gcs network);
        # _dispatch keeps a HEARTBEAT only if it is a GCS's, refuses every SETUP_SIGNING (so the sender can be told
        # why), and keeps any other unsigned frame only if it is ground-station traffic (_unsigned_refusal)
        return self._unsigned_net or msg_id in self._unsigned_ok

    def _dispatch(self, m, now: float, addr=None) -> tuple[str | None, object]:
        """One decoded frame: (None if taken, else the counter of why it was refused; the agent message for us)."""
        c = self.counters
        kind = m.get_type()
        if kind == "BAD_DATA":
            why = refusal(m)
            if why == "bad_signature_dropped" and addr is not None:
                self._stream_clash(bytes(getattr(m, "data", b"")), addr)
            return why, None
        if kind.startswith("UNKNOWN"):
            return "unknown", None
        if kind == "SETUP_SIGNING":
            if self._badly_signed(m):
                return "bad_signature_dropped", None
            self._refuse_key_change(m, now, addr)
            return "setup_signing_refused", None
        unsigned = self.signing and not m.get_signed()
        if unsigned and kind != "HEARTBEAT":
            why = self._unsigned_refusal(m, addr)
            if why is not None:
                return why, None
        src = m.get_srcSystem()
        if self.signing and m.get_signed() and 1 <= src <= MAX_ROBOT_ID and m.get_link_id() not in PEER_LINKS:
            return "replayed_dropped", None       # a robot's frame to a ground station, replayed to us
        if self.signing and m.get_signed() and src > MAX_ROBOT_ID and addr is not None:
            streams, key = self._gcs_streams, (m.get_link_id(), src, m.get_srcComponent())
            if key in streams or len(streams) < MAX_GCS_STREAMS:
                streams[key] = addr
        if kind == "HEARTBEAT":
            why = self._on_heartbeat(m, now)
            if why is None and m.type == self._gcs_type and addr is not None:
                self._gcs_seen[addr] = now
            return why, None
        agent = codec.from_mavlink(m)
        if unsigned and agent is not None and agent.sender <= MAX_ROBOT_ID:
            return "unsigned_dropped", None       # robots' messages always come signed
        if agent is None or agent.sender > MAX_ROBOT_ID:
            # a ground station's request: a standard message, or one of ours from a system id that is no robot's
            if addr is None:
                return "ignored", None
            if len(self.gcs_inbox) >= MAX_GCS_INBOX:
                return "gcs_overflow", None
            c.gcs_requests += 1
            c.unsigned_gcs_taken += unsigned
            self._gcs_seen[addr] = now
            self.gcs_inbox.append((m if agent is None else agent, addr))
            return None, None
        if agent.sender == self.robot_id or agent.dest not in (0, self.robot_id):
            return "not_for_us", None
        c.agent_received += 1
        return None, agent

    def _stream_clash(self, frame: bytes, addr) -> None:
        """A ground station's frame refused for its signature though signed with our key (so for its timestamp):
        if another address signed on the same link id, system and component (one replay window for both), say so
        once for this address."""
        secret = self.mav.signing.secret_key
        if secret is None or len(frame) < 25 or frame[0] != 0xFD or frame[1] + 25 != len(frame):
            return                                # not one whole signed MAVLink 2 frame
        if frame[5] <= MAX_ROBOT_ID:
            return
        if hashlib.sha256(bytes(secret) + frame[:-6]).digest()[:6] != frame[-6:]:
            return                                # another key: not a clash
        stream = (frame[-13], frame[5], frame[6])
        other = self._gcs_streams.get(stream)
        if other is None or other == addr or (stream, addr) in self._clashes or len(self._clashes) >= MAX_GCS_STREAMS:
            return
        self._clashes.add((stream, addr))
        self.log.warning("ground station at %s:%s signs as system %d component %d on link id %d, as the one at "
                         "%s:%s does: one replay window for both, so the older timestamps are dropped as replays; "
                         "give one of them another link id or system id", *addr[:2], stream[1], stream[2],
                         stream[0], *other[:2])

    def _unsigned_refusal(self, m, addr) -> str | None:
        """Why an unsigned frame other than a HEARTBEAT (let through by ``_allow_unsigned`` only from an
        ``unsigned_gcs`` network) is refused, or None if it is ground-station traffic: a ground station's system id
        (not this fleet's: its robots always sign; MAVSDK's default 245 is taken) from an address that is no peer's."""
        if self._badly_signed(m):
            return "bad_signature_dropped"
        if not (self._unsigned_net and m.get_srcSystem() not in self._fleet
                and not any(addr[:2] == p[:2] for p in self._peers)):
            return "unsigned_dropped"
        return None

    def _badly_signed(self, m) -> bool:
        """A frame pymavlink let through only because its id may come unsigned (``_allow_unsigned``), though it is
        signed, with a wrong signature or an old timestamp."""
        return self.signing and not m.get_signed() and bool(m.get_header().incompat_flags & _IFLAG_SIGNED)

    def _refuse_key_change(self, m, now: float, addr) -> None:
        """Tell a SETUP_SIGNING's sender why nothing changed: one STATUSTEXT per address and KEY_REFUSAL_PERIOD
        (to a robot on the peer link id, where it takes robot frames; to anyone else on the ground-station one)."""
        if addr is None:
            return
        told = self._key_refusals
        last = told.get(addr)
        if last is not None and now - last < KEY_REFUSAL_PERIOD:
            return
        if last is None and len(told) >= MAX_KEY_REFUSAL_SENDERS:
            for a in [a for a, t in told.items() if now - t >= KEY_REFUSAL_PERIOD]:
                del told[a]
            if len(told) >= MAX_KEY_REFUSAL_SENDERS:
                return
        told[addr] = now
        src = m.get_srcSystem()
        self.log.warning("SETUP_SIGNING from system %d at %s refused: the key is set on the robot, not over the "
                         "network", src, addr)
        text = self.mav.statustext_encode(MAV_SEVERITY_WARNING, KEY_REFUSAL_TEXT.encode())
        link_id = PEER_LINK if 1 <= src <= MAX_ROBOT_ID else GCS_LINK
        if self._sendto(self._pack(text, link_id), addr):
            self.counters.setup_signing_replies += 1

    def _on_heartbeat(self, m, now: float) -> str | None:
        """Record a HEARTBEAT: None if taken, else why not."""
        c = self.counters
        is_gcs = m.type == self._gcs_type
        if self._badly_signed(m):
            return "bad_signature_dropped"
        if self.signing and not m.get_signed() and not is_gcs:
            return "unsigned_dropped"
        src = m.get_srcSystem()
        if is_gcs:
            self.gcs_last_heartbeat = now
        elif src == self.robot_id:
            return "not_for_us"
        elif not 1 <= src <= MAX_ROBOT_ID:
            return "ignored"
        else:
            back = src in self._beats.lost
            self._beats.hear(src, now)
            if back:
                self.log.info("peer %d is back", src)
        c.heartbeats += 1
        return None

    # ------------------------------------------------------------------ liveness
    def peers_lost(self, now: float) -> list[int]:
        """Peers silent for more than ``heartbeat_timeout`` at ``now`` and not reported before."""
        self._now = max(self._now, now)
        due = self._beats.due(now)
        if self._left:
            left = sorted(self._left - set(due))
            self._left.clear()
            self._beats.lost.update(left)
            due = sorted(set(due) | set(left))
        return due

    @property
    def peers_alive(self) -> list[int]:
        """Peers heard within ``heartbeat_timeout`` of the latest ``now`` given to poll/peers_lost."""
        return self._beats.alive(self._now)

    def close(self) -> None:
        for t in self._transports():
            t.close()


def open_link(comms, robot_id: int, **kw) -> MavlinkLink:
    """The link a robot config's ``comms`` describes: its key loaded, its transport opened (peers' addresses only
    over ``udp``)."""
    from runtime.comms.transport import open_transport

    key = load_key(comms.signing_key) if comms.signing_key else None
    transport = open_transport(comms, robot_id)
    try:
        return MavlinkLink(robot_id, comms.listen, [p.address for p in comms.peers] if transport is None else [],
                           comms.gcs, signing_key=key, heartbeat_timeout=comms.heartbeat_timeout,
                           peer_loss=comms.peer_loss, loss_burst=comms.loss_burst, loss_seed=comms.loss_seed,
                           unsigned_gcs=comms.unsigned_gcs, fleet=[p.id for p in comms.peers], transport=transport,
                           **kw)
    except BaseException:
        if transport is not None:
            transport.close()
        raise


def was_signed(frame) -> bool:
    """True if a raw frame is MAVLink 2 with the 'signed' incompat flag set (a parser without the key does not
    say so)."""
    return len(frame) > 2 and frame[0] == 0xFD and bool(frame[2] & _IFLAG_SIGNED)
