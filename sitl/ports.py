"""Pick UDP port blocks on loopback that nothing is bound to (tests and benchmarks run beside a fleet)."""
from __future__ import annotations

import socket


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
