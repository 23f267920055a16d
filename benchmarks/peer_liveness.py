"""False peer loss against the time to detect a real kill, on the in-process host (runtime/inprocess.py).

An idle kinematic fleet of ``--robots`` robots runs for ``--hours`` simulated hours per seed with every datagram to
every peer lost at ``--loss`` (independently, or with ``--spell S``, in bad spells of mean S s, the link's
Gilbert-Elliott model: every copy to that peer lost during a spell, the share lost still ``--loss``; with
``--fixed`` every bad spell lasts exactly S s); every
``on_peer_lost`` of a peer that is alive is a false loss.  Then ``--kills`` times a robot is killed and the time
until every live peer has reported it lost is the detection time.  Prints rates and times, asserts nothing.

    PYTHONPATH=. python benchmarks/peer_liveness.py --robots 4 --hours 2 --loss 0.1
    PYTHONPATH=. python benchmarks/peer_liveness.py --robots 4 --hours 2 --loss 0.1 --spell 2 [--fixed]
"""
from __future__ import annotations

import argparse
import logging
import random
import statistics
from dataclasses import replace

from runtime.inprocess import kinematic
from runtime.messages import BROADCAST


class Spells:
    """Per (sender, receiver) channel: bad spells of mean ``burst`` s lose every copy, good ones of mean
    ``burst (1 - p) / p`` lose none (runtime/comms/link.py's ``_loses``); ``burst`` 0: each copy lost with p."""

    def __init__(self, p: float, burst: float, seed: int, fixed: bool = False):
        self.p, self.burst, self.rng, self.state, self.fixed = p, burst, random.Random(seed), {}, fixed

    def _spell(self, bad: bool) -> float:
        if bad and self.fixed:
            return self.burst
        return self.rng.expovariate(1.0 / self.burst if bad else self.p / (self.burst * (1.0 - self.p)))

    def loses(self, channel, now: float) -> bool:
        if not self.burst:
            return self.rng.random() < self.p
        if channel not in self.state:
            bad = self.rng.random() < self.p
            self.state[channel] = (bad, now + self._spell(bad))
        bad, until = self.state[channel]
        while until <= now:
            bad = not bad
            until += self._spell(bad)
        self.state[channel] = (bad, until)
        return bad


def lossy(bus, spells: Spells, ids) -> None:
    """``bus`` loses copies per channel by ``spells`` (its own drop set to 0)."""
    inner = bus.send
    bus.drop = 0.0

    def send(msgs, now):
        kept = []
        for m in msgs:
            for dest in ([m.dest] if m.dest != BROADCAST else [r for r in ids if r != m.sender]):
                if not spells.loses((m.sender, dest), now):
                    kept.append(replace(m, dest=dest) if m.dest == BROADCAST else m)
        inner(kept, now)

    bus.send = send


def fleet(n: int, loss: float, spell: float, seed: int, timeout: float, fixed: bool = False):
    starts = {r: (float(r), 0.0, 0.0) for r in range(1, n + 1)}
    f = kinematic(starts, "auction", seed=seed, heartbeat_timeout=timeout, period=0.1)
    spells = Spells(loss, spell, seed, fixed)
    for bus in (f.bus, getattr(f, "beats", None)):         # the agent messages, and the heartbeats if the host has them
        if bus is not None:
            lossy(bus, spells, tuple(starts))
    return f


def lost_counts(f) -> int:
    return sum(len(h.core.stats.peers_lost) for h in f.robots.values())


def false_losses(n, loss, spell, seed, hours, timeout, fixed) -> int:
    f = fleet(n, loss, spell, seed, timeout, fixed)
    f.run(hours * 3600.0)
    return lost_counts(f)


def detection(n, loss, spell, seed, timeout, fixed, rnd) -> float | None:
    """Kill a robot at a random time after a warm-up; seconds until every live peer has reported it lost."""
    f = fleet(n, loss, spell, seed, timeout, fixed)
    f.run(20.0 + rnd.uniform(0.0, 5.0))
    victim, t0 = rnd.choice(sorted(f.robots)), f.now
    f.kill(victim)
    peers = [r for r in f.robots if r != victim]
    f.run(t0 + 10 * timeout + 30.0,
          stop=lambda fl: all(victim in fl.robots[r].core.stats.peers_lost for r in peers))
    if not all(victim in f.robots[r].core.stats.peers_lost for r in peers):
        return None
    return f.now - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=4)
    ap.add_argument("--hours", type=float, default=1.0, help="simulated hours per seed for the false-loss rate")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--loss", type=float, default=0.1)
    ap.add_argument("--spell", type=float, default=0.0, help="mean bad-spell length, s (0: independent loss)")
    ap.add_argument("--fixed", action="store_true", help="bad spells last exactly --spell s")
    ap.add_argument("--timeout", type=float, default=3.0, help="comms.heartbeat_timeout, s")
    ap.add_argument("--kills", type=int, default=20)
    a = ap.parse_args()
    logging.disable(logging.WARNING)
    n_false = sum(false_losses(a.robots, a.loss, a.spell, s, a.hours, a.timeout, a.fixed) for s in range(a.seeds))
    robot_hours = a.robots * a.hours * a.seeds
    rnd = random.Random(1)
    times = [detection(a.robots, a.loss, a.spell, 1000 + k, a.timeout, a.fixed, rnd) for k in range(a.kills)]
    got = [t for t in times if t is not None]
    spell = f"{'fixed' if a.fixed else 'mean'} {a.spell} s spells" if a.spell else "independent"
    print(f"robots {a.robots}  loss {a.loss}  {spell}  timeout {a.timeout} s")
    print(f"false losses: {n_false} in {robot_hours:g} robot-hours = {n_false / robot_hours:.3g} per robot-hour")
    if got:
        print(f"kill detected by every peer: mean {statistics.mean(got):.2f} s, max {max(got):.2f} s "
              f"({len(got)}/{len(times)} kills)")


if __name__ == "__main__":
    main()
