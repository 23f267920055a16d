"""Forged and replayed messages change nothing and are counted (issue 14, items 4 and 5).

Unsigned fleets (a fleet can still choose so) on the in-memory bus (runtime/inprocess.py: robot cores with kinematic motion), the forgeries
going through the codec as a daemon's link would decode them: forged Prices do not livelock the epsilon auction
nor raise its cost, a forged task set does not send a robot to an attacker's point, forged Awards do not leave
two robots on one task under BS.  What no check can tell from a genuine message without signing (values within
the protocol under a fleet robot's id) is dropped by signing: the wire tests at the end."""
from __future__ import annotations

import math
import time
from collections import Counter

import pytest

from runtime.allocation.formation import messages as M
from runtime.comms import codec, dialect
from runtime.comms.link import GCS_LINK, MavlinkLink, signing_timestamp
from runtime.messages import DONE, OPEN, RobotState, TaskRecord
from runtime.inprocess import Fleet, kinematic
from runtime.tasks.goto import Goto

STARTS = {1: (-3.0, -3.0), 2: (-3.0, 3.0), 3: (3.0, -3.0), 4: (3.0, 3.0)}
POSITIONS = [(0.0, 1.5), (1.5, 0.0), (0.0, -1.5), (-1.5, 0.0)]
ATTACKER_POINT = (4.5, 4.5)
KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))
NAV_WAYPOINT, LOCAL_ENU = 16, 4


def decoded(msg):
    """``msg`` as a daemon's codec hands it on after decoding its frame, or None: refused at decode (``invalid``)."""
    mod = dialect.load()
    mav = mod.MAVLink(None, srcSystem=msg.sender, srcComponent=1)
    frame = codec.encode(msg, mav)
    parser = mod.MAVLink(None, srcSystem=0, srcComponent=0)
    try:
        return codec.from_mavlink(parser.parse_buffer(frame)[0])
    except codec.InvalidMessage:
        return None


def drops(f: Fleet) -> Counter:
    """Every robot's drops by reason: its node, its agent, the solvers of its rounds."""
    out: Counter = Counter()
    for r in f.robots.values():
        out += r.node.dropped
        out += r.agent.dropped
        for rnd in r.agent.rounds.values():
            out += rnd.solver.dropped
    return out


class Forger:
    """Puts forged messages on the bus as a host on the fleet's network would (they go through the codec)."""

    def __init__(self, f: Fleet):
        self.f = f
        self.refused_at_decode = 0

    def send(self, msgs) -> None:
        for msg in msgs:
            got = decoded(msg)
            if got is None:
                self.refused_at_decode += 1
            else:
                self.f.bus.send([got], self.f.now)


def formation(method: str, positions=POSITIONS) -> tuple[Fleet, list[int]]:
    f = kinematic(STARTS, method=method)
    f.run(0.5)
    ids = f.hand_in(1, [Goto(x, y, hold=None) for x, y in positions])      # station keeping: never done
    return f, ids


def held(f: Fleet) -> dict[int, tuple[int, ...]]:
    return {rid: tuple(c.task_id for c in r.agent.commitments) for rid, r in f.robots.items()}


def cost(f: Fleet, ids, assignment) -> float:
    return sum(math.dist(STARTS[r], POSITIONS[ids.index(t[0])]) for r, t in assignment.items())


def round_of(f: Fleet) -> int | None:
    """The round every robot has joined, once they all have."""
    common = set.intersection(*(set(r.agent.rounds) for r in f.robots.values()))
    return min(common) if common else None


