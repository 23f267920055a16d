"""UDP beside Zenoh client/router beside Zenoh peer mesh, at N robots, in one process: the transports' cost when every
robot sends signed agent frames to every other.

Each robot is a real :class:`runtime.comms.link.MavlinkLink` (signed, the fleet key) on its transport: ``udp`` (one
socket each, every frame sent to the N-1 peer addresses), ``zenoh-client`` (one Zenoh session each, a client of one
router, a Python session in router mode in the same process; each frame published once) or ``zenoh-peer`` (sessions
in peer mode, each listening on loopback and seeded with robot 1's endpoint; Zenoh's gossip builds the mesh).  All in
this one process (N links polled in turn by one thread, which sleeps 1 ms when a pass brought nothing; Zenoh's own
threads beside it), so CPU is the whole process's (the router's included) and latency includes the wait for the
polling loop to come round (with N links, one pass of N polls and the N sends).

Per transport and N: time until every robot counts every other alive (membership: heartbeats over UDP, liveliness
tokens over Zenoh), then ``--seconds`` of traffic, every robot sending one Bid (a 39-byte signed MAVLink 2 frame) to
all at ``--rate`` Hz: deliveries per second (and the share of the N (N-1) expected), p50/p99 latency, CPU per
delivered frame and per robot-second, resident memory per robot (the process's growth over opening the links, /
N).  Then with ``--auction N`` and ``--dr N``: the epsilon auction (N goals) and paper 000's Double Round (N/5
transport objects) on in-process robot cores, first on the in-memory bus, then over each transport (Fleet(links=)),
to convergence (every task taken, the result unchanged for 2 sim s, DR 5): agent messages and frames published per
robot, sim and wall seconds to converge, and whether the result equals the in-memory bus's (:class:`Problem`).  With
``--join``: a robot joining a fleet of three robot cores at run time, how soon it is in every roster and how soon
every core reports it lost once it stops (:func:`joining`).  Prints markdown tables; asserts nothing.

    PYTHONPATH=. python benchmarks/transport_scale.py --robots 10 50 100 --seconds 4
    PYTHONPATH=. python benchmarks/transport_scale.py --robots --auction 50 100 --dr 50 100
    PYTHONPATH=. python benchmarks/transport_scale.py --robots --join
"""
from __future__ import annotations

import argparse
import logging
import math
import os
import socket
import statistics
import time

from runtime.allocation.formation import messages as M
from runtime.comms.link import MavlinkLink

KEY = bytes(range(32))
TRANSPORTS = ("udp", "zenoh-client", "zenoh-peer")


