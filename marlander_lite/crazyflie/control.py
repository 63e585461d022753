"""Cascaded PID that makes a Crazyflie follow the paper's velocity action (eq. 3).

The policy outputs a velocity ``u`` per drone; the simulator turns it into a target position
``p + u dt`` (:func:`marlander_lite.task.next_target_position`) and a target velocity ``u``.
This controller tracks both, drone by drone, in three stages:

1. **position / velocity -> thrust vector.** ``F = K_p e_p + K_i int e_p + K_d e_v + m g e_z``
   (world frame, N), with the integral clipped per axis. ``F_z`` is kept within the thrust the
   motors can give, and the horizontal part within ``tan(max_tilt) F_z``.
2. **attitude -> body torques.** The desired attitude has body z along ``F`` and zero yaw. With
   ``E = R_d^T R - R^T R_d`` the rotation error is ``e_R = (E_32, E_13, E_21)`` (twice the angle
   for small errors), and ``tau = K_w (w_d - w_b) + K_I int(-e_R)``, clipped, where
   ``w_d = clip(-(K_R / K_w) e_R)`` is the demanded body rate (without the clip this is the usual
   ``-K_R e_R - K_w w_b``); ``w_b`` is the body angular velocity. Torques are in PWM counts.
3. **mixer.** The collective thrust ``F . z_b`` sets a common PWM
   (``w = sqrt(T / (4 k_f))`` -> PWM); each motor adds its share of the torques, signs from the
   rotor positions and spin directions; PWM is clipped to the motors' range and mapped to RPM.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from marlander_lite.crazyflie.params import CF2XParams
from marlander_lite.rotations import RotationRows, world_to_body

Triple = tuple[float, float, float]


@dataclass(frozen=True)
class PIDGains:
    """Gains and limits of :class:`CascadedPID` (per axis x, y, z).

    The position gains and the attitude P and I gains are the published ones for this kind of
    controller on a CF2X (Source: gym-pybullet-drones' ``DSLPIDControl``, Panerati et al. 2021;
    docs/references.md). The published attitude D gains (20000, 20000, 12000) assume a faster
    inner loop: held for one 48 Hz tick, their damping torque changes the body rate by about
    4 times the rate itself, so the discrete loop is unstable (spectral radius 3.3 in roll,
    :func:`attitude_loop_spectral_radius`) and only the torque clip keeps it to a small, fast
    oscillation. We lower them to (5000, 5000, 4000), which keeps the spectral radius of the
    linearised attitude loop below 0.91 at every control rate from 30 to 240 Hz (0.53 at 48 Hz).

    Lower damping needs two limits to behave when the torque saturates. The attitude law
    ``-K_R e_R - K_w w`` is written ``K_w (w_d - w)`` with a demanded rate ``w_d = -(K_R / K_w) e_R``
    clipped to ``max_body_rate``, so that the drone never turns faster than it can stop; and the
    torque bound is raised from the published 3200 to 9600 PWM (still within the motors' range:
    hover is at about 38,750 PWM, a roll command moves each motor by half the torque command).
    With these, a 1 m/s step is reached without overshoot beyond the steady offset of the
    ``p + u dt`` target (see :class:`~marlander_lite.crazyflie.simulator.CrazyflieSwarm`).
    """

    pos_p: Triple = (0.4, 0.4, 1.25)
    """K_p on the position error (N/m)."""
    pos_i: Triple = (0.05, 0.05, 0.05)
    """K_i on the integrated position error (N/(m s))."""
    pos_d: Triple = (0.2, 0.2, 0.5)
    """K_d on the velocity error (N/(m/s))."""
    pos_integral_limit: Triple = (2.0, 2.0, 0.15)
    """Bound of each component of the integrated position error (m s)."""
    att_p: Triple = (70000.0, 70000.0, 60000.0)
    """K_R on the rotation error (PWM)."""
    att_i: Triple = (0.0, 0.0, 500.0)
    """K_I on the integrated rotation error (PWM/s)."""
    att_d: Triple = (5000.0, 5000.0, 4000.0)
    """K_w on the body angular velocity (PWM/(rad/s))."""
    att_integral_limit: Triple = (1500.0, 1500.0, 1500.0)
    """Bound of each component of the integrated rotation error (s)."""
    torque_limit: float = 9600.0
    """Bound of each torque command (PWM); see the class docstring."""
    max_body_rate: float = 4.0
    """Bound of the body rate the attitude loop demands (rad/s); see the class docstring."""
    max_tilt_deg: float = 30.0
    """Largest angle between the commanded thrust and the vertical (deg); limits horizontal acceleration
    to about ``g tan(max_tilt)``."""

    def __post_init__(self) -> None:
        check_gains(self)
        if min(self.att_d) <= 0 or self.max_body_rate <= 0:
            raise ValueError("att_d and max_body_rate must be > 0 (the attitude law divides by att_d).")
        if not 0 < self.max_tilt_deg < 90:
            raise ValueError(f"max_tilt_deg must be in (0, 90) degrees, got {self.max_tilt_deg!r}.")


def check_gains(gains: object) -> None:
    """Raise a ``ValueError`` unless every field of a gains dataclass is finite and >= 0 (one value or three)."""
    for name, value in vars(gains).items():
        values = value if isinstance(value, tuple) else (value,)
        if len(values) not in (1, 3) or not all(math.isfinite(v) and v >= 0 for v in values):
            raise ValueError(
                f"{type(gains).__name__}.{name} must be finite and >= 0 (three per-axis values), got {value!r}."
            )


PUBLISHED_DSL_GAINS = PIDGains(
    att_d=(20000.0, 20000.0, 12000.0),
    att_integral_limit=(1.0, 1.0, 1500.0),
    torque_limit=3200.0,
    max_body_rate=1000.0,
    max_tilt_deg=89.0,
)
"""The cascaded PID as gym-pybullet-drones publishes it (``DSLPIDControl``, [Panerati2021]): a held-out tracker.