def test_forged_prices_neither_livelock_the_epsilon_auction_nor_raise_its_cost():
    base, ids = formation("auction")
    base.run(60.0)
    want = held(base)
    assert all(len(t) == 1 for t in want.values()) and all(r.agent.converged for r in base.robots.values())

    f, ids = formation("auction")
    f.run(30.0, stop=lambda fl: round_of(fl) is not None)
    rid = round_of(f)
    assert rid is not None and any(r.agent.allocating for r in f.robots.values())   # forged mid-auction
    unclaimed = next(t for t in range(4) if t != f.robots[1].agent.rounds[rid].solver.held)
    before = drops(f)
    forger = Forger(f)
    forger.send([            # within the wire's ranges: without the checks they livelocked this auction
        M.Price(99, 0, 0, 99, 1e5, 0, rid),          # from no robot of the fleet
        M.Price(98, 0, 1, 98, 2e5, 0, rid),          # from no robot of the fleet
        M.Price(2, 0, 2, 7, 3e5, 0, rid),            # held by a robot that is not in the round
        M.Price(2, 0, 3, 3, 4e5, 0, rid),            # held by another robot than its sender
        M.Price(3, 0, 0, 4, 5e5, 0, rid),            # held by another robot than its sender
        M.Price(3, 0, 9, 3, 6e5, 0, rid),            # a task index beyond the round's four
        M.Price(4, 0, 1, 4, 5e6, 0, rid),            # a price beyond the protocol's range
        M.Price(4, 0, 2, 4, -40.0, 0, rid),          # a negative price
        M.Price(2, 1, unclaimed, 1, 7e5, 0, rid),    # names its recipient holder of a task it does not claim
    ])
    f.run(f.now + 0.1)
    got = drops(f) - before
    assert forger.refused_at_decode == 2
    assert got["not a robot of the fleet"] == 2 * 4                   # every robot hears robots 99 and 98
    assert got["robot not in the round"] == 3                         # the others hear robot 2
    assert got["price held by a robot other than its sender"] == 3 + 3 + 1
    assert got["task not in the round"] == 3
    f.run(60.0)
    assert held(f) == want                                            # the same assignment, so the same cost
    assert cost(f, ids, held(f)) == pytest.approx(cost(base, ids, want))
    assert all(r.agent.converged for r in f.robots.values())
    assert f.bus.stats.sent < 2 * base.bus.stats.sent                 # no price war


def test_a_forged_task_set_does_not_send_a_robot_to_an_attackers_point():
    """Three tasks, four robots: one robot is free and would take any task the table gained."""
    f, ids = formation("auction", POSITIONS[:3])
    f.run(30.0, stop=lambda fl: round_of(fl) is not None)
    rid = round_of(f)
    genuine = f.robots[1].node.table.entries[ids[0]]
    x, y = ATTACKER_POINT
    record = dict(command=NAV_WAYPOINT, frame=LOCAL_ENU, state=OPEN, param1=0.0, param2=0.0, param3=0.0,
                  param4=math.nan, x=x, y=y)
    before = drops(f)
    forger = Forger(f)
    forger.send([
        TaskRecord(99, 0, 99 << 16 | 1, **record),                   # from no robot of the fleet
        TaskRecord(2, 0, 77 << 16 | 1, **record),                    # a task no robot of the fleet minted
        TaskRecord(2, 0, genuine.id, **{**record, "state": DONE}),   # a known task, elsewhere, "done"
        TaskRecord(2, 0, 2 << 16 | 9, **{**record, "x": math.inf}),  # refused at decode
        M.TaskInfo(1, 0, 0, x, y, 3, rid),                           # the round's task 0 somewhere else
        M.TaskInfo(1, 0, 0, *POSITIONS[0], 9, rid),                  # a round of nine tasks?
        M.RoundStart(2, 0, 3 << 16 | 5, (ids[0],), (2, 3)),          # a round id that is not its sender's
        M.RoundStart(2, 0, 2 << 16 | 5, (ids[0],), (2, 3, 42)),      # robot 42 is no robot of the fleet
    ])
    f.run(f.now + 0.1)
    got = drops(f) - before
    assert forger.refused_at_decode == 1
    assert got["not a robot of the fleet"] == 4
    assert got["a task no robot of the fleet minted"] == 3
    assert got["contradicts the task table"] == 3
    assert got["contradicts the round's task set"] == 2 * 3
    assert got["round start outside the protocol"] == 2              # robot 3 is named in both; 2 sent them
    seen = []

    def watch(fl):
        for r in fl.robots.values():
            for c in r.agent.commitments:
                e = r.node.table.entries[c.task_id]
                seen.append((c.task.position == (e.x, e.y), c.task.position))
    f.run(60.0, observe=watch)
    assert seen and all(ok for ok, _ in seen)
    assert all(pos != ATTACKER_POINT for _, pos in seen)
    assert all(set(r.node.table.entries) == set(ids) for r in f.robots.values())
    assert all(f.table_state(t) == OPEN for t in ids)
    assert sorted(t for h in held(f).values() for t in h) == sorted(ids)


