"""Robot configs: one robot's identity, base, GPS, localization, comms, control, planning and allocation.

``base:`` is a union chosen by ``base.type`` (the drivers' registry, :mod:`runtime.drivers.registry`)
and ``allocation:`` a union chosen by ``allocation.method`` (:mod:`runtime.allocation.registry`): each
driver and each method brings its own options dataclass, which is the schema of its section.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Optional

from runtime.comms.networks import EXPECTED as NETWORK, parse_network
from runtime.config.build import ConfigError, Tagged, _build, _read_yaml, deep_merge, rng, union_field
from runtime.config.world import POSE_RANGES, Datum


def _bases():
    from runtime.drivers.registry import config_classes
    return config_classes()


def _sensors():
    from runtime.drivers.registry import sensor_config_classes
    return sensor_config_classes()


def _methods():
    from runtime.allocation.registry import options_classes
    return options_classes()


@dataclass(frozen=True)
class RobotIdentity:
    id: int = field(default=1, metadata=rng(1, 250))
    name: str = ""
    armed: bool = True       # at start: allowed to drive and take tasks (a ground station can disarm it)


@dataclass(frozen=True)
class GpsConfig:
    """The older spelling of one ``sensors:`` entry of ``type: nmea_gps`` (read as that entry when no
    ``nmea_gps`` is listed and ``enabled``)."""
    enabled: bool = True
    port: str = "loop://"
    baudrate: int = field(default=9600, metadata=rng(300, 921600))


@dataclass(frozen=True)
class LocalizationConfig:
    gps_sigma: float = field(default=0.5, metadata=rng(0.001, 100))        # m, 1-sigma per axis
    odom_sigma_v: float = field(default=0.02, metadata=rng(0.0, 10))       # m/s
    odom_sigma_w: float = field(default=0.05, metadata=rng(0.0, 10))       # rad/s
    gate: float = field(default=13.8, metadata=rng(0.1, 1000))             # chi^2(2) 99.9 %
    # the filter relocalises (position from GPS, heading found again from motion) when the squared Mahalanobis
    # distances of the last consistency_window fixes sum above chi^2(2 x window) at this probability; 0: off
    consistency_window: int = field(default=10, metadata=rng(0, 1000))     # GPS fixes
    consistency: float = field(default=0.9999, metadata=rng(0.5, 0.999999))
    # x, y (m), heading (rad) in the fleet frame where the operator placed the robot; null: from the first GPS fix
    # with heading unknown until the robot has moved.  x, y lie in the largest arena (|x|, |y| <= 50 km) and, with
    # planning.map, inside that map (checked at start-up); the heading within a little over a turn either way
    initial_pose: Optional[tuple[float, float, float]] = field(default=None, metadata=POSE_RANGES)


@dataclass(frozen=True)
class Peer:
    id: int = field(metadata=rng(1, 250))
    address: str = field(default="127.0.0.1:14601")


def _endpoint(text: str) -> str:
    from runtime.comms.zenoh_transport import parse_endpoint      # no zenoh import: only the pattern
    return parse_endpoint(text)


def _fleet(text: str) -> str:
    from runtime.comms.zenoh_transport import parse_fleet
    return parse_fleet(text)


@dataclass(frozen=True)
class ZenohConfig:
    """``comms.zenoh``: used when ``comms.transport`` is ``zenoh`` (runtime/comms/zenoh_transport.py)."""
    mode: Literal["client", "peer"] = "client"
    # endpoints (tcp/HOST:PORT): client, the segment's router(s) (more than one: failover); peer, seed peers
    connect: tuple[str, ...] = field(default=(), metadata={"check": (_endpoint, "a Zenoh endpoint PROTO/HOST:PORT")})
    listen: tuple[str, ...] = field(default=(), metadata={"check": (_endpoint, "a Zenoh endpoint PROTO/HOST:PORT")})
    fleet: str = field(default="fleet", metadata={"check": (_fleet, "a fleet name for the keys mrta/<fleet>/...")})
    congestion: Literal["drop", "block"] = "drop"
    config: Optional[str] = None     # a Zenoh JSON5 config file under these keys: TLS, access control (docs/transport.md)


@dataclass(frozen=True)
class CommsConfig:
    transport: Literal["udp", "zenoh"] = "udp"     # what moves peer frames (runtime/comms/transport.py)
    zenoh: ZenohConfig = ZenohConfig()
    listen: str = "127.0.0.1:14601"
    peers: tuple[Peer, ...] = ()
    gcs: Optional[str] = "127.0.0.1:14550"
    signing_key: Optional[str] = None     # path to a fleet key file (32 bytes hex)
    heartbeat_timeout: float = field(default=3.0, metadata=rng(0.1, 60))
    startup_grace: float = field(default=15.0, metadata=rng(0.1, 3600))   # s: a peer never heard by then is lost
    # share of datagrams to each peer left unsent at random (a lossy radio, for testing; 0: none)
    peer_loss: float = field(default=0.0, metadata=rng(0.0, 1.0))
    # s: mean length of a spell in which every datagram to a peer is lost (bursts); 0: each lost on its own
    loss_burst: float = field(default=0.0, metadata=rng(0.0, 3600.0))
    loss_seed: Optional[int] = field(default=None, metadata=rng(0, 2**32 - 1))   # of the loss draws; null: robot id
    # networks (CIDR, IPv4 or IPv6) whose ground stations may send unsigned frames to a signed robot; peers still sign
    unsigned_gcs: tuple[str, ...] = field(default=(), metadata={"check": (parse_network, NETWORK)})


@dataclass(frozen=True)
class ControlConfig:
    rate: float = field(default=20.0, metadata=rng(1, 200))            # Hz
    lookahead: float = field(default=0.35, metadata=rng(0.05, 10))     # m
    cruise_speed: float = field(default=0.25, metadata=rng(0.01, 2.0)) # m/s (the base clips to its limit)
    max_turn_rate: float = field(default=2.0, metadata=rng(0.1, 10))   # rad/s
    goal_tolerance: float = field(default=0.08, metadata=rng(0.005, 5))


@dataclass(frozen=True)
class PlanningConfig:
    map: Optional[str] = None       # world config used as the map (relative to this file); null: open field
    planner: Literal["astar", "rrt", "euclid"] = "astar"
    inflate: Optional[float] = field(default=None, metadata=rng(0.0, 5.0))   # m; null: the base's radius
    rrt_iterations: int = field(default=20000, metadata=rng(1, 1_000_000))   # per tree (planner rrt)


@dataclass(frozen=True)
class RobotConfig:
    robot: RobotIdentity = RobotIdentity()
    base: Any = union_field("type", _bases, "create_oi")
    # the robot's sensors beyond its base, each chosen by its type (runtime.drivers.registry.SENSORS)
    sensors: tuple[Any, ...] = field(default=(), metadata={"tagged": Tagged("type", _sensors, None)})
    gps: GpsConfig = GpsConfig()
    localization: LocalizationConfig = LocalizationConfig()
    comms: CommsConfig = CommsConfig()
    control: ControlConfig = ControlConfig()
    planning: PlanningConfig = PlanningConfig()
    allocation: Any = union_field("method", _methods, "auction")
    datum: Datum = Datum()
    source: str = ""

    def sensor_list(self) -> tuple:
        """Every sensor the daemon opens: ``sensors:``, and the ``gps:`` section as an ``nmea_gps`` entry when
        none is listed and it is enabled (configs written before ``sensors:``)."""
        if any(s.type == "nmea_gps" for s in self.sensors) or not self.gps.enabled:
            return self.sensors
        from runtime.drivers.nmea_gps import NmeaGpsConfig
        return (NmeaGpsConfig(port=self.gps.port, baudrate=self.gps.baudrate),) + self.sensors

    @property
    def has_gps(self) -> bool:
        return any(s.type == "nmea_gps" for s in self.sensor_list())


def load_robot(path: str | Path, overrides: dict | None = None) -> RobotConfig:
    data = _read_yaml(path)
    if overrides:
        data = deep_merge(data, overrides)
    check_one_gps(data, str(path))
    return _build(RobotConfig, data, str(path), "")


def check_one_gps(data: Any, file: str) -> None:
    """A config gives its GPS once: as a ``sensors:`` entry of ``type: nmea_gps`` or as the older ``gps:``
    section, not both (which one would the daemon open?)."""
    if not isinstance(data, dict) or "gps" not in data or not isinstance(data.get("sensors"), list):
        return
    for i, entry in enumerate(data["sensors"]):
        if isinstance(entry, dict) and entry.get("type") == "nmea_gps":
            raise ConfigError(file, "gps", f"no gps: section beside sensors[{i}] (type nmea_gps): give the GPS "
                              "once, as that entry")
