"""A base's emulator in this process and a daemon's base loop in a child process, for the kill and freeze tests
(``tests/test_base_stop.py``) and their measurement (``benchmarks/base_stop.py``).

The child (``python -m tests.stop_rig CONFIG``) does what ``mrta daemon`` does with its base and nothing else:
opens it through the registry, starts its stop guard (:func:`runtime.drivers.guard.start`, as ``runtime.daemon.run``
does), and every 50 ms polls it, drives it at 0.2 m/s and 0.3 rad/s and beats the guard.  The emulator runs on a
thread every 5 ms of wall time on a kinematic body; :meth:`StopRig.standstill_after` signals the child and times
how long the body's wheels take to stand still."""
from __future__ import annotations

import itertools
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PERIOD = 0.005
BASES = ("create_pty", "arcos_pty", "arcos_tcp", "cia402")
_channels = itertools.count(100 + os.getpid() % 1000 * 10)    # CAN channel numbers on the shared hub


def _emulator(kind: str):
    """(device, body, the child's base config, wheels still?)."""
    if kind == "create_pty":
        from sitl.devices.create_oi import CreateOIDevice
        from tests.fakes import FakeBody
        body = FakeBody()
        dev = CreateOIDevice(body)
        return dev, body, {"type": "create_oi", **dev.endpoint()}, lambda: body.cmd == (0.0, 0.0)
    if kind.startswith("arcos"):
        from sitl.devices.arcos import ArcosDevice
        from tests.arcos_util import FakePioneer
        body = FakePioneer()
        link = None
        if kind == "arcos_tcp":
            from sitl.devices.tcp_link import open_tcp
            link = open_tcp(18101)
        dev = ArcosDevice(body, link=link)
        return dev, body, {"type": "arcos", **dev.endpoint()}, lambda: body.wheel_rates() == (0.0, 0.0)
    from runtime.drivers.cia402 import Cia402Config
    from sitl.devices.cia402 import Cia402Device
    from tests.can_util import WheelBody
    body = WheelBody()
    dev = Cia402Device(body, Cia402Config(), robot_id=next(_channels))
    return dev, body, {"type": "cia402", **dev.endpoint()}, lambda: body.rates == [0.0, 0.0]


class StopRig:
    def __init__(self, kind: str):
        self.dev, self.body, self.base_cfg, self.still = _emulator(kind)
        self.t0 = time.monotonic()
        self.done = threading.Event()
        self.errors: list[BaseException] = []
        self.thread = threading.Thread(target=self._emulate, daemon=True)
        self.thread.start()
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
        self.child = subprocess.Popen([sys.executable, "-m", "tests.stop_rig", json.dumps(self.base_cfg)],
                                      cwd=ROOT, env=env, stderr=subprocess.PIPE, text=True)

    def _emulate(self) -> None:
        last = time.monotonic()
        try:
            while not self.done.is_set():
                now = time.monotonic()
                self.body.step(now - last)
                last = now
                self.dev.service(now - self.t0)
                time.sleep(PERIOD)
        except BaseException as exc:       # noqa: BLE001 - reported by the test
            self.errors.append(exc)

    def wait(self, cond, timeout: float) -> float | None:
        """Seconds until ``cond()`` held (polled every 5 ms), or None after ``timeout``."""
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            if cond():
                return time.monotonic() - t0
            if self.child.poll() is not None and not self.stopped_child:
                raise AssertionError(f"the child exited {self.child.returncode}: {self.child.stderr.read()}")
            time.sleep(PERIOD)
        return None

    stopped_child = False

    def standstill_after(self, sig: int, moving_timeout: float = 20.0, still_timeout: float = 10.0) -> float | None:
        """Wait until the child drives the body, send it ``sig``, return the seconds until the wheels stood
        still (None: not within ``still_timeout``)."""
        if self.wait(lambda: not self.still(), moving_timeout) is None:
            raise AssertionError(f"the body never moved: {self.errors}")
        time.sleep(0.2)
        self.stopped_child = True
        os.kill(self.child.pid, sig)
        return self.wait(self.still, still_timeout)

    def signal_when_moving(self, sig: int, moving_timeout: float = 20.0) -> float:
        """Wait until the child drives the body, then send it ``sig``; the time it was sent."""
        if self.wait(lambda: not self.still(), moving_timeout) is None:
            raise AssertionError(f"the body never moved: {self.errors}")
        time.sleep(0.2)
        self.stopped_child = True
        os.kill(self.child.pid, sig)
        return time.monotonic()

    def stays_still(self, seconds: float) -> bool:
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            if not self.still():
                return False
            time.sleep(PERIOD)
        return True

    @staticmethod
    def standstill_all(rigs: list["StopRig"], sigs: list[int], still_timeout: float = 10.0) -> list[float | None]:
        """:meth:`standstill_after` for several rigs at once (their children run side by side)."""
        sent = [r.signal_when_moving(sig) for r, sig in zip(rigs, sigs)]
        took: list[float | None] = [None] * len(rigs)
        while time.monotonic() - max(sent) < still_timeout and None in took:
            for i, r in enumerate(rigs):
                if took[i] is None and r.still():
                    took[i] = time.monotonic() - sent[i]
            time.sleep(PERIOD)
        return took

    def close(self) -> str:
        """Kill the child (wakes a frozen one first), stop the emulator; the child's stderr."""
        if self.child.poll() is None:
            os.kill(self.child.pid, signal.SIGCONT)
            self.child.kill()
        _, err = self.child.communicate(timeout=10)
        self.done.set()
        self.thread.join(2.0)
        self.dev.close()
        return err


def _child(base: dict) -> None:
    from runtime.drivers import guard
    from runtime.drivers.registry import driver_class, open_base
    from runtime.log import setup
    setup("INFO")
    cfg = driver_class(base["type"]).Config(**base)
    drv = open_base(cfg, 1)
    t0 = time.monotonic()
    drv.open(0.0)
    g = guard.start(drv, 1, drv.log)
    while True:
        now = time.monotonic() - t0
        drv.poll(now)
        drv.set_velocity(0.2, 0.3, now)
        if g is not None:
            g.beat()
        time.sleep(0.05)


if __name__ == "__main__":
    _child(json.loads(sys.argv[1]))
