"""Zenoh routers for a SITL fleet (``mrta sitl run --transport zenoh --segments K``): K routers on loopback, each a
Python session in router mode (:func:`runtime.comms.zenoh_transport.open_router`), linked to the first one; the
robots split among them in blocks of consecutive ids, as robots share a radio segment.  A router can be stopped and
started again on the same endpoint (a router restart), or unlinked from the others (a segment split)."""
from __future__ import annotations

from sitl.ports import free_port


class Segments:
    def __init__(self, k: int, robots, fleet: str = "sitl", host: str = "127.0.0.1"):
        from runtime.comms.zenoh_transport import load_zenoh

        load_zenoh()
        robots = self.robots = sorted(robots)
        k = max(1, min(int(k), len(robots)))
        self.fleet = fleet
        self.endpoints = [f"tcp/{host}:{free_port(host=host)}" for _ in range(k)]
        self.links: list[list[str]] = [[] if i == 0 else [self.endpoints[0]] for i in range(k)]
        per = -(-len(robots) // k)
        self.segment = {rid: i // per for i, rid in enumerate(robots)}      # robot id -> its router's index
        self.routers: list = [None] * k
        try:
            for i in range(k):
                self.start(i)
        except BaseException:
            self.close()
            raise

    def comms(self, rid: int) -> dict:
        """Robot ``rid``'s ``comms`` keys: client of its segment's router; the fleet's key prefix."""
        return {"transport": "zenoh", "zenoh": {"mode": "client", "connect": [self.endpoints[self.segment[rid]]],
                                                 "fleet": self.fleet},
                "peers": [{"id": o} for o in self.robots if o != rid]}      # ids only: no addresses

    def start(self, i: int, linked: bool = True) -> None:
        """Router ``i`` open on its endpoint (linked to the first router unless ``linked`` is False: a segment split
        off the others; its clients reconnect to it as they do after a restart)."""
        from runtime.comms.zenoh_transport import open_router

        if self.routers[i] is None:
            self.routers[i] = open_router([self.endpoints[i]], self.links[i] if linked else (),
                                          what=f"SITL router {i}")

    def stop(self, i: int) -> None:
        if self.routers[i] is not None:
            self.routers[i].close()
            self.routers[i] = None

    def close(self) -> None:
        for i in range(len(self.routers)):
            self.stop(i)
