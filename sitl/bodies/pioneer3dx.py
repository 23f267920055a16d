"""A simulated Pioneer 3-DX: a dynamic pybullet multibody with its 16-sonar ring, read by the ARCOS emulator.

Body kind ``"pioneer3dx"`` (:mod:`sitl.bodies.registry`); :mod:`sitl.devices.arcos` drives it.  Where each
number comes from:

* chassis outline: the convex hull of the 16 SonarUnit positions of AriaCoda ``params/p3dx-sh.p`` (the
  transducers sit on the body's rim), 10 mm inside them so every ray starts outside the body; it runs
  from 255 mm behind the wheel axle to 166 mm ahead and 272 mm wide, inside RobotRadius 250 mm.  The
  parameter file's RobotLength 511 / RobotWidth 425 include bumper rings and the tyres, which p3dx-sh
  declares absent (FrontBumpers false) and which are modelled here by the wheels themselves;
* height 217 mm (Webots' Pioneer 3-DX model documentation: 485 x 381 x 217 mm, 10 kg); the underside
  60 mm above the floor (chosen: clear of the caster, below the wheel hubs);
* mass 10 kg in all (the same Webots figure), its centre 40 mm behind the axle so the rear caster carries
  a share (the batteries sit behind the axle);
* wheels: 195 mm tyres (:attr:`runtime.drivers.arcos_protocol.RobotParams.wheel_diameter_mm`), 47.5 mm wide (chosen),
  on a 357 mm track (DiffConvFactor 0.0056, as ARIA uses it); cylinders, velocity-controlled;
* caster: a 37.5 mm radius frictionless sphere 211 mm behind the axle (p2os_urdf's pioneer3dx swivel at
  -185 mm and its wheel 26 mm further back, radius 37.5 mm);
* sonar: the 16 units' positions and headings from p3dx-sh, 200 mm above the floor (above the tyres, as
  the real rings are), range limit 5 m (ARIA's sonar device).  Each sonar is five rays spread over its
  25 degree beam (the Polaroid 600-series transducer's main lobe): a sonar reports the nearest echo in
  its cone, and the front ring's 20 degree spacing would leave gaps a single ray per sonar cannot see
  into (a box corner or a robot between two axes).  The nearest of the five is the reading.
"""
from __future__ import annotations

import math

import numpy as np
import pybullet as p

from runtime.drivers.arcos_protocol import P3DX_SH
from sitl.bodies.common import clip_wheels, touching, tyre_radii, yaw_of
from sitl.bodies.diffdrive import GroundTruth
from sitl.sensing import raycast

PARAMS = P3DX_SH
WHEEL_RADIUS = PARAMS.wheel_diameter_mm / 2000.0          # m
WHEEL_WIDTH = 0.0475
WHEEL_TRACK = PARAMS.track_mm / 1000.0
HULL_INSET = 0.010            # m inside the sonar positions
BODY_BOTTOM = 0.060           # m above the floor
BODY_TOP = 0.217
CASTER_RADIUS = 0.0375
CASTER_X = -0.211
MASS_TOTAL = 10.0
MASS_WHEEL = 0.6
MASS_CASTER = 0.2
MASS_CHASSIS = MASS_TOTAL - 2 * MASS_WHEEL - MASS_CASTER
COM_X = -0.040                # chassis centre of mass behind the axle
MAX_WHEEL_SPEED = PARAMS.max_vel_mm_s / 1000.0            # MaxVelocity, m/s
MAX_WHEEL_TORQUE = 1.0        # N m per wheel: about 2 m/s^2 on the 10 kg body, below tipping forward
WHEEL_FRICTION = 1.0
CHASSIS_FRICTION = 0.3
SONAR_Z = 0.200
SONAR_MAX_RANGE = PARAMS.sonar_max_range_mm / 1000.0
SONAR_BEAM = math.radians(25.0)
SONAR_RAYS = 5

