"""CAN across processes without kernel SocketCAN: a socketcand-protocol server on loopback.

The daemons run in processes of their own, the emulated drives in the SITL's; kernel ``vcan`` needs a module
these kernels lack, and python-can's ``virtual`` bus is in-process only.  :class:`CanHub` serves named buses
(``channel``) over TCP in socketcand's ASCII protocol (:mod:`sitl.socketcand_protocol`), so any client of the
stock python-can ``socketcand`` interface -- the CiA 402 driver, ``python -m can.logger``, ``can.viewer`` --
joins a robot's bus with ``interface=socketcand, host=127.0.0.1, port=N, channel=canID``.  Each channel is
bridged to a python-can ``virtual`` channel in this process where the emulated drives sit.

Why socketcand rather than the alternatives (see docs/can.md): slcan is point to point (one serial line, one
peer: a logger beside the daemon needs a relay) and its python-can interface waits 2 s after opening by
default; python-can-remote is one more dependency (websockets) and not maintained since 2019; UDP multicast is
unreliable and often missing in containers.  socketcand over TCP is ordered and lossless, needs no extra
package on either side, and is what a real robot can serve too (socketcand on its SocketCAN interface), so the
driver config is the same against the SITL and a remote robot.

Semantics: a frame sent by one client reaches the drives and every other raw-mode client of that channel (not
the sender, as on SocketCAN without ``CAN_RAW_RECV_OWN_MSGS``); a frame the drives send reaches every raw-mode
client.  The stock client compares the handshake replies byte for byte (``_expect_msg``: one ``recv(256)``
must equal ``< ok >``), so frames for a client that has just entered raw mode wait until it has sent a command
or ``RAW_GRACE`` seconds have passed, lest they arrive in the same read as its ``< ok >``.  Malformed input is
counted and skipped (no ``< error >`` reply: the stock client would take it for an error frame).

Frames move in :meth:`CanHub.pump`: clients' input to the channel's virtual bus, the channel's ``on_input``
hook (the emulated drives read their buses there), then whatever is on the channel's bus to the clients.  The
hub's thread pumps whenever a client sends (clients in other processes, and a driver blocked on SDO in this
one); the SITL device pumps its channel in every ``service`` call, so in lock-step everything a daemon sent
before the world moves on has reached the drives, and everything the drives sent is in the daemon's socket
before its next cycle: no frame is late by a thread's turn, and runs stay repeatable.

The SITL's CAN devices share one hub per process (:func:`acquire` / :func:`release`): the first device starts
it on a free port, the last one to close stops it.
"""
from __future__ import annotations

import selectors
import socket
import threading
import time
from dataclasses import dataclass

import can

from runtime.log import get_logger
from sitl import socketcand_protocol as S

RAW_GRACE = 0.2             # s: frames for a client entering raw mode wait this long unless it speaks first
MAX_PENDING = 1 << 20       # bytes queued for a slow client before its frames are dropped
SELECT_TIMEOUT = 0.05

log = get_logger("sitl.can_hub")


@dataclass
class HubStats:
    clients: int = 0            # connections accepted
    commands: int = 0           # well-formed commands taken
    bad_commands: int = 0       # unknown verb, wrong mode, or a send that is not a frame
    frames_in: int = 0          # frames sent by clients
    frames_out: int = 0         # frame lines queued to clients
    overflow_drops: int = 0     # frame lines dropped for a client that does not read
    dropped_bytes: int = 0      # bytes clients sent outside well-formed commands
    errors: int = 0             # exceptions caught while serving a client (the client is closed)


class _Client:
    def __init__(self, sock: socket.socket, addr):
        self.sock = sock
        self.addr = addr
        self.splitter = S.Splitter()
        self.channel: _Channel | None = None
        self.mode = "new"                # new -> bcm (after open) -> raw (after rawmode)
        self.ready_at = 0.0              # monotonic time before which frames wait (the raw-mode grace)
        self.pending = bytearray()
        self.lock = threading.Lock()
        self.closed = False


class _Channel:
    def __init__(self, hub: "CanHub", name: str, on_input):
        self.name = name
        self.virtual = f"mrta-can-hub-{hub.port}-{name}"
        self.clients: set[_Client] = set()         # raw mode: they get every frame
        self.members: set[_Client] = set()         # opened this channel (any mode)
        self.on_input = on_input
        self.bus = can.Bus(interface="virtual", channel=self.virtual)


