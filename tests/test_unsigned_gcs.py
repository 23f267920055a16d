"""Ground stations that cannot sign (``comms.unsigned_gcs``): a signed robot takes unsigned ground-station frames from
the networks listed, and only those; peers sign whatever the list says; both outcomes are counted."""
from __future__ import annotations

import logging
import socket
import time

import pytest
import yaml

from runtime import config as C
from runtime.comms import dialect
from runtime.comms.link import DROP_REASONS, MavlinkLink
from runtime.comms.networks import Networks
from runtime.config.build import ConfigError

KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))


# ---------------------------------------------------------------------- config

def _robot_file(tmp_path, nets) -> str:
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump({"robot": {"id": 1}, "comms": {"unsigned_gcs": nets}}))
    return str(path)


def test_unsigned_gcs_is_empty_by_default_and_takes_ipv4_and_ipv6_networks(tmp_path):
    assert C.RobotConfig().comms.unsigned_gcs == ()
    nets = ["127.0.0.1/32", "10.0.0.0/24", "fd00::/64", "::1"]
    assert C.load_robot(_robot_file(tmp_path, nets)).comms.unsigned_gcs == tuple(nets)


@pytest.mark.parametrize("nets, key, why", [
    (["127.0.0.1/32", "10.0.0.1/24"], "comms.unsigned_gcs[1]", "host bits set: the network is 10.0.0.0/24"),
    (["lan"], "comms.unsigned_gcs[0]", "not an IPv4 or IPv6 network"),
    (["300.0.0.0/8"], "comms.unsigned_gcs[0]", "not an IPv4 or IPv6 network"),
    (["10.0.0.0/33"], "comms.unsigned_gcs[0]", "not an IPv4 or IPv6 network"),
    ([""], "comms.unsigned_gcs[0]", "empty"),
    ([24], "comms.unsigned_gcs[0]", None),
    ("10.0.0.0/24", "comms.unsigned_gcs", None),
])
def test_a_bad_network_is_one_line_naming_the_file_and_key(tmp_path, nets, key, why):
    path = _robot_file(tmp_path, nets)
    with pytest.raises(ConfigError) as exc:
        C.load_robot(path)
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith(f"{path}: {key}: expected ")
    if why is not None:
        assert "a network in CIDR form" in msg and why in msg


