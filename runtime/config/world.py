"""World configs: the arena, its box obstacles and the geodetic datum of the fleet frame."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from runtime.config.build import load, rng


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


def load_world(path: str | Path) -> WorldConfig:
    return load(WorldConfig, path)
