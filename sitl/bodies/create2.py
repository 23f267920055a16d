"""A simulated iRobot Create 2: a dynamic pybullet multibody and the readings its emulator serves.

Body kind ``"create2"`` (:mod:`sitl.bodies.registry`); the Create OI device drives it for either OI
model (a Create 1 runs on this body too: same size and wheels within a few percent).

The body is built from primitives (no URDF file): a cylinder shell, two velocity-controlled wheel
joints (sphere collision shapes, cheap and single-contact on the floor) and two frictionless caster
spheres on fixed joints.  Everything the device emulators read comes from the physics: wheel joint
angles, contact points, base velocity, motor torques.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pybullet as p

from runtime.drivers.create_oi_protocol import GEOMETRY
from sitl.bodies.common import clip_wheels, touching, tyre_radii
from sitl.bodies.diffdrive import LEFT, RIGHT, Chassis, GroundTruth
from sitl.bodies.diffdrive import build_body as diff_body

# Size and wheels from the one geometry table the driver and the planner read; the rest from the
# robot's published dimensions and mass.
_G = GEOMETRY["create2"]
SHELL_RADIUS = _G.radius_mm / 1000.0      # m
SHELL_TOP = 0.092             # m above the floor
SHELL_CLEARANCE = 0.010       # m, floor to the underside of the shell
WHEEL_RADIUS = _G.wheel_diameter_mm / 2000.0   # m
WHEEL_RADIUS_SIGMA = 0.004    # relative spread of the tyres' effective rolling radius
WHEEL_TRACK = _G.track_mm / 1000.0        # m between wheel contact points
CASTER_RADIUS = 0.012         # m
CASTER_X = 0.13               # m ahead of / behind the axle
MASS_SHELL = 3.2              # kg
MASS_WHEEL = 0.15             # kg each
MASS_CASTER = 0.05            # kg each
MAX_WHEEL_SPEED = _G.max_wheel_mm_s / 1000.0   # m/s
MAX_WHEEL_TORQUE = 0.3        # N m per wheel at the wheel shaft (below the traction limit ~0.6)
WHEEL_FRICTION = 1.0
SHELL_FRICTION = 0.3

# Bumper: contacts on the shell within +-BUMPER_ARC of the heading count; inside +-BUMPER_CENTRE
# both switches close (the bumper is one piece on two switches).
BUMPER_ARC = math.radians(90.0)
BUMPER_CENTRE = math.radians(15.0)
CONTACT_MARGIN = 0.002        # m: manifold points farther apart than this are not touching

# Battery (OI packets 21-26): Create 2 capacity as the robot reports it.
CAPACITY_MAH = 2696.0
V_FULL_MV = 16800.0
V_EMPTY_MV = 13200.0
R_INTERNAL = 0.15             # ohm
IDLE_CURRENT_MA = 180.0       # electronics, sensors, OI
MOTOR_KT = 0.3                # N m per A at the wheel (incl. gearbox)
MOTOR_R = 2.0                 # ohm winding resistance
MOTOR_EFFICIENCY = 0.6
MOTOR_NO_LOAD_MA = 120.0      # per motor at full speed (gearbox and brush losses), scales with speed
THERMAL_TAU = 600.0           # s
THERMAL_GAIN = 2.0            # K per W of battery loss at steady state

SHELL_CENTRE_Z = (SHELL_CLEARANCE + SHELL_TOP) / 2      # base frame height above the floor
SHELL_HEIGHT = SHELL_TOP - SHELL_CLEARANCE


CHASSIS = Chassis(mass=MASS_SHELL, centre_z=SHELL_CENTRE_Z, track=WHEEL_TRACK, wheel_mass=MASS_WHEEL,
                  caster_radius=CASTER_RADIUS, caster_x=CASTER_X, caster_mass=MASS_CASTER, friction=SHELL_FRICTION,
                  wheel_friction=WHEEL_FRICTION, max_wheel_torque=MAX_WHEEL_TORQUE)


def build_body(client: int, start: tuple[float, float, float], gui: bool = False,
               wheel_radii: tuple[float, float] = (WHEEL_RADIUS, WHEEL_RADIUS)) -> int:
    """Create the multibody at ``start`` = (x, y, yaw) on the floor and return its body id.

    ``wheel_radii`` are the tyres' effective rolling radii (left, right); the motors and encoders
    work in joint angle, so a radius off the nominal 36 mm is real odometry error."""
    kw = {"physicsClientId": client}
    shell = p.createCollisionShape(p.GEOM_CYLINDER, radius=SHELL_RADIUS, height=SHELL_HEIGHT, **kw)
    vis_shell = p.createVisualShape(p.GEOM_CYLINDER, radius=SHELL_RADIUS, length=SHELL_HEIGHT,
                                    rgbaColor=(0.2, 0.2, 0.2, 1), **kw) if gui else -1
    return diff_body(client, start, CHASSIS, shell, vis_shell, wheel_radii, gui)


@dataclass
class Battery:
    """Charge, terminal voltage and temperature of the pack, integrated from the motor load."""
    charge_mah: float
    temperature_c: float
    ambient_c: float
    current_ma: float = -IDLE_CURRENT_MA

    def soc(self) -> float:
        return min(1.0, max(0.0, self.charge_mah / CAPACITY_MAH))

    def open_circuit_mv(self) -> float:
        return V_EMPTY_MV + (V_FULL_MV - V_EMPTY_MV) * self.soc()

    def voltage_mv(self) -> float:
        return max(0.0, self.open_circuit_mv() + self.current_ma * R_INTERNAL)

    def integrate(self, motor_power_w: float, motor_ma: float, dt: float) -> None:
        """Draw idle current, ``motor_ma`` and ``motor_power_w`` (at pack voltage) for ``dt`` seconds."""
        volts = self.open_circuit_mv() / 1000.0
        amps = (IDLE_CURRENT_MA + motor_ma) / 1000.0 + (motor_power_w / volts if volts > 0 else 0.0)
        self.current_ma = -amps * 1000.0 if self.charge_mah > 0 else 0.0
        self.charge_mah = max(0.0, self.charge_mah - amps * 1000.0 * dt / 3600.0)
        loss_w = amps * amps * R_INTERNAL
        target = self.ambient_c + THERMAL_GAIN * loss_w
        self.temperature_c += (target - self.temperature_c) * min(1.0, dt / THERMAL_TAU)


class SimCreate2(GroundTruth):
    """One Create 2 body in a :class:`sitl.world.World`; the device emulators call these methods (ground truth:
    :class:`~sitl.bodies.diffdrive.GroundTruth`)."""

    radius = SHELL_RADIUS         # the world keeps starts this far inside the arena walls
    centre_z = SHELL_CENTRE_Z

    def __init__(self, client: int, robot_id: int, start: tuple[float, float, float],
                 rng: np.random.Generator, gui: bool = False, wheel_radius_sigma: float = WHEEL_RADIUS_SIGMA):
        self.robot_id = robot_id
        self._client = client
        self._kw = {"physicsClientId": client}
        # tyre tolerance and wear: each wheel's rolling radius is off the nominal by ~0.4 % (1 sigma)
        self.wheel_radii = tyre_radii(rng, WHEEL_RADIUS, wheel_radius_sigma)
        self.body_id = build_body(client, start, gui, self.wheel_radii)
        self._targets = (0.0, 0.0)
        self._torques = (0.0, 0.0)
        self._rates = (0.0, 0.0)
        ambient = float(rng.uniform(22.0, 26.0))
        self._battery = Battery(charge_mah=float(rng.uniform(0.9, 1.0)) * CAPACITY_MAH,
                                temperature_c=ambient, ambient_c=ambient)
        self._contacts: list | None = None     # this step's contacts; the world clears it as it steps

    # -------------------------------------------------------------- commands
    def set_wheel_speeds(self, left_mps: float, right_mps: float) -> None:
        """Wheel motor targets (m/s at the rim), clipped to +-0.5 m/s."""
        left, right = clip_wheels(self.robot_id, left_mps, right_mps, MAX_WHEEL_SPEED)
        if (left, right) == self._targets:
            return
        self._targets = (left, right)
        p.setJointMotorControlArray(self.body_id, [LEFT, RIGHT], p.VELOCITY_CONTROL,
                                    targetVelocities=[left / WHEEL_RADIUS, right / WHEEL_RADIUS],
                                    forces=[MAX_WHEEL_TORQUE] * 2, **self._kw)

    def wheel_targets(self) -> tuple[float, float]:
        """The commanded wheel speeds after clipping (m/s)."""
        return self._targets

    # -------------------------------------------------------------- physics hook
    def after_step(self, dt: float) -> None:
        """Sample the motor load and draw its charge over the last ``dt`` seconds (called by the world)."""
        states = p.getJointStates(self.body_id, [LEFT, RIGHT], **self._kw)
        self._rates = (states[0][1], states[1][1])
        self._torques = (states[0][3], states[1][3])
        power = no_load = 0.0
        for tau, omega in zip(self._torques, self._rates):
            amps = abs(tau) / MOTOR_KT
            power += abs(tau * omega) / MOTOR_EFFICIENCY + amps * amps * MOTOR_R
            no_load += MOTOR_NO_LOAD_MA * min(1.0, abs(omega) * WHEEL_RADIUS / MAX_WHEEL_SPEED)
        self._battery.integrate(power, no_load, dt)

    # -------------------------------------------------------------- sensors
    def wheel_travel(self) -> tuple[float, float]:
        """Cumulative signed distance each wheel rolled as its encoder sees it (m): joint angle x the
        nominal 36 mm radius.  The true distance differs by the tyre's radius error (``wheel_radii``)."""
        states = p.getJointStates(self.body_id, [LEFT, RIGHT], **self._kw)
        return states[0][0] * WHEEL_RADIUS, states[1][0] * WHEEL_RADIUS

    def motor_currents_ma(self) -> tuple[int, int]:
        """Left/right motor current (mA) from the present wheel motor torques."""
        states = p.getJointStates(self.body_id, [LEFT, RIGHT], **self._kw)
        return tuple(int(round(abs(s[3]) / MOTOR_KT * 1000.0)) for s in states)

    def bumps(self) -> tuple[bool, bool]:
        """Left/right bumper: any other body touching the front arc of the shell."""
        x, y, yaw = self.pose()
        c, s = math.cos(yaw), math.sin(yaw)
        left = right = False
        for cp in self.contacts():
            if cp[3] != -1:
                continue
            dx, dy = cp[5][0] - x, cp[5][1] - y
            lx, ly = c * dx + s * dy, -s * dx + c * dy
            bearing = math.atan2(ly, lx)
            if abs(bearing) > BUMPER_ARC:
                continue
            if bearing >= -BUMPER_CENTRE:
                left = True
            if bearing <= BUMPER_CENTRE:
                right = True
        return left, right

    def wheel_drop(self) -> tuple[bool, bool]:
        """Left/right wheel not touching anything (lifted)."""
        return (not self._touching(LEFT), not self._touching(RIGHT))

    def _touching(self, link: int) -> bool:
        return any(cp[3] == link for cp in self.contacts())

    def contacts(self) -> list:
        """Contact points of this body with other bodies, closer than the margin, as pybullet reports them
        (``linkIndexA`` at [3]).  Asked once per physics step: the device samples bumpers and wheel drop
        every step, and contacts only change when the world steps (:meth:`stepped`)."""
        if self._contacts is None:
            self._contacts = touching(self._client, self.body_id, CONTACT_MARGIN)
        return self._contacts

    def stepped(self) -> None:
        """The world stepped: contacts are stale."""
        self._contacts = None

    def battery(self) -> dict:
        """charge_mah, capacity_mah, voltage_mv, current_ma (negative discharging), temperature_c."""
        b = self._battery
        return {"charge_mah": b.charge_mah, "capacity_mah": CAPACITY_MAH, "voltage_mv": b.voltage_mv(),
                "current_ma": b.current_ma, "temperature_c": b.temperature_c}
