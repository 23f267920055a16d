"""A daemon's recording channels streamed to the SITL launcher over a loopback TCP connection, so that one
``mrta sitl run FLEET --live`` shows a fleet of daemon processes whole.

Why a stream to the launcher rather than a Foxglove server per daemon that the launcher relays: the launcher is
then the one Foxglove server and needs no WebSocket client (subscriptions, reconnects, a per-client backlog in
each daemon that drops the oldest messages when the launcher falls behind); TCP keeps each robot's messages whole
and in order; the daemon writes already-encoded bytes (the schemas once per channel, then each message), so the
launcher copies them into its own channels without decoding them.

The daemon's side is :class:`RelaySender` (``mrta daemon --live-relay HOST:PORT``, which the launcher passes):
every message its :class:`~runtime.recording.recorder.Recorder` logs goes out as a frame; writes never block the
control cycle (a bounded buffer, :data:`MAX_BUFFER`: past it messages are dropped and counted, never a channel's
announcement); a broken connection ends the relay with one warning line, the robot runs on.

The launcher's side is :class:`RelayServer`: it listens on a free loopback port, and :meth:`RelayServer.poll`
(from the launcher's loop) accepts daemons, reads what they sent and logs it on channels of the launcher's
recorder: robot N's ``/robot_N/...`` topics as they are, its others (``/allocation``, ``/log``, ``/world``) under
``/robot_N`` (``/robot_N/allocation``), each channel marked ``relayed`` so the launcher's own ``run.mcap`` leaves
them out (each daemon records them in ``robot_N.mcap``).

A frame: ``u32`` length of the rest, ``u8`` kind, ``u16`` channel id, then for :data:`CHANNEL` the channel as JSON
(robot, topic, message encoding, schema name, encoding and data in base64) and for :data:`MESSAGE` the log time
(``u64`` ns) and the encoded message.  The receiver drops what it cannot read (a frame too long, bad JSON, a
message on a channel never announced) and counts it in ``dropped``; a connection sending garbage is closed.
"""
from __future__ import annotations

import base64
import json
import socket
import struct

from runtime.log import get_logger

HEAD = struct.Struct("<IBH")            # length of what follows the length field, kind, channel id
TIME = struct.Struct("<Q")
CHANNEL, MESSAGE = 0, 1
MAX_BUFFER = 8 << 20                   # bytes waiting to be sent: past it a daemon drops messages (counted)
MAX_FRAME = 16 << 20                   # a longer frame is garbage: the receiver closes the connection
READ = 1 << 20                         # bytes read from one daemon per poll at most (the launcher's loop goes on)


def frame(kind: int, cid: int, body: bytes) -> bytes:
    return HEAD.pack(len(body) + 3, kind, cid) + body


