"""Mission protocol: MissionServer (vehicle) <-> MissionClient (GCS) in memory through real MAVLink bytes,
over clean and lossy/duplicating/reordering channels; a third-party GCS (pymavlink's own dialects);
random message sequences that must never raise and must all be counted."""
from __future__ import annotations

import heapq
import math
import random

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from runtime.comms import dialect
from runtime.comms import mission as M
from runtime.comms.mission import MissionClient, MissionItem, MissionServer

VEHICLE, GCS_ID = 3, 255
OLD = [MissionItem(i, 3, 16, x=33.7755 + i * 1e-5, y=-84.3963, z=0.0) for i in range(3)]
NEW = [MissionItem(i, 3, 16, 0.5, 0.25, 0.0, math.nan, 33.775573 + i * 1e-6, -84.3963324, 1.5)
       for i in range(5)] + [MissionItem(5, 4, 16, x=1.25, y=-2.5),          # local ENU, metres
                             MissionItem(6, 3, 17, x=33.7756, y=-84.3963)]    # NAV_LOITER_UNLIM


@pytest.fixture(scope="module")
def mod():
    return dialect.load()


class Store:
    """What a daemon would keep: the mission, its plan id, and a log of callbacks."""

    def __init__(self, items=()):
        self.items, self.plan, self.calls, self.verdict = list(items), 7, [], None

    def on_upload(self, items):
        self.calls.append(("upload", len(items)))
        self.items, self.plan = list(items), self.plan + 1
        return self.plan

    def on_clear(self, mission_type):
        self.calls.append(("clear", mission_type))
        self.items = []

    def validate(self, items):
        return self.verdict


def make_server(mod, store, **kw):
    mav = mod.MAVLink(None, srcSystem=VEHICLE, srcComponent=1)
    return MissionServer(mav, VEHICLE, on_upload=store.on_upload, on_clear=store.on_clear,
                         items=lambda t: store.items, plan_id=lambda t: store.plan,
                         validate=store.validate, **kw)


def make_client(mod, sysid=GCS_ID):
    return MissionClient(mod.MAVLink(None, srcSystem=sysid, srcComponent=190), VEHICLE)


def wire(msg, sender, receiver_mod):
    """Pack with the sender's MAVLink object, decode with a fresh parser of ``receiver_mod``."""
    rx = receiver_mod.MAVLink(None)
    rx.robust_parsing = True
    return rx.parse_buffer(bytes(msg.pack(sender))) or []


def on_wire(items, mod):
    """The items as they come back after one MISSION_ITEM_INT encoding (float32, 1e7 / 1e4 integers)."""
    mav = mod.MAVLink(None, srcSystem=1, srcComponent=1)
    return [MissionItem.from_mavlink(wire(it.to_mavlink_int(mav, 1, 1), mav, mod)[0]) for it in items]


class Net:
    """Server and clients joined by an in-memory channel; ``loss``/``dup`` probabilities, random delay up
    to ``delay`` seconds (so messages overtake each other)."""

    def __init__(self, mod, server, seed=0, loss=0.0, dup=0.0, delay=0.0):
        self.mod, self.server, self.rng = mod, server, random.Random(seed)
        self.loss, self.dup, self.delay = loss, dup, delay
        self.queue, self.n, self.now, self.clients = [], 0, 0.0, {}
        self.drop = lambda msg: False                 # a test's own losses

    def add(self, name, client):
        self.clients[name] = client
        return client

    def send(self, msg, sender, to):
        if self.rng.random() < self.loss or self.drop(msg):
            return
        for _ in range(2 if self.rng.random() < self.dup else 1):
            for m in wire(msg, sender, self.mod):
                self.n += 1
                heapq.heappush(self.queue, (self.now + self.rng.uniform(0, self.delay), self.n, to, m))

    def to_vehicle(self, name, msgs):
        for m in msgs:
            self.send(m, self.clients[name].mav, "vehicle:" + name)

    def step(self, dt=0.01):
        self.now += dt
        while self.queue and self.queue[0][0] <= self.now:
            _, _, to, m = heapq.heappop(self.queue)
            if to.startswith("vehicle:"):
                for r in self.server.handle(m, self.now, to.split(":", 1)[1]):
                    self.send(r.msg, self.server.mav, r.dest)
            elif to in self.clients:                  # else: to a ground station no longer listening
                self.to_vehicle(to, self.clients[to].handle(m, self.now))
        for r in self.server.tick(self.now):
            self.send(r.msg, self.server.mav, r.dest)
        for name, c in self.clients.items():
            self.to_vehicle(name, c.tick(self.now))

    def run(self, until, limit=120.0):
        while not until() and self.now < limit:
            self.step()
        return until()