def test_forged_awards_do_not_put_two_robots_on_one_task_under_bs():
    f, ids = formation("bs")
    f.run(60.0)
    first = held(f)
    assert sorted(t[0] for t in first.values()) == sorted(ids)
    rid = round_of(f)
    # a robot that bid in an auction it did not win, for a task cheaper to it than its own (so it would keep it)
    taker, seller, auction, bid = min(
        (r, s, a, b) for r, robot in f.robots.items() for sol in [robot.agent.rounds[rid].solver]
        for (s, a), b in sol._bids_sent.items()
        if (s, a) not in sol._awards_seen and b.task != sol.assignment and b.cost < sol.won[sol.assignment])
    task = f.robots[taker].agent.rounds[rid].tasks[bid.task]
    holder = next(r for r, h in first.items() if h == (task,))
    before = drops(f)
    forger = Forger(f)
    forger.send([
        M.Award(seller, taker, auction, bid.task, taker, bid.cost + 1.0, bid.cost, rid),   # a cost never bid
        M.Award(seller, taker, 98765, bid.task, taker, bid.cost, bid.cost, rid),           # an auction not bid in
        M.Award(seller, taker, auction, bid.task, 9, bid.cost, bid.cost, rid),             # winner not in the round
        M.Award(77, taker, auction, bid.task, taker, bid.cost, bid.cost, rid),             # no robot of the fleet
        M.Award(seller, taker, auction, bid.task, taker, math.inf, bid.cost, rid),         # refused at decode
    ])
    f.run(f.now + 0.1)
    got = drops(f) - before
    assert forger.refused_at_decode == 1
    assert got["award at a cost I did not bid"] == 1 and got["award without bid"] == 1
    assert got["robot not in the round"] == 1 and got["not a robot of the fleet"] == 1
    assert held(f) == first
    # An award at the taker's own bid in its auctioneer's name cannot be told from a genuine one without signing:
    # the taker keeps the cheaper task, which another robot holds.  Once both have settled, the lower id keeps it.
    forger.send([M.Award(seller, taker, auction, bid.task, taker, bid.cost, bid.cost, rid)])
    f.run(f.now + 0.1)
    assert held(f)[taker] == (task,) == held(f)[holder]                # two robots on one task, for now
    f.run(f.now + 60.0)
    now = held(f)
    assert all(len(h) == 1 for h in now.values())
    assert sorted(h[0] for h in now.values()) == sorted(ids), now       # one robot per task again


def test_forged_coalition_messages_neither_block_a_task_nor_break_a_coalition():
    """Coalition method: a CoalitionDone for a task not handed in yet (without the check it kept that task from
    ever being offered), or from a robot that is not the auctioneer (it broke a coalition on its way), and a
    TaskOffer placing a task elsewhere than the fleet table: ignored and counted; the task is done."""
    from runtime.allocation.coalition.wdp_messages import CoalitionDone, TaskOffer
    from runtime.tasks.rendezvous import Rendezvous

    f = kinematic(STARTS, method="coalition")
    f.run(0.5)

    def ignored(fl):
        return sum(r.agent.member.stats.ignored + r.agent.auction.stats.ignored + r.agent.member.stats.contradicting
                   for r in fl.robots.values())

    forger = Forger(f)
    before = ignored(f)
    forger.send([CoalitionDone(1, 0, 1 << 16 | 1, 1 << 16 | 1, (2, 3))])     # the id the next task will get
    f.run(f.now + 0.1)
    assert ignored(f) - before == 3
    (task,) = f.hand_in(1, [Rendezvous(0.0, 0.0, 2, 100.0)])
    assert task == 1 << 16 | 1
    f.run(60.0, stop=lambda fl: sum(bool(r.agent.member.job) for r in fl.robots.values()) == 2)
    members = {rid for rid, r in f.robots.items() if r.agent.member.job}
    assert len(members) == 2
    job = f.robots[min(members)].agent.member.job
    before = ignored(f)
    outsider = next(r for r in f.robots if r not in members and r != 1)
    forger.send([CoalitionDone(outsider, 0, job.round, task, job.robots),             # not the auctioneer
                 TaskOffer(1, 0, job.round + 1, task, *ATTACKER_POINT, 1, 99.0, (1, 2, 3, 4))])
    f.run(f.now + 0.1)
    assert all(f.robots[r].agent.member.job is not None for r in members)          # the coalition holds
    assert ignored(f) - before >= len(members)
    f.run(200.0, stop=lambda fl: fl.table_state(task) == DONE)
    assert f.table_state(task) == DONE and sorted(f.done()[task]) == sorted(members)