class RelaySender:
    """The daemon's end: connects to ``address`` (host, port) and sends robot ``robot_id``'s channels."""

    def __init__(self, address: tuple[str, int], robot_id: int, timeout: float = 5.0):
        self.robot = int(robot_id)
        self.log = get_logger("recording", robot_id)
        self.sock = socket.create_connection(address, timeout=timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.sock.setblocking(False)
        self.address = address
        self.ids: dict[str, int] = {}
        self.buf = bytearray()
        self.sent = 0
        self.dropped = 0
        self.stopped: str | None = None

    def channel(self, topic: str, encoding: str, schema) -> int:
        """The id of ``topic``'s channel, announcing it first (``schema``: a foxglove Schema)."""
        cid = self.ids.get(topic)
        if cid is None:
            cid = self.ids[topic] = len(self.ids) + 1
            if self.stopped is not None:
                return cid
            body = json.dumps({"robot": self.robot, "topic": topic, "encoding": encoding, "schema": schema.name,
                               "schema_encoding": schema.encoding,
                               "schema_data": base64.b64encode(bytes(schema.data)).decode()}).encode()
            self.buf += frame(CHANNEL, cid, body)
        return cid

    def send(self, cid: int, payload: bytes, ns: int) -> None:
        if self.stopped is not None:
            return
        if len(self.buf) > MAX_BUFFER:
            self.dropped += 1
        else:
            self.buf += frame(MESSAGE, cid, TIME.pack(ns) + payload)
            self.sent += 1
        if len(self.buf) >= 65536:
            self.flush()

    def flush(self) -> None:
        """Send what the socket takes now; a connection gone ends the relay with one warning line."""
        while self.buf and self.stopped is None:
            try:
                n = self.sock.send(self.buf)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                self.stopped = f"{self.address[0]}:{self.address[1]}: {exc.strerror or exc}"
                if isinstance(exc, (BrokenPipeError, ConnectionResetError)):    # the launcher's run ended first
                    self.log.info("live relay ended: %s", self.stopped)
                else:
                    self.log.warning("live relay stopped: %s (the robot runs on)", self.stopped)
                self.buf.clear()
                self.close()
                return
            del self.buf[:n]

    def close(self) -> None:
        if self.stopped is None and self.buf:
            self.sock.setblocking(True)
            self.sock.settimeout(1.0)
            try:
                self.sock.sendall(self.buf)
            except OSError:
                pass
        self.buf.clear()
        try:
            self.sock.close()
        except OSError:
            pass


class _Peer:
    def __init__(self, sock: socket.socket):
        self.sock = sock
        self.buf = bytearray()
        self.channels: dict[int, object] = {}
        self.robot: int | None = None


class RelayServer:
    """The launcher's end: listens on ``host`` (loopback) at a free port and logs what daemons send on channels
    of ``rec`` (a Recorder).  ``on_message(robot, topic, payload)``: told every message relayed."""

    def __init__(self, rec, host: str = "127.0.0.1", on_message=None):
        self.rec = rec
        self.on_message = on_message
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.bind((host, 0))
        self.sock.listen(64)
        self.sock.setblocking(False)
        self.address = self.sock.getsockname()[:2]
        self.peers: list[_Peer] = []
        self.messages = 0
        self.dropped = 0
        self.log = get_logger("recording")

    def poll(self) -> None:
        """Accept daemons, read what they sent, log it (bounded work per call)."""
        while True:
            try:
                conn, _ = self.sock.accept()
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                return
            conn.setblocking(False)
            self.peers.append(_Peer(conn))
        for p in list(self.peers):
            self._read(p)

    def _read(self, p: _Peer) -> int:
        """Bytes read from ``p`` now (at most :data:`READ`), its frames logged; the peer dropped at its end."""
        got, ended = 0, False
        while got < READ:
            try:
                data = p.sock.recv(READ - got)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                data = b""
            if not data:
                ended = True
                break
            got += len(data)
            p.buf += data
        if not self._frames(p):
            self.log.warning("live relay: robot %s sent what is not a relay stream; its connection closed",
                             p.robot if p.robot is not None else "?")
            ended = True
        if ended:
            self._drop_peer(p)
        return got

    def _frames(self, p: _Peer) -> bool:
        buf, off = p.buf, 0
        while len(buf) - off >= HEAD.size:
            length, kind, cid = HEAD.unpack_from(buf, off)
            if not 3 <= length <= MAX_FRAME:
                return False
            end = off + 4 + length
            if end > len(buf):
                break
            body = bytes(buf[off + HEAD.size:end])
            off = end
            if kind == CHANNEL:
                self._channel(p, cid, body)
            elif kind == MESSAGE and cid in p.channels and len(body) >= TIME.size:
                (ns,) = TIME.unpack_from(body)
                topic, ch = p.channels[cid]
                payload = body[TIME.size:]
                ch.log(payload, log_time=ns)
                self.messages += 1
                if self.on_message is not None:
                    self.on_message(p.robot, topic, payload)
            else:
                self.dropped += 1
        del buf[:off]
        return True

    def _channel(self, p: _Peer, cid: int, body: bytes) -> None:
        fx = self.rec.fx
        try:
            d = json.loads(body)
            robot, topic = int(d["robot"]), str(d["topic"])
            schema = fx.Schema(name=str(d["schema"]), encoding=str(d["schema_encoding"]),
                               data=base64.b64decode(d["schema_data"]))
            encoding = str(d["encoding"])
        except (ValueError, KeyError, TypeError):
            self.dropped += 1
            return
        p.robot = robot
        prefix = f"/robot_{robot}"
        if not topic.startswith(prefix + "/"):
            topic = prefix + (topic if topic.startswith("/") else "/" + topic)
        try:
            ch = self.rec.relayed_channel(topic, encoding, schema, robot)
        except Exception:          # the SDK refused the channel (an encoding or schema it does not know)
            self.dropped += 1
            return
        p.channels[cid] = (topic, ch)

    def _drop_peer(self, p: _Peer) -> None:
        try:
            p.sock.close()
        except OSError:
            pass
        self.peers.remove(p)

    def close(self) -> None:
        for p in list(self.peers):
            for _ in range(64):          # what was sent before the run ended (a daemon still running: bounded)
                if not self._read(p) or p not in self.peers:
                    break
            if p in self.peers:
                self._drop_peer(p)
        self.sock.close()
