"""A simulated small industrial AMR with two CAN wheel drives: a dynamic pybullet multibody.

Body kind ``"candiff"`` (:mod:`sitl.bodies.registry`); the CiA 402 device (:mod:`sitl.devices.cia402`) drives
it.  The dimensions are our own choice for a small indoor AMR of the class of a cart-pulling or shelf robot
(no vendor's drawing): a box chassis 0.44 m long, 0.38 m wide and 0.20 m high with 30 mm ground clearance,
18 kg; two driven wheels of 150 mm diameter (0.075 m radius) on a 0.34 m track at the chassis' centre, each
behind a 24:1 gearbox (the motor and encoder are the drive's, :mod:`sitl.devices.cia402`); a caster 0.16 m
ahead of and behind the axle.  The footprint circle is 0.30 m (the chassis' half diagonal, 0.291 m, rounded
up).  It has no bumpers and no range sensors: industrial bases carry safety scanners, which this one leaves
out.

The device works in wheel joint terms, as a motor encoder does: :meth:`SimCanDiff.set_wheel_rates` (rad/s,
positive rolls forward), :meth:`wheel_angles` and :meth:`wheel_rates`.  Each tyre's rolling radius is off
the nominal by the world's ``wheel_radius_sigma``, so odometry from the encoders drifts as on a real robot.
"""
from __future__ import annotations

import numpy as np
import pybullet as p

from sitl.bodies.common import clip_wheels, tyre_radii
from sitl.bodies.diffdrive import LEFT, RIGHT, Chassis, GroundTruth
from sitl.bodies.diffdrive import build_body as diff_body

LENGTH, WIDTH, HEIGHT, CLEARANCE = 0.44, 0.38, 0.20, 0.03      # m
RADIUS = 0.30                 # m: the circle holding the chassis (half diagonal 0.291 m)
WHEEL_RADIUS = 0.075          # m nominal
TRACK = 0.34                  # m between the wheels' contact points
CASTER_RADIUS = 0.03          # m
CASTER_X = 0.16               # m ahead of / behind the axle
MASS_CHASSIS, MASS_WHEEL, MASS_CASTER = 18.0, 0.8, 0.2   # kg
MAX_WHEEL_RATE = 1.5 / WHEEL_RADIUS     # rad/s: 1.5 m/s at the rim, above what the drives are asked for
MAX_WHEEL_TORQUE = 4.0        # N m at the wheel (traction limit ~5 N m with mu = 1)
WHEEL_FRICTION = 1.0
CHASSIS_FRICTION = 0.3

CENTRE_Z = CLEARANCE + HEIGHT / 2         # base frame height above the floor
CHASSIS = Chassis(mass=MASS_CHASSIS, centre_z=CENTRE_Z, track=TRACK, wheel_mass=MASS_WHEEL,
                  caster_radius=CASTER_RADIUS, caster_x=CASTER_X, caster_mass=MASS_CASTER, friction=CHASSIS_FRICTION,
                  wheel_friction=WHEEL_FRICTION, max_wheel_torque=MAX_WHEEL_TORQUE)


def build_body(client: int, start: tuple[float, float, float], gui: bool, wheel_radii: tuple[float, float]) -> int:
    """Create the multibody at ``start`` = (x, y, yaw) on the floor and return its id."""
    kw = {"physicsClientId": client}
    half = (LENGTH / 2, WIDTH / 2, HEIGHT / 2)
    chassis = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, **kw)
    visual = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=(0.9, 0.55, 0.1, 1), **kw) if gui else -1
    return diff_body(client, start, CHASSIS, chassis, visual, wheel_radii, gui)


class SimCanDiff(GroundTruth):
    """One CAN differential base in a :class:`sitl.world.World`; the CiA 402 device calls these methods (ground
    truth: :class:`~sitl.bodies.diffdrive.GroundTruth`)."""

    radius = RADIUS
    centre_z = CENTRE_Z

    def __init__(self, client: int, robot_id: int, start: tuple[float, float, float], rng: np.random.Generator,
                 gui: bool = False, wheel_radius_sigma: float = 0.004):
        self.robot_id = robot_id
        self._kw = {"physicsClientId": client}
        self.wheel_radii = tyre_radii(rng, WHEEL_RADIUS, wheel_radius_sigma)
        self.body_id = build_body(client, start, gui, self.wheel_radii)
        self._targets = (0.0, 0.0)

    # -------------------------------------------------------------- commands
    def set_wheel_rates(self, left: float, right: float) -> None:
        """Wheel motor targets in rad/s (positive rolls forward), clipped to MAX_WHEEL_RATE."""
        targets = clip_wheels(self.robot_id, left, right, MAX_WHEEL_RATE)
        if targets == self._targets:
            return
        self._targets = targets
        p.setJointMotorControlArray(self.body_id, [LEFT, RIGHT], p.VELOCITY_CONTROL, targetVelocities=list(targets),
                                    forces=[MAX_WHEEL_TORQUE] * 2, **self._kw)

    def wheel_targets(self) -> tuple[float, float]:
        return self._targets

    # -------------------------------------------------------------- physics hooks
    def stepped(self) -> None:
        """The world stepped (nothing cached here)."""

    def after_step(self, dt: float) -> None:
        """Motor-load sample (no battery model on this body)."""

    # -------------------------------------------------------------- sensors
    def wheel_angles(self) -> tuple[float, float]:
        """Cumulative wheel joint angles (rad), as the motor encoders see them through the gearbox."""
        left, right = p.getJointStates(self.body_id, [LEFT, RIGHT], **self._kw)
        return left[0], right[0]

    def wheel_rates(self) -> tuple[float, float]:
        """Wheel joint rates (rad/s)."""
        left, right = p.getJointStates(self.body_id, [LEFT, RIGHT], **self._kw)
        return left[1], right[1]
