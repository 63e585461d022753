"""Forces on a Crazyflie: motors, ground effect, drag and a bounded downwash model.

Each function works on ONE drone (or one pair of drones) with plain floats and the ``math``
module, and is free of PyBullet, so each formula can be tested on its own. The simulator
calls them at every control tick and sums their results into ONE force and ONE torque per
drone, in the body frame, which it hands to PyBullet at every physics step.

Why floats and not numpy arrays over the drones: a numpy call on a few numbers costs 0.3 to 1
microsecond whatever its size, a float operation about 0.03, and a drone's whole model is about
100 float operations. A control tick vectorised over the drones (tried, with the same bits) was
slower than this drone-by-drone code up to 16 drones, the downwash's pair sum included
(``benchmarks/bench_crazyflie.py``).

Symbols: ``w_i`` rotor speed (RPM), ``T_i = k_f w_i^2`` rotor thrust (N), ``R`` propeller radius,
``r_ij`` entries of the drone's rotation matrix (body to world).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from marlander_lite.crazyflie.params import CF2XParams

RPM_TO_RAD_S = 2.0 * math.pi / 60.0
Vector = tuple[float, float, float]


def motor_wrench(
    rpm: Sequence[float], params: CF2XParams, thrust_gain: Sequence[float] = (1.0, 1.0, 1.0, 1.0)
) -> tuple[float, float, float, float]:
    """Collective thrust and body torques of the four rotors: ``(F_z, tau_x, tau_y, tau_z)`` in N and N m.

    Args:
        rpm: rotor speeds ``w_1..w_4`` (RPM), motors M1..M4.
        params: the drone (``k_f``, ``k_m``, rotor positions, yaw signs).
        thrust_gain: per-rotor thrust multiplier (the ground effect, :func:`ground_effect_gain`).

    Thrust ``T_i = k_f w_i^2 g_i`` acts along body z at rotor ``i``'s centre ``(x_i, y_i)``, so
    ``tau_x = sum y_i T_i`` and ``tau_y = -sum x_i T_i``; the rotors' drag torques give
    ``tau_z = sum s_i k_m w_i^2``.
    """
    kf, km = params.kf, params.km
    (x0, y0), (x1, y1), (x2, y2), (x3, y3) = params.rotor_xy
    s0, s1, s2, s3 = params.yaw_signs
    w0, w1, w2, w3 = rpm
    g0, g1, g2, g3 = thrust_gain
    q0, q1, q2, q3 = w0 * w0, w1 * w1, w2 * w2, w3 * w3
    t0, t1, t2, t3 = kf * q0 * g0, kf * q1 * g1, kf * q2 * g2, kf * q3 * g3
    # Written out rotor by rotor (the simulator calls this per drone and tick), summed from M1 to M4.
    fz = (((0.0 + t0) + t1) + t2) + t3
    tx = (((0.0 + y0 * t0) + y1 * t1) + y2 * t2) + y3 * t3
    ty = (((0.0 - x0 * t0) - x1 * t1) - x2 * t2) - x3 * t3
    tz = (((0.0 + s0 * km * q0) + s1 * km * q1) + s2 * km * q2) + s3 * km * q3
    return fz, tx, ty, tz


def ground_effect_gain(height: float, params: CF2XParams) -> float:
    """Thrust multiplier of one rotor at ``height`` (m) above the surface below it: ``1 + C_ge (R / (4 h))^2``.

    The model grows without bound as ``h -> 0``; we bound it by clipping ``h`` at the rotor
    height of a drone standing level on a surface, ``h_min = collision_height / 2 + rotor_z``
    (25 mm): no rotor of an upright drone gets closer, and a tilted one must not gain more.
    With the published ``C_ge = 11.37`` the largest gain is 1.61.
    """
    return ground_effect_gains((height,), params)[0]


def ground_effect_gains(heights: Sequence[float], params: CF2XParams) -> tuple[float, ...]:
    """:func:`ground_effect_gain` of each rotor of one drone, ``heights`` in m (one call per drone and tick)."""
    floor = params.collision_height / 2 + params.rotor_z
    radius, coeff = params.prop_radius, params.ground_effect_coeff
    gains = []
    for h in heights:
        ratio = radius / (4.0 * (h if h > floor else floor))
        gains.append(1.0 + coeff * ratio * ratio)
    return tuple(gains)


def drag_force(rpm_sum: float, vel_body: Vector, params: CF2XParams) -> Vector:
    """Rotor drag in the body frame (N): ``-(sum_i w_i) diag(k_xy, k_xy, k_z) v_body``.

    Args:
        rpm_sum: ``sum_i w_i`` in RPM (converted to rad/s here).
        vel_body: the drone's velocity in body axes (m/s).

    Blade flapping and induced drag both grow with rotor speed, hence the factor ``sum w_i``.
    At hover (about 6,060 rad/s summed) and 3 m/s this is about 0.017 N, 6 % of the weight.
    """
    spin = rpm_sum * RPM_TO_RAD_S
    kxy, kz = params.drag_coeff_xy * spin, params.drag_coeff_z * spin
    return -kxy * vel_body[0], -kxy * vel_body[1], -kz * vel_body[2]


def downwash_push(dz: float, horizontal_sq: float, thrust_above: float, params: CF2XParams) -> float:
    """Vertical force (N, <= 0) on a drone from the wake of one drone ``dz`` metres above it.

    For a drone ``dz > 0`` below another, at horizontal distance ``d`` (``horizontal_sq = d^2``)::

        F = -min(c1 (R / (4 dz))^2, T_above) * exp(-d^2 / (2 w^2)) * min(1, dz / h_b),
        w = c2 dz + r_s

    with the published ``(c1, c2, c3) = (2267.18, 0.16, -0.11)`` (Source: gym-pybullet-drones,
    Panerati et al. 2021; docs/references.md) and ``T_above`` the upper
    drone's thrust. Three choices, ours, keep the model bounded and continuous:

    * ``min(., T_above)``: the wake carries the momentum of the thrust that made it and cannot
      push harder than that; the published peak ``c1 (R / 4 dz)^2`` is infinite at ``dz = 0``
      (two drones at the same height blow up in simulators that use it raw).
    * the wake width starts at the rotor span ``r_s = arm + R`` (6.3 cm) and widens with the
      published slope ``c2``; the published offset ``c3`` makes ``|c2 dz + c3|`` shrink to zero
      0.69 m below the rotor, which we read as a sign slip and do not use.
    * ``min(1, dz / h_b)`` with ``h_b`` the body height (25 mm): a drone beside another one is
      not in its wake; this makes the force continuous at ``dz = 0``.

    Returns 0 for ``dz <= 0`` (the other drone is not above).
    """
    if dz <= 0.0:
        return 0.0
    c1, c2, _ = params.downwash_coeffs
    radius = params.prop_radius
    ratio = radius / (4.0 * dz)
    peak = c1 * ratio * ratio
    peak = thrust_above if thrust_above < peak else peak  # min(peak, T_above), as min() picks, without the call
    width = c2 * dz + params.arm + radius
    onset = dz / params.collision_height
    onset = onset if onset < 1.0 else 1.0
    return -peak * math.exp(-horizontal_sq / (2.0 * width * width)) * onset


class MotorLag:
    """First-order lag of the rotor speeds behind their command, over ticks of ``period`` s.

    With ``w(t) = c + (w0 - c) e^(-t / tau)`` the thrust ``k_f w^2`` averaged over the tick
    ``T`` is ``k_f (c^2 + 2 c (w0 - c) m1 + (w0 - c)^2 m2)``, ``m1 = tau / T (1 - e^(-T / tau))``,
    ``m2 = tau / (2 T) (1 - e^(-2 T / tau))``. The effective speed is the square root of that
    mean square, so the force held over the tick equals the lagging motors' mean force exactly.
    ``tau = 0`` means no lag (:attr:`active` is False).
    """

    def __init__(self, tau: float, period: float) -> None:
        self.decay = math.exp(-period / tau) if tau > 0 else 0.0
        self.m1 = tau / period * (1.0 - self.decay) if tau > 0 else 0.0
        self.m2 = tau / (2.0 * period) * (1.0 - self.decay**2) if tau > 0 else 0.0
        self.active = self.decay > 0.0

    def step(self, command: Sequence[float], rpm: Sequence[float]) -> tuple[list[float], list[float]]:
        """One tick from rotor speeds ``rpm`` towards ``command`` (RPM): ``(effective, at the tick's end)``."""
        decay, m1, m2 = self.decay, self.m1, self.m2
        effective, now = [], []
        for c, w0 in zip(command, rpm, strict=True):
            gap = w0 - c
            effective.append(math.sqrt(max(c * c + 2.0 * c * gap * m1 + gap * gap * m2, 0.0)))
            now.append(c + gap * decay)
        return effective, now
