"""The ``zenoh`` transport: a robot's peer frames through Eclipse Zenoh (``pip install 'mrta-runtime[zenoh]'``,
the ``eclipse-zenoh`` package, imported only when this transport is chosen).

* **client** mode (the default): the robot's session connects to its segment's router(s) (``comms.zenoh.connect``;
  more than one is failover: the session reconnects to whichever answers); routers of several segments are linked
  to each other (``mrta router --connect``).  A client that loses its router reconnects when one is back.
* **peer** mode, for a small fleet without a router: each session listens (``comms.zenoh.listen``) and connects to
  a few seed peers (``comms.zenoh.connect``); Zenoh's gossip finds the rest and builds a full mesh.

Keys (``<fleet>`` is ``comms.zenoh.fleet``, ``<me>`` the robot id):

* ``mrta/<fleet>/all/<me>``: every frame for all peers, published once (one publisher);
* ``mrta/<fleet>/to/<dest>/<me>``: a frame addressed to robot ``<dest>`` (``target_system`` != 0);
* ``mrta/<fleet>/alive/<me>``: the robot's liveliness token.

A robot subscribes to ``mrta/<fleet>/all/*`` and ``mrta/<fleet>/to/<me>/*`` (its own publications excluded).  The
key only routes: the sender the link believes is the frame's signed system id, never the key (the router is not
trusted; a forged frame is dropped by the link's signature check and counted, as over UDP).

Congestion (``comms.zenoh.congestion``): ``drop`` (the default, UDP's semantics: a frame that cannot be queued is
dropped, never blocking the control loop) or ``block``.  Received frames wait in a bounded queue (:data:`QUEUE`)
filled by the session's thread; what overflows is counted in ``queue_dropped``, as the kernel's UDP drops are in
``kernel_dropped``.

Membership: liveliness tokens.  A token appearing (now, or already there when the robot starts) counts as the robot
heard; its disappearing (the session closed, or its lease ran out: ``comms.heartbeat_timeout``) reports it lost to
the link at once; the core still waits for its messages to be silent for the heartbeat timeout, as over UDP.  A
robot outside ``comms.peers`` joins the roster at its first message (``joins``; :meth:`RobotCore._admit
<runtime.robot.core.RobotCore._admit>`), never by its token alone: the router is not trusted.

:func:`open_router` opens a session in router mode (``mrta router``); a site may run ``zenohd`` instead: same wire.
"""
from __future__ import annotations

import json
import re
from collections import deque

from runtime.errors import InputError

QUEUE = 4096                          # received frames waiting for the link's poll; beyond, dropped and counted
KEEP_ALIVES = 4                       # keep-alive messages per lease (Zenoh's default)
FLEET = re.compile(r"[A-Za-z0-9_-]{1,64}")
ENDPOINT = re.compile(r"(tcp|udp|tls|quic|ws|unixsock-stream)/(\[[0-9A-Fa-f:.]+\]|[^/\s:\[\]]+):(\d{1,5})")
NEEDS = "the zenoh transport needs the eclipse-zenoh package: pip install 'mrta-runtime[zenoh]'"


def parse_endpoint(text: str) -> str:
    """``text`` if it is a Zenoh endpoint ``PROTO/HOST:PORT`` (tcp, udp, tls, quic, ws), else ValueError."""
    m = ENDPOINT.fullmatch(text)
    if m is None or not 0 <= int(m.group(3)) <= 65535:
        raise ValueError("like tcp/192.168.1.10:7447")
    return text


def parse_fleet(text: str) -> str:
    if FLEET.fullmatch(text) is None:
        raise ValueError("letters, digits, '_' and '-' only, 1..64 of them")
    return text


def load_zenoh():
    """The ``zenoh`` module, or InputError saying how to install it."""
    try:
        import zenoh
    except ImportError:
        raise InputError(NEEDS) from None
    return zenoh


def session_config(mode: str, connect=(), listen=(), lease: float | None = None, file: str | None = None):
    """A Zenoh config: ``mode`` (client, peer, router), endpoints, multicast scouting off (no multicast on the
    networks this runs on; routers and seed peers are named); ``lease`` s before a silent session is dropped.
    ``file``: a Zenoh JSON5 config file to start from (TLS certificates, access control, user/password: Zenoh's own
    keys, docs/transport.md); the keys above are set over it."""
    zenoh = load_zenoh()
    try:
        conf = zenoh.Config.from_file(file) if file else zenoh.Config()
    except zenoh.ZError as e:
        raise InputError(f"{file}: expected a Zenoh JSON5 config file ({str(e).split(' at ')[0]})") from None
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if lease is not None:
        conf.insert_json5("transport/link/tx/lease", str(max(100, int(lease * 1000))))
        conf.insert_json5("transport/link/tx/keep_alive", str(KEEP_ALIVES))
    return conf