def test_mrta_daemon_check_refuses_a_bad_network_with_exit_2(tmp_path, capsys):
    from runtime.cli import main

    path = _robot_file(tmp_path, ["10.0.0.1/24"])
    assert main(["daemon", path, "--check"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "comms.unsigned_gcs[0]" in err and path in err


def test_networks_match_ipv4_ipv6_and_ipv4_seen_through_an_ipv6_socket():
    nets = Networks(["127.0.0.1/32", "fd00::/64"])
    assert ("127.0.0.1", 5) in nets and ("127.0.0.2", 5) not in nets
    assert ("fd00::7", 5, 0, 0) in nets and ("fd01::7", 5, 0, 0) not in nets
    assert ("::ffff:127.0.0.1", 5, 0, 0) in nets
    assert None not in Networks(["0.0.0.0/0"]) and ("x", 1) not in nets and not Networks()


# ---------------------------------------------------------------------- the link

def _mav(system: int, key=None):
    mav = dialect.load().MAVLink(None, srcSystem=system, srcComponent=190)
    if key is not None:
        mav.signing.secret_key, mav.signing.sign_outgoing, mav.signing.link_id = key, True, 1
        mav.signing.timestamp = int((time.time() - 1420070400) * 100_000)
    return mav


def command_long(system: int, key=None) -> bytes:
    mav = _mav(system, key)
    return mav.command_long_encode(1, 1, 512, 0, 148, 0, 0, 0, 0, 0, 0).pack(mav)


def param_request_list(system: int, key=None) -> bytes:
    mav = _mav(system, key)
    return mav.param_request_list_encode(1, 1).pack(mav)


def robot_state(system: int) -> bytes:
    from runtime.comms import codec
    from runtime.messages import RobotState

    return codec.encode(RobotState(system, 0, 1, (), 0.0, 0.0, 0, 0), _mav(system))


class Net:
    """Loopback sockets, one per sender address; ``send`` a datagram to the link and poll it (bounded)."""

    def __init__(self):
        self.socks: list[socket.socket] = []

    def sock(self) -> socket.socket:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        self.socks.append(s)
        return s

    def send(self, link, data: bytes, sock=None) -> None:
        before = link.counters.datagrams
        (sock or self.sock()).sendto(data, link.address)
        t0 = time.monotonic()
        while link.counters.datagrams == before and time.monotonic() - t0 < 2.0:
            link.poll(0.0)
            time.sleep(0.001)
        assert link.counters.datagrams == before + 1, "the datagram did not arrive within 2 s"

    def close(self):
        for s in self.socks:
            s.close()


@pytest.fixture
def net():
    n = Net()
    yield n
    n.close()


@pytest.fixture
def link_with():
    made = []

    def make(nets=(), peers=(), key=KEY, fleet=()):
        made.append(MavlinkLink(1, "127.0.0.1:0", peers, None, signing_key=key, unsigned_gcs=nets, fleet=fleet))
        return made[-1]

    yield make
    for link in made:
        link.close()


def _reconciles(c) -> bool:
    return c.datagrams == c.received + sum(getattr(c, k) for k in DROP_REASONS)


def test_unsigned_requests_from_a_listed_network_are_taken_and_counted(link_with, net):
    link = link_with(["127.0.0.1/32"])
    net.send(link, command_long(255))
    net.send(link, param_request_list(255))
    c = link.counters
    assert [m.get_type() for m, _ in link.gcs_inbox] == ["COMMAND_LONG", "PARAM_REQUEST_LIST"]
    assert (c.unsigned_gcs_taken, c.gcs_requests, c.received, c.unsigned_dropped) == (2, 2, 2, 0)
    assert link.gcs_addresses()                       # the station now gets telemetry too
    net.send(link, command_long(255, KEY))            # a signed request is no unsigned one
    assert (c.unsigned_gcs_taken, c.gcs_requests) == (2, 3) and _reconciles(c)


def test_unsigned_requests_from_elsewhere_change_nothing_and_are_counted(link_with, net):
    for nets in ((), ["10.0.0.0/24", "::1/128"]):
        link = link_with(nets)
        net.send(link, command_long(255))
        net.send(link, param_request_list(255))
        c = link.counters
        assert link.gcs_inbox == [] and not link.gcs_addresses()
        assert (c.unsigned_dropped, c.unsigned_gcs_taken, c.received) == (2, 0, 0) and _reconciles(c)


def test_peer_traffic_stays_signed_whatever_the_list_says(link_with, net):
    """From a listed network: an unsigned frame claiming a fleet robot's system id (a peer's, or this robot's), an
    unsigned agent message (even from an id outside the fleet), an unsigned request from a peer's address, and a
    wrongly signed frame are all refused; a station on an id outside the fleet (MAVSDK's 245) is taken."""
    peer = net.sock()
    link = link_with(["127.0.0.0/8"], peers=[f"127.0.0.1:{peer.getsockname()[1]}"], fleet=[2, 3])
    net.send(link, command_long(2))                   # a peer's system id
    net.send(link, param_request_list(1))             # this robot's own id
    net.send(link, robot_state(2))                    # an agent message
    net.send(link, robot_state(245))                  # an agent message from an id outside the fleet
    net.send(link, command_long(255), sock=peer)      # a ground station's id from a peer's address
    c = link.counters
    assert link.gcs_inbox == [] and c.unsigned_dropped == 5 and c.unsigned_gcs_taken == 0
    net.send(link, param_request_list(245))           # a MAVSDK app's default system id, outside the fleet
    assert len(link.gcs_inbox) == 1 and c.unsigned_gcs_taken == 1
    link.gcs_inbox.clear()
    net.send(link, command_long(255, OTHER_KEY))      # signed with another key: a bad signature, not unsigned
    net.send(link, command_long(2, OTHER_KEY))
    assert c.bad_signature_dropped == 2 and link.gcs_inbox == [] and link.poll(0.0) == []
    assert c.agent_received == 0 and c.received == 1 and _reconciles(c)      # the one request from 245


def _ipv6_loopback() -> bool:
    try:
        with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as s:
            s.bind(("::1", 0))
        return True
    except OSError:
        return False


@pytest.mark.skipif(not _ipv6_loopback(), reason="no IPv6 loopback")
def test_an_ipv6_station_is_taken_from_a_listed_ipv6_network_only():
    for nets, taken in ((["::1/128"], 1), (["fd00::/64", "127.0.0.0/8"], 0)):
        link = MavlinkLink(1, "[::1]:0", [], None, signing_key=KEY, unsigned_gcs=nets)
        s = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
        try:
            s.bind(("::1", 0))
            s.sendto(command_long(255), link.address)
            t0 = time.monotonic()
            while link.counters.datagrams == 0 and time.monotonic() - t0 < 2.0:
                link.poll(0.0)
                time.sleep(0.001)
            c = link.counters
            assert (len(link.gcs_inbox), c.unsigned_gcs_taken, c.unsigned_dropped) == (taken, taken, 1 - taken)
        finally:
            s.close()
            link.close()


def test_without_signing_the_list_changes_nothing(link_with, net):
    link = link_with(["10.0.0.0/24"], key=None)
    net.send(link, command_long(255))
    assert len(link.gcs_inbox) == 1 and link.counters.unsigned_gcs_taken == 0


def test_answers_to_an_unsigned_station_are_signed(link_with, net):
    from runtime.comms.link import was_signed

    link = link_with(["127.0.0.1/32"])
    s = net.sock()
    net.send(link, command_long(255), sock=s)
    m, addr = link.gcs_inbox[0]
    assert link.send_to(link.mav.command_ack_encode(512, 0), addr)
    s.settimeout(2.0)
    data, _ = s.recvfrom(65535)
    assert was_signed(data)


# ---------------------------------------------------------------------- a SITL fleet and a stock station

@pytest.fixture(params=[["127.0.0.1/32"], None], ids=["listed", "not-listed"])
def unsigned_fleet(request, tmp_path, caplog):
    """operator_4 on free ports, lock-stepped and signed, with (or without) 127.0.0.1/32 in every robot's
    comms.unsigned_gcs, and a pymavlink station on loopback without the key."""
    from sitl import launcher
    from tests.sitl_util import StockGcs, shipped_fleet

    f = launcher.build(shipped_fleet(tmp_path, "operator_4.yaml"), tmp_path / "run", unsigned_gcs=request.param)
    with caplog.at_level(logging.INFO):
        run = launcher.Lockstep(f)
    gcs = StockGcs(f.robots[1].udp_port, 1)
    try:
        yield request.param, f, run, gcs
    finally:
        gcs.close()
        run.close()
        f.close()


def _ask(gcs):
    from pymavlink import mavutil

    gcs.heartbeat()
    gcs.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                              mavutil.mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0)
    gcs.mav.param_request_list_send(1, 1)


def test_a_station_that_cannot_sign_is_answered_only_from_a_listed_network(unsigned_fleet, caplog):
    nets, f, run, gcs = unsigned_fleet
    daemon = run.daemons[1]
    said = [r for r in caplog.get_records("setup") if "accepting unsigned ground-station frames" in r.getMessage()]
    if nets:
        assert {r.robot for r in said} == set(f.robots) and len(said) == len(f.robots)
        assert "from 127.0.0.1/32" in said[0].getMessage()
    else:
        assert said == []
    before = daemon.snapshot()["link"]
    _ask(gcs)
    seen = gcs.wait(lambda m: m.get_type() == "PARAM_VALUE", 5.0, run.step)
    for _ in range(20):                               # and what else the robot would answer, if anything
        run.step()
    seen += gcs.drain()
    kinds = {m.get_type() for m in seen if m.get_srcSystem() == 1}
    link = daemon.snapshot()["link"]
    assert "HEARTBEAT" in kinds                       # the robot is seen either way (its GCS telemetry)
    if nets:
        assert {"COMMAND_ACK", "AUTOPILOT_VERSION", "PARAM_VALUE"} <= kinds
        assert link["unsigned_gcs_taken"] - before["unsigned_gcs_taken"] == 2
        assert link["unsigned_dropped"] == before["unsigned_dropped"]
    else:
        assert not kinds & {"COMMAND_ACK", "AUTOPILOT_VERSION", "PARAM_VALUE"}
        assert link["unsigned_dropped"] - before["unsigned_dropped"] == 2      # the request and the PARAM_REQUEST_LIST
        assert link["unsigned_gcs_taken"] == 0


@pytest.mark.parametrize("unsigned_fleet", [["127.0.0.1/32"]], indirect=True, ids=["listed"])
def test_an_unsigned_frame_claiming_a_peers_id_is_not_taken_from_a_listed_network(unsigned_fleet):
    _, f, run, _ = unsigned_fleet
    daemon = run.daemons[1]
    before = daemon.snapshot()["link"]
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.bind(("127.0.0.1", 0))
        s.settimeout(0.05)
        # robot 2's system id, as a ground-station request and as an agent message (an award is peer traffic)
        s.sendto(command_long(2), ("127.0.0.1", f.robots[1].udp_port))
        s.sendto(robot_state(2), ("127.0.0.1", f.robots[1].udp_port))
        answered = []
        for _ in range(20):
            run.step()
            try:
                answered.append(s.recvfrom(65535)[0])
            except (BlockingIOError, socket.timeout):
                pass
    finally:
        s.close()
    link = daemon.snapshot()["link"]
    assert answered == []
    assert link["unsigned_dropped"] - before["unsigned_dropped"] == 2
    assert link["unsigned_gcs_taken"] == before["unsigned_gcs_taken"]


def test_mrta_sitl_run_refuses_a_bad_unsigned_gcs_with_one_line_and_exit_2(tmp_path, capsys):
    from runtime.cli import main
    from tests.sitl_util import shipped_fleet

    fleet = str(shipped_fleet(tmp_path, "operator_4.yaml"))
    for extra, want in ((["--unsigned-gcs", "127.0.0.1/32", "--unsigned-gcs", "10.0.0.1/24"],
                         "--unsigned-gcs: expected a network in CIDR form"),
                        (["--unsigned-gcs", "127.0.0.1/32", "--no-signing"], "--unsigned-gcs: expected a signed fleet")):
        assert main(["sitl", "run", fleet, "--run-dir", str(tmp_path / "run"), *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and want in err, err


def test_mrta_sitl_run_sets_the_list_on_every_robot(tmp_path):
    from sitl import launcher
    from tests.sitl_util import shipped_fleet

    f = launcher.build(shipped_fleet(tmp_path, "operator_4.yaml"), tmp_path / "run",
                       unsigned_gcs=["127.0.0.1/32", "fd00::/64"])
    try:
        assert {C.load_robot(r.config_path).comms.unsigned_gcs for r in f.robots.values()} == \
            {("127.0.0.1/32", "fd00::/64")}
    finally:
        f.close()


def test_mrta_mission_without_a_key_uploads_only_where_its_network_is_listed(unsigned_fleet, capsys):
    """`mrta mission upload` without --key (a station that cannot sign) against the signed fleet: taken from a listed
    network; elsewhere the robot stays silent to it and the tool says the fleet signs."""
    import threading

    from runtime.cli import main
    from tests.sitl_util import CONFIGS

    nets, f, run, _ = unsigned_fleet
    target = f"127.0.0.1:{f.robots[1].udp_port}"
    rc: list[int] = []
    tool = threading.Thread(target=lambda: rc.append(main(
        ["mission", "upload", target, str(CONFIGS / "missions" / "square_6.waypoints"), "--timeout", "3"])))
    tool.start()
    t0 = time.monotonic()
    while tool.is_alive() and time.monotonic() - t0 < 20.0:
        run.step()
        time.sleep(0.002)
    tool.join(timeout=10.0)
    err = capsys.readouterr().err
    tasks = run.daemons[1].core.node.table.listing()
    if nets:
        assert rc == [0] and len(tasks) == 6, err
    else:
        assert rc == [1] and tasks == [] and "pass --key FILE" in err, err
