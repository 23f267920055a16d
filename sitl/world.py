"""The project's one pybullet world: arena walls, static box obstacles and robot bodies, in one of two profiles.

* :data:`SITL` (the default): a floor with friction, gravity, 0.3 m walls and 5 ms steps; the robots are full
  wheeled bodies (:mod:`sitl.bodies`) driven through their device emulators.
* :data:`PLANAR` (paper 000's foraging, :mod:`sitl.foraging.world`): no floor and no gravity, walls as tall as
  the robots' discs, 50 ms steps; the robots are discs on planar joints commanded by unicycle velocities, and
  range sensing is closed-form (:mod:`sitl.sensing`).

Each :class:`World` owns its own pybullet DIRECT (or GUI) client, so several worlds can live in one
process.  Time only moves in :meth:`World.step`; with the same seed and the same call sequence a run
is bit-for-bit repeatable.  Robots interact only through pybullet contacts.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pybullet as p

from runtime.config import WorldConfig
from runtime.errors import InputError
from runtime.log import get_logger
from sitl.bodies.registry import body_class

__all__ = ["World", "Profile", "SITL", "PLANAR"]

GRAVITY = 9.81
WALL_THICKNESS = 0.1
WALL_HEIGHT = 0.3
SOLVER_ITERATIONS = 10          # default 50; 10 keeps wheel/contact errors < 1 % at dt = 5 ms
FLOOR_FRICTION = 1.0
OBSTACLE_FRICTION = 0.5
MOTOR_SAMPLE_PERIOD = 0.02      # s of sim time between motor-load samples for the battery model


@dataclass(frozen=True)
class Profile:
    """What kind of world: its physics and its arena's build."""
    name: str
    dt: float                   # s, default physics step
    max_dt: float               # s, the largest step it takes
    gravity: float              # m/s^2 (0: bodies move in the plane only)
    floor: bool                 # a floor plane (wheeled bodies stand on it)
    wall_bottom: float          # m, z of the walls' bottom ...
    wall_height: float          # ... and their height
    wall_friction: float
    solver_iterations: int


SITL = Profile("sitl", 1 / 200, 0.05, GRAVITY, True, 0.0, WALL_HEIGHT, OBSTACLE_FRICTION, SOLVER_ITERATIONS)
# the walls reach from a disc's bottom to a disc's height above its top, for discs of up to 0.25 m centred 0.25 m up
PLANAR = Profile("planar", 0.05, 0.1, 0.0, False, -0.25, 1.0, 0.1, SOLVER_ITERATIONS)


