"""A fleet's UDP ports: blocks on loopback that nothing is bound to (tests and benchmarks run beside a fleet), and
how far ``--instance N`` moves a fleet's ports."""
from __future__ import annotations

import socket

from runtime import config as C


def free_port(udp: bool = False, host: str = "127.0.0.1") -> int:
    """A port free on ``host`` now (TCP, or UDP with ``udp``), for one server the caller starts next."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM if udp else socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def free_udp_base(n: int, start: int = 21000, stride: int = 97) -> int:
    """A base port such that base .. base+n+1 are all free UDP ports on 127.0.0.1."""
    for base in range(start, 60000, stride):
        socks = []
        try:
            for k in range(n + 2):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                s.bind(("127.0.0.1", base + k))
                socks.append(s)
            return base
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise RuntimeError(f"no block of {n + 2} free UDP ports on 127.0.0.1")


INSTANCE_STRIDE = 100      # ports an --instance moves a fleet by (as ArduPilot's SITL does, by 10 per vehicle)


def check_instance(fleet, instance: int) -> None:
    """InputError naming ``--instance`` unless every port of ``fleet`` moved to ``instance`` stays <= 65535."""
    _, gcs_port = C.parse_hostport(fleet.gcs, fleet.source, "gcs")
    top = max(fleet.base_port + max(r.id for r in fleet.robots), gcs_port) + INSTANCE_STRIDE * instance
    if top > 65535:
        raise C.ConfigError("--instance", "", f"an instance whose ports stay <= 65535 (this fleet's reach {top} at "
                            f"--instance {instance})", instance)
