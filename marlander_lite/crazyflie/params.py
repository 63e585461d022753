"""Numbers that describe a Crazyflie 2.x (CF2X) and how it is simulated.

Two typed, frozen dataclasses hold every constant of the PyBullet back end:

* :class:`CF2XParams`: the quadrotor itself (mass, inertia, rotor layout, motor
  coefficients, aerodynamic coefficients). Defaults are the published CF2X figures of
  gym-pybullet-drones (Panerati et al. 2021) and the Crazyflie 2.1 data sheet, each listed with its
  source in ``docs/references.md``; the URDF ``marlander_lite/assets/cf2x.urdf`` is written
  from the same numbers (a test checks that the two agree).
* :class:`PhysicsConfig`: which effects are simulated and at which rates.

Rotor layout (body frame: x forward, y left, z up; seen from above)::

        M4 (+x,+y) CW    M1 (+x,-y) CCW
                  \\    /
                    ()          the arms are 45 deg off the x axis ("X" configuration)
                  /    \\
        M3 (-x,+y) CCW   M2 (-x,-y) CW

Diagonal pairs spin the same way, so their reaction torques cancel in hover. A rotor
spinning counter-clockwise (angular velocity along +z) pushes the body clockwise, i.e.
contributes ``-k_m w^2`` to the yaw torque.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal, get_args

import numpy as np

GRAVITY = 9.81
"""Standard gravity (m/s^2), the same value the point-mass simulator uses."""


@dataclass(frozen=True)
class CF2XParams:
    """Physical constants of one Crazyflie 2.x in "X" configuration (SI units unless stated).

    Motors follow the usual quadratic model: rotor ``i`` spinning at ``w_i`` RPM makes thrust
    ``T_i = k_f w_i^2`` along body z and a reaction torque ``s_i k_m w_i^2`` about body z, with
    ``s_i = yaw_signs[i]``. The firmware commands a PWM value per motor; ``w = pwm_to_rpm_scale
    pwm + pwm_to_rpm_offset`` within ``[pwm_min, pwm_max]``.

    Source: gym-pybullet-drones' CF2X model and DSL PID (Panerati et al. 2021) for the mass, inertia,
    arm, k_f, k_m, motor map and the ground-effect, drag and downwash coefficients; the Bitcraze
    Crazyflie 2.1 data sheet for the take-off weight (docs/references.md).
    """

    mass: float = 0.027
    """Take-off mass m (kg). The CF 2.1 datasheet says 29 g with battery; 27 g is the common model value."""
    ixx: float = 1.4e-5
    """Moment of inertia about body x (kg m^2); equal to ``iyy`` by symmetry."""
    iyy: float = 1.4e-5
    """Moment of inertia about body y (kg m^2)."""
    izz: float = 2.17e-5
    """Moment of inertia about body z (kg m^2)."""
    arm: float = 0.0397
    """Distance from the centre to each motor axis (m)."""
    rotor_xy: tuple[tuple[float, float], ...] = ((0.028, -0.028), (-0.028, -0.028), (-0.028, 0.028), (0.028, 0.028))
    """Rotor centres (x, y) in the body frame (m), motors M1..M4 (published: +-0.028 m, i.e. arm / sqrt 2)."""
    rotor_z: float = 0.0125
    """Height of the rotor plane above the body origin (m): the top of the collision cylinder."""
    yaw_signs: tuple[float, ...] = (-1.0, 1.0, -1.0, 1.0)
    """Sign of each rotor's reaction torque about body z: -1 for counter-clockwise rotors (M1, M3)."""
    kf: float = 3.16e-10
    """Thrust coefficient k_f (N / RPM^2)."""
    km: float = 7.94e-12
    """Torque coefficient k_m (N m / RPM^2)."""
    prop_radius: float = 0.0231
    """Propeller radius R (m), used by the ground-effect and downwash models."""
    pwm_to_rpm_scale: float = 0.2685
    """RPM per PWM count of the motor map ``w = scale pwm + offset``."""
    pwm_to_rpm_offset: float = 4070.3
    """RPM at zero PWM of the motor map."""
    pwm_min: float = 20000.0
    """Smallest PWM the controller sends while flying."""
    pwm_max: float = 65535.0
    """Largest PWM (16-bit)."""
    collision_radius: float = 0.06
    """Radius of the collision cylinder (m)."""
    collision_height: float = 0.025
    """Height of the collision cylinder (m); the body origin is at its centre."""
    ground_effect_coeff: float = 11.36859
    """C_ge of the ground-effect model ``T_i (1 + C_ge (R / (4 h_i))^2)``, h_i the rotor's height above the surface."""
    drag_coeff_xy: float = 9.1785e-7
    """Rotor drag coefficient along body x and y (N per (m/s) per (rad/s) of summed rotor speed)."""
    drag_coeff_z: float = 10.311e-7
    """Rotor drag coefficient along body z (same units)."""
    downwash_coeffs: tuple[float, float, float] = (2267.18, 0.16, -0.11)
    """Published downwash fit (c1 in N, c2, c3 in m); see :func:`marlander_lite.crazyflie.physics.downwash_push`."""

    def __post_init__(self) -> None:
        positive = ("mass", "ixx", "iyy", "izz", "arm", "kf", "km", "prop_radius", "collision_radius")
        for name in positive:
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"CF2XParams.{name} must be a finite number > 0, got {value!r}.")
        if len(self.rotor_xy) != 4 or len(self.yaw_signs) != 4:
            raise ValueError("CF2XParams describes a quadrotor: rotor_xy and yaw_signs need 4 entries each.")
        if not self.pwm_min < self.pwm_max:
            raise ValueError(f"pwm_min ({self.pwm_min}) must be below pwm_max ({self.pwm_max}).")
        if self.max_rpm**2 * self.kf * 4 <= self.mass * GRAVITY:
            raise ValueError("The motors cannot lift this mass: raise kf or pwm_max, or lower the mass.")

    # Derived figures: properties so that they follow any change of the fields above.
    @property
    def weight(self) -> float:
        """m g (N)."""
        return self.mass * GRAVITY

    @property
    def hover_rpm(self) -> float:
        """RPM at which four rotors carry the weight: ``sqrt(m g / (4 k_f))`` (about 14,468)."""
        return math.sqrt(self.weight / (4.0 * self.kf))

    @property
    def max_rpm(self) -> float:
        """RPM at ``pwm_max`` (about 21,666)."""
        return self.pwm_to_rpm_scale * self.pwm_max + self.pwm_to_rpm_offset

    @property
    def max_thrust(self) -> float:
        """Total thrust at ``max_rpm`` (N, about 0.593)."""
        return 4.0 * self.kf * self.max_rpm**2

    @property
    def thrust_to_weight(self) -> float:
        """Max thrust over weight (about 2.24; published 2.25)."""
        return self.max_thrust / self.weight

    @property
    def rotor_positions(self) -> np.ndarray:
        """Rotor centres in the body frame, ``(4, 3)`` m."""
        xy = np.asarray(self.rotor_xy, dtype=float)
        return np.column_stack((xy, np.full(4, self.rotor_z)))

    @property
    def inertia(self) -> np.ndarray:
        """Diagonal of the inertia tensor ``(3,)`` kg m^2."""
        return np.array([self.ixx, self.iyy, self.izz])


