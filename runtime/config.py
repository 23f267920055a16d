"""Typed configuration: robots, fleets and worlds in YAML.

Every config is a tree of frozen dataclasses.  ``_build`` walks the YAML against the dataclass
fields and raises :class:`ConfigError` naming the file, the dotted key and what was expected, so
the CLI can print one line and exit 2.  Ranges and choices live in field metadata::

    speed: float = field(default=0.3, metadata=rng(0.0, 0.5))
"""
from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Optional

import yaml

from runtime.errors import InputError


class ConfigError(InputError):
    """A config value is missing or wrong; ``str()`` is the one line a person sees."""

    def __init__(self, file: str | Path, key: str, expected: str, got: Any = dataclasses.MISSING):
        self.file, self.key, self.expected = str(file), key, expected
        msg = f"{file}: {key}: expected {expected}" if key else f"{file}: expected {expected}"
        if got is not dataclasses.MISSING:
            shown = repr(got)
            msg += f", got {shown[:60] + '...' if len(shown) > 60 else shown}"
        super().__init__(msg)


def rng(lo: float | None = None, hi: float | None = None, **extra: Any) -> dict:
    """Field metadata: inclusive numeric range."""
    return {"lo": lo, "hi": hi, **extra}


# --------------------------------------------------------------------------- schema

@dataclass(frozen=True)
class Datum:
    """Geodetic origin of the local ENU frame."""
    lat: float = field(default=33.7756, metadata=rng(-90, 90))
    lon: float = field(default=-84.3963, metadata=rng(-180, 180))
    alt: float = field(default=300.0, metadata=rng(-500, 9000))


@dataclass(frozen=True)
class Box:
    """An axis-aligned (then yawed) box obstacle: centre and full size in metres."""
    center: tuple[float, float]
    size: tuple[float, float]
    height: float = field(default=0.5, metadata=rng(0.01, 10))
    yaw: float = field(default=0.0, metadata=rng(-math.pi, math.pi))


@dataclass(frozen=True)
class WorldConfig:
    size: tuple[float, float] = (10.0, 10.0)   # metres, x by y, centred on the origin
    obstacles: tuple[Box, ...] = ()
    datum: Datum = Datum()
    walls: bool = True
    resolution: float = field(default=0.05, metadata=rng(0.005, 5.0))  # occupancy grid cell (m)
    source: str = ""


@dataclass(frozen=True)
class RobotIdentity:
    id: int = field(default=1, metadata=rng(1, 250))
    name: str = ""


@dataclass(frozen=True)
class BaseConfig:
    type: Literal["create_oi"] = "create_oi"
    model: Literal["create1", "create2"] = "create2"
    port: str = "loop://"            # any pyserial URL
    baudrate: Optional[int] = None   # None: model default (57600 / 115200)
    mode: Literal["safe", "full"] = "safe"
    watchdog: float = field(default=0.5, metadata=rng(0.05, 10.0))
    max_speed: float = field(default=0.5, metadata=rng(0.01, 0.5))   # m/s per wheel


@dataclass(frozen=True)
class GpsConfig:
    enabled: bool = True
    port: str = "loop://"
    baudrate: int = field(default=9600, metadata=rng(300, 921600))


@dataclass(frozen=True)
class LocalizationConfig:
    gps_sigma: float = field(default=0.5, metadata=rng(0.001, 100))        # m, 1-sigma per axis
    odom_sigma_v: float = field(default=0.02, metadata=rng(0.0, 10))       # m/s
    odom_sigma_w: float = field(default=0.05, metadata=rng(0.0, 10))       # rad/s
    gate: float = field(default=13.8, metadata=rng(0.1, 1000))             # chi^2(2) 99.9 %
    # x, y, heading in the fleet frame where the operator placed the robot; null: from the first GPS fix
    # with heading unknown until the robot has moved
    initial_pose: Optional[tuple[float, float, float]] = None


@dataclass(frozen=True)
class Peer:
    id: int = field(metadata=rng(1, 250))
    address: str = field(default="127.0.0.1:14601")