def start(net, client, how, *args):
    """``client.start_<how>(*args)`` at the net's time, its first messages sent; returns the client."""
    name = next(n for n, c in net.clients.items() if c is client)
    net.to_vehicle(name, getattr(client, "start_" + how)(*args, now=net.now))
    return client


# ------------------------------------------------------------------------------------------ encoding

def test_item_int_scaling_follows_common_xml(mod):
    mav = mod.MAVLink(None, srcSystem=1, srcComponent=1)
    glob = MissionItem(0, mod.MAV_FRAME_GLOBAL_RELATIVE_ALT, 16, x=33.7756, y=-84.3963)
    glob = glob.to_mavlink_int(mav, 1, 1)
    assert (glob.x, glob.y) == (337756000, -843963000)                 # degrees * 1e7
    local = MissionItem(0, mod.MAV_FRAME_LOCAL_ENU, 16, x=1.2345, y=-2.5).to_mavlink_int(mav, 1, 1)
    assert (local.x, local.y) == (12345, -25000)                       # metres * 1e4
    raw = MissionItem(0, mod.MAV_FRAME_MISSION, 177, x=4, y=7).to_mavlink_int(mav, 1, 1)
    assert (raw.x, raw.y) == (4, 7)
    unset = MissionItem(0, mod.MAV_FRAME_GLOBAL_INT, 16, x=math.nan, y=1.0).to_mavlink_int(mav, 1, 1)
    assert unset.x == M.INT32_MAX and math.isnan(MissionItem.from_mavlink(wire(unset, mav, mod)[0]).x)
    with pytest.raises(ValueError):
        MissionItem(0, mod.MAV_FRAME_LOCAL_NED, 16, x=300000.0).to_mavlink_int(mav, 1, 1)


def test_legacy_mission_item_keeps_float_coordinates(mod):
    mav = mod.MAVLink(None, srcSystem=1, srcComponent=1)
    msg = mav.mission_item_encode(1, 1, 2, 3, 16, 0, 1, 0, 0, 0, 0, 33.5, -84.25, 3.0, 0)
    item = MissionItem.from_mavlink(wire(msg, mav, mod)[0])
    assert (item.seq, item.x, item.y, item.z) == (2, 33.5, -84.25, 3.0)


def test_items_with_nan_params_compare_equal():
    a = MissionItem(0, 3, 16, param4=math.nan)
    b = MissionItem(0, 3, 16, param4=float("nan"))
    assert a == b and hash(a) == hash(b)
    assert a != MissionItem(0, 3, 16, param4=0.0)


# ------------------------------------------------------------------------------------------ round trips

def test_upload_then_download_round_trip(mod):
    store = Store(OLD)
    net = Net(mod, make_server(mod, store))
    c = start(net, net.add("gcs", make_client(mod)), "upload", NEW)
    assert net.run(lambda: c.done) and c.result == M.ACCEPTED and c.error is None
    assert store.items == on_wire(NEW, mod) and store.calls == [("upload", len(NEW))]
    [ev] = net.server.pop_events()
    assert (ev.kind, ev.count, ev.plan_id) == ("accepted", len(NEW), store.plan)
    start(net, c, "download", M.MISSION)
    assert net.run(lambda: c.done) and c.result == M.ACCEPTED
    assert c.items == on_wire(NEW, mod)
    net.run(lambda: False, limit=net.now + 0.1)
    assert not net.server.busy                       # the final ACK ended the download
    assert net.server.stats["received"] == net.server.stats[M.HANDLED]


