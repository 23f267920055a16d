"""A live fuzz of a SITL fleet (issue 14, item 9): while a signed fleet runs lock-step, every daemon's MAVLink
port and the operator's ground-station socket get random, truncated and bit-flipped datagrams, and valid but
forged ones (unsigned, signed with the wrong key, replayed, and frames a robot sent its ground station replayed
to its peers).  The fleet still meets its goal, nothing raises, and every fuzz datagram is counted where it
landed (the counters reconcile datagram by datagram)."""
from __future__ import annotations

import math
import random
import socket
import time

import pytest

from runtime.allocation.formation import messages as M
from runtime.comms import codec, dialect
from runtime.comms.link import DROP_REASONS, GCS_LINK, PEER_LINK, signing_timestamp
from runtime.messages import RobotState, TaskRecord
from sitl import launcher
from tests.sitl_util import shipped_fleet

OTHER_KEY = bytes(range(1, 33))
# what only hostile datagrams give in a healthy signed fleet (genuine traffic can also be not_for_us or ignored)
BATCH = 10                  # fuzz datagrams per target and control cycle
HOSTILE = ("parse_errors", "bad_crc", "unsigned_dropped", "bad_signature_dropped", "replayed_dropped", "unknown")


class Fuzzer:
    """Sends hostile datagrams to the targets, counting per target; captures what robot 2 streams to a ground
    station (an unsigned GCS HEARTBEAT is enough to be streamed to) to replay it."""

    def __init__(self, robots: dict[int, int], seed: int = 14):
        self.rng = random.Random(seed)
        self.robots = robots
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.mod = dialect.load()
        self.sent: dict[tuple, int] = {}
        self.captured: list[bytes] = []
        self._stamp = signing_timestamp(time.time())

    def listen_to(self, rid: int) -> None:
        gcs = self.mod.MAVLink(None, srcSystem=255, srcComponent=190)
        hb = gcs.heartbeat_encode(self.mod.MAV_TYPE_GCS, self.mod.MAV_AUTOPILOT_INVALID, 0, 0, 4).pack(gcs)
        self.sock.sendto(hb, ("127.0.0.1", self.robots[rid]))

    def capture(self) -> None:
        while len(self.captured) < 200:
            try:
                self.captured.append(self.sock.recv(65535))
            except BlockingIOError:
                return

    def _forged(self) -> bytes:
        r = self.rng
        sender = r.choice(list(self.robots) + [99, 255])
        msg = r.choice([
            RobotState(sender, 0, r.randrange(0, 9), tuple(r.randrange(1, 2**24) for _ in range(r.randrange(3))),
                       r.uniform(-1e3, 1e3), math.nan, r.randrange(99), r.randrange(2**32)),
            TaskRecord(sender, 255, (sender % 251 or 1) << 16 | r.randrange(1, 9), 16, 4, r.randrange(4), 0.0, 0.0,
                       0.0, 0.0, r.uniform(-9, 9), r.uniform(-9, 9)),
            M.Price(sender, 0, r.randrange(4), sender, r.uniform(0, 1e5), 0, sender << 16 | 1),
            M.Award(sender, r.choice(list(self.robots)), r.randrange(1, 9), r.randrange(4), r.choice(list(self.robots)),
                    1.0, 1.0, 1 << 16 | 1),
        ])
        mav = self.mod.MAVLink(None, srcSystem=msg.sender, srcComponent=1)
        if r.random() < 0.5:                          # signed, with the wrong key, on any link id
            self._stamp += 1
            s = mav.signing
            s.secret_key, s.sign_outgoing, s.link_id, s.timestamp = OTHER_KEY, True, r.choice([PEER_LINK, GCS_LINK]), \
                self._stamp + 10**9 * r.random()
            s.timestamp = int(s.timestamp)
        return codec.encode(msg, mav)

    def datagram(self) -> bytes:
        r = self.rng
        kind = r.choice(["random", "forged", "replayed", "cut", "flipped"])
        if kind == "random":
            return r.randbytes(r.randrange(1, 300))
        base = r.choice(self.captured) if self.captured and kind != "forged" and r.random() < 0.7 else self._forged()
        if kind == "cut":
            return base[:r.randrange(1, len(base))]
        if kind == "flipped":
            data = bytearray(base)
            for _ in range(r.randrange(1, 4)):
                bit = r.randrange(len(data) * 8)
                data[bit // 8] ^= 1 << (bit % 8)
            return bytes(data)
        return base

    def send(self, target: tuple, n: int) -> None:
        for _ in range(n):
            self.sock.sendto(self.datagram(), target)
        self.sent[target] = self.sent.get(target, 0) + n

    def close(self) -> None:
        self.sock.close()


def recording(monkeypatch) -> list:
    """The lock-step runs ``run_lockstep`` makes from now on (their daemons and operator), as they are made."""
    runs = []

    class Recording(launcher.Lockstep):
        def __init__(self, fleet, *args, **kw):
            super().__init__(fleet, *args, **kw)
            runs.append(self)

    monkeypatch.setattr(launcher, "Lockstep", Recording)
    return runs


def hostile(c) -> int:
    return sum(getattr(c, k) for k in HOSTILE)


@pytest.mark.slow
def test_a_signed_fleet_under_live_fuzz_meets_its_goal_and_counts_every_datagram(tmp_path, monkeypatch):
    f = launcher.build(shipped_fleet(tmp_path, "create2_4.yaml"), tmp_path / "run")
    assert f.key is not None                                            # signed by default
    runs = recording(monkeypatch)
    fuzz = Fuzzer({rid: r.udp_port for rid, r in f.robots.items()})
    before = {}

    def on_step(fleet):
        run = runs[0]
        if not before:                                                  # the first cycle: counters before the fuzz
            host, port = run.op.gcs.address.rsplit(":", 1)
            fuzz.gcs = (host, int(port))
            for rid, d in run.daemons.items():
                before[rid] = d.link.counters.as_dict()
            before["gcs"] = run.op.gcs.counters.as_dict()
            fuzz.listen_to(2)
            return
        fuzz.capture()
        for rid in fleet.robots:
            fuzz.send(("127.0.0.1", fleet.robots[rid].udp_port), BATCH)
        fuzz.send(fuzz.gcs, BATCH)

    t0 = time.monotonic()
    try:
        res = launcher.run_lockstep(f, timeout=60, on_step=on_step, picture=False)
    finally:
        fuzz.close()
        f.close()
    wall = time.monotonic() - t0
    print(f"verdict: {res['verdict']} at {res['sim_time']:.1f} s sim, {wall:.1f} s wall; "
          f"{sum(fuzz.sent.values())} fuzz datagrams, {len(fuzz.captured)} captured for replay")
    assert res["goal_met"], res["verdict"]
    run = runs[0]
    counted = {rid: d.link.counters for rid, d in run.daemons.items()}
    counted["gcs"] = run.op.gcs.counters
    for who, c in counted.items():
        target = fuzz.gcs if who == "gcs" else ("127.0.0.1", f.robots[who].udp_port)
        sent = fuzz.sent[target]
        got = hostile(c) - sum(before[who][k] for k in HOSTILE)
        kernel = c.kernel_dropped - before[who]["kernel_dropped"]
        unread = BATCH                                                  # the last batch: the run ended before it
        print(who, {k: getattr(c, k) for k in ("datagrams", "received", "kernel_dropped") + DROP_REASONS})
        assert c.datagrams == c.received + c.dropped                     # one outcome per datagram
        assert sent - unread - kernel <= got <= sent, (who, sent, got, kernel)   # each fuzz datagram: hostile
    assert any(counted[rid].replayed_dropped for rid in (1, 3, 4))      # robot 2's ground-station frames, replayed
    assert counted["gcs"].bad_signature_dropped > 0                     # ... and replayed to the operator
    assert all(not d.core.node.dropped for d in run.daemons.values())        # nothing forged got past the link
    snap = run.daemons[1].snapshot()                                     # what a daemon's --stats file shows
    assert snap["link"] == counted[1].as_dict() and {"kernel_dropped", "replayed_dropped"} <= set(snap["link"])
    assert snap["fleet_dropped"] == {} and "agent_dropped" in snap
    assert wall < 60


@pytest.mark.slow
def test_an_unsigned_fleet_keeps_its_verdict_under_a_flood_of_forged_status_with_values_out_of_range(tmp_path,
                                                                                                   monkeypatch):
    """Issue 14's finding: out-of-range status to the operator's port crashed the launcher.  Unsigned (the fleet's
    choice) the operator takes only what validates: every forged frame below is invalid or from no robot of the
    fleet, and the verdict stays true."""
    f = launcher.build(shipped_fleet(tmp_path, "create2_4.yaml"), tmp_path / "run", signing=False)
    runs = recording(monkeypatch)
    mod = dialect.load()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rng = random.Random(5)
    state = {"sent": 0}

    def bad() -> bytes:
        r = rng.randrange(1, 5)
        msg = rng.choice([
            RobotState(r, 0, rng.choice([5, 9, 200]), (), 0.0, 0.0, 0, 0),                   # no such state
            RobotState(r, 0, 3, (rng.randrange(251, 65535) << 16 | 1,), 0.0, 0.0, 0, 0),     # no robot's task
            RobotState(rng.randrange(5, 251), 0, 3, (), 0.0, 0.0, 0, 0),                      # no robot of the fleet
            TaskRecord(r, 255, 0xFFFF0001, 16, 4, 1, 0, 0, 0, 0, 1.0, 1.0),                  # origin 65535
            TaskRecord(r, 255, 1 << 16 | 1, 16, 4, 7, 0, 0, 0, 0, 1.0, 1.0),                  # state 7
            TaskRecord(r, 255, 1 << 16 | 1, 16, 4, 1, 0, 0, 0, 0, math.inf, 1.0),             # position
            TaskRecord(r, 255, 1 << 16 | 1, 16, 4, 1, 0, 0, 0, 0, 1.0, 1.0, (9, 200)),        # holders
        ])
        mav = mod.MAVLink(None, srcSystem=msg.sender, srcComponent=1)
        return codec.encode(msg, mav)

    def on_step(fleet):
        run = runs[0]
        if "target" not in state:
            host, port = run.op.gcs.address.rsplit(":", 1)
            state["target"], state["before"] = (host, int(port)), run.op.gcs.counters.as_dict()
        for _ in range(BATCH):
            sock.sendto(bad(), state["target"])
        state["sent"] += BATCH

    try:
        res = launcher.run_lockstep(f, timeout=60, on_step=on_step, picture=False)
    finally:
        sock.close()
        f.close()
    assert res["goal_met"], res["verdict"]
    c = runs[0].op.gcs.counters
    before = state["before"]
    refused = (c.invalid + c.not_for_us) - (before["invalid"] + before["not_for_us"])
    print(f"verdict: {res['verdict']}; {state['sent']} forged datagrams, operator counters {c.as_dict()}")
    assert state["sent"] - BATCH - c.kernel_dropped <= refused <= state["sent"], (state["sent"], c.as_dict())
    assert c.datagrams == c.received + c.dropped