# ------------------------------------------------------------------------------ on the wire: signing drops them

def _frame(msg, key=None, link_id=0, stamp=None) -> bytes:
    mod = dialect.load()
    mav = mod.MAVLink(None, srcSystem=msg.sender, srcComponent=1)
    if key is not None:
        mav.signing.secret_key, mav.signing.sign_outgoing, mav.signing.link_id = key, True, link_id
        mav.signing.timestamp = stamp or signing_timestamp(time.time())
    return codec.encode(msg, mav)


def test_signing_drops_forgeries_in_a_fleet_robots_name_that_no_check_could_tell():
    """Within the protocol and in a fleet robot's name: a Price at a plausible price, a task record of a new
    task at the attacker's point, an award at the winner's own bid.  Unsigned, with the wrong key, replayed, or
    replayed from what the robot sent its ground station: each dropped and counted; the genuine frame passes."""
    rx = MavlinkLink(1, "127.0.0.1:0", [], signing_key=KEY)
    try:
        forged = [M.Price(2, 0, 1, 2, 900.0, 0, 2 << 16 | 1),
                  TaskRecord(2, 0, 2 << 16 | 7, NAV_WAYPOINT, LOCAL_ENU, OPEN, 0, 0, 0, 0, *ATTACKER_POINT),
                  M.Award(2, 1, 3, 0, 1, 4.25, 4.0, 2 << 16 | 1)]
        stamp = signing_timestamp(time.time())
        for k, msg in enumerate(forged):
            assert rx.feed(_frame(msg), 0.0) == []                                  # unsigned
            assert rx.feed(_frame(msg, OTHER_KEY, stamp=stamp + 10 * k), 0.0) == []  # the wrong key
            assert rx.feed(_frame(msg, KEY, GCS_LINK, stamp + 10 * k), 0.0) == []     # signed for the GCS
        genuine = _frame(M.Price(2, 0, 1, 2, 3.5, 0, 2 << 16 | 1), KEY, 0, stamp + 100)
        assert [m.price for m in rx.feed(genuine, 0.0)] == [3.5]
        assert rx.feed(genuine, 0.0) == []                                           # replayed
        c = rx.counters
        assert (c.unsigned_dropped, c.bad_signature_dropped, c.replayed_dropped) == (3, 3 + 1, 3)
        assert c.received == 1 and c.datagrams == c.received + c.dropped
    finally:
        rx.close()


def test_a_frame_captured_on_the_ground_station_side_and_replayed_to_a_peer_is_dropped():
    """Robot 2 streams to a ground station (here a bare socket): its signed HEARTBEAT and RobotState replayed to
    robot 1 neither count as robot 2's liveness nor reach robot 1's node; its peer traffic still does."""
    import socket

    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(2.0)
    a = MavlinkLink(1, "127.0.0.1:0", [], signing_key=KEY)
    b = MavlinkLink(2, "127.0.0.1:0", [f"127.0.0.1:{a.address[1]}"], "127.0.0.1:%d" % gcs.getsockname()[1],
                    signing_key=KEY)
    try:
        assert b.send_gcs(b.heartbeat()) and b.send_gcs(RobotState(2, 0, 1, (), 0.0, 0.0, 0, 0))
        captured = [gcs.recvfrom(65535)[0] for _ in range(2)]
        assert all(frame[-13] == GCS_LINK for frame in captured)
        for frame in captured:
            assert a.feed(frame, 1.0) == []
        assert a.counters.replayed_dropped == 2 and a.peers_alive == []
        b.poll(1.0)                                      # its peer HEARTBEAT (link 0)
        b.send_agent([M.Bid(2, 1, 1, 0, 2.0)], 1.0)
        got, t0 = [], time.monotonic()
        while not got and time.monotonic() - t0 < 2:
            got = a.poll(1.0)
        assert got == [M.Bid(2, 1, 1, 0, 2.0)] and a.peers_alive == [2]
    finally:
        for s in (a, b, gcs):
            s.close()


# ------------------------------------------------------------ every private message type of every family, unsigned

