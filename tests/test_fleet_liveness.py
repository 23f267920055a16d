"""Peer liveness (runtime/comms/liveness.py): a peer is lost once neither its heartbeats nor its messages have been
heard for the timeout, on the daemon's core and on the in-process host alike; a 10 % lossy radio no longer makes
live peers lost, and a robot that really stops is still lost within the timeout."""
from __future__ import annotations

import logging

from runtime import config as C
from runtime.drivers.base import BaseSensors
from runtime.comms.liveness import PeerLiveness, Silence
from runtime.inprocess import kinematic
from runtime.messages import RobotState
from runtime.robot.core import Inbox, RobotCore, Sensed
from runtime.robot.ports import BaseFacts


def test_silence_reports_a_peer_once_per_silence_and_names_the_live_ones():
    s = Silence([2, 3], 3.0)
    s.hear(2, 0.0)
    s.hear(3, 1.0)
    assert s.due(3.5) == [2] and s.due(3.9) == [] and s.alive(3.9) == [3]
    s.hear(2, 4.0)
    assert s.alive(4.0) == [2, 3] and s.due(7.1) == [2, 3]


def test_a_peer_whose_heartbeats_stop_but_whose_messages_come_is_not_lost_until_they_stop_too():
    live = PeerLiveness([2, 3], 3.0)
    live.hear(2, 0.0)
    live.hear(2, 2.0)                                    # a RobotState got through
    assert live.due(3.1, beats_lost=[2, 3]) == [3]       # 3: no message ever, its heartbeats silent: lost
    assert live.due(4.9) == []                           # 2: heard 2.9 s ago
    assert live.due(5.1) == [2] and live.due(9.0) == []  # silent on both streams now; once per silence


def test_a_lost_peer_heard_again_is_lost_again_after_a_new_silence():
    live = PeerLiveness([2], 3.0)
    live.hear(2, 0.0)
    assert live.due(3.1, beats_lost=[2]) == [2]
    live.hear(2, 4.0)                                    # a message: live again (heartbeats still silent)
    assert live.due(6.0) == [] and live.due(7.1) == [2]
    assert live.due(8.0, beats_alive=[2]) == []          # heartbeats back: live until they stop again
    live.hear(2, 8.0)
    assert live.due(11.5) == [] and live.due(12.0, beats_lost=[2]) == [2]


def _cfg():
    return C.from_dict(C.RobotConfig, {
        "robot": {"id": 1}, "gps": {"enabled": False}, "planning": {"planner": "euclid"},
        "comms": {"peers": [{"id": 2, "address": "127.0.0.1:14602"}]}}, "robot.yaml")


def test_the_daemons_core_keeps_a_peer_its_link_timed_out_while_its_messages_come():
    """The link reports heartbeat silence (Inbox.lost) once; the core re-auctions only when messages are silent too."""
    core = RobotCore(_cfg(), BaseFacts(radius=0.17))
    sensed = Sensed(pose=(0.0, 0.0, 0.0), sensors=BaseSensors())
    state = RobotState(2, 0, 1, (), 1.0, 1.0, 0, 0)
    core.step(0.0, sensed, Inbox(peers=[state], alive=[2]))
    core.step(2.5, sensed, Inbox(peers=[state]))
    core.step(3.5, sensed, Inbox(lost=[2]))              # heartbeats silent since 0.4 s, a message 1 s ago
    assert core.stats.peers_lost == []
    core.step(5.6, sensed, Inbox())
    assert core.stats.peers_lost == [2]


def _idle_fleet(n, **bus):
    starts = {r: (float(r), 0.0, 0.0) for r in range(1, n + 1)}
    return kinematic(starts, "auction", period=0.1, **bus)


def test_a_lossy_radio_makes_no_live_peer_lost_in_a_simulated_hour():
    """Four idle robots, 10 % of datagrams lost independently: about 40 false losses in this hour with one stream
    (heartbeats or messages alone, 1e-3 per second per peer), none expected with both (1e-6)."""
    logging.disable(logging.WARNING)
    try:
        f = _idle_fleet(4, drop=0.1, seed=3)
        f.run(3600.0)
    finally:
        logging.disable(logging.NOTSET)
    assert [p for h in f.robots.values() for p in h.core.stats.peers_lost] == []
    assert f.beats.stats.dropped > 0 and f.bus.stats.dropped > 0


def test_a_killed_robot_is_lost_by_every_peer_within_the_timeout():
    f = _idle_fleet(4, drop=0.1, seed=4)
    f.run(20.05)
    f.kill(2)
    t0 = f.now
    f.run(t0 + 10.0, stop=lambda fl: all(2 in fl.robots[r].core.stats.peers_lost for r in (1, 3, 4)))
    assert all(2 in f.robots[r].core.stats.peers_lost for r in (1, 3, 4))
    assert f.now - t0 <= 3.0 + 0.2                       # timeout, a delivery and a cycle after the last frame