def test_fence_and_rally_download_empty_and_refuse_uploads(mod):
    store = Store(OLD)
    net = Net(mod, make_server(mod, store))
    c = net.add("gcs", make_client(mod))
    for mt in (M.FENCE, M.RALLY):
        start(net, c, "download", mt)
        assert net.run(lambda: c.done) and c.result == M.ACCEPTED and c.items == []
        start(net, c, "upload", OLD[:1], mt)
        assert net.run(lambda: c.done) and c.result == M.UNSUPPORTED and "MAV_MISSION_UNSUPPORTED" in c.error
        start(net, c, "clear", mt)
        assert net.run(lambda: c.done) and c.result == M.ACCEPTED
    assert store.items == OLD and store.calls == []


@pytest.mark.parametrize("how", ["clear_all", "count_zero", "clear_all_types"])
def test_clear(mod, how):
    store = Store(OLD)
    net = Net(mod, make_server(mod, store))
    c = net.add("gcs", make_client(mod))
    if how == "count_zero":
        start(net, c, "upload", [])
    else:
        start(net, c, "clear", M.ALL if how == "clear_all_types" else M.MISSION)
    assert net.run(lambda: c.done) and c.result == M.ACCEPTED
    assert store.items == [] and store.calls == [("clear", M.ALL if how == "clear_all_types" else M.MISSION)]
    assert [e.kind for e in net.server.pop_events()] == ["cleared"]


def test_refused_upload_keeps_the_old_mission(mod):
    store = Store(OLD)
    store.verdict = (mod.MAV_MISSION_INVALID_PARAM1, "item 2: hold time must be >= 0")
    net = Net(mod, make_server(mod, store))
    c = start(net, net.add("gcs", make_client(mod)), "upload", NEW)
    assert net.run(lambda: c.done) and c.result == mod.MAV_MISSION_INVALID_PARAM1
    assert "MAV_MISSION_INVALID_PARAM1" in c.error and "\n" not in c.error
    assert store.items == OLD and store.calls == []
    [ev] = net.server.pop_events()
    assert (ev.kind, ev.result, ev.reason) == ("refused", mod.MAV_MISSION_INVALID_PARAM1, store.verdict[1])


def test_callback_that_raises_is_answered_with_error(mod):
    store = Store(OLD)
    store.on_upload = lambda items: 1 / 0
    net = Net(mod, make_server(mod, store))
    c = start(net, net.add("gcs", make_client(mod)), "upload", NEW)
    assert net.run(lambda: c.done) and c.result == M.ERROR and store.items == OLD


def test_too_many_items_no_space(mod):
    store = Store(OLD)
    net = Net(mod, make_server(mod, store, max_items=4))
    c = start(net, net.add("gcs", make_client(mod)), "upload", NEW)
    assert net.run(lambda: c.done) and c.result == M.NO_SPACE and store.items == OLD


# ------------------------------------------------------------------------------------------ one at a time

def test_second_ground_station_is_denied_while_a_transfer_runs(mod):
    store = Store(OLD)
    net = Net(mod, make_server(mod, store), delay=0.05)
    a = net.add("a", make_client(mod, 255))
    b = net.add("b", make_client(mod, 254))
    start(net, a, "upload", NEW)
    net.run(lambda: net.server.busy)
    start(net, b, "upload", OLD)
    assert net.run(lambda: a.done and b.done)
    assert a.result == M.ACCEPTED and b.result == M.DENIED and "MAV_MISSION_DENIED" in b.error
    assert store.items == on_wire(NEW, mod) and net.server.stats["denied"] == 1
    start(net, b, "download")                        # free again
    assert net.run(lambda: b.done) and b.result == M.ACCEPTED and b.items == on_wire(NEW, mod)