@dataclass(frozen=True)
class CommsConfig:
    listen: str = "127.0.0.1:14601"
    peers: tuple[Peer, ...] = ()
    gcs: Optional[str] = "127.0.0.1:14550"
    signing_key: Optional[str] = None     # path to a fleet key file (32 bytes hex)
    heartbeat_timeout: float = field(default=3.0, metadata=rng(0.1, 60))
    startup_grace: float = field(default=15.0, metadata=rng(0.1, 3600))   # s: a peer never heard by then is lost


@dataclass(frozen=True)
class ControlConfig:
    rate: float = field(default=20.0, metadata=rng(1, 200))            # Hz
    lookahead: float = field(default=0.35, metadata=rng(0.05, 10))     # m
    cruise_speed: float = field(default=0.25, metadata=rng(0.01, 0.5)) # m/s
    max_turn_rate: float = field(default=2.0, metadata=rng(0.1, 10))   # rad/s
    goal_tolerance: float = field(default=0.08, metadata=rng(0.005, 5))


@dataclass(frozen=True)
class PlanningConfig:
    map: Optional[str] = None       # world config used as the map (relative to this file); null: open field
    planner: Literal["astar", "rrt", "euclid"] = "astar"
    inflate: float = field(default=0.17, metadata=rng(0.0, 5.0))   # obstacle inflation: robot radius (m)
    rrt_iterations: int = field(default=20000, metadata=rng(1, 1_000_000))   # per tree (planner rrt)


@dataclass(frozen=True)
class AllocationConfig:
    method: Literal["bs", "rtma", "auction"] = "auction"    # epsilon auction: optimal, the default
    bid_timeout: float = field(default=1.0, metadata=rng(0.01, 60))
    formation: tuple[tuple[float, float], ...] = ()   # task positions in the fleet frame (m)
    initiator: bool = False        # this robot announces the formation (one robot per fleet)


@dataclass(frozen=True)
class RobotConfig:
    robot: RobotIdentity = RobotIdentity()
    base: BaseConfig = BaseConfig()
    gps: GpsConfig = GpsConfig()
    localization: LocalizationConfig = LocalizationConfig()
    comms: CommsConfig = CommsConfig()
    control: ControlConfig = ControlConfig()
    planning: PlanningConfig = PlanningConfig()
    allocation: AllocationConfig = AllocationConfig()
    datum: Datum = Datum()
    source: str = ""


@dataclass(frozen=True)
class FleetRobot:
    id: int = field(metadata=rng(1, 250))
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)   # x, y, yaw in the world frame


@dataclass(frozen=True)
class FleetConfig:
    world: str
    robot: str                                    # robot config template, relative to this file
    robots: tuple[FleetRobot, ...]
    formation: tuple[tuple[float, float], ...]    # task positions (m)
    gcs: str = "127.0.0.1:14550"
    base_port: int = field(default=14600, metadata=rng(1024, 65000))
    signing_key: Optional[str] = None
    seed: int = 1
    speedup: float = field(default=1.0, metadata=rng(0.1, 100))
    timeout: float = field(default=120.0, metadata=rng(1, 36000))    # sim seconds
    gps_noise: float = field(default=0.3, metadata=rng(0.0, 50))     # m, 1-sigma
    source: str = ""


# --------------------------------------------------------------------------- builder

def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "one of " + "|".join(map(str, typing.get_args(tp)))
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in typing.get_args(tp))
    if origin is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_type_name(args[0])}"
        return f"a list of {len(args)} numbers" if all(a in (float, int) for a in args) else "a list"
    if dataclasses.is_dataclass(tp):
        return "a mapping"
    if tp is type(None):
        return "null"
    return {float: "a number", int: "an integer", str: "a string", bool: "true/false"}.get(tp, str(tp))


