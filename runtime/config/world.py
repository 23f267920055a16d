"""World configs: the arena, its box obstacles and the geodetic datum of the fleet frame."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from runtime.config.build import ConfigError, load, rng

MAX_CELLS = 4_000_000     # occupancy grid cells a world may need (each costs ~60 bytes while a planner is built)
MAX_SIDE = 100_000        # m: the largest arena's side
MAX_HALF = MAX_SIDE // 2  # m: |x|, |y| of a point in the largest arena (a pose or obstacle of any world)
# field metadata of a pose (x, y, heading): x, y in the largest arena, the heading (rad) a little over a turn either way
POSE_RANGES = {"items": (rng(-MAX_HALF, MAX_HALF), rng(-MAX_HALF, MAX_HALF), rng(-7, 7))}


@dataclass(frozen=True)
class Datum:
    """Geodetic origin of the local ENU frame."""
    lat: float = field(default=33.7756, metadata=rng(-90, 90))
    lon: float = field(default=-84.3963, metadata=rng(-180, 180))
    alt: float = field(default=300.0, metadata=rng(-500, 9000))


@dataclass(frozen=True)
class Box:
    """An axis-aligned (then yawed) box obstacle: centre (inside the arena, see :func:`load_world`) and full size
    in metres (each side > 0)."""
    center: tuple[float, float] = field(metadata=rng(-MAX_HALF, MAX_HALF))
    size: tuple[float, float] = field(metadata=rng(0, MAX_SIDE, lo_open=True))
    height: float = field(default=0.5, metadata=rng(0.01, 10))
    yaw: float = field(default=0.0, metadata=rng(-math.pi, math.pi))


@dataclass(frozen=True)
class WorldConfig:
    size: tuple[float, float] = field(default=(10.0, 10.0), metadata=rng(0.01, MAX_SIDE))  # m, x by y, centred on 0
    obstacles: tuple[Box, ...] = ()
    datum: Datum = Datum()
    walls: bool = True
    resolution: float = field(default=0.05, metadata=rng(0.005, 5.0))  # occupancy grid cell (m)
    source: str = ""


def load_world(path: str | Path) -> WorldConfig:
    world: WorldConfig = load(WorldConfig, path)
    nx, ny = (math.ceil(side / world.resolution - 1e-9) for side in world.size)
    if nx * ny > MAX_CELLS:
        raise ConfigError(path, "size, resolution", f"at most {MAX_CELLS} occupancy grid cells (a coarser resolution "
                          f"or a smaller size), got {nx} x {ny} cells")
    for i, box in enumerate(world.obstacles):
        check_inside(world, box.center, str(path), f"obstacles[{i}].center")
    return world


def inside(world: WorldConfig, x: float, y: float) -> bool:
    """Whether (x, y) lies inside the world's arena (centred on the origin)."""
    return abs(x) < world.size[0] / 2 and abs(y) < world.size[1] / 2


def check_inside(world: WorldConfig, point, file: str, key: str) -> None:
    """ConfigError naming ``key`` unless ``point`` (x, y, ...) lies inside the world's arena."""
    if not inside(world, point[0], point[1]):
        sx, sy = world.size
        raise ConfigError(file, key, f"a point inside the {sx:g} x {sy:g} m arena of {world.source or 'the world'} "
                          f"(|x| < {sx / 2:g}, |y| < {sy / 2:g})", tuple(point))