def test_silent_download_is_released_after_the_idle_timeout(mod):
    net = Net(mod, make_server(mod, Store(OLD)))
    a, b = net.add("a", make_client(mod, 255)), net.add("b", make_client(mod, 254))
    net.to_vehicle("a", [a.mav.mission_request_list_encode(VEHICLE, 1, 0)])    # a asks, then goes quiet
    net.step()
    assert net.server.busy
    net.run(lambda: not net.server.busy, limit=net.now + M.IDLE_TIMEOUT + 0.1)
    start(net, b, "download")
    assert net.run(lambda: b.done) and b.result == M.ACCEPTED and b.items == on_wire(OLD, mod)


# ------------------------------------------------------------------------------------------ timeouts

def replies_of(server, msgs, now, source="gcs"):
    return [r.msg for m in msgs for r in server.handle(m, now, source)]


def test_vehicle_rerequests_then_cancels_a_silent_upload(mod):
    store = Store(OLD)
    server = make_server(mod, store)
    gcs = mod.MAVLink(None, srcSystem=GCS_ID, srcComponent=190)
    [req] = replies_of(server, wire(gcs.mission_count_encode(VEHICLE, 1, 4, 0), gcs, mod), 0.0)
    assert (req.get_type(), req.seq, req.target_system) == ("MISSION_REQUEST_INT", 0, GCS_ID)
    times = []
    t = 0.0
    while server.busy and t < 30:
        t = round(t + 0.05, 2)
        for r in server.tick(t):
            times.append((t, r.msg.get_type()))
    assert [k for _, k in times] == ["MISSION_REQUEST_INT"] * M.MAX_RETRIES + ["MISSION_ACK"]
    assert times[0][0] == pytest.approx(M.DEFAULT_TIMEOUT)
    assert times[-1][0] == pytest.approx(M.DEFAULT_TIMEOUT * (M.MAX_RETRIES + 1))
    [ev] = server.pop_events()
    assert ev.kind == "cancelled" and ev.result == M.CANCELLED and store.items == OLD


def test_client_gives_up_after_retries_with_one_line(mod):
    c = make_client(mod)
    sent = [m.get_type() for m in c.start_upload(NEW, now=0.0)]
    t = 0.0
    while not c.done and t < 30:
        t = round(t + 0.05, 2)
        sent += [m.get_type() for m in c.tick(t)]
    assert sent == ["MISSION_COUNT"] * (1 + M.MAX_RETRIES) and c.result == M.TIMEOUT
    assert t == pytest.approx(M.DEFAULT_TIMEOUT * (M.MAX_RETRIES + 1))
    assert "did not answer MISSION_COUNT" in c.error and "\n" not in c.error


def test_lost_final_ack_is_repeated_without_a_second_upload(mod):
    store = Store(OLD)
    net = Net(mod, make_server(mod, store))
    lost = []
    net.drop = lambda m: m.get_type() == "MISSION_ACK" and not lost and not lost.append(m)
    c = start(net, net.add("gcs", make_client(mod)), "upload", NEW[:2])
    assert net.run(lambda: c.done) and c.result == M.ACCEPTED
    assert len(lost) == 1 and store.calls == [("upload", 2)]
    assert net.now >= M.DEFAULT_TIMEOUT                 # it took the client's retry of the last item


def test_out_of_sequence_item_is_dropped_and_the_expected_one_requested(mod):
    server = make_server(mod, Store(OLD))
    gcs = mod.MAVLink(None, srcSystem=GCS_ID, srcComponent=190)
    replies_of(server, wire(gcs.mission_count_encode(VEHICLE, 1, 3, 0), gcs, mod), 0.0)
    item2 = NEW[2].to_mavlink_int(gcs, VEHICLE, 1)
    [req] = replies_of(server, wire(item2, gcs, mod), 0.5)
    assert (req.get_type(), req.seq) == ("MISSION_REQUEST_INT", 0)
    assert server.stats["out_of_sequence"] == 1
    assert replies_of(server, wire(item2, gcs, mod), 0.55) == []        # re-requests are rate limited
    assert server.stats["out_of_sequence"] == 2


