"""A stop guard that outlives the daemon: a small child process holding a duplicate of the base's port.

Some bases stop by themselves when their master goes quiet (a Pioneer's ARCOS watchdog, a CiA 402 drive's
heartbeat consumer); a Create's Open Interface does not: it keeps its last Drive Direct until told otherwise, so a
daemon that dies or freezes mid-drive leaves the robot circling.  :class:`StopGuard` forks a child (no new
interpreter: it runs wherever the daemon runs, whatever the service user may execute) that keeps two file
descriptors and closes every other: the port (serial device, pty or TCP socket, shared with the daemon) and the
read end of a heartbeat pipe whose write end only the daemon holds.  The daemon writes one byte per control
cycle (:meth:`StopGuard.beat`).  The guard writes the base's stop bytes on the port when

* the pipe reaches end of file without a goodbye (the daemon died: SIGKILL, a crash, the OOM killer): the *final*
  stop (a Create: Drive Direct 0 0, then Start, which leaves it in Passive, where it ignores drive commands), then
  it exits;
* no byte came for ``bound`` seconds of wall time (the daemon is frozen: SIGSTOP, a debugger, a hung call): the
  *pause* stop (a Create: Drive Direct 0 0), once per silence; a daemon that wakes up drives on.

In the SITL a daemon also beats while it waits for the simulator's clock (``SharedClock.on_wait``): a paused world
(the launcher drawing the run's picture, a stalled simulator) is not a frozen daemon.  A daemon that closes cleanly
sends the goodbye byte first (its own close has stopped the base), and the guard exits without writing.  The
guard writes its lines with ``os.write`` (no logging lock a thread of the daemon may have held at the fork) and
costs one idle process; its reaction is measured in ``docs/bases.md``.
"""
from __future__ import annotations

import math
import os
import select
import signal
import time

BEAT = b"."
GOODBYE = b"q"


class StopGuard:
    """The daemon's side: start the guard process on ``port_fd``, beat every cycle, say goodbye at close.

    ``pause`` and ``final`` are the bytes the guard writes on a freeze and on death; ``bound`` the seconds of
    silence that count as a freeze; ``name`` the base and robot, for the guard's one line per episode."""

    def __init__(self, port_fd: int, pause: bytes, final: bytes, bound: float, name: str, log):
        self.bound = float(bound)
        self.log = log
        self.errors = 0
        self._beat_t = -math.inf
        read_end, self._write_end = os.pipe()
        os.set_blocking(self._write_end, False)
        try:
            self.pid = os.fork()
        except BaseException:
            os.close(read_end)
            os.close(self._write_end)
            raise
        if self.pid == 0:                              # the guard
            code = 1
            try:
                for sig in (signal.SIGTERM, signal.SIGINT):
                    signal.signal(sig, signal.SIG_DFL)
                os.setsid()                            # a terminal's Ctrl-C goes to the daemon, not here
                low = 3
                for fd in sorted({port_fd, read_end}):
                    os.closerange(low, fd)
                    low = fd + 1
                os.closerange(low, os.sysconf("SC_OPEN_MAX"))
                code = watch(port_fd, read_end, self.bound, pause, final, name)
            finally:
                os._exit(code)
        os.close(read_end)

    def alive(self) -> bool:
        """The guard process still runs."""
        try:
            return os.waitpid(self.pid, os.WNOHANG) == (0, 0)
        except ChildProcessError:
            return False

    def beat(self) -> None:
        """One heartbeat (non-blocking; a full pipe means the guard is behind, which is no reason to stop); at
        most one write per tenth of the bound, however often it is called."""
        if self._write_end is None:
            return
        now = time.monotonic()
        if now - self._beat_t < self.bound / 10:
            return
        self._beat_t = now
        try:
            os.write(self._write_end, BEAT)
        except BlockingIOError:
            pass
        except OSError as exc:                          # the guard is gone: say so once
            self.errors += 1
            if self.errors == 1:
                self.log.error("stop guard (pid %d) gone (%s): the base will not be stopped if this daemon dies",
                               self.pid, exc)

    def close(self, goodbye: bool = True, timeout: float = 1.0) -> None:
        """Goodbye (the daemon has stopped the base itself; without it the guard sends its final stop), then wait
        for the guard to exit."""
        if self._write_end is None:
            return
        if goodbye:
            try:
                os.set_blocking(self._write_end, True)
                os.write(self._write_end, GOODBYE)
            except OSError:
                pass
        os.close(self._write_end)
        self._write_end = None
        deadline = time.monotonic() + timeout
        while self.alive():
            if time.monotonic() > deadline:
                os.kill(self.pid, signal.SIGKILL)
                os.waitpid(self.pid, 0)
                break
            time.sleep(0.005)


def start(base, robot_id, log) -> StopGuard | None:
    """A guard for ``base`` (open) if it has one (``base.guard`` seconds, stop bytes and a port descriptor), else
    None; the daemon beats it every cycle."""
    stop = base.stop_bytes()
    if base.guard is None or stop is None:
        return None
    fd = base.port_fd()
    if fd is None:
        log.warning("no stop guard: the base's port has no file descriptor to hand over (loop:// or closed)")
        return None
    try:
        guard = StopGuard(fd, *stop, base.guard, f"robot={robot_id}", log)
    except OSError as exc:                  # no process or descriptor left: the daemon runs, without its guard
        log.error("no stop guard (%s): the base will not be stopped if this daemon dies or freezes", exc)
        return None
    log.info("stop guard pid %d: stops the base %.2f s after the last cycle, or when this daemon dies",
             guard.pid, base.guard)
    return guard


def port_fd(ser) -> int | None:
    """The file descriptor under a pyserial port (a device or pty, or ``socket://``); None for ``loop://`` and
    other ports without one."""
    for obj in (ser, getattr(ser, "_socket", None)):
        try:
            fd = obj.fileno()
        except Exception:               # noqa: BLE001 - pyserial raises its own kinds for ports without one
            continue
        if isinstance(fd, int) and fd >= 0:
            return fd
    return None


def _write(fd: int, data: bytes) -> str | None:
    """``data`` on the port; None, or why not."""
    try:
        os.set_blocking(fd, True)      # the daemon's description is non-blocking; it no longer writes
        os.write(fd, data)
        return None
    except OSError as exc:
        return str(exc)


def _say(name: str, text: str) -> None:
    t = time.time()
    stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t)) + f",{int(t % 1 * 1000):03d}"
    try:
        os.write(2, f"{stamp} WARNING {name} mrta.stop_guard: {text}\n".encode())
    except OSError:
        pass


def watch(port: int, beats: int, bound: float, pause: bytes, final: bytes, name: str) -> int:
    """The guard's loop: returns when the daemon said goodbye or died."""
    paused = False
    silent_since = time.monotonic()
    while True:
        ready, _, _ = select.select([beats], [], [], bound)
        now = time.monotonic()
        if not ready:
            if not paused:
                why = _write(port, pause)
                paused = True
                _say(name, f"daemon silent for {now - silent_since:.2f} s: sent the base's stop"
                           + (f" (failed: {why})" if why else ""))
            continue
        data = os.read(beats, 4096)
        if not data:
            why = _write(port, final)
            _say(name, "daemon gone: sent the base's stop" + (f" (failed: {why})" if why else ""))
            return 0
        if GOODBYE in data:
            return 0
        if paused:
            _say(name, f"daemon beating again after {now - silent_since:.2f} s")
        paused = False
        silent_since = now
