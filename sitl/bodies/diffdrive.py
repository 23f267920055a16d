"""Two-wheel bodies with a caster ahead of and behind the axle: the pybullet multibody of a chassis on two driven
wheels and two casters, and the ground-truth readings (the per-wheel helpers are in :mod:`sitl.bodies.common`).

Wheels are velocity-controlled revolute joints with sphere collision shapes (cheap, one contact on the floor);
casters are frictionless spheres on fixed joints.  A body module gives its own chassis shape and numbers
(:class:`Chassis`) and mixes :class:`GroundTruth` into its class.
"""
from __future__ import annotations

from dataclasses import dataclass

import pybullet as p

from sitl.bodies.common import yaw_of

LEFT, RIGHT = 0, 1            # link indices of the wheel joints
CASTERS = (2, 3)


@dataclass(frozen=True)
class Chassis:
    mass: float               # kg, the chassis alone
    centre_z: float           # m: the base frame (chassis centre) above the floor
    track: float              # m between the wheels' contact points
    wheel_mass: float         # kg each
    caster_radius: float      # m
    caster_x: float           # m ahead of / behind the axle
    caster_mass: float        # kg each
    friction: float           # chassis lateral friction
    wheel_friction: float
    max_wheel_torque: float   # N m the wheel motors hold
    colour: tuple = (0.2, 0.2, 0.2, 1)


def build_body(client: int, start: tuple[float, float, float], c: Chassis, shape: int, visual: int,
               wheel_radii: tuple[float, float], gui: bool = False) -> int:
    """The multibody at ``start`` = (x, y, yaw) on the floor: chassis collision ``shape`` (and ``visual``, -1 for
    none), wheels of ``wheel_radii`` (left, right), casters; returns its body id."""
    kw = {"physicsClientId": client}
    wheels = [p.createCollisionShape(p.GEOM_SPHERE, radius=r, **kw) for r in wheel_radii]
    caster = p.createCollisionShape(p.GEOM_SPHERE, radius=c.caster_radius, **kw)
    vis_wheel = vis_caster = -1
    if gui:
        vis_wheel = p.createVisualShape(p.GEOM_SPHERE, radius=wheel_radii[0], rgbaColor=(0.1, 0.1, 0.1, 1), **kw)
        vis_caster = p.createVisualShape(p.GEOM_SPHERE, radius=c.caster_radius, rgbaColor=(0.6, 0.6, 0.6, 1), **kw)
    caster_z = c.caster_radius - c.centre_z
    half = c.track / 2
    x, y, yaw = start
    body = p.createMultiBody(
        baseMass=c.mass, baseCollisionShapeIndex=shape, baseVisualShapeIndex=visual,
        basePosition=(x, y, c.centre_z), baseOrientation=p.getQuaternionFromEuler((0, 0, yaw)),
        linkMasses=[c.wheel_mass, c.wheel_mass, c.caster_mass, c.caster_mass],
        linkCollisionShapeIndices=[wheels[0], wheels[1], caster, caster],
        linkVisualShapeIndices=[vis_wheel, vis_wheel, vis_caster, vis_caster],
        linkPositions=[(0, half, wheel_radii[0] - c.centre_z), (0, -half, wheel_radii[1] - c.centre_z),
                       (c.caster_x, 0, caster_z), (-c.caster_x, 0, caster_z)],
        linkOrientations=[(0, 0, 0, 1)] * 4,
        linkInertialFramePositions=[(0, 0, 0)] * 4,
        linkInertialFrameOrientations=[(0, 0, 0, 1)] * 4,
        linkParentIndices=[0, 0, 0, 0],
        linkJointTypes=[p.JOINT_REVOLUTE, p.JOINT_REVOLUTE, p.JOINT_FIXED, p.JOINT_FIXED],
        linkJointAxis=[(0, 1, 0), (0, 1, 0), (0, 0, 1), (0, 0, 1)],
        **kw)
    # contactProcessingThreshold=0: only touching manifold points become solver constraints.  A rolling
    # sphere leaves stale points behind in the manifold; solving those too costs half the step time.
    p.changeDynamics(body, -1, lateralFriction=c.friction, restitution=0.0, contactProcessingThreshold=0.0,
                     activationState=p.ACTIVATION_STATE_DISABLE_SLEEPING, **kw)
    for link in (LEFT, RIGHT):
        p.changeDynamics(body, link, lateralFriction=c.wheel_friction, spinningFriction=0.0,
                         rollingFriction=0.0, restitution=0.0, jointDamping=0.0,
                         contactProcessingThreshold=0.0, **kw)
    for link in CASTERS:
        p.changeDynamics(body, link, lateralFriction=0.0, spinningFriction=0.0, rollingFriction=0.0,
                         restitution=0.0, contactProcessingThreshold=0.0, **kw)
    # Revolute joints start with a default velocity motor of small force; replace it with ours.
    p.setJointMotorControlArray(body, [LEFT, RIGHT], p.VELOCITY_CONTROL, targetVelocities=[0.0, 0.0],
                                forces=[c.max_wheel_torque] * 2, **kw)
    return body


class GroundTruth:
    """Ground-truth readings of a body with ``body_id``, ``_kw`` (the pybullet client) and ``centre_z``."""

    body_id: int
    centre_z: float
    _kw: dict

    def pose(self) -> tuple[float, float, float]:
        """Ground truth x, y (m) and yaw (rad), ENU."""
        pos, orn = p.getBasePositionAndOrientation(self.body_id, **self._kw)
        return pos[0], pos[1], yaw_of(orn)

    def height(self) -> float:
        """Ground truth height of the base frame above the floor (m)."""
        return p.getBasePositionAndOrientation(self.body_id, **self._kw)[0][2]

    def velocity(self) -> tuple[float, float]:
        """Ground truth vx, vy (m/s), ENU."""
        lin, _ = p.getBaseVelocity(self.body_id, **self._kw)
        return lin[0], lin[1]

    def yaw_rate(self) -> float:
        """Ground truth turn rate (rad/s, counter-clockwise)."""
        return p.getBaseVelocity(self.body_id, **self._kw)[1][2]

    def place(self, x: float, y: float, yaw: float, z: float | None = None) -> None:
        """Teleport the body (test and launcher use only; zeroes its velocity)."""
        p.resetBasePositionAndOrientation(self.body_id, (x, y, self.centre_z if z is None else z),
                                          p.getQuaternionFromEuler((0, 0, yaw)), **self._kw)
        p.resetBaseVelocity(self.body_id, (0, 0, 0), (0, 0, 0), **self._kw)
