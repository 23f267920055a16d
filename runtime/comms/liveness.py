"""When a peer is lost (sans-IO), the one rule both hosts apply: a peer is lost once *nothing* from it has been
heard for more than ``comms.heartbeat_timeout``: neither the link's HEARTBEAT (1 Hz) nor any fleet message (its
RobotState goes out at 1 Hz, more while it allocates).  Once per silence; hearing it again makes it live.

Two trackers make the decision, each a :class:`Silence`:

* the host's, of HEARTBEATs: the daemon's link (:meth:`runtime.comms.link.MavlinkLink.peers_lost`) or, on the
  in-process host, :class:`runtime.inprocess.Liveness` (a :class:`Silence` fed by the heartbeats the host sends
  for each robot as its link would).  It reports a peer when its heartbeats stop (``Inbox.lost``) and names the
  peers whose heartbeats are back (``Inbox.alive``);
* the core's :class:`PeerLiveness`, of every peer message the fleet node takes.  A peer the host reported is lost
  only once its messages have been silent for the timeout too.

Why both streams: with independent loss p per datagram, a silence of the timeout T on one 1 Hz stream needs
about T losses in a row (p^T per second per peer: 1e-3 at p = 0.1, T = 3 s, about ten false losses per robot-hour
in a fleet of four), on two independent streams twice as many (p^2T: 1e-6), at the same time to detect a robot
that really stopped.  Measured in docs/architecture.md ("Peer liveness"), benchmarks/peer_liveness.py.
"""
from __future__ import annotations

import math
from collections.abc import Iterable


class Silence:
    """Peers heard once and then silent for more than ``timeout`` are due (once per silence); hearing one again
    makes it live.  ``peers`` None: any sender is a peer (the daemon's link hears robots by system id)."""

    def __init__(self, peers: Iterable[int] | None, timeout: float):
        self.peers = None if peers is None else frozenset(int(p) for p in peers)
        self.timeout = float(timeout)
        self.heard: dict[int, float] = {}
        self.lost: set[int] = set()

    def admit(self, peer: int) -> None:
        """Track ``peer`` from now on too (a robot that joined the fleet at run time)."""
        if self.peers is not None:
            self.peers |= {int(peer)}

    def hear(self, sender: int, now: float) -> None:
        if self.peers is None or sender in self.peers:
            self.heard[sender] = max(now, self.heard.get(sender, now))
            self.lost.discard(sender)

    def silent(self, peer: int, now: float) -> bool:
        return now - self.heard.get(peer, -math.inf) > self.timeout

    def due(self, now: float) -> list[int]:
        lost, timeout = self.lost, self.timeout        # silent() inlined: every robot asks every cycle
        out = sorted(p for p, t in self.heard.items() if p not in lost and now - t > timeout)
        lost.update(out)
        return out

    def alive(self, now: float) -> list[int]:
        """Peers heard within ``timeout`` (the link's ``peers_alive``)."""
        lost, timeout = self.lost, self.timeout
        return sorted(p for p, t in self.heard.items() if p not in lost and not now - t > timeout)


class PeerLiveness:
    """The core's side of the rule: the host's heartbeat verdicts joined with the peer messages the core takes.

    Each cycle: :meth:`hear` every peer message, then :meth:`due` with the host's ``lost`` (heartbeats silent now)
    and ``alive`` (heartbeats heard within the timeout) returns the peers lost now."""

    def __init__(self, peers: Iterable[int], timeout: float):
        self.messages = Silence(peers, timeout)
        self.beats_silent: set[int] = set()      # peers whose heartbeats the host reported silent, not back yet
        self.lost: set[int] = set()              # reported lost, not heard since

    def admit(self, peer: int) -> None:
        """Track ``peer`` too: a robot that joined the fleet at run time."""
        self.messages.admit(peer)

    def hear(self, sender: int, now: float) -> None:
        self.messages.hear(sender, now)
        self.lost.discard(sender)

    def due(self, now: float, beats_lost: Iterable[int] = (), beats_alive: Iterable[int] = ()) -> list[int]:
        if not self.beats_silent and isinstance(beats_lost, (list, tuple, set)) and not beats_lost:
            return []                              # no heartbeat silent, none gone silent now: nobody is due
        peers = self.messages.peers
        self.beats_silent -= set(beats_alive)
        for p in beats_lost:
            if p in peers:
                self.beats_silent.add(p)
                self.lost.discard(p)               # a new heartbeat silence: reportable again
        out = sorted(p for p in self.beats_silent if p not in self.lost and self.messages.silent(p, now))
        self.lost.update(out)
        return out