def _forgeries(msg, rng, fleet_ids) -> list:
    """Three forgeries of a genuine message, each within the protocol: the same message in another fleet robot's name;
    in its sender's name with every amount scaled (x0.3-3) and every flag flipped; and with every amount at the
    protocol's largest value (1e6: a Price there was the issue's attack)."""
    import dataclasses
    ids = ("sender", "dest", "task", "round", "auction", "holder", "winner", "robot", "phase", "n_tasks", "command",
           "frame", "state", "seq", "reason")
    out = []
    others = [r for r in fleet_ids if r not in (msg.sender, msg.dest)]
    if others:
        out.append(dataclasses.replace(msg, sender=rng.choice(others)))
    scaled, top = {}, {}
    for f in dataclasses.fields(msg):
        v = getattr(msg, f.name)
        if isinstance(v, bool):
            scaled[f.name] = not v
        elif isinstance(v, float) and f.name not in ids and math.isfinite(v):
            scaled[f.name] = v * rng.uniform(0.3, 3.0) + rng.uniform(-1.0, 1.0)
            if f.name not in ("x", "y"):
                top[f.name] = 1e6
    out += [dataclasses.replace(msg, **c) for c in (scaled, top) if c]
    return out


def _made_up(cls, seen: dict, rng, fleet_ids):
    """A message of a type the run never sent: its ids taken from the family's messages that were sent, robots from
    the fleet, amounts plausible (1-20)."""
    import dataclasses
    import typing
    values = {}
    for m in seen.values():
        values.update({k: v for k, v in vars(m).items() if k not in ("sender", "dest")})
    hints = typing.get_type_hints(cls)
    kw = {"sender": rng.choice(fleet_ids), "dest": 0}
    for f in dataclasses.fields(cls):
        if f.name in kw:
            continue
        base = typing.get_origin(hints[f.name]) is typing.Annotated and typing.get_args(hints[f.name])[0] \
            or hints[f.name]
        if f.name in values and isinstance(values[f.name], base if isinstance(base, type) else object):
            kw[f.name] = values[f.name]
        elif base is bool:
            kw[f.name] = True
        elif base is float:
            kw[f.name] = rng.uniform(1.0, 20.0)
        elif base is int:
            kw[f.name] = 1
        else:
            kw[f.name] = tuple(fleet_ids)
    return cls(**kw)


class EveryType:
    """Forges every message type of a fleet on the bus as it goes: the first genuine one of each type in each of
    ``phases`` (s) is forged three ways (:func:`_forgeries`) 0.2 s later; at ``late`` s every type of ``types`` that
    was never sent is made up (:func:`_made_up`) and put on the bus.  Genuine messages go through the codec too, as
    on the wire (a value the protocol refuses is lost)."""

    def __init__(self, f: Fleet, types, phases=(0.0, 4.0, 10.0), late=12.0, seed=0):
        import random
        self.f, self.types, self.phases, self.late = f, tuple(types), phases, late
        self.rng = random.Random(seed)
        self.ids = sorted(f.robots)
        self.seen: dict = {}
        self.forged: Counter = Counter()
        self.refused: Counter = Counter()
        self.genuine_refused: Counter = Counter()
        self._done: set = set()
        self._due: list = []
        self._made = False
        send = f.bus.send

        def wired(msgs, now):
            out = []
            for m in msgs:
                got = decoded(m)
                if got is None:
                    self.genuine_refused[type(m).__name__] += 1
                    continue
                out.append(got)
                self._note(got, now)
            if now >= self.late and not self._made:
                self._made = True
                self._due += [(now, _made_up(c, self.seen, self.rng, self.ids)) for c in self.types
                              if c.__name__ not in self.seen]
            for t, m in [d for d in self._due if d[0] <= now]:
                self._due.remove((t, m))
                got = decoded(m)
                (self.refused if got is None else self.forged)[type(m).__name__] += 1
                if got is not None:
                    out.append(got)
            send(out, now)

        f.bus.send = wired

    def _note(self, m, now: float) -> None:
        name = type(m).__name__
        self.seen.setdefault(name, m)
        phase = max((k for k, p in enumerate(self.phases) if now >= p), default=None)
        if phase is not None and (name, phase) not in self._done:
            self._done.add((name, phase))
            self._due += [(now + 0.2, g) for g in _forgeries(m, self.rng, self.ids)]

    def tried(self) -> set[str]:
        return set(self.forged) | set(self.refused)


CONFLICT_BOUND = 15.0      # s two robots may hold one formation task before the protocol resolves it