def test_messages_for_another_system_or_from_another_source_are_counted(mod):
    server = make_server(mod, Store(OLD))
    gcs = mod.MAVLink(None, srcSystem=GCS_ID, srcComponent=190)
    assert replies_of(server, wire(gcs.mission_count_encode(VEHICLE + 1, 1, 3, 0), gcs, mod), 0.0) == []
    assert replies_of(server, wire(gcs.mission_count_encode(VEHICLE, 5, 3, 0), gcs, mod), 0.0) == []
    assert server.stats["not_for_us"] == 2
    replies_of(server, wire(gcs.mission_count_encode(VEHICLE, 1, 3, 0), gcs, mod), 0.0)
    assert replies_of(server, wire(NEW[0].to_mavlink_int(gcs, VEHICLE, 1), gcs, mod), 0.1, "other") == []
    assert replies_of(server, wire(NEW[0].to_mavlink_int(gcs, VEHICLE, 1), gcs, mod), 0.1) != []
    item = NEW[1].to_mavlink_int(gcs, VEHICLE, 1)
    item.mission_type = M.FENCE
    assert replies_of(server, wire(item, gcs, mod), 0.2) == []
    assert (server.stats["other_source"], server.stats["wrong_mission_type"]) == (1, 1)


def test_gcs_error_ack_cancels_the_upload(mod):
    store = Store(OLD)
    server = make_server(mod, store)
    gcs = mod.MAVLink(None, srcSystem=GCS_ID, srcComponent=190)
    replies_of(server, wire(gcs.mission_count_encode(VEHICLE, 1, 3, 0), gcs, mod), 0.0)
    replies_of(server, wire(gcs.mission_ack_encode(VEHICLE, 1, M.CANCELLED, 0), gcs, mod), 0.1)
    assert not server.busy and store.items == OLD
    assert [e.kind for e in server.pop_events()] == ["cancelled"]


# ------------------------------------------------------------------------------------------ lossy channel

SEEDS = range(24)


def _lossy(mod, seed, what, loss):
    store = Store(OLD)
    net = Net(mod, make_server(mod, store), seed=seed, loss=loss, dup=0.1, delay=0.3)
    c = net.add("gcs", make_client(mod))
    {"upload": lambda: start(net, c, "upload", NEW), "download": lambda: start(net, c, "download"),
     "clear": lambda: start(net, c, "clear")}[what]()
    finished = net.run(lambda: c.done)
    net.run(lambda: False, limit=net.now + 12)        # let the vehicle finish its own retries
    return finished, c, store, net.server


@pytest.mark.parametrize("loss, min_ok", [(0.15, 0.9), (0.5, 0.0)])
@pytest.mark.parametrize("what", ["upload", "download", "clear"])
def test_lossy_reordering_channel_completes_or_fails_cleanly(mod, what, loss, min_ok):
    """15 % loss: nearly all complete; 50 % loss: many fail, and each failure must be clean."""
    ok = 0
    for seed in SEEDS:
        finished, c, store, server = _lossy(mod, seed, what, loss)
        assert finished, f"seed {seed}: client never finished"
        kinds = [e.kind for e in server.pop_events()]
        if c.result == M.ACCEPTED:
            ok += 1
        else:
            assert c.error and "\n" not in c.error, f"seed {seed}"
        if what == "upload":
            assert kinds.count("accepted") <= 1
            assert store.items == (on_wire(NEW, mod) if "accepted" in kinds else OLD), f"seed {seed}"
            if c.result == M.ACCEPTED:
                assert "accepted" in kinds
        elif what == "download":
            assert store.items == OLD and (c.result != M.ACCEPTED or c.items == on_wire(OLD, mod))
        else:
            assert store.items == ([] if "cleared" in kinds else OLD)
        assert not server.busy, f"seed {seed}: vehicle still busy"
    assert ok >= min_ok * len(SEEDS), f"only {ok}/{len(SEEDS)} {what}s completed at {loss:.0%} loss"


