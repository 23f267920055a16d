"""The transport seam without Zenoh: ``udp`` runs exactly as before with the zenoh package absent (its import
blocked here), the ``comms.transport`` / ``comms.zenoh`` keys and their errors, and what `mrta router` and
`mrta sitl run --transport zenoh` say when the extra is missing."""
from __future__ import annotations

import sys
import time
import typing

import pytest

from runtime import cli
from runtime import config as C
from runtime.allocation.formation import messages as M
from runtime.comms.link import open_link
from runtime.comms.transport import TRANSPORTS, open_transport
from runtime.config.robot import CommsConfig, Peer
from runtime.errors import InputError

KEY_FILE_TEXT = bytes(range(32)).hex() + "\n"


@pytest.fixture
def no_zenoh(monkeypatch):
    """``import zenoh`` raises ImportError, as where the [zenoh] extra is not installed."""
    monkeypatch.setitem(sys.modules, "zenoh", None)


def test_udp_runs_with_zenoh_absent(no_zenoh, tmp_path):
    key = tmp_path / "fleet.key"
    key.write_text(KEY_FILE_TEXT)
    a = open_link(CommsConfig(listen="127.0.0.1:0", gcs=None, signing_key=str(key)), 1)
    try:
        b = open_link(CommsConfig(listen="127.0.0.1:0", gcs=None, signing_key=str(key),
                                  peers=(Peer(1, "127.0.0.1:%d" % a.address[1]),)), 2)
        try:
            assert a.transport is a.udp and b.transport.copies
            b.send_agent([M.Bid(2, 0, 1, 5, 0.5)], 0.0)
            got, t0 = [], time.monotonic()
            while not got and time.monotonic() - t0 < 2.0:
                got += a.poll(0.0)
                time.sleep(0.001)
            assert got == [M.Bid(2, 0, 1, 5, 0.5)] and b.counters.peer_sent == 1
        finally:
            b.close()
    finally:
        a.close()


def test_choosing_zenoh_without_the_extra_says_how_to_install_it(no_zenoh):
    comms = CommsConfig(transport="zenoh")
    with pytest.raises(InputError, match=r"pip install 'mrta-runtime\[zenoh\]'"):
        open_transport(comms, 1)


def test_mrta_router_without_the_extra_is_one_line_exit_2(no_zenoh, capsys):
    assert cli.main(["router", "--listen", "tcp/127.0.0.1:7447", "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "mrta-runtime[zenoh]" in err


@pytest.mark.parametrize("argv, expected", [
    (["--listen", "127.0.0.1:7447"], "--listen: expected a Zenoh endpoint PROTO/HOST:PORT"),
    (["--listen", "tcp/127.0.0.1:7447", "--connect", "tcp/host"], "--connect: expected a Zenoh endpoint"),
    (["--listen", "tcp/127.0.0.1:99999"], "--listen: expected a Zenoh endpoint"),
])
def test_mrta_router_refuses_a_bad_endpoint(capsys, argv, expected):
    assert cli.main(["router", *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"mrta: {expected}"), err


def test_the_config_offers_every_registered_transport():
    hint = typing.get_type_hints(CommsConfig)["transport"]
    assert set(typing.get_args(hint)) == set(TRANSPORTS)


def _robot(tmp_path, comms: str):
    p = tmp_path / "robot.yaml"
    p.write_text("robot: {id: 1}\ngps: {enabled: false}\ncomms:\n" + comms)
    return p


@pytest.mark.parametrize("comms, key, expected", [
    ("  transport: zenoh\n", "comms.zenoh.connect", "the segment's router endpoint(s)"),
    ("  transport: zenoh\n  zenoh: {connect: [localhost:7447]}\n", "comms.zenoh.connect[0]", "a Zenoh endpoint"),
    ("  transport: zenoh\n  zenoh: {connect: [tcp/a:1], fleet: a/b}\n", "comms.zenoh.fleet", "a fleet name"),
    ("  transport: zenoh\n  zenoh: {connect: [tcp/a:1], congestion: wait}\n", "comms.zenoh.congestion", "one of"),
    ("  transport: mqtt\n", "comms.transport", "one of"),
])
def test_bad_transport_keys_name_the_key(tmp_path, comms, key, expected):
    with pytest.raises(InputError) as e:
        C.validate_robot(C.load_robot(_robot(tmp_path, comms)))
    assert f": {key}: expected" in str(e.value) and expected in str(e.value), str(e.value)


def test_over_zenoh_peers_are_ids_without_addresses(tmp_path):
    cfg = C.load_robot(_robot(tmp_path, "  transport: zenoh\n  zenoh: {mode: client, connect: [tcp/127.0.0.1:7447]}\n"
                                        "  peers: [{id: 2}, {id: 3}]\n"))
    C.validate_robot(cfg)
    assert [p.id for p in cfg.comms.peers] == [2, 3] and cfg.comms.zenoh.congestion == "drop"
    peer = C.load_robot(_robot(tmp_path, "  transport: zenoh\n  zenoh: {mode: peer, listen: [tcp/127.0.0.1:0]}\n"))
    C.validate_robot(peer)                    # peer mode needs no router


def test_sitl_segments_need_zenoh(capsys):
    assert cli.main(["sitl", "run", "create2_4", "--segments", "2"]) == 2
    assert "--segments: expected with --transport zenoh" in capsys.readouterr().err
