"""CAN round-trip latency through the socketcand hub (sitl/can_hub.py) beside python-can's ``virtual`` bus,
measured in the same run (ratios printed).

Two round trips, each on both transports:

* echo: one frame out, the far end sends one back.  ``virtual``: both buses in this process, the far end a
  thread blocked in ``recv``.  hub: the stock python-can ``socketcand`` client in a *second process*, the far
  end on the hub's virtual channel in this one, answering from the hub's ``on_input`` hook as the SITL's
  emulated drives do.
* SDO upload: a ``canopen`` master reads 0x6041.  ``virtual``: from a plain ``canopen`` LocalNode, both networks
  with python-can's receive thread (as canopen's own tests run).  hub: from the SITL's emulated CiA 402 drive
  (sitl/devices/cia402.py), the master's frames through the hub's TCP socket.

    python benchmarks/can_latency.py [--n 2000]
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import threading
import time

import can
import canopen

from runtime.drivers import cia402_protocol as P

CLIENT = r"""
import json, sys, time, can
host, port, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
bus = can.Bus(interface="socketcand", host=host, port=port, channel="bench")
msg = can.Message(arbitration_id=0x601, data=bytes(8), is_extended_id=False)
times = []
for i in range(n + 50):
    t0 = time.perf_counter()
    bus.send(msg)
    while True:
        r = bus.recv(2.0)
        if r is None or r.arbitration_id == 0x581:
            break
    if i >= 50:
        times.append(time.perf_counter() - t0)
bus.shutdown()
print(json.dumps(times))
"""


def summary(times: list[float]) -> tuple[float, float]:
    """Median and 99th percentile in microseconds."""
    s = sorted(times)
    return statistics.median(s) * 1e6, s[int(0.99 * (len(s) - 1))] * 1e6


def echo_virtual(n: int) -> list[float]:
    a = can.Bus(interface="virtual", channel="bench-echo")
    b = can.Bus(interface="virtual", channel="bench-echo")
    stop = threading.Event()

    def echo():
        while not stop.is_set():
            m = b.recv(0.1)
            if m is not None:
                b.send(can.Message(arbitration_id=0x581, data=m.data, is_extended_id=False))
    th = threading.Thread(target=echo, daemon=True)
    th.start()
    msg = can.Message(arbitration_id=0x601, data=bytes(8), is_extended_id=False)
    times = []
    for i in range(n + 50):
        t0 = time.perf_counter()
        a.send(msg)
        a.recv(2.0)
        if i >= 50:
            times.append(time.perf_counter() - t0)
    stop.set()
    th.join()
    a.shutdown()
    b.shutdown()
    return times


def echo_hub(n: int) -> list[float]:
    from sitl.can_hub import CanHub
    hub = CanHub()
    far = None

    def answer():
        while (m := far.recv(0)) is not None:
            far.send(can.Message(arbitration_id=0x581, data=m.data, is_extended_id=False))
    far = can.Bus(interface="virtual", channel=hub.add_channel("bench", on_input=answer))
    try:
        out = subprocess.run([sys.executable, "-c", CLIENT, hub.host, str(hub.port), str(n)], capture_output=True,
                             text=True, timeout=300, check=True).stdout
    finally:
        far.shutdown()
        hub.close()
    return json.loads(out)


class StillBody:
    """Wheels that do not turn: the SDO benchmark needs the drives, not motion."""

    def set_wheel_rates(self, left, right):
        pass

    def wheel_angles(self):
        return 0.0, 0.0

    def wheel_rates(self):
        return 0.0, 0.0


def sdo_reads(master: canopen.Network, od, n: int) -> list[float]:
    node = master.add_node(1, od)
    times = []
    for i in range(n + 20):
        t0 = time.perf_counter()
        node.sdo[0x6041].raw
        if i >= 20:
            times.append(time.perf_counter() - t0)
    return times


def sdo_virtual(n: int) -> list[float]:
    """canopen as its own tests use it: a LocalNode and a master on one virtual channel, each network with
    python-can's receive thread."""
    slave = canopen.Network().connect(interface="virtual", channel="bench-sdo")
    slave.create_node(1, P.object_dictionary(1))
    master = canopen.Network().connect(interface="virtual", channel="bench-sdo")
    try:
        return sdo_reads(master, P.object_dictionary(1), n)
    finally:
        master.disconnect()
        slave.disconnect()


def sdo_hub(n: int) -> list[float]:
    """The SITL's emulated drive behind the hub; the master's frames through the hub's TCP socket."""
    from runtime.drivers.cia402 import Cia402Config
    from sitl.devices.cia402 import Cia402Device

    dev = Cia402Device(StillBody(), Cia402Config(), robot_id=9)
    ep = dev.endpoint()
    master = canopen.Network().connect(interface="socketcand", host=ep["host"], port=ep["port"], channel=ep["channel"])
    try:
        return sdo_reads(master, P.object_dictionary(1), n)
    finally:
        master.disconnect()
        dev.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2000, help="round trips per measurement")
    args = ap.parse_args()
    rows = [("echo, one frame each way", echo_virtual(args.n), echo_hub(args.n)),
            ("canopen SDO upload of 0x6041", sdo_virtual(args.n // 4), sdo_hub(args.n // 4))]
    print(f"{'round trip':32} {'virtual (us) median / p99':>27} {'hub over TCP (us)':>25} {'ratio':>7}")
    for name, v, h in rows:
        (vm, v99), (hm, h99) = summary(v), summary(h)
        print(f"{name:32} {vm:12.0f} / {v99:8.0f}   {hm:12.0f} / {h99:8.0f}   {hm / vm:7.2f}")


if __name__ == "__main__":
    main()