def open_session(conf, what: str):
    zenoh = load_zenoh()
    try:
        return zenoh.open(conf)
    except zenoh.ZError as e:
        raise InputError(f"{what}: cannot open a Zenoh session ({str(e).split(' at ')[0].strip()})") from None


def open_router(listen, connect=(), what: str = "mrta router", file: str | None = None):
    """A Zenoh session in router mode listening on ``listen`` and linked to the routers at ``connect`` (``file``: a
    Zenoh config file under them, :func:`session_config`)."""
    return open_session(session_config("router", connect, listen, file=file), what)


class ZenohTransport:
    """One robot's Zenoh session: publishes its peer frames, queues the fleet's, watches liveliness tokens."""

    copies = False           # a frame is published once: the link draws its loss model per sender on receipt
    peer_addresses = False   # peers are ids: their frames come through the router
    joins = True             # a robot on the fleet's keys reaches every other: one not in comms.peers may join

    @classmethod
    def check_config(cls, comms, file: str) -> None:
        """A client names its router(s); a Zenoh config file exists.  Peers are ids: their frames come through the
        router, so their addresses are not used."""
        from pathlib import Path

        from runtime.config.build import ConfigError
        z = comms.zenoh
        if z.mode == "client" and not z.connect:
            raise ConfigError(file, "comms.zenoh.connect", "the segment's router endpoint(s) (client mode)", [])
        if z.config is not None and not Path(z.config).is_file():
            raise ConfigError(file, "comms.zenoh.config", "a Zenoh JSON5 config file", z.config)

    def __init__(self, robot_id: int, fleet: str = "fleet", *, mode: str = "client", connect=(), listen=(),
                 congestion: str = "drop", lease: float | None = None, queue: int = QUEUE, file: str | None = None):
        zenoh = load_zenoh()
        self.robot_id = int(robot_id)
        self.prefix = f"mrta/{parse_fleet(fleet)}"
        self._cc = zenoh.CongestionControl.BLOCK if congestion == "block" else zenoh.CongestionControl.DROP
        self._queue: deque = deque()
        self._cap = int(queue)
        self._overflow = 0
        self._members: deque = deque()
        self.session = open_session(session_config(mode, connect, listen, lease, file), "comms.zenoh.connect")
        s, me, remote = self.session, self.robot_id, zenoh.Locality.REMOTE
        self._all = s.declare_publisher(f"{self.prefix}/all/{me}", congestion_control=self._cc)
        self._to: dict[int, object] = {}
        self._subs = [s.declare_subscriber(f"{self.prefix}/all/*", self._on_frame, allowed_origin=remote),
                      s.declare_subscriber(f"{self.prefix}/to/{me}/*", self._on_frame, allowed_origin=remote)]
        self._put = zenoh.SampleKind.PUT
        self._alive = s.liveliness().declare_subscriber(f"{self.prefix}/alive/*", self._on_token, history=True)
        self._token = s.liveliness().declare_token(f"{self.prefix}/alive/{me}")

    @classmethod
    def from_config(cls, comms, robot_id: int) -> "ZenohTransport":
        z = comms.zenoh
        return cls(robot_id, z.fleet, mode=z.mode, connect=z.connect, listen=z.listen, congestion=z.congestion,
                   lease=comms.heartbeat_timeout, file=z.config)

    # ------------------------------------------------------------------ the session's thread
    def _on_frame(self, sample) -> None:
        if len(self._queue) >= self._cap:
            self._overflow += 1
            return
        self._queue.append((sample.payload.to_bytes(), str(sample.key_expr)))

    def _on_token(self, sample) -> None:
        self._members.append((str(sample.key_expr), sample.kind == self._put))

    # ------------------------------------------------------------------ the transport interface
    def destinations(self, dest: int) -> list:
        return [int(dest)]

    def send(self, frame: bytes, where: int) -> None:
        if where == 0:
            pub = self._all
        else:
            pub = self._to.get(where)
            if pub is None:
                pub = self._to[where] = self.session.declare_publisher(f"{self.prefix}/to/{where}/{self.robot_id}",
                                                                       congestion_control=self._cc)
        try:
            pub.put(frame)
        except Exception as e:            # zenoh.ZError: the session is closing
            raise OSError(str(e)) from None

    def receive(self, counters, limit: int):
        """Up to ``limit`` queued frames: ``(data, None, origin)``, origin the key's last part (the sender's
        claimed id, for the loss model only)."""
        q = self._queue
        for _ in range(min(limit, len(q))):
            data, key = q.popleft()
            yield data, None, ("zenoh", key.rpartition("/")[2])

    def membership(self) -> list:
        out = []
        while self._members:
            key, joined = self._members.popleft()
            tail = key.rpartition("/")[2]
            if tail.isascii() and tail.isdigit() and len(tail) <= 3:        # a robot id, 1..250 taken by the link
                out.append((int(tail), joined))
        return out

    def check_drops(self, counters) -> None:
        counters.queue_dropped = self._overflow

    def close(self) -> None:
        try:
            self.session.close()
        except Exception:                 # already closed
            pass
