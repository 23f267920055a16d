"""The zenoh transport on loopback: links and a fleet of in-process robot cores with real Zenoh sessions through a
router (Python session in router mode, free ports), two linked routers, a router restarted mid-auction, a segment
split off and rejoined, liveliness, the loss model on receipt, and forged frames published by another session.

Needs the [zenoh] extra (CI installs it with [test]); skipped, saying so, where it is missing."""
from __future__ import annotations

import dataclasses
import json
import math
import time
from types import SimpleNamespace

import pytest
from hypothesis import HealthCheck, example, given, settings, strategies as st

zenoh = pytest.importorskip("zenoh", reason="the [zenoh] extra is not installed: pip install 'mrta-runtime[zenoh]'")

from runtime.allocation import registry  # noqa: E402
from runtime.allocation.formation import messages as M  # noqa: E402
from runtime.comms import codec, dialect  # noqa: E402
from runtime.comms.link import COMPONENT_ID, PEER_LINK, MavlinkLink, signing_guard, signing_timestamp  # noqa: E402
from runtime.comms.zenoh_transport import ZenohTransport, open_router, session_config  # noqa: E402
from runtime.config.robot import CommsConfig, Peer, ZenohConfig  # noqa: E402
from runtime.inprocess import Fleet, Kinematic, kinematic, robot_config  # noqa: E402
from runtime.robot.core import RobotCore  # noqa: E402
from runtime.robot.ports import BaseFacts  # noqa: E402
from runtime.tasks.goto import Goto  # noqa: E402
from sitl.segments import Segments  # noqa: E402
from sitl.ports import free_port

KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))
STARTS = {1: (0.0, 0.0, 0.0), 2: (2.0, 0.0, math.pi), 3: (0.0, 2.0, 0.0), 4: (2.0, 2.0, 0.0)}
TASKS = [Goto(1.2, 0.9), Goto(-1.0, 0.5), Goto(0.5, 2.5), Goto(2.5, 1.3)]     # no two robots tie for one
SPEEDUP = 3.0             # sim seconds per wall second: the sessions move frames in wall time (a loaded machine
#                           must still beat the 3 s heartbeat timeout: 1 s of wall time)
_fleets = iter(range(10**6))


@pytest.fixture
def segments():
    made = []

    def make(k, robots=STARTS):
        seg = Segments(k, robots, fleet=f"t{next(_fleets)}")
        made.append(seg)
        return seg

    yield make
    for seg in made:
        seg.close()


@pytest.fixture
def links():
    made = []

    def make(rid, seg, key=KEY, **kw):
        t = ZenohTransport(rid, seg.fleet, connect=[seg.endpoints[seg.segment.get(rid, 0)]], lease=3.0)
        link = MavlinkLink(rid, "127.0.0.1:0", [], None, signing_key=key, transport=t, **kw)
        made.append(link)
        return link

    yield make
    for link in made:
        link.close()


def pump(link_list, done, limit=3.0, now=0.0) -> dict:
    """Poll the links until ``done(messages by link)`` or ``limit`` wall seconds."""
    got = {id(k): [] for k in link_list}
    t0 = time.monotonic()
    while not done(got) and time.monotonic() - t0 < limit:
        for k in link_list:
            got[id(k)] += k.poll(now)
        time.sleep(0.002)
    return got


