"""Paper 000's foraging world: the SITL's pybullet world (:class:`sitl.world.World`) in its planar profile, a
square walled arena with Pioneer-sized disc robots commanded by unicycle velocities; objects and the delivery
point are marks on the floor, not bodies.

Bodies.  Each robot is a disc of the p3dx-sh RobotRadius (0.25 m) and the Pioneer's 10 kg
(:mod:`sitl.bodies.pioneer3dx`), moving in the plane: a fixed-base pybullet multibody of three joints
(prismatic x, prismatic y, revolute yaw) whose last link carries the collision shape, a sphere of the robot
radius with its centre at that height (all robots and walls share the height, so every contact is in the plane
and a sphere is exactly a disc).  No floor, no gravity, no wheels: the engine solves only robot-robot and
robot-wall contacts.  Robots physically block and push each other; interference comes from those contacts.

Drive.  ``command(robot, v, w)`` sets the target (m/s, rad/s), clipped to the base's limits; the command the
motors follow approaches it at the ARCOS accelerations (0.3 m/s^2, 100 deg/s^2, :mod:`sitl.devices.arcos`)
and is turned into world-frame joint velocity targets at every physics step.  The joint motors are
force-limited: the drive force of the full Pioneer body's two wheel motors (2 x 1 N m on 97.5 mm tyres,
20.5 N) along x and along y, and that force on half the track as the turning torque.  A robot that stands still
holds with the same motors, so a driving robot pushes a standing one only slowly and the two do not overlap.

Sensing (ground truth, as the sweeps need): pose, bumpers (contact within 5 mm on the front 135 degrees, split
left/right as the Pioneer's front bumper segments are; computed from the discs, no contact query), and the
16-sonar ring in closed form (:mod:`sitl.sensing.sonar_ring`).

Time: ``advance(seconds)`` takes whole physics steps of ``dt`` (default :data:`DT`); between calls nothing
moves.  With the same calls a run is bit-for-bit repeatable.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np
import pybullet as p

from runtime.config import WorldConfig
from runtime.errors import InputError
from sitl.bodies import pioneer3dx as p3dx
from sitl.devices.arcos import ROT_ACCEL, TRANS_ACCEL
from sitl.sensing import sonar_ring as sonar
from sitl.world import PLANAR, World

RADIUS = p3dx.PARAMS.radius_mm / 1000.0          # 0.25 m
MASS = p3dx.MASS_TOTAL                            # 10 kg
DRIVE_FORCE = 2 * p3dx.MAX_WHEEL_TORQUE / p3dx.WHEEL_RADIUS      # N, both wheel motors at their torque limit
TURN_TORQUE = DRIVE_FORCE * p3dx.WHEEL_TRACK / 2                 # N m
ACCEL = TRANS_ACCEL / 1000.0                      # m/s^2, ARCOS default
ROT_ACC = math.radians(ROT_ACCEL)                 # rad/s^2
MAX_SPEED = 0.75                                  # m/s: the robot config's base.max_speed
MAX_TURN = 2 * MAX_SPEED / p3dx.WHEEL_TRACK
DT = PLANAR.dt                                    # s, physics step (see docs/foraging.md)
SOLVER_ITERATIONS = PLANAR.solver_iterations
BUMP_MARGIN = 0.005                               # m: a disc this close to another or a wall touches it
BUMPER_HALF = p3dx.BUMPER_ARC / 2                 # 67.5 deg each side of ahead
BUMPER_CENTRE = p3dx.BUMPER_ARC / p3dx.BUMPER_SEGMENTS / 2        # the centre segment presses both sides
HEIGHT = RADIUS                                   # centre height of every disc (and of the planar profile's walls)
FRICTION = PLANAR.wall_friction                   # between bodies (painted metal)
PARKED = 1000.0                                   # m: where a removed robot's body waits, out of everyone's way


class ForagingWorld:
    """Robots ``starts`` ({id: (x, y, yaw)}) in a ``size`` x ``size`` m walled arena centred on the origin."""

    def __init__(self, starts: Mapping[int, tuple[float, float, float]], size: float = 10.0, dt: float = DT,
                 solver_iterations: int = SOLVER_ITERATIONS, radius: float = RADIUS):
        if not (math.isfinite(dt) and 0 < dt <= 0.1):
            raise InputError(f"foraging world dt: expected a physics step in (0, 0.1] s, got {dt!r}")
        if not (math.isfinite(size) and size > 4 * radius):
            raise InputError(f"foraging world size: expected more than {4 * radius:g} m, got {size!r}")
        self.size, self.dt, self.radius = float(size), float(dt), float(radius)
        self.ids = tuple(sorted(int(r) for r in starts))
        self.index = {r: k for k, r in enumerate(self.ids)}
        start = np.array([starts[r] for r in self.ids], dtype=float).reshape(-1, 3)
        self._check_starts(start)
        n = len(self.ids)
        self.alive = np.ones(n, dtype=bool)
        self.poses = start.copy()
        self._origin = start.copy()                  # joint zero of each robot (x, y; yaw is the joint's own)
        self._origin[:, 2] = 0.0
        self.target = np.zeros((n, 2))               # (v, w) commanded
        self.velocity = np.zeros((n, 2))             # (v, w) after the acceleration limits
        self._sent: list = [None] * n                # last joint targets handed to each robot's motors
        self._sonar_at: int | None = None
        self._sonar = np.zeros((n, sonar.N_SONARS))
        self.arena = World(WorldConfig(size=(self.size, self.size), walls=True), dt=self.dt, profile=PLANAR,
                           solver_iterations=solver_iterations)
        self._client = self.arena.client_id
        kw = self._kw = {"physicsClientId": self._client}
        disc = p.createCollisionShape(p.GEOM_SPHERE, radius=self.radius, **kw)
        self.bodies = [self._robot(disc, row) for row in start]

    def _check_starts(self, start: np.ndarray) -> None:
        lim = self.size / 2 - self.radius
        for rid, (x, y, yaw) in zip(self.ids, start):
            if not all(math.isfinite(v) for v in (x, y, yaw)):
                raise InputError(f"robot {rid} start: expected finite (x, y, yaw), got {(x, y, yaw)!r}")
            if abs(x) > lim or abs(y) > lim:
                raise InputError(f"robot {rid} start ({x:g}, {y:g}): expected inside the {self.size:g} m arena "
                                 f"by at least the robot radius {self.radius:g} m")
        for a in range(len(start)):
            for b in range(a):
                if math.dist(start[a, :2], start[b, :2]) < 2 * self.radius:
                    raise InputError(f"robot {self.ids[a]} start: expected at least {2 * self.radius:g} m from robot "
                                     f"{self.ids[b]}, the two overlap")

    def _robot(self, disc: int, start) -> int:
        kw = self._kw
        body = p.createMultiBody(
            baseMass=0, basePosition=(float(start[0]), float(start[1]), HEIGHT),
            linkMasses=[1e-3, 1e-3, MASS], linkCollisionShapeIndices=[-1, -1, disc], linkVisualShapeIndices=[-1] * 3,
            linkPositions=[(0, 0, 0)] * 3, linkOrientations=[(0, 0, 0, 1)] * 3,
            linkInertialFramePositions=[(0, 0, 0)] * 3, linkInertialFrameOrientations=[(0, 0, 0, 1)] * 3,
            linkParentIndices=[0, 1, 2], linkJointTypes=[p.JOINT_PRISMATIC, p.JOINT_PRISMATIC, p.JOINT_REVOLUTE],
            linkJointAxis=[(1, 0, 0), (0, 1, 0), (0, 0, 1)], **kw)
        p.resetJointState(body, 2, float(start[2]), **kw)            # the base frame is unturned: yaw is joint 2
        for j in range(3):
            p.changeDynamics(body, j, linearDamping=0.0, angularDamping=0.0, jointDamping=0.0,
                             lateralFriction=FRICTION, restitution=0.0, **kw)
        p.setJointMotorControlArray(body, [0, 1, 2], p.VELOCITY_CONTROL, targetVelocities=[0, 0, 0],
                                    forces=[DRIVE_FORCE, DRIVE_FORCE, TURN_TORQUE], **kw)
        return body

    # ------------------------------------------------------------------ commands and time
    @property
    def t(self) -> float:
        """Simulated time (s)."""
        return self.arena.t

    def command(self, robot: int, v: float, w: float) -> None:
        """Target unicycle velocity of ``robot`` (m/s, rad/s), clipped to the base's limits."""
        k = self.index[robot]
        if not (math.isfinite(v) and math.isfinite(w)):
            v = w = 0.0
        self.target[k] = (min(max(v, -MAX_SPEED), MAX_SPEED), min(max(w, -MAX_TURN), MAX_TURN))

    def advance(self, seconds: float) -> None:
        """Run ``round(seconds / dt)`` physics steps, then read every pose."""
        steps = max(1, int(round(seconds / self.dt)))
        heading = self.poses[:, 2].copy()
        step_v, step_w = ACCEL * self.dt, ROT_ACC * self.dt
        live = np.flatnonzero(self.alive).tolist()
        for _ in range(steps):            # (minimum of maximum: np.clip's values without its dispatch)
            self.velocity[:, 0] += np.minimum(np.maximum(self.target[:, 0] - self.velocity[:, 0], -step_v), step_v)
            self.velocity[:, 1] += np.minimum(np.maximum(self.target[:, 1] - self.velocity[:, 1], -step_w), step_w)
            mid = heading + 0.5 * self.velocity[:, 1] * self.dt        # heading at the middle of the step
            vx, vy = (self.velocity[:, 0] * np.cos(mid)).tolist(), (self.velocity[:, 0] * np.sin(mid)).tolist()
            w = self.velocity[:, 1].tolist()
            for k in live:
                targets = (vx[k], vy[k], w[k])
                if targets != self._sent[k]:
                    self._sent[k] = targets
                    p.setJointMotorControlArray(self.bodies[k], [0, 1, 2], p.VELOCITY_CONTROL,
                                                targetVelocities=targets,
                                                forces=[DRIVE_FORCE, DRIVE_FORCE, TURN_TORQUE], **self._kw)
            self.arena.step()
            heading += self.velocity[:, 1] * self.dt
        self._read_poses()

    def _read_poses(self) -> None:
        for k in np.flatnonzero(self.alive).tolist():
            states = p.getJointStates(self.bodies[k], [0, 1, 2], **self._kw)
            o = self._origin[k]
            self.poses[k] = (o[0] + states[0][0], o[1] + states[1][0],
                             math.remainder(o[2] + states[2][0], math.tau))

    def remove(self, robot: int) -> None:
        """Take ``robot`` out of the world (a failed robot, gone): its body is parked far away, collides with
        nothing and no sonar sees it."""
        k = self.index[robot]
        if not self.alive[k]:
            return
        self.alive[k] = False
        self.target[k] = self.velocity[k] = 0.0
        body = self.bodies[k]
        p.setCollisionFilterGroupMask(body, 2, 0, 0, **self._kw)
        p.setJointMotorControlArray(body, [0, 1, 2], p.VELOCITY_CONTROL, targetVelocities=[0, 0, 0],
                                    forces=[DRIVE_FORCE, DRIVE_FORCE, TURN_TORQUE], **self._kw)
        p.resetJointState(body, 0, PARKED + 10 * k - self._origin[k, 0], **self._kw)
        self.poses[k] = (PARKED + 10 * k, self.poses[k, 1], self.poses[k, 2])
        self._sonar_at = None

    # ------------------------------------------------------------------ sensing
    def pose(self, robot: int) -> tuple[float, float, float]:
        return tuple(float(v) for v in self.poses[self.index[robot]])

    def bumpers(self) -> np.ndarray:
        """(N, 2) bools: left and right front bumper pressed, per robot (rows in ``ids`` order)."""
        n = len(self.ids)
        xy, yaw = self.poses[:, :2], self.poses[:, 2]
        pts, owner = [], []
        half = self.size / 2
        for axis in (0, 1):                                  # walls: the touching point on the wall
            for sign in (1.0, -1.0):
                near = self.alive & (sign * xy[:, axis] >= half - self.radius - BUMP_MARGIN)
                for k in np.flatnonzero(near):
                    q = xy[k].copy()
                    q[axis] = sign * half
                    pts.append(q)
                    owner.append(k)
        if n > 1:
            d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
            touch = (d <= 2 * self.radius + BUMP_MARGIN) & self.alive[:, None] & self.alive[None, :]
            np.fill_diagonal(touch, False)
            for a, b in zip(*np.nonzero(touch)):
                pts.append((xy[a] + xy[b]) / 2)
                owner.append(a)
        out = np.zeros((n, 2), dtype=bool)
        for q, k in zip(pts, owner):
            rel = math.remainder(math.atan2(q[1] - xy[k, 1], q[0] - xy[k, 0]) - yaw[k], math.tau)
            if abs(rel) <= BUMPER_HALF:
                out[k, 0] |= rel >= -BUMPER_CENTRE
                out[k, 1] |= rel <= BUMPER_CENTRE
        return out

    def sonar(self) -> np.ndarray:
        """(N, 16) sonar ranges (m from each transducer; :data:`sitl.sensing.sonar_ring.MAX_RANGE` for no echo), rows
        in ``ids`` order; a removed robot's row is all no-echo.  Computed once per physics step."""
        if self._sonar_at != self.arena.steps:
            live = np.flatnonzero(self.alive)
            self._sonar[:] = sonar.MAX_RANGE
            if len(live):
                self._sonar[live] = sonar.ring_ranges(self.poses[live], self.radius, self.size / 2)
            self._sonar_at = self.arena.steps
        return self._sonar

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        self.arena.close()

    def __enter__(self) -> "ForagingWorld":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