PhysicsPreset = Literal["bare", "aero"]
"""Named physics settings: ``"bare"`` rigid body + motors only; ``"aero"`` adds ground effect, drag, downwash."""
PHYSICS_PRESETS: tuple[str, ...] = get_args(PhysicsPreset)


@dataclass(frozen=True)
class PhysicsConfig:
    """What the PyBullet back end simulates, and how often.

    The physics engine runs at ``physics_hz``; the cascaded PID runs at ``control_hz`` and holds
    its motor command in between; the policy acts at ``TaskConfig.policy_hz``. Each rate must
    divide the one above it (default 240 / 48 / 24 Hz: 5 physics steps per PID tick, 2 PID ticks
    per action). The aerodynamic effects (ground effect, drag, downwash) are evaluated at the
    control rate from the state the PID reads, and held, as forces in the body frame, until the
    next tick: at 48 Hz a Crazyflie moves at most 6 cm in that time.
    """

    physics_hz: float = 240.0
    """PyBullet time step is ``1 / physics_hz`` (s)."""
    control_hz: float = 48.0
    """Rate of the cascaded PID (Hz)."""
    ground_effect: bool = False
    """Extra thrust near the floor or the plate (:func:`~marlander_lite.crazyflie.physics.ground_effect_gain`)."""
    drag: bool = False
    """Rotor drag against the body velocity (:func:`~marlander_lite.crazyflie.physics.drag_force`)."""
    downwash: bool = False
    """Bounded wake of drones above (:func:`~marlander_lite.crazyflie.physics.downwash_push`)."""
    motor_time_constant: float = 0.0
    """First-order lag of the rotor speed behind its command (s); 0 means the rotors follow at once.
    With a lag, the force held over a tick is the exact mean of the lagging rotors' thrust."""

    def __post_init__(self) -> None:
        for name in ("physics_hz", "control_hz"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"PhysicsConfig.{name} must be a finite number > 0 Hz, got {value!r}.")
        if not (np.isfinite(self.motor_time_constant) and self.motor_time_constant >= 0):
            raise ValueError(f"motor_time_constant must be a finite number >= 0 s, got {self.motor_time_constant!r}.")
        ratio_to_count(self.physics_hz, self.control_hz, "physics_hz", "control_hz")
        for name in ("ground_effect", "drag", "downwash"):
            if not isinstance(getattr(self, name), bool):
                raise TypeError(f"PhysicsConfig.{name} must be True or False, got {getattr(self, name)!r}.")

    @classmethod
    def preset(cls, name: str, **changes: Any) -> PhysicsConfig:
        """A named setting (one of ``PHYSICS_PRESETS``) with optional field changes."""
        if name not in PHYSICS_PRESETS:
            raise ValueError(f"Unknown physics preset {name!r}; allowed: {', '.join(PHYSICS_PRESETS)}.")
        aero = name == "aero"
        base = cls(ground_effect=aero, drag=aero, downwash=aero)
        return base.replace(**changes) if changes else base

    def replace(self, **changes: Any) -> PhysicsConfig:
        """A copy with some fields changed; unknown names raise with the list of fields."""
        known = [f.name for f in dataclasses.fields(self)]
        unknown = sorted(set(changes) - set(known))
        if unknown:
            raise TypeError(f"Unknown physics option(s) {unknown}; allowed: {', '.join(known)}.")
        return dataclasses.replace(self, **changes)

    @property
    def steps_per_tick(self) -> int:
        """Physics steps per PID tick."""
        return ratio_to_count(self.physics_hz, self.control_hz, "physics_hz", "control_hz")

    @property
    def aero_effects(self) -> tuple[str, ...]:
        """Names of the aerodynamic effects switched on."""
        return tuple(name for name in ("ground_effect", "drag", "downwash") if getattr(self, name))