# ------------------------------------------------------------------------------------------ third party

def test_pymavlink_stock_dialects_as_ground_station(mod):
    """pymavlink's own common (MAVLink 2) and MAVLink 1 'all' dialects talk to our server through bytes;
    the upload uses MAVWPLoader's legacy MISSION_ITEMs, as MAVProxy sends them."""
    from pymavlink import mavwp
    from pymavlink.dialects.v10 import all as v10
    from pymavlink.dialects.v20 import common as v20

    store = Store(OLD)
    server = make_server(mod, store)
    loader = mavwp.MAVWPLoader()
    loader.load("configs/missions/square_6.waypoints")
    wps = [loader.wp(i) for i in range(1, loader.count())]            # line 0 is home
    g1 = v10.MAVLink(None, srcSystem=GCS_ID, srcComponent=190)
    g2 = v20.MAVLink(None, srcSystem=GCS_ID, srcComponent=190)

    def send(gmav, gmod, msg):
        return [d for r in replies_of(server, wire(msg, gmav, mod), 0.0) for d in wire(r, server.mav, gmod)]

    [req] = send(g1, v10, g1.mission_count_encode(VEHICLE, 1, len(wps)))
    for i, wp in enumerate(wps):
        assert (req.get_type(), req.seq) == ("MISSION_REQUEST_INT", i)
        msg = g1.mission_item_encode(VEHICLE, 1, i, wp.frame, wp.command, 0, wp.autocontinue, wp.param1,
                                     wp.param2, wp.param3, wp.param4, wp.x, wp.y, wp.z)
        [req] = send(g1, v10, msg)
    assert (req.get_type(), req.type) == ("MISSION_ACK", v20.MAV_MISSION_ACCEPTED)
    assert [(it.x, it.y) for it in store.items] == [(pytest.approx(w.x), pytest.approx(w.y)) for w in wps]

    [count] = send(g2, v20, g2.mission_request_list_encode(VEHICLE, 1, 0))
    assert count.get_type() == "MISSION_COUNT" and count.count == len(wps)
    got = []
    for i in range(count.count):
        [item] = send(g2, v20, g2.mission_request_encode(VEHICLE, 1, i, 0))    # deprecated request
        assert item.get_type() == "MISSION_ITEM_INT" and item.seq == i
        got.append((item.x, item.y))
    # legacy MISSION_ITEM carries float32 degrees (~0.5 m here): why it is deprecated
    assert got == [(round(float(np.float32(w.x)) * 1e7), round(float(np.float32(w.y)) * 1e7)) for w in wps]
    assert send(g2, v20, g2.mission_ack_encode(VEHICLE, 1, 0, 0)) == [] and not server.busy


def test_a_home_line_as_mavproxy_sends_it_is_skipped_and_the_rest_renumbered(mod):
    """MAVProxy's `wp load` sends a WPL file's home line as item 0 (current, NAV_WAYPOINT, MAV_FRAME_GLOBAL): the
    vehicle keeps no home, so that item is skipped and the waypoints after it are items 0.. of the mission."""
    from pymavlink import mavwp

    loader = mavwp.MAVWPLoader()
    loader.load("configs/missions/square_6.waypoints")
    wps = [loader.wp(i) for i in range(loader.count())]
    assert (wps[0].seq, wps[0].current, wps[0].frame, wps[0].command) == (0, 1, 0, 16)      # the home line
    store = Store(OLD)
    server = make_server(mod, store)
    g = mod.MAVLink(None, srcSystem=GCS_ID, srcComponent=190)
    replies_of(server, wire(g.mission_count_encode(VEHICLE, 1, len(wps)), g, mod), 0.0)
    for wp in wps:
        msg = g.mission_item_int_encode(VEHICLE, 1, wp.seq, wp.frame, wp.command, wp.current, wp.autocontinue,
                                        wp.param1, wp.param2, wp.param3, wp.param4, int(wp.x * 1e7),
                                        int(wp.y * 1e7), wp.z)
        [ack] = [m for r in replies_of(server, wire(msg, g, mod), 0.0) for m in wire(r, server.mav, mod)]
    assert (ack.get_type(), ack.type) == ("MISSION_ACK", M.ACCEPTED) and server.home_skipped
    assert [it.seq for it in store.items] == list(range(len(wps) - 1))
    assert [(it.x, it.y) for it in store.items] == [(pytest.approx(w.x), pytest.approx(w.y)) for w in wps[1:]]