class World:
    """A lock-stepped pybullet world built from a :class:`runtime.config.WorldConfig`."""

    def __init__(self, cfg: WorldConfig, seed: int = 0, dt: float | None = None, gui: bool = False,
                 wheel_radius_sigma: float = 0.004, profile: Profile = SITL, solver_iterations: int | None = None):
        # wheel_radius_sigma: relative 1-sigma spread of each tyre's rolling radius (0 = ideal wheels)
        dt = profile.dt if dt is None else dt
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and 0 < dt <= profile.max_dt):
            raise InputError(f"world dt: expected a time step in (0, {profile.max_dt:g}] s, got {dt!r}")
        self.cfg = cfg
        self.profile = profile
        self.wheel_radius_sigma = float(wheel_radius_sigma)
        self.seed = int(seed)
        self.dt = float(dt)
        self.gui = gui
        self._steps = 0
        self._unsampled = 0
        self._sample_every = max(1, int(round(MOTOR_SAMPLE_PERIOD / self.dt)))
        self._bodies: dict = {}                # robot id -> body (a class of sitl.bodies)
        self._log = get_logger("sitl.world")
        self._client = p.connect(p.GUI if gui else p.DIRECT)
        if self._client < 0:
            raise RuntimeError("pybullet: could not connect a physics client")
        kw = self._kw = {"physicsClientId": self._client}
        p.resetSimulation(**kw)
        iterations = profile.solver_iterations if solver_iterations is None else int(solver_iterations)
        p.setPhysicsEngineParameter(fixedTimeStep=self.dt, numSubSteps=0, numSolverIterations=iterations,
                                    deterministicOverlappingPairs=1, **kw)
        p.setGravity(0, 0, -profile.gravity, **kw)
        self.floor_id = None
        if profile.floor:
            self.floor_id = self._static_body(p.createCollisionShape(p.GEOM_PLANE, **kw), (0, 0, 0), 0.0,
                                              visual=p.createVisualShape(p.GEOM_PLANE, **kw) if gui else -1)
            p.changeDynamics(self.floor_id, -1, lateralFriction=FLOOR_FRICTION, restitution=0.0, **kw)
        self.wall_ids: list[int] = []
        if cfg.walls:
            sx, sy = cfg.size
            t = WALL_THICKNESS
            for cx, cy, hx, hy in ((0, sy / 2 + t / 2, sx / 2 + t, t / 2), (0, -sy / 2 - t / 2, sx / 2 + t, t / 2),
                                   (sx / 2 + t / 2, 0, t / 2, sy / 2), (-sx / 2 - t / 2, 0, t / 2, sy / 2)):
                self.wall_ids.append(self._box((cx, cy), (2 * hx, 2 * hy), profile.wall_height, 0.0,
                                               profile.wall_bottom, profile.wall_friction))
        self.obstacle_ids = [self._box(b.center, b.size, b.height, b.yaw) for b in cfg.obstacles]
        self._log.debug("world %s (%s): %d walls, %d obstacles, dt %.4f s", cfg.source or "<config>", profile.name,
                        len(self.wall_ids), len(self.obstacle_ids), self.dt)

    # -------------------------------------------------------------- building
    def _static_body(self, shape: int, pos, yaw: float, visual: int = -1) -> int:
        return p.createMultiBody(baseMass=0, baseCollisionShapeIndex=shape, baseVisualShapeIndex=visual,
                                 basePosition=pos, baseOrientation=p.getQuaternionFromEuler((0, 0, yaw)),
                                 **self._kw)

    def _box(self, center, size, height: float, yaw: float, bottom: float = 0.0,
             friction: float = OBSTACLE_FRICTION) -> int:
        half = (size[0] / 2, size[1] / 2, height / 2)
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, **self._kw)
        vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=(0.7, 0.5, 0.3, 1),
                                  **self._kw) if self.gui else -1
        body = self._static_body(shape, (center[0], center[1], bottom + height / 2), yaw, vis)
        p.changeDynamics(body, -1, lateralFriction=friction, restitution=0.0, **self._kw)
        return body

    def add_box(self, center: tuple[float, float], size: tuple[float, float], height: float = 0.5,
                yaw: float = 0.0) -> int:
        """A static box that is not in the world config, so in no robot's map (an unmapped obstacle)."""
        bid = self._box(center, size, height, yaw)
        self.obstacle_ids.append(bid)
        return bid

    def add_body(self, robot_id: int, start: tuple[float, float, float], kind: str):
        """Put a body of ``kind`` (:data:`sitl.bodies.registry.BODIES`) on the floor at ``start`` = (x, y, yaw)
        and return it."""
        cls = body_class(kind)
        if robot_id in self._bodies:
            raise InputError(f"robot {robot_id}: expected a unique robot id, it is already in the world")
        if len(start) != 3 or not all(math.isfinite(v) for v in start):
            raise InputError(f"robot {robot_id} start: expected (x, y, yaw) finite numbers, got {start!r}")
        x, y, yaw = (float(v) for v in start)
        sx, sy = self.cfg.size
        r = cls.radius
        if self.cfg.walls and (abs(x) > sx / 2 - r or abs(y) > sy / 2 - r):
            raise InputError(f"robot {robot_id} start ({x}, {y}): expected inside the {sx:g} x {sy:g} m arena "
                             f"by at least the robot radius {r} m")
        rng = np.random.default_rng([self.seed, int(robot_id)])
        body = cls(self._client, robot_id, (x, y, yaw), rng, gui=self.gui, wheel_radius_sigma=self.wheel_radius_sigma)
        self._bodies[robot_id] = body
        return body

    # -------------------------------------------------------------- running
    @property
    def t(self) -> float:
        """Simulated time (s)."""
        return self._steps * self.dt

    @property
    def steps(self) -> int:
        """Physics steps taken."""
        return self._steps

    @property
    def bodies(self) -> dict:
        return self._bodies

    @property
    def client_id(self) -> int:
        return self._client

    def step(self, n: int = 1) -> None:
        """Advance ``n`` physics steps of ``dt``; every ``MOTOR_SAMPLE_PERIOD`` of sim time, update every
        body's motor load and battery over the steps since the last update."""
        for _ in range(n):
            p.stepSimulation(**self._kw)
        self._steps += n
        for body in self._bodies.values():
            body.stepped()
        self._unsampled += n
        if self._unsampled >= self._sample_every:
            elapsed = self._unsampled * self.dt
            self._unsampled = 0
            for body in self._bodies.values():
                body.after_step(elapsed)

    def close(self) -> None:
        if self._client is not None and self._client >= 0:
            try:
                p.disconnect(**self._kw)
            except p.error:
                pass
            self._client = -1

    def __enter__(self) -> "World":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