def free_port(kind=socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rss() -> float:
    """Resident memory of this process, MB."""
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


class Net:
    """N links on one transport (and the router it needs)."""

    def __init__(self, kind: str, ids, fleet: str):
        self.kind, self.router, self.links = kind, None, {}
        try:
            self._open(kind, list(ids), fleet)
        except BaseException:
            self.close()
            raise

    def _open(self, kind: str, ids: list, fleet: str) -> None:
        from runtime.comms.zenoh_transport import ZenohTransport, open_router

        if kind == "udp":
            for r in ids:                # bound to free ports first, then told each other's addresses
                self.links[r] = MavlinkLink(r, "127.0.0.1:0", [], None, signing_key=KEY)
            for r, link in self.links.items():
                link.udp.peers = [o.address for q, o in self.links.items() if q != r]
            return
        if kind == "zenoh-client":
            ep = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
            self.router = open_router([ep])
            for r in ids:
                t = ZenohTransport(r, fleet, connect=[ep], lease=3.0)
                self.links[r] = MavlinkLink(r, "127.0.0.1:0", [], None, signing_key=KEY, transport=t)
            return
        seed = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"        # robot 1's; the others any free port
        for r in ids:
            t = ZenohTransport(r, fleet, mode="peer", listen=[seed if r == ids[0] else "tcp/127.0.0.1:0"],
                               connect=[] if r == ids[0] else [seed], lease=3.0)
            self.links[r] = MavlinkLink(r, "127.0.0.1:0", [], None, signing_key=KEY, transport=t)

    def close(self) -> None:
        for link in self.links.values():
            link.close()
        if self.router is not None:
            self.router.close()


def membership(net: Net, limit: float) -> tuple[float, float]:
    """(seconds until every link counts every other alive, or inf; the share of (robot, peer) pairs alive then)."""
    n = len(net.links)
    t0 = time.monotonic()
    while True:
        now = time.monotonic()
        for link in net.links.values():
            link.poll(now)
        alive = sum(len(link.peers_alive) for link in net.links.values())
        if alive == n * (n - 1):
            return now - t0, 1.0
        if now - t0 > limit:
            return math.inf, alive / (n * (n - 1))
        time.sleep(0.005)


def traffic(net: Net, seconds: float, rate: float) -> dict:
    links = net.links
    n = len(links)
    sent: dict[tuple[int, int], float] = {}
    lat: list[float] = []
    period = 1.0 / rate
    cpu0, t0 = time.process_time(), time.monotonic()
    next_send, seq, end = t0, 0, t0 + seconds
    while True:
        now = time.monotonic()
        if now >= end + 1.0:
            break
        if now >= next_send and now < end:
            seq += 1
            for r, link in links.items():
                sent[(r, seq)] = time.monotonic()
                link.send_agent([M.Bid(r, 0, 1, seq, 0.5)], now)
            next_send += period
        got = len(lat)
        for link in links.values():
            for m in link.poll(now):
                if isinstance(m, M.Bid) and m.auction == 1:
                    lat.append(time.monotonic() - sent[(m.sender, m.task)])
        if len(lat) == got:
            time.sleep(0.001)           # nothing came: wait as a daemon between cycles does, not spin
    cpu = time.process_time() - cpu0
    expected = seq * n * (n - 1)
    lat.sort()
    return {"delivered": len(lat), "expected": expected, "per_s": len(lat) / seconds,
            "p50": lat[len(lat) // 2] if lat else math.nan, "p99": lat[int(len(lat) * 0.99)] if lat else math.nan,
            "cpu": cpu, "cpu_per_frame_us": 1e6 * cpu / max(1, len(lat)), "cpu_per_robot_s": cpu / (n * seconds),
            "peer_sent": sum(link.counters.peer_sent for link in links.values()) / n,
            "dropped": sum(link.counters.kernel_dropped + link.counters.queue_dropped for link in links.values())}


def scale(kinds, robots, seconds, rate, connect_limit) -> list[dict]:
    for kind in kinds:                  # imports, the dialect and Zenoh's runtime loaded before any row is measured
        warm = Net(kind, (1, 2), f"warm{kind.replace('-', '')}")
        membership(warm, 10.0)
        warm.close()
    rows = []
    for n in robots:
        for kind in kinds:
            m0 = rss()
            t0 = time.monotonic()
            net = Net(kind, range(1, n + 1), f"bench{n}{kind.replace('-', '')}")
            opened = time.monotonic() - t0
            try:
                t_member, share = membership(net, connect_limit)
                mem = (rss() - m0) / n
                row = {"transport": kind, "n": n, "open_s": opened, "member_s": opened + t_member,
                       "member_share": share, "mb_per_robot": mem}
                row.update(traffic(net, seconds, rate))
            finally:
                net.close()
            rows.append(row)
            print(_row(row), flush=True)
    return rows


HEAD = ("| transport | N | full membership (s) | deliveries/s | delivered | p50 (ms) | p99 (ms) | CPU/frame (us) | "
        "CPU/robot/s (ms) | frames sent/robot | MB/robot |\n|---|---|---|---|---|---|---|---|---|---|---|")


def _row(r: dict) -> str:
    member = f"{r['member_s']:.2f}" if math.isfinite(r["member_s"]) else f"never ({100 * r['member_share']:.0f} %)"
    return (f"| {r['transport']} | {r['n']} | {member} | {r['per_s']:.0f} | "
            f"{100 * r['delivered'] / max(1, r['expected']):.1f} % | {1e3 * r['p50']:.1f} | {1e3 * r['p99']:.1f} | "
            f"{r['cpu_per_frame_us']:.0f} | {1e3 * r['cpu_per_robot_s']:.1f} | {r['peer_sent']:.0f} | "
            f"{r['mb_per_robot']:.2f} |")


# ---------------------------------------------------------------------------------------------- auctions

class Problem:
    """N robots in a 20 m square and the tasks one method converges on (seeded by N): ``auction`` N goals, each held
    by one robot (cost over the Hungarian optimum reported); ``dr`` N/5 transport objects of 40 wu (paper 000's Double
    Round, default options), each led by a robot with a group.  ``result(fleet)`` is what must equal the in-memory
    bus's: the auction's task -> holder (or the robot that did it), DR's task -> its group (robots committed to it)."""

    def __init__(self, method: str, n: int):
        import random
        from runtime.tasks.goto import Goto
        from runtime.tasks.transport import Transport

        rng = random.Random(n)
        self.method, self.n = method, n
        self.starts = {r: (rng.uniform(-10, 10), rng.uniform(-10, 10), 0.0) for r in range(1, n + 1)}
        if method == "auction":
            self.tasks = [Goto(rng.uniform(-10, 10), rng.uniform(-10, 10), hold=None) for _ in range(n)]
        else:
            self.tasks = [Transport(rng.uniform(-10, 10), rng.uniform(-10, 10), 40.0, 108.0, 100.0)
                          for _ in range(max(1, n // 5))]

    def fleet(self, links=None):
        from runtime.allocation import registry
        from runtime.inprocess import Fleet, Kinematic, robot_config
        from runtime.robot.core import RobotCore
        from runtime.robot.ports import BaseFacts

        m = registry.method(self.method)
        facts = BaseFacts(radius=0.17, max_speed=0.5, ranging=True)
        cores = {r: RobotCore(robot_config(r, tuple(self.starts), m.options(), period=0.1), facts,
                              method=m, base_config=None) for r in self.starts}
        return Fleet(cores, Kinematic(self.starts, 0.5), period=0.1, links=links)

    def result(self, f) -> dict:
        if self.method == "dr":            # task -> (its leader, the robots of its group)
            lead = {c.task_id: r for r in f.live() for c in f.robots[r].agent.commitments if c.role == "leader"}
            return {t: (lead.get(t), tuple(sorted(v))) for t, v in f.holders().items()}
        out = {t: tuple(sorted(v)) for t, v in f.holders().items()}
        for t, robots in f.done().items():
            out.setdefault(t, tuple(robots))
        return out

    def summary(self, result: dict, ids) -> str:
        """The auction: % over the Hungarian optimum; DR: robots in groups, and the group sizes."""
        if self.method == "dr":
            sizes = sorted((len(g) for _, g in result.values()), reverse=True)
            return f"{sum(sizes)} robots in groups of {'/'.join(map(str, sizes))}"
        gap = self.gap(result, ids)
        return f"{gap:+.2f} % over the optimum" if math.isfinite(gap) else ""

    def whole(self, result: dict, ids) -> bool:
        """Every task taken (the auction: by one robot each)."""
        if self.method == "dr":
            return set(result) == set(ids) and all(lead is not None for lead, _ in result.values())
        return set(result) == set(ids) and all(len(v) == 1 for v in result.values())

    def gap(self, result: dict, ids) -> float:
        """% over the optimum (the auction), else NaN."""
        if self.method != "auction" or not result:
            return math.nan
        from scipy.optimize import linear_sum_assignment
        import numpy as np
        where = dict(zip(ids, self.tasks))
        got = sum(math.dist(self.starts[v[0]][:2], (where[t].x, where[t].y)) for t, v in result.items())
        c = np.array([[math.dist(self.starts[r][:2], (g.x, g.y)) for g in self.tasks] for r in sorted(self.starts)])
        rr, cc = linear_sum_assignment(c)
        return 100 * (got / float(c[rr, cc].sum()) - 1)

    def settler(self, ids):
        """A stop test: every task taken, the result unchanged for ``still`` sim seconds: 2 for the auction, 5 for DR
        (longer than one of its leaders' auctions: collecting bids, awards and the winners' confirmations, 3 s)."""
        still = 2.0 if self.method == "auction" else 5.0
        last = {"a": None, "since": 0.0}

        def settled(f) -> bool:
            a = self.result(f)
            if a != last["a"]:
                last["a"], last["since"] = a, f.now
            return self.whole(a, ids) and f.now - last["since"] >= still
        settled.last = last            # when the result last changed
        return settled


def converge(method: str, kinds, sizes, speedup: float) -> list[dict]:
    """``method`` to convergence at each size over each transport, against the in-memory bus (the class docstring
    of :class:`Problem`)."""
    rows = []
    for n in sizes:
        pb = Problem(method, n)
        ref = pb.fleet()
        ref.run(0.5)
        t0, cpu0, sent0 = time.monotonic(), time.process_time(), ref.bus.stats.sent
        ids = ref.hand_in(1, pb.tasks)
        done = pb.settler(ids)
        ref.run(120.0, stop=done)
        want = pb.result(ref)
        rows.append({"method": method, "transport": "in-memory bus", "n": n, "sim_s": done.last["since"] - 0.5,
                     "wall_s": time.monotonic() - t0, "cpu_s": time.process_time() - cpu0,
                     "frames_per_robot": math.nan, "msgs_per_robot": (ref.bus.stats.sent - sent0) / n, "lost_per_robot": 0.0,
                     "settled": done(ref), "same": True, "differ": 0, "tasks": len(ids), "summary": pb.summary(want, ids)})
        print(_auction_row(rows[-1]), flush=True)
        for kind in kinds:
            net = Net(kind, pb.starts, f"{method}{n}{kind.replace('-', '')}")
            try:
                f = pb.fleet(net.links)
                membership(net, 60.0)
                msgs = {"n": 0}
                inner = f.bus.send

                def count(batch, now):
                    msgs["n"] += len(batch)
                    inner(batch, now)
                f.bus.send = count
                sent0 = {r: link.counters.peer_sent for r, link in net.links.items()}
                lost0 = _lost(net)
                t0, s0, cpu0 = time.monotonic(), f.now, time.process_time()

                def pace(fl):
                    ahead = (fl.now - s0) / speedup - (time.monotonic() - t0)
                    if ahead > 0:
                        time.sleep(ahead)
                ids = f.hand_in(1, pb.tasks)
                done = pb.settler(ids)
                f.run(f.now + 120.0, stop=done, observe=pace)
                got = pb.result(f)
                per = [net.links[r].counters.peer_sent - sent0[r] for r in pb.starts]
                rows.append({"method": method, "transport": kind, "n": n, "sim_s": done.last["since"] - s0,
                             "wall_s": time.monotonic() - t0, "cpu_s": time.process_time() - cpu0,
                             "frames_per_robot": statistics.mean(per), "msgs_per_robot": msgs["n"] / n,
                             "lost_per_robot": (_lost(net) - lost0) / n,
                             "settled": done(f), "same": got == want, "summary": pb.summary(got, ids), "tasks": len(ids),
                             "differ": sum(got.get(t) != want.get(t) for t in ids)})
                print(_auction_row(rows[-1]), flush=True)
            finally:
                net.close()
    return rows


def _lost(net: Net) -> int:
    """Frames the links lost on receipt: the kernel's and the queue's overflows, and frames refused as replays."""
    return sum(k.counters.kernel_dropped + k.counters.queue_dropped + k.counters.bad_signature_dropped
               + k.counters.replayed_dropped for k in net.links.values())


AUCTION_HEAD = ("| method | transport | N | converged | sim s to the final result | wall s | CPU s | agent messages/robot | "
                "frames sent/robot | frames lost on receipt/robot | = in-memory result | result |\n"
                "|---|---|---|---|---|---|---|---|---|---|---|---|")


def _auction_row(r: dict) -> str:
    same = "True" if r["same"] else f"False ({r['differ']} of {r['tasks']} tasks differ)"
    frames = f"{r['frames_per_robot']:.0f}" if math.isfinite(r["frames_per_robot"]) else ""
    return (f"| {r['method']} | {r['transport']} | {r['n']} | {r['settled']} | {r['sim_s']:.1f} | {r['wall_s']:.1f} | "
            f"{r['cpu_s']:.1f} | {r['msgs_per_robot']:.1f} | {frames} | {r['lost_per_robot']:.1f} | {same} | {r['summary']} |")


# ---------------------------------------------------------------------------------------------- loss detection

def detect(timeout: float = 3.0) -> None:
    """How soon a peer that stops is reported lost by the link (``peers_lost``), wall clock: over UDP when its
    heartbeats stop; over Zenoh when its process is frozen (SIGSTOP: its socket stays open, as a robot out of radio
    range; the router drops it when its lease, ``comms.heartbeat_timeout``, runs out) and when it is killed (its
    socket closed)."""
    import signal
    import subprocess
    import sys
    from runtime.comms.zenoh_transport import ZenohTransport, open_router

    for trial in range(3):
        ports = free_port(), free_port()
        a = MavlinkLink(1, f"127.0.0.1:{ports[0]}", [f"127.0.0.1:{ports[1]}"], None, heartbeat_timeout=timeout)
        b = MavlinkLink(2, f"127.0.0.1:{ports[1]}", [f"127.0.0.1:{ports[0]}"], None, heartbeat_timeout=timeout)
        stop = time.monotonic() + 2.3 + 0.3 * trial
        while True:
            now = time.monotonic()
            if now < stop:
                b.poll(now)
            a.poll(now)
            if a.peers_lost(now):
                print(f"udp: heartbeats stopped, lost after {now - stop:.2f} s (timeout {timeout} s)")
                break
            time.sleep(0.005)
        a.close()
        b.close()
    ep = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    router = open_router([ep])
    for how in (signal.SIGSTOP, signal.SIGKILL):
        a = MavlinkLink(1, "127.0.0.1:0", [], None, heartbeat_timeout=timeout,
                        transport=ZenohTransport(1, "detect", connect=[ep], lease=timeout))
        child = subprocess.Popen([sys.executable, "-c", (
            "from runtime.comms.zenoh_transport import ZenohTransport\nimport time\n"
            f"t = ZenohTransport(2, 'detect', connect=['{ep}'], lease={timeout})\nprint('up', flush=True)\n"
            "time.sleep(600)\n")], stdout=subprocess.PIPE, text=True)
        child.stdout.readline()
        t0 = time.monotonic()
        while 2 not in a.peers_alive and time.monotonic() - t0 < 10:
            a.poll(time.monotonic())
            time.sleep(0.01)
        child.send_signal(how)
        t0 = time.monotonic()
        while time.monotonic() - t0 < 30:
            now = time.monotonic()
            a.poll(now)
            if 2 in a.peers_lost(now):
                print(f"zenoh: {signal.Signals(how).name}, lost after {now - t0:.2f} s (lease {timeout} s)")
                break
            time.sleep(0.005)
        child.kill()
        child.wait()
        a.close()
    router.close()


# ---------------------------------------------------------------------------------------------- joining

def _paced(f, until: float, stop) -> None:
    """``f.run`` to ``until`` (sim s) with its clock held to wall time (one sim second per wall second)."""
    t0, s0 = time.monotonic(), f.now

    def pace(fl):
        ahead = (fl.now - s0) - (time.monotonic() - t0)
        if ahead > 0:
            time.sleep(ahead)
    f.run(until, stop=stop, observe=pace)


def joining(trials: int = 3, timeout: float = 3.0) -> None:
    """How soon a robot that joins a running fleet of three is in every robot core's roster (and they in its), and
    how soon every core reports it lost once it stops, wall clock (the fleet's clock held to wall time; robot cores of
    the auction method on real signed links, :class:`runtime.inprocess.Fleet` with ``links``).  Over Zenoh (one
    router): the joiner's config names no peers; it stops with its session closed (killed) or with its session open
    and its cycles stopped (hung: its connection up, nothing sent).  Over UDP, which takes no joins, the fourth robot
    is configured from the start and killed, for the loss bound the joins must keep.  Each trial starts the join and
    the stop at another point of the 1 s heartbeat period."""
    from runtime.comms.zenoh_transport import ZenohTransport, open_router
    from runtime.inprocess import Fleet, Kinematic, kinematic_core

    PERIOD = 0.05                    # the daemon's control period (20 Hz): the cores notice at their next cycle
    starts = {1: (0.0, 0.0, 0.0), 2: (2.0, 0.0, 0.0), 3: (0.0, 2.0, 0.0), 4: (2.0, 2.0, 0.0)}
    print(f"| transport | how it stopped | session open (s) | its token/heartbeat at every link after (s) | in every "
          f"core's roster after (s) | the fleet in its roster after (s) | lost by every link after (s) | "
          f"lost by every core after (s) | bound |\n|---|---|---|---|---|---|---|---|---|")

    def lost_times(f, victim, links, t_stop):
        at_link, at_core = {}, {}

        def stop(fl):
            now = time.monotonic() - t_stop
            for r in (1, 2, 3):
                if r not in at_link and victim in getattr(links[r], "_beats").lost:
                    at_link[r] = now
                if r not in at_core and victim in fl.robots[r].core.stats.peers_lost:
                    at_core[r] = now
            return len(at_core) == 3
        _paced(f, f.now + 4 * timeout, stop)
        return max(at_link.values(), default=math.nan), max(at_core.values(), default=math.nan)

    for how in ("killed", "hung"):
        for trial in range(trials):
            ep = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
            router = open_router([ep])
            links = {}
            try:
                def link(r):
                    return MavlinkLink(r, "127.0.0.1:0", [], None, signing_key=KEY, heartbeat_timeout=timeout,
                                       transport=ZenohTransport(r, "join", connect=[ep], lease=timeout))
                for r in (1, 2, 3):
                    links[r] = link(r)
                cores = {r: kinematic_core(r, (1, 2, 3), "auction", period=PERIOD, heartbeat_timeout=timeout, joins=True)
                         for r in (1, 2, 3)}
                f = Fleet(cores, Kinematic({r: starts[r] for r in (1, 2, 3)}, 0.5), period=PERIOD, links=links)
                _paced(f, 20.0, lambda fl: all(len(k.peers_alive) == 2 for k in links.values()))
                _paced(f, f.now + 1.0 + 0.3 * trial, None)
                t0 = time.monotonic()
                links[4] = link(4)
                opened = time.monotonic() - t0
                f.join(kinematic_core(4, (4,), "auction", period=PERIOD, heartbeat_timeout=timeout, joins=True),
                       starts[4], links[4])
                t1, s1 = time.monotonic(), f.now
                seen, alive = {}, {}

                def everyone(fl):
                    now = time.monotonic() - t1
                    for r in (1, 2, 3):
                        if r not in seen and 4 in fl.robots[r].core.roster:
                            seen[r] = now
                        if r not in alive and 4 in links[r].peers_alive:
                            alive[r] = now
                    if 4 not in seen and fl.robots[4].core.roster == {1, 2, 3}:
                        seen[4] = now
                    return len(seen) == 4 and len(alive) == 3
                _paced(f, f.now + 10.0, everyone)
                _paced(f, s1 + 2.0 + 0.3 * trial, None)      # stopping at another point of its 1 s schedule
                t_stop = time.monotonic()
                if how == "killed":
                    f.kill(4)                        # its session closes
                else:
                    f.bus.down.add(4)                # nothing sent or polled again; its session stays open
                    f.motion.remove(4)
                link_lost, core_lost = lost_times(f, 4, links, t_stop)
                fleet = max(seen[r] for r in (1, 2, 3))
                print(f"| zenoh | {how} | {opened:.3f} | {max(alive.values()):.2f} | {fleet:.2f} | {seen[4]:.2f} | "
                      f"{link_lost:.2f} | {core_lost:.2f} | {timeout:g} s after its last message |", flush=True)
            finally:
                for k in links.values():
                    k.close()
                router.close()
    for trial in range(trials):                  # the in-process host's in-memory bus (10 ms delay), sim time
        from runtime.inprocess import kinematic
        f = kinematic({r: starts[r] for r in (1, 2, 3)}, "auction", period=PERIOD, heartbeat_timeout=timeout,
                      joins=True)
        f.run(1.0 + 0.3 * trial)
        s1 = f.now
        f.join(kinematic_core(4, (4,), "auction", period=PERIOD, heartbeat_timeout=timeout, joins=True), starts[4])
        f.run(s1 + 5.0, stop=lambda fl: all(4 in fl.robots[r].core.roster for r in (1, 2, 3)))
        fleet = f.now - s1
        f.run(s1 + 5.0, stop=lambda fl: fl.robots[4].core.roster == {1, 2, 3})
        mine = f.now - s1
        f.run(s1 + 2.0 + 0.3 * trial)
        s2 = f.now
        f.kill(4)
        f.run(s2 + 4 * timeout, stop=lambda fl: all(4 in fl.robots[r].core.stats.peers_lost for r in (1, 2, 3)))
        print(f"| in-memory bus (sim s) | killed | | | {fleet:.2f} | {mine:.2f} | | {f.now - s2:.2f} | "
              f"{timeout:g} s after its last message |", flush=True)
    for trial in range(trials):
        links = {r: MavlinkLink(r, "127.0.0.1:0", [], None, signing_key=KEY, heartbeat_timeout=timeout)
                 for r in starts}
        try:
            for r, k in links.items():
                k.udp.peers = [o.address for q, o in links.items() if q != r]
            cores = {r: kinematic_core(r, tuple(starts), "auction", period=PERIOD, heartbeat_timeout=timeout)
                     for r in starts}
            f = Fleet(cores, Kinematic(starts, 0.5), period=PERIOD, links=links)
            _paced(f, 20.0, lambda fl: all(len(k.peers_alive) == 3 for k in links.values()))
            _paced(f, f.now + 2.0 + 0.3 * trial, None)
            t_stop = time.monotonic()
            f.kill(4)
            link_lost, core_lost = lost_times(f, 4, links, t_stop)
            print(f"| udp | killed (configured, no join) | | | | | {link_lost:.2f} | {core_lost:.2f} | "
                  f"{timeout:g} s after its last message |", flush=True)
        finally:
            for k in links.values():
                k.close()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--robots", type=int, nargs="*", default=[10, 50, 100])
    p.add_argument("--transports", nargs="*", default=list(TRANSPORTS), choices=TRANSPORTS)
    p.add_argument("--seconds", type=float, default=4.0, help="of traffic per row")
    p.add_argument("--rate", type=float, default=5.0, help="frames per robot per second")
    p.add_argument("--connect-limit", type=float, default=60.0, help="s to wait for full membership")
    p.add_argument("--auction", type=int, nargs="*", default=[], help="fleet sizes for the auction runs")
    p.add_argument("--dr", type=int, nargs="*", default=[], help="fleet sizes for the Double Round runs")
    p.add_argument("--speedup", type=float, default=2.0, help="auction and dr runs: sim seconds per wall second")
    p.add_argument("--detect", action="store_true", help="also time how soon a stopped peer is reported lost")
    p.add_argument("--join", action="store_true", help="also time how soon a robot joining a fleet of robot cores "
                   "is in every roster, and how soon every core reports it lost once it stops")
    args = p.parse_args()
    logging.disable(logging.WARNING)
    if args.robots:
        print(HEAD)
        scale(args.transports, args.robots, args.seconds, args.rate, args.connect_limit)
    if args.auction or args.dr:
        print(AUCTION_HEAD)
    for method, sizes in (("auction", args.auction), ("dr", args.dr)):
        converge(method, args.transports, sizes, args.speedup)
    if args.detect:
        detect()
    if args.join:
        joining()


if __name__ == "__main__":
    main()