# Bumpers (ArBumpers.cpp): five front segments over 135 degrees, segment 0 the leftmost; five rear ones.
BUMPER_SEGMENTS = 5
BUMPER_ARC = math.radians(135.0)
CONTACT_MARGIN = 0.002
LEFT, RIGHT = 0, 1
CASTER = 2

CHASSIS_CENTRE_Z = (BODY_BOTTOM + BODY_TOP) / 2
_COM = (COM_X, 0.0, CHASSIS_CENTRE_Z - WHEEL_RADIUS)       # chassis centre of mass in the base frame
_COM_INV = tuple(-v for v in _COM)


def hull_outline() -> list[tuple[float, float]]:
    """The chassis outline (x, y in m, robot frame): the sonar positions pulled HULL_INSET towards the centre."""
    pts = []
    for u in PARAMS.sonar_units:
        x, y = u.x / 1000.0, u.y / 1000.0
        r = math.hypot(x, y)
        pts.append((x * (r - HULL_INSET) / r, y * (r - HULL_INSET) / r))
    return pts


def sonar_rays() -> np.ndarray:
    """(16 * SONAR_RAYS, 4): per ray its origin x, y and direction angle in the robot frame, and its sonar number."""
    return raycast.fan([(u.x / 1000.0, u.y / 1000.0, math.radians(u.heading)) for u in PARAMS.sonar_units],
                       SONAR_BEAM, SONAR_RAYS)


_RAYS = sonar_rays()


def build_body(client: int, start: tuple[float, float, float], gui: bool = False,
               wheel_radii: tuple[float, float] = (WHEEL_RADIUS, WHEEL_RADIUS)) -> int:
    """Create the multibody at ``start`` = (x, y, yaw) and return its body id (base frame: between the wheels,
    at axle height)."""
    kw = {"physicsClientId": client}
    axle_z = WHEEL_RADIUS
    outline = hull_outline()
    verts = [(x, y, z - axle_z) for x, y in outline for z in (BODY_BOTTOM, BODY_TOP)]
    chassis = p.createCollisionShape(p.GEOM_MESH, vertices=verts, **kw)
    wheel_orn = p.getQuaternionFromEuler((math.pi / 2, 0, 0))     # cylinder axis along y
    wheels = [p.createCollisionShape(p.GEOM_CYLINDER, radius=r, height=WHEEL_WIDTH, **kw) for r in wheel_radii]
    caster = p.createCollisionShape(p.GEOM_SPHERE, radius=CASTER_RADIUS, **kw)
    vis = [-1, -1, -1]
    if gui:
        vis = [p.createVisualShape(p.GEOM_MESH, vertices=verts, rgbaColor=(0.8, 0.1, 0.1, 1), **kw),
               p.createVisualShape(p.GEOM_CYLINDER, radius=WHEEL_RADIUS, length=WHEEL_WIDTH,
                                   rgbaColor=(0.1, 0.1, 0.1, 1), **kw),
               p.createVisualShape(p.GEOM_SPHERE, radius=CASTER_RADIUS, rgbaColor=(0.6, 0.6, 0.6, 1), **kw)]
    half = WHEEL_TRACK / 2
    x, y, yaw = start
    body = p.createMultiBody(
        baseMass=MASS_CHASSIS, baseCollisionShapeIndex=chassis, baseVisualShapeIndex=vis[0],
        basePosition=(x, y, axle_z), baseOrientation=p.getQuaternionFromEuler((0, 0, yaw)),
        baseInertialFramePosition=_COM,
        linkMasses=[MASS_WHEEL, MASS_WHEEL, MASS_CASTER],
        linkCollisionShapeIndices=[wheels[0], wheels[1], caster],
        linkVisualShapeIndices=[vis[1], vis[1], vis[2]],
        linkPositions=[(0, half, wheel_radii[0] - axle_z), (0, -half, wheel_radii[1] - axle_z),
                       (CASTER_X, 0, CASTER_RADIUS - axle_z)],
        linkOrientations=[wheel_orn, wheel_orn, (0, 0, 0, 1)],
        linkInertialFramePositions=[(0, 0, 0)] * 3,
        linkInertialFrameOrientations=[(0, 0, 0, 1)] * 3,
        linkParentIndices=[0, 0, 0],
        linkJointTypes=[p.JOINT_REVOLUTE, p.JOINT_REVOLUTE, p.JOINT_FIXED],
        linkJointAxis=[(0, 0, 1), (0, 0, 1), (0, 0, 1)],       # the cylinder's own axis: the axle
        **kw)
    p.changeDynamics(body, -1, lateralFriction=CHASSIS_FRICTION, restitution=0.0, contactProcessingThreshold=0.0,
                     activationState=p.ACTIVATION_STATE_DISABLE_SLEEPING, **kw)
    for link in (LEFT, RIGHT):
        p.changeDynamics(body, link, lateralFriction=WHEEL_FRICTION, spinningFriction=0.0, rollingFriction=0.0,
                         restitution=0.0, jointDamping=0.0, contactProcessingThreshold=0.0, **kw)
    p.changeDynamics(body, CASTER, lateralFriction=0.0, spinningFriction=0.0, rollingFriction=0.0,
                     restitution=0.0, contactProcessingThreshold=0.0, **kw)
    p.setJointMotorControlArray(body, [LEFT, RIGHT], p.VELOCITY_CONTROL, targetVelocities=[0.0, 0.0],
                                forces=[MAX_WHEEL_TORQUE] * 2, **kw)
    return body