def _build(tp: Any, value: Any, file: str, key: str, meta: dict | None = None) -> Any:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _build(inner[0], value, file, key, meta)
    if origin is Literal:
        if value not in typing.get_args(tp):
            raise ConfigError(file, key, _type_name(tp), value)
        return value
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(file, key, _type_name(tp), value)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_build(args[0], v, file, f"{key}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(file, key, _type_name(tp), value)
        return tuple(_build(a, v, file, f"{key}[{i}]", meta) for i, (a, v) in enumerate(zip(args, value)))
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(file, key, "a mapping", value)
        fields = {f.name: f for f in dataclasses.fields(tp) if f.name != "source"}
        for k in value:
            if k not in fields:
                raise ConfigError(file, f"{key}.{k}" if key else str(k),
                                  "no such key (known: " + ", ".join(fields) + ")")
        kwargs = {}
        hints = typing.get_type_hints(tp)
        for name, f in fields.items():
            sub = f"{key}.{name}" if key else name
            if name in value:
                kwargs[name] = _build(hints[name], value[name], file, sub, dict(f.metadata))
            elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ConfigError(file, sub, f"{_type_name(hints[name])} (required)")
        if "source" in {f.name for f in dataclasses.fields(tp)}:
            kwargs["source"] = file
        return tp(**kwargs)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(file, key, "true/false", value)
        return value
    if tp in (int, float):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        if tp is int and ok and not float(value).is_integer():
            ok = False
        if not ok or not math.isfinite(value):
            raise ConfigError(file, key, _type_name(tp), value)
        value = tp(value)
        lo, hi = (meta or {}).get("lo"), (meta or {}).get("hi")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise ConfigError(file, key, f"a number in [{lo}, {hi}]", value)
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(file, key, "a string", value)
        return value
    raise TypeError(f"unsupported config type {tp!r} at {key}")


def _read_yaml(path: str | Path) -> Any:
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(path, "", f"a readable YAML file ({exc.strerror})") from None
    try:
        return yaml.safe_load(text) or {}
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark else "document"
        raise ConfigError(path, where, "valid YAML") from None


def from_dict(tp: type, data: Any, file: str = "<dict>") -> Any:
    """Build a config dataclass from plain data (as loaded from YAML)."""
    return _build(tp, data, file, "")


def load(tp: type, path: str | Path) -> Any:
    return _build(tp, _read_yaml(path), str(path), "")


def load_world(path: str | Path) -> WorldConfig:
    return load(WorldConfig, path)


def load_robot(path: str | Path, overrides: dict | None = None) -> RobotConfig:
    data = _read_yaml(path)
    if overrides:
        data = deep_merge(data, overrides)
    return _build(RobotConfig, data, str(path), "")


def load_fleet(path: str | Path) -> FleetConfig:
    fleet: FleetConfig = load(FleetConfig, path)
    base = Path(path).parent
    for key in ("world", "robot"):
        target = base / getattr(fleet, key)
        if not target.is_file():
            raise ConfigError(path, key, "a path to an existing file relative to the fleet file", getattr(fleet, key))
    ids = [r.id for r in fleet.robots]
    if len(set(ids)) != len(ids):
        raise ConfigError(path, "robots", "unique robot ids", ids)
    if len(fleet.formation) < 1:
        raise ConfigError(path, "formation", "at least one position")
    return dataclasses.replace(fleet, world=str(base / fleet.world), robot=str(base / fleet.robot))


def deep_merge(a: Any, b: Any) -> Any:
    """Return ``a`` with mappings in ``b`` merged in (``b`` wins)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = dict(a)
        for k, v in b.items():
            out[k] = deep_merge(a.get(k), v) if k in a else v
        return out
    return b


def to_dict(cfg: Any) -> Any:
    """Plain data for a config (inverse of :func:`from_dict`, ``source`` dropped)."""
    if dataclasses.is_dataclass(cfg):
        return {f.name: to_dict(getattr(cfg, f.name)) for f in dataclasses.fields(cfg) if f.name != "source"}
    if isinstance(cfg, tuple):
        return [to_dict(v) for v in cfg]
    return cfg


def parse_hostport(text: str, file: str = "<arg>", key: str = "address") -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not (0 < int(port) < 65536):
        raise ConfigError(file, key, "host:port with port in 1..65535", text)
    return host, int(port)