def ratio_to_count(fast_hz: float, slow_hz: float, fast_name: str, slow_name: str) -> int:
    """``fast_hz / slow_hz`` as an integer >= 1, or a ``ValueError`` naming both rates."""
    ratio = fast_hz / slow_hz
    count = round(ratio)
    if count < 1 or abs(ratio - count) > 1e-9 * ratio:
        raise ValueError(
            f"{slow_name}={slow_hz:g} Hz must divide {fast_name}={fast_hz:g} Hz a whole number of times "
            f"(e.g. 240 / 48 / 24 Hz, or 240 / 30 / 30 Hz)."
        )
    return count


def build_physics(physics: PhysicsConfig | Mapping[str, Any] | str | None) -> PhysicsConfig:
    """The env option ``physics`` as a :class:`PhysicsConfig`.

    Accepts a :class:`PhysicsConfig`, a preset name (``"bare"`` or ``"aero"``), a mapping of
    field changes (optionally with ``"preset"``), or ``None`` for ``"aero"``.
    """
    if physics is None:
        return PhysicsConfig.preset("aero")
    if isinstance(physics, PhysicsConfig):
        return physics
    if isinstance(physics, str):
        return PhysicsConfig.preset(physics)
    if isinstance(physics, Mapping):
        changes = dict(physics)
        return PhysicsConfig.preset(changes.pop("preset", "aero"), **changes)
    raise TypeError(
        f"physics must be a PhysicsConfig, one of {PHYSICS_PRESETS}, or a mapping of PhysicsConfig fields; "
        f"got {physics!r}."
    )