class SimPioneer3DX(GroundTruth):
    """One Pioneer 3-DX body in a :class:`sitl.world.World`; the ARCOS emulator calls these methods."""

    radius = PARAMS.radius_mm / 1000.0     # RobotRadius: holds the chassis (0.246 m) and the wheels (0.224 m)

    def __init__(self, client: int, robot_id: int, start: tuple[float, float, float],
                 rng: np.random.Generator, gui: bool = False, wheel_radius_sigma: float = 0.004):
        self.robot_id = robot_id
        self._client = client
        self._kw = {"physicsClientId": client}
        self.wheel_radii = tyre_radii(rng, WHEEL_RADIUS, wheel_radius_sigma)
        self.body_id = build_body(client, start, gui, self.wheel_radii)
        self._targets = (0.0, 0.0)
        self._contacts: list | None = None
        self.rays_cast = 0
        self.sonar = raycast.Beams(self, _RAYS, SONAR_Z, SONAR_MAX_RANGE)   # the ring, mounted on this body
        self._fired: dict[tuple, raycast.Beams] = {}    # the ring's rays of each set of sonars fired together

    # -------------------------------------------------------------- commands
    def set_wheel_speeds(self, left_mps: float, right_mps: float) -> None:
        """Wheel motor targets (m/s at the rim), clipped to MaxVelocity.  The left wheel's joint axis points
        along the body's y axis, so forward is a negative joint rate on both (axis z of the turned cylinder)."""
        left, right = clip_wheels(self.robot_id, left_mps, right_mps, MAX_WHEEL_SPEED)
        if (left, right) == self._targets:
            return
        self._targets = (left, right)
        p.setJointMotorControlArray(self.body_id, [LEFT, RIGHT], p.VELOCITY_CONTROL,
                                    targetVelocities=[-left / WHEEL_RADIUS, -right / WHEEL_RADIUS],
                                    forces=[MAX_WHEEL_TORQUE] * 2, **self._kw)

    def wheel_targets(self) -> tuple[float, float]:
        return self._targets

    # -------------------------------------------------------------- physics hooks
    def after_step(self, dt: float) -> None:
        """Nothing to integrate: the ARCOS emulator keeps the battery."""

    def stepped(self) -> None:
        self._contacts = None

    # -------------------------------------------------------------- sensors
    def wheel_travel(self) -> tuple[float, float]:
        """Cumulative signed distance each wheel rolled as its encoder sees it (m): joint angle x nominal radius."""
        states = p.getJointStates(self.body_id, [LEFT, RIGHT], **self._kw)
        return -states[0][0] * WHEEL_RADIUS, -states[1][0] * WHEEL_RADIUS

    def wheel_rates(self) -> tuple[float, float]:
        """Each wheel's present rim speed as its encoder sees it (m/s)."""
        states = p.getJointStates(self.body_id, [LEFT, RIGHT], **self._kw)
        return -states[0][1] * WHEEL_RADIUS, -states[1][1] * WHEEL_RADIUS

    def contacts(self) -> list:
        if self._contacts is None:
            self._contacts = touching(self._client, self.body_id, CONTACT_MARGIN)
        return self._contacts

    def bumper_segments(self) -> tuple[int, int]:
        """(front, rear) bumper bits, bit 0 the first segment (front: leftmost; rear: as ArBumpers numbers
        them, from the rear right), for chassis contacts within the 135 degree arc ahead or behind."""
        x, y, yaw = self.pose()
        c, s = math.cos(yaw), math.sin(yaw)
        front = rear = 0
        width = BUMPER_ARC / BUMPER_SEGMENTS
        for cp in self.contacts():
            if cp[3] != -1:
                continue
            dx, dy = cp[5][0] - x, cp[5][1] - y
            bearing = math.atan2(-s * dx + c * dy, c * dx + s * dy)
            for off, is_front in ((0.0, True), (math.pi, False)):
                rel = math.remainder(bearing - off, math.tau)
                if abs(rel) <= BUMPER_ARC / 2:
                    k = min(BUMPER_SEGMENTS - 1, int((BUMPER_ARC / 2 - rel) // width))
                    if is_front:
                        front |= 1 << k
                    else:
                        rear |= 1 << k
        return front, rear

    def bumps(self) -> tuple[bool, bool]:
        """Left/right: a front bumper segment left of centre (or the centre one) / right of centre is pressed."""
        front, _ = self.bumper_segments()
        return bool(front & 0b00111), bool(front & 0b11100)

    def wheel_drop(self) -> tuple[bool, bool]:
        """Left/right wheel not touching anything (lifted)."""
        links = {cp[3] for cp in self.contacts()}
        return LEFT not in links, RIGHT not in links

    def sonar_ranges(self, sonars) -> dict[int, float]:
        """Range (m) each sonar in ``sonars`` measures now: the nearest hit of its rays within 5 m, from the
        transducer; 5 m when nothing echoes."""
        key = tuple(sonars)
        beams = self._fired.get(key)
        if beams is None:                     # ARCOS fires a few fixed pairs in turn: each selected once
            beams = self._fired[key] = self.sonar.select(sonars)
        out = {int(n): SONAR_MAX_RANGE for n in key}
        if not len(beams.rays):
            return out
        (dist,), n_cast = raycast.cast_many([beams])
        self.rays_cast += n_cast
        rays = beams.rays
        for k, row in enumerate(rays):
            n = int(row[3])
            out[n] = min(out[n], float(dist[k]))
        return out

    def _frame(self) -> tuple[tuple, tuple]:
        """Position and orientation of the base frame (pybullet reports the base's centre of mass)."""
        com, orn = p.getBasePositionAndOrientation(self.body_id, **self._kw)
        return p.multiplyTransforms(com, orn, _COM_INV, (0, 0, 0, 1))

    def pose(self) -> tuple[float, float, float]:
        """Ground truth x, y (m) and yaw (rad) of the point between the wheels, ENU."""
        pos, orn = self._frame()
        return pos[0], pos[1], yaw_of(orn)

    def height(self) -> float:
        """Ground truth height of the base frame (the axle) above the floor (m); ~0.0975 when resting."""
        return self._frame()[0][2]

    def place(self, x: float, y: float, yaw: float, z: float | None = None) -> None:
        """Teleport the body (test and launcher use only; zeroes its velocity)."""
        orn = p.getQuaternionFromEuler((0, 0, yaw))
        com, _ = p.multiplyTransforms((x, y, WHEEL_RADIUS if z is None else z), orn, _COM, (0, 0, 0, 1))
        p.resetBasePositionAndOrientation(self.body_id, com, orn, **self._kw)
        p.resetBaseVelocity(self.body_id, (0, 0, 0), (0, 0, 0), **self._kw)
