"""Transports: what moves a robot's peer frames.  The link (:class:`runtime.comms.link.MavlinkLink`) keeps framing,
signing, replay windows, counters and the loss model; a transport only moves bytes.

``comms.transport`` chooses one from :data:`TRANSPORTS` (one module each, imported only when chosen):

* ``udp`` (the default, :class:`runtime.comms.udp.UdpTransport`): the robot's UDP socket sends each peer frame to
  every address in ``comms.peers``; nothing to install;
* ``zenoh`` (:class:`runtime.comms.zenoh_transport.ZenohTransport`, ``pip install 'mrta-runtime[zenoh]'``): each
  frame is published once on a fleet-scoped key through the segment's Zenoh router (client mode) or straight to the
  other peers (peer mode); membership from liveliness tokens.  docs/transport.md says when to choose which.

Ground stations stay on MAVLink/UDP at each robot (``comms.listen``, ``comms.gcs``) whatever the transport.

A transport has:

* ``copies``: True if :meth:`destinations` are receivers (the link draws its loss model per copy when sending);
  False if a frame is published once (the link draws it per sender on receipt);
* ``destinations(dest) -> list``: where a peer frame for robot ``dest`` (0: all) goes;
* ``send(frame, where)``: raises OSError when it cannot;
* ``receive(counters, limit)``: yields ``(data, source address or None, origin)``, ``origin`` being the sender's
  key for the loss model (None when ``copies``);
* ``membership() -> [(robot id, joined)]``: robots seen joining or leaving since the last call (UDP: none);
* ``check_drops(counters)``: brings ``kernel_dropped`` (UDP) or ``queue_dropped`` up to what it dropped unread;
* ``close()``;
* ``peer_addresses``: True if ``comms.peers`` addresses are used (and so must resolve);
* ``joins``: True if a robot not in ``comms.peers`` reaches the fleet and is reached by it (no address needed), so
  the robot core may take it into the roster at run time when its first message arrives (UDP: False);
* ``check_config(comms, file)`` (a classmethod): ConfigError naming ``file`` and the key unless the transport's own
  keys of ``comms`` can work (``mrta daemon --check``).
"""
from __future__ import annotations

import importlib

from runtime.errors import InputError

# comms.transport -> (module, class); "udp" is built by the link itself from comms.listen and comms.peers
TRANSPORTS = {
    "udp": ("runtime.comms.udp", "UdpTransport"),
    "zenoh": ("runtime.comms.zenoh_transport", "ZenohTransport"),
}


def transport_class(name: str, what: str = "comms.transport") -> type:
    """The class of transport ``name`` (its module imported; a transport imports its engine only when opened)."""
    if name not in TRANSPORTS:
        raise InputError(f"{what}: expected one of {', '.join(TRANSPORTS)}, got {name!r}")
    module, cls = TRANSPORTS[name]
    return getattr(importlib.import_module(module), cls)


def transport_joins(name: str) -> bool:
    """Whether robots may join a fleet on transport ``name`` at run time (its class's ``joins``)."""
    return bool(transport_class(name).joins)


def open_transport(comms, robot_id: int, what: str = "comms.transport"):
    """The peer transport ``comms`` (a robot config's ``comms``) names, opened; None for ``udp`` (the link opens
    its own socket).  InputError (one line) when the transport's package is missing or it cannot open."""
    if comms.transport == "udp":
        return None
    return transport_class(comms.transport, what).from_config(comms, robot_id)