Its attitude D gains (20000, 20000, 12000), its +-3200 PWM torque clip and its roll/pitch integral bound of 1, with
nothing our defaults add: no tilt limit (89 degrees: :class:`PIDGains` wants one below 90), no clip of the demanded
body rate (1000 rad/s). Ticked at 48 Hz, as that project's examples run it, the attitude loop is unstable in the
linear model (:func:`attitude_loop_spectral_radius` 3.3 in roll) and the torque clip keeps it to a small, fast
oscillation. No policy is trained or tuned against it: the transfer matrix's ``held-out DSL PID`` column flies it
(with ``"bare"`` physics, that project's default) to ask how a policy does on a tracker it has never met. One
difference of structure stays: ``DSLPIDControl`` damps the rate of its Euler angles, this class the body rates."""


def mix_to_rpm(
    base: float,
    tx: float,
    ty: float,
    tz: float,
    mix: Sequence[Sequence[float]],
    scale: float,
    offset: float,
    lo: float,
    hi: float,
) -> tuple[float, float, float, float]:
    """Motor mixer of both trackers: PWM ``base + a_i tx + b_i ty + c_i tz`` per motor (rows ``(a_i, b_i, c_i)`` of
    ``mix``), clamped to ``[lo, hi]``, then mapped to rotor speed ``scale * pwm + offset`` (RPM).

    Written out motor by motor: it runs for every drone at every control tick.
    """
    (a0, b0, c0), (a1, b1, c1), (a2, b2, c2), (a3, b3, c3) = mix
    pwm0 = base + a0 * tx + b0 * ty + c0 * tz
    pwm1 = base + a1 * tx + b1 * ty + c1 * tz
    pwm2 = base + a2 * tx + b2 * ty + c2 * tz
    pwm3 = base + a3 * tx + b3 * ty + c3 * tz
    return (
        scale * (lo if pwm0 < lo else hi if pwm0 > hi else pwm0) + offset,
        scale * (lo if pwm1 < lo else hi if pwm1 > hi else pwm1) + offset,
        scale * (lo if pwm2 < lo else hi if pwm2 > hi else pwm2) + offset,
        scale * (lo if pwm3 < lo else hi if pwm3 > hi else pwm3) + offset,
    )


def mixer_matrix(params: CF2XParams) -> np.ndarray:
    """How each motor's PWM moves with a torque command, ``(4, 3)``.

    Row ``i`` is ``(sign(y_i) / 2, -sign(x_i) / 2, s_i)``: a positive roll command speeds up the
    rotors on the +y side, a positive pitch command those on the -x side (both raise the torque
    in :func:`~marlander_lite.crazyflie.physics.motor_wrench`), and a positive yaw command the
    rotors whose reaction torque is positive.
    """
    xy = np.asarray(params.rotor_xy)
    return np.column_stack((0.5 * np.sign(xy[:, 1]), -0.5 * np.sign(xy[:, 0]), np.asarray(params.yaw_signs)))


class CascadedPID:
    """The three-stage controller for ``num_drones`` drones, stepped every ``dt`` seconds.

    Call :meth:`update` at each control tick for each drone; it returns the four motor speeds
    (RPM). Per-drone state (the two integrators) lives in this object's :attr:`state` array;
    :meth:`reset` clears it. The arithmetic is on floats, one drone at a time (see
    :mod:`marlander_lite.crazyflie.physics` for why that is faster than numpy for a handful of
    drones); this is the reference that :func:`marlander_lite.crazyflie.tick_kernels.pid_tick`
    compiles for all drones of a swarm at once.
    """

    def __init__(self, params: CF2XParams, gains: PIDGains, num_drones: int, dt: float) -> None:
        self.params, self.gains, self.dt = params, gains, dt
        self.num_drones = num_drones
        self._mix = [tuple(row) for row in mixer_matrix(params).tolist()]
        self._tan_tilt = math.tan(math.radians(gains.max_tilt_deg))
        rpm_min = params.pwm_to_rpm_scale * params.pwm_min + params.pwm_to_rpm_offset
        self.thrust_min = 4.0 * params.kf * rpm_min**2
        """Collective thrust at ``pwm_min`` (N): the controller never asks for less while flying."""
        self.thrust_max = params.max_thrust
        """Collective thrust at ``pwm_max`` (N)."""
        self._weight = params.weight
        self.state = np.zeros((num_drones, 9))
        """Per-drone memory ``(N, 9)``: :attr:`pos_integral`, :attr:`att_integral`, :attr:`thrust_vector` side by
        side, in one array that both engines update in place (see :mod:`marlander_lite.crazyflie.tick_kernels`)."""
        self.pos_integral = self.state[:, 0:3]
        """Integrated position error per drone ``(N, 3)`` (m s), a view of :attr:`state`."""
        self.att_integral = self.state[:, 3:6]
        """Integrated (negative) rotation error per drone ``(N, 3)`` (s), a view of :attr:`state`."""
        self.thrust_vector = self.state[:, 6:9]
        """Last commanded thrust vector ``F`` per drone ``(N, 3)`` (world frame, N), a view of :attr:`state`."""
        # Gains and limits as tuples of floats, read once per tick.
        self._pos_gains = (gains.pos_p, gains.pos_i, gains.pos_d, gains.pos_integral_limit)
        # Per attitude axis: -K_R / K_w (formed as the scalar law does), K_I, K_w, integral bound.
        self._att_gains = tuple(
            (-kp / kd, ki, kd, limit)
            for kp, ki, kd, limit in zip(gains.att_p, gains.att_i, gains.att_d, gains.att_integral_limit, strict=True)
        )
        self._motor_map = (params.pwm_to_rpm_scale, params.pwm_to_rpm_offset, params.pwm_min, params.pwm_max)

    def reset(self, drones: Sequence[int] | None = None) -> None:
        """Clear the integrators of ``drones`` (indices; all by default)."""
        rows = slice(None) if drones is None else list(drones)
        self.state[rows, 0:6] = 0.0

    def update(
        self,
        i: int,
        pos: Sequence[float],
        rot: RotationRows,
        vel: Sequence[float],
        ang_vel: Sequence[float],
        target_pos: Sequence[float],
        target_vel: Sequence[float],
    ) -> tuple[float, float, float, float]:
        """One control tick of drone ``i``: its four motor speeds (RPM).

        Args:
            i: drone index (selects its integrators).
            pos, vel, ang_vel: position (m), velocity (m/s), angular velocity (rad/s), world frame.
            rot: its rotation matrix, :func:`~marlander_lite.rotations.quat_to_matrix_rows`.
            target_pos, target_vel: where the drone should be (m) and how fast it should move (m/s).
        """
        p, dt = self.params, self.dt
        (kpx, kpy, kpz), (kix, kiy, kiz), (kdx, kdy, kdz), (lx, ly, lz) = self._pos_gains
        # 1. position / velocity -> thrust vector F (world frame, N), integral clipped per axis.
        # The drone's memory as floats (one read and one write of its row of the state array per tick).
        ix, iy, iz, *att = self.state[i, 0:6].tolist()
        ex, ey, ez = target_pos[0] - pos[0], target_pos[1] - pos[1], target_pos[2] - pos[2]
        ix, iy, iz = ix + ex * dt, iy + ey * dt, iz + ez * dt
        ix = ix if -lx < ix < lx else (lx if ix > 0 else -lx)
        iy = iy if -ly < iy < ly else (ly if iy > 0 else -ly)
        iz = iz if -lz < iz < lz else (lz if iz > 0 else -lz)
        fx = kpx * ex + kix * ix + kdx * (target_vel[0] - vel[0])
        fy = kpy * ey + kiy * iy + kdy * (target_vel[1] - vel[1])
        fz = kpz * ez + kiz * iz + kdz * (target_vel[2] - vel[2]) + self._weight
        fz = self.thrust_min if fz < self.thrust_min else self.thrust_max if fz > self.thrust_max else fz
        horizontal = math.sqrt(fx * fx + fy * fy)
        cap = self._tan_tilt * fz
        if horizontal > cap:
            fx, fy = fx * cap / horizontal, fy * cap / horizontal
        # 2. attitude -> torques. Desired axes d1, d2, d3: d3 along F, d2 = d3 x e_x normalised (zero yaw).
        norm = math.sqrt(fx * fx + fy * fy + fz * fz)
        zx, zy, zz = fx / norm, fy / norm, fz / norm
        m = math.sqrt(zy * zy + zz * zz)
        yy, yz = zz / m, -zy / m
        xx, xy, xz = yy * zz - yz * zy, yz * zx, -yy * zx
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = rot
        # e_R = vee(R_d^T R - R^T R_d) = (d3.r2 - r3.d2, d1.r3 - r1.d3, d2.r1 - r2.d1), r_k the columns of R.
        e = (
            (zx * r01 + zy * r11 + zz * r21) - (yy * r12 + yz * r22),
            (xx * r02 + xy * r12 + xz * r22) - (zx * r00 + zy * r10 + zz * r20),
            (yy * r10 + yz * r20) - (xx * r01 + xy * r11 + xz * r21),
        )
        w_body = world_to_body(rot, ang_vel)
        limit_t, max_rate = self.gains.torque_limit, self.gains.max_body_rate
        torque = []
        for k, (rate_gain, ki, kd, limit) in enumerate(self._att_gains):
            acc = att[k] - e[k] * dt
            att[k] = acc = acc if -limit < acc < limit else (limit if acc > 0 else -limit)
            # -K_R e - K_w w = K_w (w_d - w) with the demanded rate w_d = -(K_R / K_w) e, clipped.
            rate = rate_gain * e[k]
            rate = rate if -max_rate < rate < max_rate else (max_rate if rate > 0 else -max_rate)
            t = kd * (rate - w_body[k]) + ki * acc
            torque.append(t if -limit_t < t < limit_t else (limit_t if t > 0 else -limit_t))
        self.state[i] = (ix, iy, iz, *att, fx, fy, fz)
        # 3. mixer: collective thrust along the current body z axis, plus each motor's torque share
        collective = fx * r02 + fy * r12 + fz * r22
        collective = 0.0 if collective < 0.0 else self.thrust_max if collective > self.thrust_max else collective
        scale, offset, lo, hi = self._motor_map
        base = (math.sqrt(collective / (4.0 * p.kf)) - offset) / scale
        tx, ty, tz = torque
        return mix_to_rpm(base, tx, ty, tz, self._mix, scale, offset, lo, hi)


def attitude_loop_spectral_radius(params: CF2XParams, gains: PIDGains, control_hz: float) -> np.ndarray:
    """Spectral radius of the linearised, discrete attitude loop per axis (roll, pitch, yaw), ``(3,)``.

    Around hover each axis is a pure inertia ``I theta'' = b u`` driven by the torque command
    ``u = -K_R (2 theta) - K_w theta'`` (PWM), held for one tick ``T = 1 / control_hz``; ``b``
    (N m per PWM) follows from the mixer, the motor map and ``dT/dw = 2 k_f w_hover``. The
    closed loop over one tick is ``x+ = (A - B K) x`` with ``A = [[1, T], [0, 1]]`` and
    ``B = [T^2 / 2, T] b / I``; it is stable when the largest ``|eigenvalue|`` is below 1.
    The integral terms are slow and left out.
    """
    w = params.hover_rpm
    d_thrust = 2.0 * params.kf * w * params.pwm_to_rpm_scale  # N per PWM count, one rotor
    d_torque_z = 2.0 * params.km * w * params.pwm_to_rpm_scale  # N m per PWM count, one rotor
    mix = mixer_matrix(params)
    xy = np.asarray(params.rotor_xy)
    b = np.array(
        [
            (xy[:, 1] * mix[:, 0]).sum() * d_thrust,
            (-xy[:, 0] * mix[:, 1]).sum() * d_thrust,
            (np.asarray(params.yaw_signs) * mix[:, 2]).sum() * d_torque_z,
        ]
    )
    t = 1.0 / control_hz
    a = np.array([[1.0, t], [0.0, 1.0]])
    out = np.empty(3)
    for axis in range(3):
        gain = b[axis] / params.inertia[axis]
        k = np.array([[2.0 * gains.att_p[axis] * gain, gains.att_d[axis] * gain]])
        out[axis] = np.abs(np.linalg.eigvals(a - np.array([[t * t / 2.0], [t]]) @ k)).max()
    return out