def wait_routes(sender, receivers, limit=3.0):
    """Until a probe from ``sender`` reaches every receiver (routes through the router are declared)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < limit:
        sender.send_agent([M.Status(sender.robot_id, 0, 99, 99, True)], 0.0)
        got = pump(receivers, lambda g: all(g.values()), limit=0.1)
        if all(got.values()):
            return
    raise AssertionError("no route through the router")


# ---------------------------------------------------------------------------------------- links

def test_a_frame_is_published_once_and_addressed_frames_reach_only_their_robot(segments, links):
    seg = segments(1)
    a, b, c = links(1, seg), links(2, seg), links(3, seg)
    wait_routes(b, [a, c])
    sent = b.counters.peer_sent
    b.send_agent([M.Bid(2, 0, 1, 5, 0.5), M.Bid(2, 3, 1, 6, 0.25)], 0.0)
    assert b.counters.peer_sent - sent == 2                 # one publication each, not one per peer
    def tasks(g, link) -> list:          # the probes of wait_routes (task 99) may still be arriving: not counted
        return sorted(m.task for m in g[id(link)] if m.task != 99)    # two keys (all, to/3): no order between them

    got = pump([a, c], lambda g: len(tasks(g, a)) >= 1 and len(tasks(g, c)) >= 2)
    assert tasks(got, a) == [5]
    assert tasks(got, c) == [5, 6]
    assert a.counters.not_for_us == 0                       # robot 1 never saw the frame for robot 3


def test_one_senders_broadcast_and_addressed_frames_are_all_taken_whatever_their_order(segments, links):
    """Two subscribers (all/*, to/<me>/*), each with its callback thread in zenoh-python, queue one robot's frames
    out of order between them; with one replay window for both the link refused the older (848 of 2,000 alternating
    frames): addressed frames are signed on a link id of their own (PEER_DIRECT_LINK), a stream of their own."""
    seg = segments(1)
    a, b = links(1, seg), links(2, seg)
    wait_routes(a, [b])
    refused, got = b.counters.bad_signature_dropped, []
    for i in range(400):
        a.send_agent([M.Status(1, 2 if i % 2 else 0, i, 1, True)], 0.0)
        if i % 50 == 49:
            got += b.poll(0.0)
    def mine(ms) -> list:                  # not wait_routes' probes (task 99)
        return [m for m in ms if isinstance(m, M.Status) and m.sender == 1 and m.task == 1]

    got += pump([b], lambda g: len(mine(got + g[id(b)])) >= 400)[id(b)]
    assert sorted(m.auction for m in mine(got)) == list(range(400)), b.counters
    assert b.counters.bad_signature_dropped == refused


def test_liveliness_reports_a_peer_joining_at_once_and_a_closed_session_lost(segments, links):
    seg = segments(1)
    a = links(1, seg)
    b = links(2, seg)                                       # never polled: it sends no heartbeat
    pump([a], lambda g: 2 in a.peers_alive, now=0.0)
    assert 2 in a.peers_alive and a.counters.heartbeats == 0          # alive by its liveliness token alone
    b.close()
    lost: list = []
    t0 = time.monotonic()
    while not lost and time.monotonic() - t0 < 3.0:
        a.poll(0.5)
        lost = a.peers_lost(0.5)                           # well inside the 3 s heartbeat timeout
        time.sleep(0.002)
    assert lost == [2]
    assert a.peers_lost(0.6) == [] and 2 not in a.peers_alive       # once per absence


def test_the_loss_model_draws_per_sender_on_receipt(segments, links):
    seg = segments(1)
    a = links(1, seg, peer_loss=0.25, loss_seed=7)
    b = links(2, seg)
    wait_routes(b, [a])
    a.counters.loss_injected = 0
    before = a.counters.agent_received
    b.send_agent([M.Bid(2, 0, 1, k, float(k)) for k in range(200)], 0.0)
    pump([a], lambda g: a.counters.agent_received - before + a.counters.loss_injected >= 200)
    n = a.counters
    assert n.agent_received - before + n.loss_injected == 200 and 20 < n.loss_injected < 80


def _forged(key: bytes | None, system: int = 2) -> bytes:
    """A Status frame from robot ``system`` on the peer link, signed with ``key`` (None: unsigned)."""
    module = dialect.load()
    mav = signing_guard(module.MAVLink)(None, srcSystem=system, srcComponent=COMPONENT_ID)
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.link_id = PEER_LINK
        mav.signing.timestamp = signing_timestamp(time.time())
    return codec.encode(M.Status(system, 0, 7, 7, True), mav)


def test_a_forged_frame_published_by_another_session_is_dropped_and_counted(segments, links):
    seg = segments(1)
    a = links(1, seg)
    b = links(2, seg)
    wait_routes(b, [a])
    rogue = zenoh.open(session_config("client", seg.endpoints))      # anyone who can reach the router
    try:
        c0 = dict(a.counters.as_dict())
        for _ in range(3):
            rogue.put(f"mrta/{seg.fleet}/all/2", _forged(OTHER_KEY))     # robot 2's key and id, a wrong key
            rogue.put(f"mrta/{seg.fleet}/to/1/2", _forged(None))         # unsigned, addressed to robot 1
            rogue.put(f"mrta/{seg.fleet}/all/2", b"\xfd\x09garbage")
            time.sleep(0.05)
        got = pump([a], lambda g: a.counters.datagrams - c0["datagrams"] >= 9)
        c = a.counters
        assert [m for m in got[id(a)] if m.task == 7] == []
        assert c.bad_signature_dropped - c0["bad_signature_dropped"] == 3
        assert c.unsigned_dropped - c0["unsigned_dropped"] == 3
        assert c.parse_errors + c.bad_crc - c0["parse_errors"] - c0["bad_crc"] == 3
        b.send_agent([M.Status(2, 0, 8, 8, True)], 0.0)                # robot 2's own frames still pass
        got = pump([a], lambda g: any(m.task == 8 for m in g[id(a)]))
        assert any(m.task == 8 for m in got[id(a)])
    finally:
        rogue.close()


# ---------------------------------------------------------------------------------------- a fleet of cores

def zenoh_fleet(seg, method="auction", **link) -> Fleet:
    """In-process robot cores (kinematic motion), each on a real link whose Zenoh session is a client of its
    segment's router."""
    m = registry.method(method)
    ids = tuple(sorted(STARTS))
    facts = BaseFacts(radius=0.17, max_speed=0.5, ranging=True)
    cores = {r: RobotCore(robot_config(r, ids, m.options(), period=0.1), facts, method=m, base_config=None)
             for r in ids}
    links = {r: MavlinkLink(r, "127.0.0.1:0", [], None, signing_key=KEY,
                            transport=ZenohTransport(r, seg.fleet, connect=[seg.endpoints[seg.segment[r]]],
                                                     lease=3.0), loss_seed=r, **link)
             for r in ids}
    return Fleet(cores, Kinematic(STARTS, 0.5), period=0.1, links=links)


def run_paced(f: Fleet, until: float, stop=None) -> float:
    """``f.run`` with the simulated clock held to at most SPEEDUP x wall time."""
    t0, s0 = time.monotonic(), f.now

    def pace(fl):
        ahead = (fl.now - s0) / SPEEDUP - (time.monotonic() - t0)
        if ahead > 0:
            time.sleep(ahead)
    return f.run(until, stop=stop, observe=pace)


def joined(f: Fleet) -> float:
    """Run until every robot's link counts every other robot alive (their liveliness tokens); the sim time then."""
    n = len(f.robots) - 1
    run_paced(f, f.now + 20.0, stop=lambda fl: all(len(link.peers_alive) == n for link in fl.bus.links.values()))
    assert all(len(link.peers_alive) == n for link in f.bus.links.values())
    return f.now


def assigned(f: Fleet) -> dict:
    """task -> the robots holding it, and (once done) the robots that did it."""
    out: dict = {t: set(v) for t, v in f.holders().items()}
    for t, robots in f.done().items():
        out.setdefault(t, set()).update(robots)
    return out


def held_once(f: Fleet, ids) -> bool:
    """Every task held (or done) by exactly one robot and known to every live robot's table: none lost, none held
    twice."""
    a = assigned(f)
    return (set(a) == set(ids) and all(len(v) == 1 for v in a.values())
            and all(set(ids) <= set(f.robots[r].node.table.entries) for r in f.live()))


def assignment(f: Fleet) -> dict:
    return {t: tuple(v) for t, v in sorted(f.holders().items())}


@pytest.fixture
def fleets():
    made = []

    def make(seg, method="auction", **link):
        f = zenoh_fleet(seg, method, **link)
        made.append(f)
        return f

    yield make
    for f in made:
        for link in f.bus.links.values():
            link.close()


@pytest.fixture(scope="module")
def in_memory() -> dict:
    """The same fleet and tasks on the in-memory bus: the assignment the transports must reach."""
    f = kinematic(STARTS, "auction", period=0.1)
    f.run(0.5)
    ids = f.hand_in(1, TASKS)
    f.run(20.0, stop=lambda fl: held_once(fl, ids))
    assert held_once(f, ids)
    return assignment(f)


@pytest.mark.parametrize("k", [1, 2], ids=["one router", "two linked routers"])
def test_a_fleet_over_routers_reaches_the_in_memory_assignment(segments, fleets, in_memory, k):
    seg = segments(k)
    f = fleets(seg)
    joined(f)
    ids = f.hand_in(1, TASKS)
    run_paced(f, 20.0, stop=lambda fl: held_once(fl, ids))
    assert assignment(f) == in_memory
    # (a frame the routers delivered twice while two of them link up is a replay to the link: bad_signature_dropped)
    assert all(link.counters.unsigned_dropped == 0 for link in f.bus.links.values())
    assert all(h.core.stats.peers_lost == [] for h in f.robots.values())


def zenoh_core(rid: int, ids) -> RobotCore:
    """Robot ``rid``'s core with a config whose transport is zenoh and whose roster is ``ids`` (``(rid,)``: none)."""
    m = registry.method("auction")
    cfg = robot_config(rid, ids, m.options(), period=0.1)
    cfg = dataclasses.replace(cfg, comms=dataclasses.replace(cfg.comms, transport="zenoh"))
    return RobotCore(cfg, BaseFacts(radius=0.17, max_speed=0.5, ranging=True), method=m, base_config=None)


def test_a_robot_that_joins_through_the_router_is_seen_bids_and_does_the_task_nearest_it(segments):
    """Three robots over one router; a fourth whose config names no peers starts mid-run.  Its liveliness token and
    its first signed frame reach every robot: each takes it into its roster (the cores take joins because their
    transport is zenoh), it bids and does the task nearest it; no task is held twice.  (The same in-process for
    every family: tests/test_membership.py.)"""
    seg = segments(1)
    three = (1, 2, 3)

    def link(r):
        return MavlinkLink(r, "127.0.0.1:0", [], None, signing_key=KEY,
                           transport=ZenohTransport(r, seg.fleet, connect=[seg.endpoints[0]], lease=3.0))
    links = {}
    try:
        for r in three:
            links[r] = link(r)
        f = Fleet({r: zenoh_core(r, three) for r in three}, Kinematic({r: STARTS[r] for r in three}, 0.5),
                  period=0.1, links=links)
        joined(f)
        new = zenoh_core(4, (4,))
        assert new.joins and new.roster == set()
        f.join(new, STARTS[4], link(4))
        links[4] = f.bus.links[4]

        def seen(fl):
            return all(4 in fl.robots[r].core.roster for r in three) and fl.robots[4].core.roster == set(three)
        run_paced(f, f.now + 10.0, stop=seen)
        assert seen(f) and all(f.robots[r].core.stats.peers_joined == [4] for r in three)
        ids = f.hand_in(1, [Goto(2.5, 2.4), Goto(-0.2, 0.3)])      # nearest robot 4, and robot 1
        twice = []

        def done(fl):       # held twice: by two robots that both settled (mid-auction a bid moves commitments about)
            twice.extend((t, h) for t, h in fl.holders().items()
                         if sum(not fl.robots[r].agent.allocating for r in h) > 1)
            return held_once(fl, ids) and 4 in fl.holders().get(ids[0], {})
        run_paced(f, f.now + 20.0, stop=done)
        assert held_once(f, ids) and f.holders()[ids[0]] == {4: (4,)} and not twice
        assert all(f.robots[r].node.dropped["not a robot of the fleet"] == 0 for r in f.robots)
    finally:
        for k in links.values():
            k.close()


@pytest.mark.slow
def test_a_robot_whose_session_is_cut_is_lost_and_its_task_reauctioned_under_10_percent_loss(segments, fleets):
    seg = segments(1)
    f = fleets(seg, peer_loss=0.1)             # the link's loss model, drawn on receipt
    joined(f)
    ids = f.hand_in(1, TASKS[:3])              # three tasks, four robots: one is free
    run_paced(f, f.now + 20.0, stop=lambda fl: held_once(fl, ids))
    assert held_once(f, ids)
    (victim,) = f.holders()[ids[0]]
    f.kill(victim)                             # its session closes with it

    def settled(fl):
        return held_once(fl, ids) and all(victim in fl.robots[r].core.stats.peers_lost for r in fl.live())
    run_paced(f, f.now + 20.0, stop=settled)
    assert held_once(f, ids) and victim not in assigned(f)[ids[0]]
    assert all(victim in f.robots[r].core.stats.peers_lost for r in f.live())
    assert sum(f.bus.links[r].counters.loss_injected for r in f.live()) > 0


@pytest.mark.slow
def test_a_router_restarted_mid_auction_loses_no_task_and_none_is_held_twice(segments, fleets):
    seg = segments(1)
    f = fleets(seg)
    joined(f)
    ids = f.hand_in(1, TASKS)
    run_paced(f, f.now + 0.1)            # the first announcements are out
    seg.stop(0)
    run_paced(f, f.now + 4.0)            # longer than the heartbeat timeout: peers are lost, work re-auctioned
    assert any(h.core.stats.peers_lost for h in f.robots.values())
    seg.start(0)                          # the clients reconnect to it
    run_paced(f, f.now + 30.0, stop=lambda fl: held_once(fl, ids))
    assert held_once(f, ids)


@pytest.mark.slow
def test_a_segment_split_carries_on_each_side_and_merges_on_rejoin(segments, fleets):
    seg = segments(2)                     # robots 1, 2 on router 0; 3, 4 on router 1
    f = fleets(seg)
    joined(f)
    seg.stop(1)
    seg.start(1, linked=False)            # segment 1 split off
    a = f.hand_in(1, TASKS[:2])
    b = f.hand_in(3, TASKS[2:])

    def apart(fl) -> bool:
        """Each side alone: knows its own tasks only, has them done by its own robots, has lost the other side."""
        side = {r: set(fl.robots[r].node.table.entries) for r in STARTS}
        got = assigned(fl)
        return (side[1] == side[2] == set(a) and side[3] == side[4] == set(b)
                and all(got.get(t) in ({1}, {2}) for t in a) and all(got.get(t) in ({3}, {4}) for t in b)
                and all(set(fl.robots[r].core.stats.peers_lost) >= other
                        for r, other in ((1, {3, 4}), (2, {3, 4}), (3, {1, 2}), (4, {1, 2}))))
    run_paced(f, f.now + 20.0, stop=apart)
    assert apart(f)
    seg.stop(1)
    seg.start(1)                          # rejoined
    run_paced(f, f.now + 30.0, stop=lambda fl: held_once(fl, a + b))
    assert held_once(f, a + b)


def test_a_router_with_access_control_refuses_what_its_rules_deny(tmp_path, links):
    """Zenoh's own access control on the router (mrta router --config FILE): robot 3 may not publish to the fleet."""
    seg = SimpleNamespace(fleet=f"t{next(_fleets)}", segment={}, endpoints=[f"tcp/127.0.0.1:{free_port()}"])
    acl = tmp_path / "router.json5"
    acl.write_text(json.dumps({"access_control": {
        "enabled": True, "default_permission": "allow",
        "rules": [{"id": "no robot 3", "permission": "deny", "flows": ["ingress"], "messages": ["put"],
                   "key_exprs": [f"mrta/{seg.fleet}/all/3"]}],
        "subjects": [{"id": "loopback", "interfaces": ["lo"]}],
        "policies": [{"rules": ["no robot 3"], "subjects": ["loopback"]}]}}))
    router = open_router(seg.endpoints, file=str(acl))
    try:
        a, b, c = links(1, seg), links(2, seg), links(3, seg)
        wait_routes(b, [a])
        c.send_agent([M.Status(3, 0, 5, 5, True)], 0.0)
        b.send_agent([M.Status(2, 0, 6, 6, True)], 0.0)
        got = pump([a], lambda g: any(m.task == 6 for m in g[id(a)]))
        time.sleep(0.1)
        got[id(a)] += a.poll(0.0)
        assert [m.task for m in got[id(a)] if m.task in (5, 6)] == [6]
    finally:
        router.close()


@settings(max_examples=40, deadline=None)
@example([("²", True), ("007", True), ("9" * 5000, False), ("", True), ("2/3", False)])
@given(st.lists(st.tuples(st.text(max_size=30), st.booleans()), max_size=20))
def test_membership_keys_of_any_shape_never_raise_and_only_robot_ids_count(events):
    """Liveliness keys come from the network: whatever their last part, membership() never raises, and the link
    takes only robot ids 1..250 other than its own."""
    from collections import deque

    t = ZenohTransport.__new__(ZenohTransport)          # the parsing only: no session
    t._members, t._put = deque(), zenoh.SampleKind.PUT
    for key, put in events:
        t._on_token(SimpleNamespace(key_expr=f"mrta/f/alive/{key}",
                                    kind=zenoh.SampleKind.PUT if put else zenoh.SampleKind.DELETE))
    out = t.membership()
    assert all(isinstance(r, int) and r >= 0 for r, _ in out)
    link = SimpleNamespace(robot_id=1, _left=set(), _beats=SimpleNamespace(lost=set(), hear=lambda r, now: None))
    for robot, joined in out:
        MavlinkLink._member(link, robot, joined, 0.0)
    assert all(1 < r <= 250 for r in link._left)


def test_sitl_segments_split_the_robots_and_their_configs_carry_no_peer_addresses(segments):
    seg = segments(2, robots={1: None, 2: None, 3: None, 4: None, 5: None})
    assert seg.segment == {1: 0, 2: 0, 3: 0, 4: 1, 5: 1} and seg.links == [[], [seg.endpoints[0]]]
    comms = seg.comms(4)
    assert comms["transport"] == "zenoh" and comms["zenoh"]["connect"] == [seg.endpoints[1]]
    assert comms["peers"] == [{"id": 1}, {"id": 2}, {"id": 3}, {"id": 5}]        # ids only
    cfg = CommsConfig(**{**comms, "zenoh": ZenohConfig(**{k: tuple(v) if isinstance(v, list) else v
                                                          for k, v in comms["zenoh"].items()}),
                         "peers": tuple(Peer(**p) for p in comms["peers"])})
    t = ZenohTransport.from_config(cfg, 4)                 # the config opens a session on its segment's router
    t.close()


def _zlink(rid, fleet, **zenoh_kw) -> MavlinkLink:
    return MavlinkLink(rid, "127.0.0.1:0", [], None, signing_key=KEY,
                       transport=ZenohTransport(rid, fleet, lease=3.0, **zenoh_kw))


def test_peer_mode_needs_no_router_and_a_client_takes_its_second_router_when_the_first_is_down(segments):
    fleet = f"t{next(_fleets)}"
    seed = f"tcp/127.0.0.1:{free_port()}"
    made = [_zlink(1, fleet, mode="peer", listen=[seed])]
    try:
        made += [_zlink(r, fleet, mode="peer", listen=["tcp/127.0.0.1:0"], connect=[seed]) for r in (2, 3)]
        wait_routes(made[2], made[:2])                     # 3 reaches 2 through the mesh gossip built
        seg = segments(1)
        dead = f"tcp/127.0.0.1:{free_port()}"         # nothing listens there
        a, b = (_zlink(r, seg.fleet, connect=[dead, seg.endpoints[0]]) for r in (1, 2))
        made += [a, b]
        wait_routes(b, [a])
    finally:
        for link in made:
            link.close()


def _sessionless(rid: int, cap: int = 64) -> ZenohTransport:
    """A ZenohTransport's receiving half without a session (frames go in through the session thread's callback),
    sending nowhere."""
    from collections import deque

    t = ZenohTransport.__new__(ZenohTransport)
    t._queue, t._cap, t._overflow, t._members, t._put = deque(), cap, 0, deque(), zenoh.SampleKind.PUT
    t.destinations = lambda dest: []
    return t


@pytest.fixture(scope="module")
def sessionless_link():
    t = _sessionless(1, cap=64)
    link = MavlinkLink(1, "127.0.0.1:0", [], None, signing_key=KEY, transport=t)
    yield link
    link.close()


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.one_of(st.binary(max_size=300),
                          st.tuples(st.integers(0, 10**6), st.integers(1, 64)).map(lambda ft: _flip_cut(*ft))),
                max_size=80))
def test_published_payloads_of_any_shape_are_counted_never_raised(sessionless_link, payloads):
    link, t = sessionless_link, sessionless_link.transport
    before = link.counters.as_dict()
    t._overflow = 0
    for p in payloads:
        t._on_frame(SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda p=p: p), key_expr="mrta/f/all/2"))
    link.poll(0.0)
    link.check_kernel_drops()
    c = link.counters
    taken = min(len(payloads), 64)
    assert c.datagrams - before["datagrams"] == taken
    assert c.datagrams == c.received + c.dropped
    assert c.queue_dropped == len(payloads) - taken


def _flip_cut(bit: int, keep: int) -> bytes:
    """Robot 2's signed Status frame with one bit flipped, cut to ``keep`` bytes."""
    frame = bytearray(_forged(KEY))
    bit %= len(frame) * 8
    frame[bit // 8] ^= 1 << (bit % 8)
    return bytes(frame[:keep])


def test_a_daemon_whose_router_does_not_answer_exits_2_naming_its_config(tmp_path, capsys):
    from runtime import cli

    robot = tmp_path / "robot.yaml"
    robot.write_text("robot: {id: 1}\ngps: {enabled: false}\nbase: {type: create_oi, port: 'loop://'}\n"
                     f"comms: {{listen: '127.0.0.1:{free_port(udp=True)}', gcs: null, transport: zenoh,\n"
                     f"        zenoh: {{connect: ['tcp/127.0.0.1:{free_port()}']}}}}\n")
    assert cli.main(["daemon", str(robot), "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{robot}: comms.zenoh.connect: cannot open a Zenoh session" in err, err


# ---------------------------------------------------------------------------------------- TLS and mTLS

def _certs(where, clients=()):
    """A throwaway CA, a router certificate for 127.0.0.1 and a client certificate per name in ``clients`` (its common
    name), made with the openssl command (PEM files in ``where``); returns {name: (cert, key)} with "ca" and
    "router"."""
    import shutil
    import subprocess

    if shutil.which("openssl") is None:
        pytest.skip("the openssl command is not installed: no certificates to test TLS with")

    def run(*args):
        subprocess.run(["openssl", *args], check=True, capture_output=True, cwd=where, timeout=30)

    def key_and_csr(name, cn):
        run("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes", "-keyout", f"{name}.key",
            "-out", f"{name}.csr", "-subj", f"/CN={cn}")

    run("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes", "-keyout", "ca.key",
        "-out", "ca.pem", "-days", "1", "-subj", "/CN=mrta test CA", "-addext", "basicConstraints=critical,CA:TRUE",
        "-addext", "keyUsage=critical,keyCertSign")
    out = {"ca": (str(where / "ca.pem"), str(where / "ca.key"))}
    for name, usage, alt in [("router", "serverAuth", "IP:127.0.0.1"), *((c, "clientAuth", f"DNS:{c}") for c in clients)]:
        key_and_csr(name, name)
        (where / f"{name}.cnf").write_text(f"basicConstraints=CA:FALSE\nextendedKeyUsage={usage}\nsubjectAltName={alt}\n")
        run("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial", "-out",
            f"{name}.pem", "-days", "1", "-extfile", f"{name}.cnf")
        out[name] = (str(where / f"{name}.pem"), str(where / f"{name}.key"))
    return out


def _json5(path, tls: dict, **more) -> str:
    path.write_text(json.dumps({"transport": {"link": {"tls": tls}}, **more}))
    return str(path)


def _crosses(src: MavlinkLink, dst: MavlinkLink, task: int, limit: float = 3.0) -> bool:
    """A signed Status from ``src`` reaches ``dst`` within ``limit`` wall seconds (sent again each 0.1 s)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < limit:
        src.send_agent([M.Status(src.robot_id, 0, task, task, True)], 0.0)
        got = pump([dst], lambda g: any(m.task == task for m in g[id(dst)]), limit=0.1)
        if any(getattr(m, "task", None) == task for m in got[id(dst)]):
            return True
    return False


def test_a_robot_reaches_its_router_over_tls_from_its_config_and_a_client_without_the_ca_cannot_connect(tmp_path):
    """The router listens on tls/127.0.0.1 with a certificate of a throwaway CA (Zenoh's own keys, mrta router
    --config); robots name the CA in the Zenoh file of comms.zenoh.config: a signed frame crosses.  A client that
    does not trust the CA is refused (one line naming comms.zenoh.connect)."""
    from runtime.errors import InputError

    certs = _certs(tmp_path)
    ep = f"tls/127.0.0.1:{free_port()}"
    router = open_router([ep], file=_json5(tmp_path / "router.json5", {
        "listen_certificate": certs["router"][0], "listen_private_key": certs["router"][1]}))
    robot = _json5(tmp_path / "robot.json5", {"root_ca_certificate": certs["ca"][0]})
    fleet, made = f"t{next(_fleets)}", []
    try:
        comms = CommsConfig(transport="zenoh", zenoh=ZenohConfig(connect=(ep,), fleet=fleet, config=robot))
        for rid in (1, 2):
            made.append(MavlinkLink(rid, "127.0.0.1:0", [], None, signing_key=KEY,
                                    transport=ZenohTransport.from_config(comms, rid)))
        assert _crosses(made[0], made[1], 5)
        with pytest.raises(InputError, match="^comms.zenoh.connect: cannot open a Zenoh session") as e:
            ZenohTransport(3, fleet, connect=[ep], lease=3.0)                    # no CA: the handshake fails
        assert "\n" not in str(e.value)
    finally:
        for link in made:
            link.close()
        router.close()


def test_mtls_admits_only_certificates_of_the_fleet_ca_and_access_control_by_common_name(tmp_path):
    """mTLS on the router (enable_mtls): a robot without a client certificate is refused; access control by the
    certificate's common name (cert_common_names), default deny: robots 1 and 2 exchange frames, robot 3, whose
    certificate is of the CA but named in no policy, neither publishes nor hears anything."""
    from runtime.errors import InputError

    certs = _certs(tmp_path, clients=("robot-1", "robot-2", "robot-3"))
    ep, fleet = f"tls/127.0.0.1:{free_port()}", f"t{next(_fleets)}"
    allow = {"id": "fleet keys", "permission": "allow", "flows": ["ingress", "egress"],
             "messages": ["put", "declare_subscriber", "liveliness_token", "declare_liveliness_subscriber",
                          "liveliness_query"], "key_exprs": [f"mrta/{fleet}/**"]}
    router = open_router([ep], file=_json5(tmp_path / "router.json5", {
        "listen_certificate": certs["router"][0], "listen_private_key": certs["router"][1],
        "root_ca_certificate": certs["ca"][0], "enable_mtls": True}, access_control={
        "enabled": True, "default_permission": "deny", "rules": [allow],
        "subjects": [{"id": "robots", "cert_common_names": ["robot-1", "robot-2"]}],
        "policies": [{"rules": ["fleet keys"], "subjects": ["robots"]}]}))
    made = []
    try:
        for rid in (1, 2, 3):
            cert, key = certs[f"robot-{rid}"]
            file = _json5(tmp_path / f"robot{rid}.json5", {"root_ca_certificate": certs["ca"][0], "enable_mtls": True,
                                                           "connect_certificate": cert, "connect_private_key": key})
            made.append(MavlinkLink(rid, "127.0.0.1:0", [], None, signing_key=KEY,
                                    transport=ZenohTransport(rid, fleet, connect=[ep], lease=3.0, file=file)))
        one, two, three = made
        assert _crosses(one, two, 5) and _crosses(two, one, 6)
        assert not _crosses(three, one, 7, limit=1.0) and not _crosses(one, three, 8, limit=0.5)
        with pytest.raises(InputError, match="cannot open a Zenoh session"):
            ZenohTransport(4, fleet, connect=[ep], lease=3.0,
                           file=_json5(tmp_path / "nocert.json5", {"root_ca_certificate": certs["ca"][0]}))
    finally:
        for link in made:
            link.close()
        router.close()