def _family_run(method: str, starts, specs, until: float, options=None, single: bool = True):
    from runtime.allocation import registry
    from runtime.messages import FLEET_MESSAGES
    f = kinematic(starts, method, options=options)
    types = tuple(registry.method(method).messages) + FLEET_MESSAGES
    forger = EveryType(f, types)
    f.run(0.5)
    ids = f.hand_in(min(starts), specs)
    twice: dict[int, float] = {}
    worst = [0.0]

    def watch(fl):
        held_now = {t for t, h in fl.holders().items() if len(h) > 1} if single else set()
        for t in held_now:
            worst[0] = max(worst[0], fl.now - twice.setdefault(t, fl.now))
        for t in set(twice) - held_now:
            del twice[t]

    def finished(fl):
        return fl.now > forger.late + 1.0 and all(r.node.table.state(t) == DONE for r in fl.robots.values()
                                                  for t in ids)
    f.run(until, stop=finished, observe=watch)
    f.run(f.now + 4.0, observe=watch)            # the tables' bound: every robot agrees
    return f, ids, forger, worst[0], types


@pytest.mark.parametrize("method", ["auction", "bs", "coalition", pytest.param("dr", marks=pytest.mark.slow),
                                    pytest.param("comutar", marks=pytest.mark.slow)])
def test_one_forgery_of_every_private_message_type_leaves_an_unsigned_fleet_valid(method):
    """Issue 31 point 5: every private message type of the family and of the fleet task table forged with plausible
    values (three ways each, at three moments, and a made-up one of each type the run never sent) on an unsigned
    fleet: every task is done (nothing stuck), no formation task is held by two robots for more than
    CONFLICT_BOUND s, nothing is held at the end, every robot's table is the same, and no genuine message is refused
    on the wire afterwards (no forged value pushed the fleet's own past the protocol's range)."""
    from runtime.allocation.dr.options import DrOptions
    from runtime.tasks.rendezvous import Rendezvous
    from runtime.tasks.surveillance import Surveillance
    from runtime.tasks.transport import Transport
    runs = {
        "auction": (STARTS, [Goto(x, y, hold=2.0) for x, y in POSITIONS], 150.0, None, True),
        "bs": (STARTS, [Goto(x, y, hold=2.0) for x, y in POSITIONS], 150.0, None, True),
        "coalition": (STARTS, [Rendezvous(0.0, 0.0, 2, 100.0), Rendezvous(1.0, 1.0, 2, 100.0)], 200.0, None, False),
        "dr": ({1: (-2, -1), 2: (-2, 0), 3: (-2, 1), 4: (2, -1), 5: (2, 0)},
               [Transport(1.5, 1.5, 20, 60, 100), Transport(-1.5, 1.0, 20, 60, 100)], 300.0,
               DrOptions(strategy="NM_NI"), False),
        "comutar": ({1: (-3.0, -3.0, 0.0), 2: (3.0, 3.0, math.pi), 3: (3.0, -3.0, math.pi / 2)},
                    [Surveillance(0.0, 0.0, 4.0, 4.0, 2.0)], 300.0, None, False),
    }
    starts, specs, until, options, single = runs[method]
    f, ids, forger, worst, types = _family_run(method, starts, specs, until, options, single)
    assert forger.tried() == {c.__name__ for c in types}, {c.__name__ for c in types} - forger.tried()
    assert sum(forger.forged.values()) >= len(types), forger.forged      # most get through the codec
    assert all(r.node.table.state(t) == DONE for r in f.robots.values() for t in ids), \
        {rid: [r.node.table.state(t) for t in ids] for rid, r in f.robots.items()}
    assert worst <= CONFLICT_BOUND, worst
    assert all(not r.agent.commitments for r in f.robots.values())
    tables = {rid: {t: (e.state, e.done_by) for t, e in r.node.table.entries.items()} for rid, r in f.robots.items()}
    assert all(tab == tables[min(tables)] for tab in tables.values()), tables
    assert not any(s == OPEN for tab in tables.values() for s, _ in tab.values())
    assert not forger.genuine_refused, forger.genuine_refused