@pytest.mark.parametrize("current, frame, command", [(1, 3, 16), (1, 6, 16), (0, 0, 16), (1, 0, 17)],
                         ids=["current-relative-alt", "current-relative-alt-int", "not-current", "loiter"])
def test_an_item_0_that_is_no_home_line_is_kept(mod, current, frame, command):
    """QGroundControl and MAVSDK mark their first waypoint current but in a relative-altitude frame; a download read
    back marks nothing current: item 0 is a task then."""
    store = Store()
    server = make_server(mod, store)
    g = mod.MAVLink(None, srcSystem=GCS_ID, srcComponent=190)
    replies_of(server, wire(g.mission_count_encode(VEHICLE, 1, 2), g, mod), 0.0)
    for seq in (0, 1):
        msg = g.mission_item_int_encode(VEHICLE, 1, seq, frame if seq == 0 else 3, command if seq == 0 else 16,
                                        current if seq == 0 else 0, 1, 0, 0, 0, 0, 337756000 + seq, -843963000, 0)
        replies_of(server, wire(msg, g, mod), 0.0)
    assert [it.seq for it in store.items] == [0, 1] and store.items[0].command == command
    assert not server.home_skipped


def test_our_client_marks_no_item_current_so_a_global_first_waypoint_is_kept(mod):
    store = Store()
    net = Net(mod, make_server(mod, store))
    items = [MissionItem(0, 0, 16, x=33.7756, y=-84.3963), MissionItem(1, 3, 16, x=33.7757, y=-84.3963)]
    c = start(net, net.add("gcs", make_client(mod)), "upload", items)
    assert net.run(lambda: c.done) and c.result == M.ACCEPTED
    assert store.items == on_wire(items, mod) and not net.server.home_skipped


# ------------------------------------------------------------------------------------------ random input

KINDS = ["mission_count", "mission_request_int", "mission_request", "mission_item_int", "mission_item",
         "mission_ack", "mission_clear_all", "mission_request_list", "heartbeat", "mission_current"]


@st.composite
def messages(draw, mod):
    kind = draw(st.sampled_from(KINDS))
    target = draw(st.sampled_from([0, VEHICLE, VEHICLE, GCS_ID, GCS_ID, 9]))
    comp = draw(st.sampled_from([0, 1, 1, 7]))
    mt = draw(st.sampled_from([0, 0, 0, 1, 2, 255, 42]))
    small = st.integers(0, 8)
    f = st.floats(width=32, allow_nan=True)
    i32 = st.integers(-2**31, 2**31 - 1)
    args = {
        "mission_count": lambda: (target, comp, draw(small), mt),
        "mission_request_int": lambda: (target, comp, draw(small), mt),
        "mission_request": lambda: (target, comp, draw(small), mt),
        "mission_item_int": lambda: (target, comp, draw(small), draw(st.integers(0, 25)),
                                     draw(st.integers(0, 65535)), 0, 1, *(draw(f) for _ in range(4)),
                                     draw(i32), draw(i32), draw(f), mt),
        "mission_item": lambda: (target, comp, draw(small), draw(st.integers(0, 25)), 16, 0, 1,
                                 *(draw(f) for _ in range(7)), mt),
        "mission_ack": lambda: (target, comp, draw(st.integers(0, 20)), mt),
        "mission_clear_all": lambda: (target, comp, mt),
        "mission_request_list": lambda: (target, comp, mt),
        "heartbeat": lambda: (6, 8, 0, 0, 4),
        "mission_current": lambda: (draw(small),),
    }[kind]()
    sysid = draw(st.sampled_from([GCS_ID, 254, VEHICLE]))
    return kind, args, sysid, draw(st.sampled_from(["a", "b", "c"])), draw(st.floats(0, 2.0))


