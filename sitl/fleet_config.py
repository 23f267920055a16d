"""SITL fleet configs: the world, the robots (each from a robot template) and the scenario.  The simulator's
own config: a robot reads only its robot config (:mod:`runtime.config`).

A fleet names a default robot template (``robot:``); a robot may name its own (``robots[i].robot``), so
one fleet can mix bases.  ``scenario:`` is a union chosen by ``scenario.type`` (:mod:`sitl.scenarios`):
what the operator hands the fleet and when, and when the run's goal is met.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import runtime
from runtime.config.build import ConfigError, load, parse_hostport, rng, union_field
from runtime.config.world import POSE_RANGES, check_inside, load_world
from runtime.errors import InputError

# The example configs shipped in the package (runtime/examples is the repository's configs/ directory)
EXAMPLES = Path(runtime.__file__).resolve().parent / "examples"


def shipped_fleets() -> list[str]:
    """Names of the shipped example fleets (``create2_4`` for ``examples/fleets/create2_4.yaml``)."""
    return sorted(p.stem for p in (EXAMPLES / "fleets").glob("*.yaml"))


def find_fleet(name_or_path: str | Path) -> Path:
    """The fleet config ``name_or_path`` names: a file, else a shipped fleet by name (with or without .yaml).
    Neither: one line listing the shipped names (InputError, exit 2)."""
    path = Path(name_or_path)
    if path.is_file():
        return path
    shipped = EXAMPLES / "fleets" / path.with_suffix(".yaml").name
    if path.name == str(name_or_path) and path.suffix in ("", ".yaml") and shipped.is_file():
        return shipped
    raise InputError(f"fleet: {str(name_or_path)!r} is neither a fleet file nor a shipped fleet "
                     f"({', '.join(shipped_fleets())})")


def _scenarios():
    from sitl.scenarios import config_classes
    return config_classes()


@dataclass(frozen=True)
class FleetRobot:
    id: int = field(metadata=rng(1, 250))
    start: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0), metadata=POSE_RANGES)   # x, y, yaw
    robot: Optional[str] = None         # this robot's template (relative to the fleet file); null: the fleet's


@dataclass(frozen=True)
class FleetConfig:
    world: str
    robot: str                                    # default robot config template, relative to this file
    robots: tuple[FleetRobot, ...]
    scenario: Any = union_field("type", _scenarios, None)
    gcs: str = "127.0.0.1:14550"
    base_port: int = field(default=14600, metadata=rng(1024, 65000))
    signing_key: Optional[str] = None             # a fleet key file, relative to this file (null: see the launcher)
    seed: int = field(default=1, metadata=rng(0, 2**32 - 1))
    speedup: float = field(default=1.0, metadata=rng(0.1, 100))
    timeout: float = field(default=120.0, metadata=rng(1, 36000))    # sim seconds
    gps_noise: float = field(default=0.3, metadata=rng(0.0, 50))     # m, 1-sigma
    # every robot's comms.peer_loss (share of datagrams to each peer lost; null: each template's own)
    peer_loss: Optional[float] = field(default=None, metadata=rng(0.0, 1.0))
    loss_burst: Optional[float] = field(default=None, metadata=rng(0.0, 3600.0))   # every robot's comms.loss_burst
    source: str = ""

    def template(self, robot_id: int) -> str:
        """The robot config template of robot ``robot_id`` (absolute path)."""
        r = next(r for r in self.robots if r.id == robot_id)
        return r.robot or self.robot


def load_fleet(path: str | Path) -> FleetConfig:
    fleet: FleetConfig = load(FleetConfig, path)
    base = Path(path).parent

    def resolve(value: str, key: str) -> str:
        target = base / value
        if not target.is_file():
            raise ConfigError(path, key, "a path to an existing file relative to the fleet file", value)
        return str(target)

    ids = [r.id for r in fleet.robots]
    if not ids:
        raise ConfigError(path, "robots", "at least one robot")
    if len(set(ids)) != len(ids):
        raise ConfigError(path, "robots", "unique robot ids", ids)
    robots = tuple(dataclasses.replace(r, robot=resolve(r.robot, f"robots[{i}].robot") if r.robot else None)
                   for i, r in enumerate(fleet.robots))
    fleet = dataclasses.replace(fleet, world=resolve(fleet.world, "world"), robot=resolve(fleet.robot, "robot"),
                                robots=robots,
                                signing_key=resolve(fleet.signing_key, "signing_key") if fleet.signing_key else None)
    parse_hostport(fleet.gcs, str(path), "gcs")
    if fleet.signing_key:
        from runtime.comms.link import load_key
        load_key(fleet.signing_key, f"{path}: signing_key")       # a key file, named with this file and key
    world = load_world(fleet.world)
    for i, r in enumerate(fleet.robots):
        check_inside(world, r.start, str(path), f"robots[{i}].start")
    fleet.scenario.check(fleet, world, str(path))
    return fleet