class CanHub:
    """A socketcand server on ``host:port`` (port 0: a free one, see :attr:`port`) with named channels."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0):
        self.stats = HubStats()
        self._listen = socket.create_server((host, port))
        self._listen.setblocking(False)
        self.host, self.port = self._listen.getsockname()[:2]
        self._channels: dict[str, _Channel] = {}
        self._lock = threading.Lock()              # channels, their client sets, flush requests
        self._pump_lock = threading.RLock()        # one pump at a time: frames keep their order
        self._flush: set[_Client] = set()
        self._clients: set[_Client] = set()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._sel = selectors.DefaultSelector()
        self._sel.register(self._listen, selectors.EVENT_READ, "listen")
        self._sel.register(self._wake_r, selectors.EVENT_READ, "wake")
        self._stop = False
        self._thread = threading.Thread(target=self._run, name=f"can-hub-{self.port}", daemon=True)
        self._thread.start()
        log.info("socketcand hub on %s:%d", self.host, self.port)

    # ------------------------------------------------------------------ channels
    def add_channel(self, name: str, on_input=None) -> str:
        """Serve channel ``name``; returns the python-can ``virtual`` channel the drives join.  ``on_input()`` is
        called in :meth:`pump` after clients' frames were put on that bus (the drives read them there)."""
        with self._lock:
            if name not in self._channels:
                self._channels[name] = _Channel(self, name, on_input)
            return self._channels[name].virtual

    def remove_channel(self, name: str) -> None:
        """Stop serving ``name``; its clients are disconnected."""
        with self._pump_lock:
            with self._lock:
                ch = self._channels.pop(name, None)
            if ch is None:
                return
            ch.bus.shutdown()
            for c in list(ch.members):
                self._request_close(c)

    def pump(self, name: str | None = None) -> int:
        """Move frames now: clients' input (of channel ``name``, or all), the channels' ``on_input`` hooks, then
        every frame on the channels' buses to their raw-mode clients.  Returns the frames moved.  Safe from any
        thread."""
        with self._pump_lock:
            with self._lock:
                chans = [self._channels[name]] if name in self._channels else \
                    ([] if name is not None else list(self._channels.values()))
                readers = [c for ch in chans for c in ch.members] if name is not None else list(self._clients)
            touched = set()
            for c in readers:
                if self._read_client(c) and c.channel is not None:
                    touched.add(c.channel)
            for ch in touched:
                if ch.on_input is not None:
                    ch.on_input()
            moved = 0
            for ch in chans:
                while True:
                    try:
                        msg = ch.bus.recv(0)
                    except can.CanError:              # removed meanwhile
                        break
                    if msg is None:
                        break
                    moved += 1
                    self._broadcast(ch, msg, None)
            return moved

    def listeners(self, name: str) -> int:
        """Clients in raw mode on channel ``name`` (they get every frame)."""
        with self._lock:
            ch = self._channels.get(name)
            return len(ch.clients) if ch else 0

    @property
    def channels(self) -> list[str]:
        with self._lock:
            return list(self._channels)

    def close(self) -> None:
        for name in self.channels:
            self.remove_channel(name)
        self._stop = True
        self._wake()
        self._thread.join(2.0)

    # ------------------------------------------------------------------ the socket thread
    def _run(self) -> None:
        try:
            while not self._stop:
                for key, events in self._sel.select(SELECT_TIMEOUT):
                    if key.data == "listen":
                        self._accept()
                    elif key.data == "wake":
                        self._drain_wake()
                    elif events & selectors.EVENT_WRITE:
                        self._flush_client(key.data)
                self.pump()                       # input from any client, and what the drives sent meanwhile
                self._flush_due()
        finally:
            for key in list(self._sel.get_map().values()):
                key.fileobj.close()
            self._sel.close()
            self._wake_w.close()

    def _accept(self) -> None:
        try:
            sock, addr = self._listen.accept()
        except (BlockingIOError, InterruptedError):
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        c = _Client(sock, addr)
        self.stats.clients += 1
        with self._lock:
            self._clients.add(c)
        self._sel.register(sock, selectors.EVENT_READ, c)
        self._reply(c, "< hi >")

    def _read_client(self, c: _Client) -> bool:
        """Take everything client ``c`` has sent; True if it sent frames."""
        frames = self.stats.frames_in
        try:
            while not c.closed:
                try:
                    data = c.sock.recv(65536)
                except (BlockingIOError, InterruptedError):
                    break
                if not data:
                    self._request_close(c)
                    break
                before = c.splitter.stats.dropped_bytes
                for text in c.splitter.feed(data):
                    self._command(c, text)
                self.stats.dropped_bytes += c.splitter.stats.dropped_bytes - before
        except OSError:
            self._request_close(c)
        except Exception as exc:       # noqa: BLE001 - one client's trouble never stops the hub
            self.stats.errors += 1
            log.warning("client %s: %s: closed", c.addr, exc)
            self._request_close(c)
        return self.stats.frames_in != frames

    def _command(self, c: _Client, text: str) -> None:
        verb, args = S.command(text)
        if verb == "open" and c.mode == "new" and len(args) == 1:
            with self._lock:
                ch = self._channels.get(args[0])
                if ch is not None:
                    c.channel, c.mode = ch, "bcm"
                    ch.members.add(c)
            self.stats.commands += 1
            self._reply(c, "< ok >" if ch is not None else "< error could not open bus >")
        elif verb == "rawmode" and c.mode == "bcm" and not args:
            c.ready_at = time.monotonic() + RAW_GRACE
            with self._lock:
                c.mode = "raw"
                c.channel.clients.add(c)
            self.stats.commands += 1
            self._reply(c, "< ok >")
        elif verb == "bcmmode" and c.mode == "raw" and not args:
            with self._lock:
                c.mode = "bcm"
                c.channel.clients.discard(c)
            self.stats.commands += 1
            self._reply(c, "< ok >")
        elif verb == "echo" and not args:
            self.stats.commands += 1
            self._reply(c, "< echo >")
        elif verb == "send" and c.mode in ("bcm", "raw"):
            msg = S.parse_send(args)
            if msg is None:
                self.stats.bad_commands += 1
                return
            self.stats.commands += 1
            self.stats.frames_in += 1
            c.ready_at = 0.0                     # it has read its < ok >: frames may flow
            try:
                c.channel.bus.send(msg)
            except can.CanError:                 # the channel is being removed
                return
            self._broadcast(c.channel, msg, c)
        else:
            self.stats.bad_commands += 1

    # ------------------------------------------------------------------ writing (any thread)
    def _broadcast(self, ch: _Channel, msg: can.Message, origin: _Client | None) -> None:
        line = S.format_frame(msg, time.time()).encode("ascii")
        with self._lock:
            targets = [c for c in ch.clients if c is not origin]
        for c in targets:
            self.stats.frames_out += 1
            self._write(c, line, frame=True)

    def _reply(self, c: _Client, text: str) -> None:
        self._write(c, text.encode("ascii"), frame=False)

    def _write(self, c: _Client, data: bytes, frame: bool) -> None:
        with c.lock:
            if c.closed:
                return
            if frame and len(c.pending) + len(data) > MAX_PENDING:
                self.stats.overflow_drops += 1
                return
            if c.pending or (frame and time.monotonic() < c.ready_at):
                c.pending += data
            else:
                try:
                    n = c.sock.send(data)
                except (BlockingIOError, InterruptedError):
                    n = 0
                except OSError:
                    return                        # the socket thread sees the close
                c.pending += data[n:]
            if not c.pending:
                return
        with self._lock:
            self._flush.add(c)
        self._wake()

    def _wake(self) -> None:
        try:
            self._wake_w.send(b"x")
        except (BlockingIOError, OSError):
            pass                                  # a wake is already pending, or the hub is closing

    def _drain_wake(self) -> None:
        try:
            while self._wake_r.recv(4096):
                pass
        except (BlockingIOError, InterruptedError):
            pass

    def _flush_due(self) -> None:
        """Send what waits (the raw-mode grace is over, or a socket was full); watch for writability if some
        still waits."""
        with self._lock:
            due, self._flush = self._flush, set()
        now = time.monotonic()
        for c in due:
            if c.closed:
                self._close_client(c)            # closed by remove_channel: unregister it here
                continue
            if now < c.ready_at:
                with self._lock:
                    self._flush.add(c)
                continue
            self._flush_client(c)

    def _flush_client(self, c: _Client) -> None:
        with c.lock:
            if c.pending and not c.closed:
                try:
                    n = c.sock.send(c.pending)
                except (BlockingIOError, InterruptedError):
                    n = 0
                except OSError:
                    n = len(c.pending)
                del c.pending[:n]
            waiting = bool(c.pending) and not c.closed
        if not c.closed:
            try:
                self._sel.modify(c.sock, selectors.EVENT_READ | (selectors.EVENT_WRITE if waiting else 0), c)
            except (KeyError, ValueError):
                pass                              # unregistered meanwhile

    def _request_close(self, c: _Client) -> None:
        with c.lock:
            c.closed = True
        with self._lock:
            self._flush.add(c)
        self._wake()

    def _close_client(self, c: _Client) -> None:
        with c.lock:
            c.closed = True
        with self._lock:
            if c.channel is not None:
                c.channel.clients.discard(c)
                c.channel.members.discard(c)
            self._flush.discard(c)
            self._clients.discard(c)
        try:
            self._sel.unregister(c.sock)
        except (KeyError, ValueError):
            pass
        c.sock.close()


# ---------------------------------------------------------------------- one hub per process
_shared: CanHub | None = None
_users = 0
_shared_lock = threading.Lock()


def acquire() -> CanHub:
    """The process's hub, started on a free loopback port by the first caller."""
    global _shared, _users
    with _shared_lock:
        if _shared is None:
            _shared = CanHub()
        _users += 1
        return _shared


def release() -> None:
    """One user fewer; the last one stops the hub."""
    global _shared, _users
    with _shared_lock:
        _users -= 1
        if _users <= 0 and _shared is not None:
            _shared.close()
            _shared, _users = None, 0