@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_server_never_raises_and_counts_every_message(mod, data):
    store = Store(OLD)
    server = make_server(mod, store)
    senders = {s: mod.MAVLink(None, srcSystem=s, srcComponent=190) for s in (GCS_ID, 254, VEHICLE)}
    seq = data.draw(st.lists(messages(mod), max_size=40))
    now, n = 0.0, 0
    for kind, args, sysid, source, dt in seq:
        now += dt
        sender = senders[sysid]
        for m in wire(getattr(sender, kind + "_encode")(*args), sender, mod):
            n += 1
            for r in server.handle(m, now, source):
                r.msg.pack(server.mav)                    # every reply encodes
        for r in server.tick(now):
            r.msg.pack(server.mav)
    s = server.stats
    assert s["received"] == n == s[M.HANDLED] + sum(s[k] for k in M.DROPS)
    assert store.items == OLD or ("upload", len(store.items)) in store.calls or store.items == []
    # whatever happened, the server frees itself and serves a clean ground station
    net = Net(mod, server)
    net.now = now
    net.run(lambda: not server.busy, limit=now + M.DEFAULT_TIMEOUT * (M.MAX_RETRIES + 2))
    assert not server.busy
    c = start(net, net.add("z", make_client(mod, 200)), "upload", NEW)
    assert net.run(lambda: c.done, limit=net.now + 30) and c.result == M.ACCEPTED


@settings(max_examples=100, deadline=None)
@given(data=st.data())
def test_client_never_raises_on_random_vehicle_messages(mod, data):
    c = make_client(mod)
    how = data.draw(st.sampled_from(["upload", "download", "clear"]))
    {"upload": lambda: c.start_upload(NEW, now=0.0), "download": lambda: c.start_download(now=0.0),
     "clear": lambda: c.start_clear(now=0.0)}[how]()
    veh = {s: mod.MAVLink(None, srcSystem=s, srcComponent=1) for s in (VEHICLE, 9)}
    now = 0.0
    for kind, args, sysid, _, dt in data.draw(st.lists(messages(mod), max_size=40)):
        now += dt
        sender = veh[VEHICLE if sysid != 9 else 9]
        for m in wire(getattr(sender, kind + "_encode")(*args), sender, mod):
            for out in c.handle(m, now):
                out.pack(c.mav)
        for out in c.tick(now):
            out.pack(c.mav)
    c.tick(now + 100)
    for _ in range(M.MAX_RETRIES + 2):
        now += 100
        c.tick(now)
    assert c.done and (c.result == M.ACCEPTED) == (c.error is None)


@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_truncated_and_bit_flipped_frames_are_counted_never_raised(mod, data):
    """A whole upload's frames with flipped bits and cut ends, parsed robustly as the link does."""
    server = make_server(mod, Store(OLD))
    gcs = mod.MAVLink(None, srcSystem=GCS_ID, srcComponent=190)
    frames = [bytes(gcs.mission_count_encode(VEHICLE, 1, len(NEW), 0).pack(gcs))]
    frames += [bytes(it.to_mavlink_int(gcs, VEHICLE, 1).pack(gcs)) for it in NEW]
    rx = mod.MAVLink(None)
    rx.robust_parsing = True
    n = 0
    for i, frame in enumerate(frames):
        raw = bytearray(frame)
        for _ in range(data.draw(st.integers(0, 3), label=f"flips {i}")):
            raw[data.draw(st.integers(0, len(raw) - 1))] ^= 1 << data.draw(st.integers(0, 7))
        raw = raw[:data.draw(st.integers(0, len(raw)), label=f"cut {i}")]
        for m in rx.parse_buffer(bytes(raw)) or []:
            n += 1
            server.handle(m, float(i), "gcs")
    s = server.stats
    assert s["received"] == n == s[M.HANDLED] + sum(s[k] for k in M.DROPS)