def test_a_decoy_task_record_is_disowned_by_its_origin_or_held_and_never_driven_to():
    """Issue 31 point 5: a forged task record of a new task at an attacker's point, unsigned.  Sent in its origin's
    name to everyone, or relayed in another robot's name to one robot only: the origin (past its start-up grace)
    disowns it when it hears of it (the record, or a robot asking it to confirm), so it ends withdrawn in every
    table.  Relayed when its origin is lost: held, never entered, dropped after UNCONFIRMED s.  Nobody drives there."""
    from runtime.fleet.node import OWN_GRACE, UNCONFIRMED
    f, ids = formation("auction", POSITIONS[:3])
    f.run(OWN_GRACE + 1.0)
    x, y = ATTACKER_POINT
    record = dict(command=NAV_WAYPOINT, frame=LOCAL_ENU, state=OPEN, param1=0.0, param2=0.0, param3=0.0,
                  param4=math.nan, x=x, y=y)
    named, relayed, orphan = 2 << 16 | 40, 2 << 16 | 41, 4 << 16 | 42
    seen = []

    def watch(fl):
        seen.extend(c.task.position for r in fl.robots.values() for c in r.agent.commitments)
    forger = Forger(f)
    forger.send([TaskRecord(2, 0, named, **record), TaskRecord(3, 1, relayed, **record)])
    f.run(f.now + 6.0, observe=watch)                                   # within the table's bound
    for t in (named, relayed):
        assert all(r.node.table.state(t) is not None and r.node.table.state(t) & 2 for r in f.robots.values()), t
    assert f.robots[2].node.dropped["a task of my own origin I never minted"] >= 2
    f.kill(4)
    f.run(f.now + 5.0, observe=watch)                                   # robot 4 is lost to the others
    forger.send([TaskRecord(3, 1, orphan, **record)])
    f.run(f.now + 1.0, observe=watch)
    assert orphan in f.robots[1].node._pending and orphan not in f.robots[1].node.table.entries
    f.run(f.now + UNCONFIRMED + 2.0, observe=watch)
    assert orphan not in f.robots[1].node._pending and orphan not in f.robots[1].node.table.entries
    assert f.robots[1].node.dropped["a task its origin never confirmed"] == 1
    assert seen and ATTACKER_POINT not in seen


def test_two_ground_stations_on_one_signing_stream_are_named_once_when_the_older_is_dropped(caplog):
    """Two stations signing as 255/190 on the same link id share one replay window: the one with the older
    timestamps has its frames dropped as replays, and the robot says so once, naming both addresses."""
    from runtime.comms.gcs import ground_mav
    rx = MavlinkLink(1, "127.0.0.1:0", [], signing_key=KEY)
    try:
        stamp = signing_timestamp(time.time())
        newer, older = ground_mav(KEY, link_id=2)[1], ground_mav(KEY, link_id=2)[1]
        newer.signing.timestamp, older.signing.timestamp = stamp + 1000, stamp
        other_link = ground_mav(KEY, link_id=7)[1]
        other_link.signing.timestamp = stamp

        def frame(mav):
            return mav.command_long_encode(1, 1, 512, 0, 148, 0, 0, 0, 0, 0, 0).pack(mav)

        with caplog.at_level("WARNING"):
            rx.feed(frame(newer), 0.0, ("127.0.0.1", 5001))
            for _ in range(3):
                rx.feed(frame(older), 0.0, ("127.0.0.1", 5002))
            rx.feed(frame(other_link), 0.0, ("127.0.0.1", 5003))
        assert rx.counters.gcs_requests == 2 and rx.counters.bad_signature_dropped == 3
        said = [r.getMessage() for r in caplog.records if "replay window" in r.getMessage()]
        assert said == ["ground station at 127.0.0.1:5002 signs as system 255 component 190 on link id 2, as the one "
                        "at 127.0.0.1:5001 does: one replay window for both, so the older timestamps are dropped as "
                        "replays; give one of them another link id or system id"]
    finally:
        rx.close()


def test_a_station_with_another_key_is_no_stream_clash(caplog):
    from runtime.comms.gcs import ground_mav
    rx = MavlinkLink(1, "127.0.0.1:0", [], signing_key=KEY)
    try:
        ours, theirs = ground_mav(KEY, link_id=2)[1], ground_mav(OTHER_KEY, link_id=2)[1]
        with caplog.at_level("WARNING"):
            rx.feed(ours.command_long_encode(1, 1, 512, 0, 148, 0, 0, 0, 0, 0, 0).pack(ours), 0.0, ("127.0.0.1", 5001))
            rx.feed(theirs.command_long_encode(1, 1, 512, 0, 148, 0, 0, 0, 0, 0, 0).pack(theirs), 0.0,
                    ("127.0.0.1", 5002))
        assert rx.counters.bad_signature_dropped == 1
        assert not [r for r in caplog.records if "replay window" in r.getMessage()]
    finally:
        rx.close()
