"""What a robot config must satisfy beyond its schema before a daemon starts: the checks `mrta daemon` runs at
start-up and `mrta daemon CONFIG --check` runs alone, without opening a device or a socket.

* every address parses (``host:port``, port 1..65535; IPv6 as ``[::1]:port``) and resolves; a peer or ground
  station is a unicast address (peers' addresses only over ``udp``: over ``zenoh`` a peer is its id, and a client
  names at least one router in ``comms.zenoh.connect``);
* no peer is the robot itself, no peer id is listed twice;
* the map file exists (relative to the config file) and loads, and ``localization.initial_pose`` lies inside it;
* the signing key file loads;
* the base driver accepts its options (e.g. a Create's baud rate): it is built, not opened;
* every ``sensors:`` entry's port is a device file that exists or a pyserial URL (``socket://``, ``loop://``).

The allocation method's options are the schema of ``allocation:`` and were checked when the config was built.
"""
from __future__ import annotations

import ipaddress
import socket
from pathlib import Path

from runtime.config.build import ConfigError, parse_hostport
from runtime.config.world import check_inside, load_world
from runtime.errors import InputError


def validate(cfg) -> None:
    """Raise ConfigError (or InputError) naming the config file and key unless the daemon can start on ``cfg``."""
    file = cfg.source or "<config>"
    comms = cfg.comms
    resolve_address(comms.listen, file, "comms.listen", listen=True)
    from runtime.comms.transport import transport_class
    transport = transport_class(comms.transport)
    seen: set[int] = set()
    for i, peer in enumerate(comms.peers):
        if peer.id == cfg.robot.id:
            raise ConfigError(file, f"comms.peers[{i}].id", f"another robot's id (robot.id is {cfg.robot.id})",
                              peer.id)
        if peer.id in seen:
            raise ConfigError(file, f"comms.peers[{i}].id", "a peer id listed once", peer.id)
        seen.add(peer.id)
        if transport.peer_addresses:
            resolve_address(peer.address, file, f"comms.peers[{i}].address")
    transport.check_config(comms, file)            # the transport's own keys (routers, its config file)
    if comms.gcs is not None:
        resolve_address(comms.gcs, file, "comms.gcs")
    if cfg.planning.map is not None:
        path = map_path(cfg)
        if not path.is_file():
            raise ConfigError(file, "planning.map", "a world YAML file (relative to this file)", cfg.planning.map)
        world = load_world(path)
        if cfg.localization.initial_pose is not None:
            check_inside(world, cfg.localization.initial_pose, file, "localization.initial_pose")
    if comms.signing_key is not None:
        from runtime.comms.link import load_key
        try:
            load_key(comms.signing_key)
        except InputError as exc:
            raise InputError(f"{file}: comms.signing_key: {exc}") from None
    from runtime.drivers.registry import open_base
    try:
        open_base(cfg.base, cfg.robot.id)          # built (its options checked), not opened
    except InputError as exc:
        raise InputError(f"{file}: base: {exc}") from None
    for i, entry in enumerate(cfg.sensors):
        port = getattr(entry, "port", None)
        if isinstance(port, str) and "://" not in port and not Path(port).exists():
            raise ConfigError(file, f"sensors[{i}].port", f"a serial device that exists or a pyserial URL "
                              f"(type {entry.type})", port)


def map_path(cfg) -> Path:
    """The robot's map file: ``planning.map`` relative to the config file."""
    path = Path(cfg.planning.map)
    return path if path.is_absolute() or not cfg.source else Path(cfg.source).parent / path


def resolve_address(text: str, file: str, key: str, listen: bool = False) -> None:
    """ConfigError naming ``key`` unless ``text`` is ``host:port`` (port 1..65535) that resolves, and (unless
    ``listen``) a unicast address."""
    host, port = parse_hostport(text, file, key)
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    try:
        infos = socket.getaddrinfo(host, port, 0, socket.SOCK_DGRAM)
    except (socket.gaierror, UnicodeError, ValueError) as exc:      # ValueError: a NUL in the host
        raise ConfigError(file, key, f"an address that resolves ({getattr(exc, 'strerror', None) or exc})",
                          text) from None
    if not listen:
        ip = ipaddress.ip_address(infos[0][4][0].split("%")[0])
        if ip.is_multicast or ip.is_unspecified or str(ip) == "255.255.255.255":
            raise ConfigError(file, key, "a unicast address", text)
