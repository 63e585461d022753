"""The two velocity trackers of the PyBullet swarm as compiled kernels, one drone per call (numba).

:func:`pid_drone` is :meth:`CascadedPID.update <marlander_lite.crazyflie.control.CascadedPID.update>`,
:func:`firmware_drone` is :meth:`FirmwareTracker.update <marlander_lite.crazyflie.firmware.FirmwareTracker.update>`,
operation for operation (see :mod:`marlander_lite.crazyflie.tick_kernels` for how the bits stay the same); the
control tick kernels there call them for every flying drone. Each tracker's memory is its own arrays
(``CascadedPID.state``; ``FirmwareTracker.pid_memory``, ``.phase``, ``.setpoint``), updated in place; its constants
are read from the tracker object by :func:`pid_constants` and :func:`firmware_constants`, whose ``limits`` layouts
are the ``PID_*`` and ``FW_*`` index names below.
"""

from __future__ import annotations

import math

import numpy as np

from marlander_lite.crazyflie.control import CascadedPID, mixer_matrix
from marlander_lite.crazyflie.firmware import DEG, FirmwareTracker
from marlander_lite.pointmass.kernels import jit_kernel

# Layout of the PID tracker's ``limits`` (its gains are two small tables, see pid_constants).
PID_DT, PID_WEIGHT, PID_THRUST_MIN, PID_THRUST_MAX, PID_TAN_TILT, PID_TORQUE_LIMIT, PID_MAX_RATE = 0, 1, 2, 3, 4, 5, 6
PID_KF, PID_SCALE, PID_OFFSET, PID_LO, PID_HI, PID_SIZE = 7, 8, 9, 10, 11, 12
# Layout of the firmware tracker's ``limits`` (the nine PIDs' constants are FirmwareTracker.pid_constants).
FW_TILT, FW_THRUST_SCALE, FW_THRUST_BASE, FW_THRUST_MIN, FW_HI, FW_SCALE, FW_OFFSET, FW_SIZE = 0, 1, 2, 3, 4, 5, 6, 7


def pid_constants(tracker: CascadedPID) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(pos_gains, att_gains, limits, mix)`` of a :class:`CascadedPID`, from the numbers its ``update`` reads.

    ``pos_gains`` ``(4, 3)``: rows K_p, K_i, K_d, integral bound, per axis x, y, z. ``att_gains`` ``(3, 4)``: per
    attitude axis ``-K_R / K_w``, K_I, K_w, integral bound. ``limits`` ``(PID_SIZE,)`` (``PID_*``). ``mix`` ``(4, 3)``.
    """
    limits = np.zeros(PID_SIZE)
    limits[PID_DT], limits[PID_WEIGHT] = tracker.dt, tracker._weight
    limits[PID_THRUST_MIN], limits[PID_THRUST_MAX] = tracker.thrust_min, tracker.thrust_max
    limits[PID_TAN_TILT] = tracker._tan_tilt
    limits[PID_TORQUE_LIMIT], limits[PID_MAX_RATE] = tracker.gains.torque_limit, tracker.gains.max_body_rate
    limits[PID_KF] = tracker.params.kf
    limits[PID_SCALE], limits[PID_OFFSET], limits[PID_LO], limits[PID_HI] = tracker._motor_map
    mix = np.array(tracker._mix)
    return np.array(tracker._pos_gains), np.array(tracker._att_gains), limits, mix


def firmware_constants(tracker: FirmwareTracker) -> tuple[np.ndarray, np.ndarray]:
    """``(limits, mix)`` of a :class:`FirmwareTracker`: ``(FW_SIZE,)`` (``FW_*``) and the mixer ``(4, 3)``."""
    g, limits = tracker.gains, np.zeros(FW_SIZE)
    limits[FW_TILT], limits[FW_THRUST_SCALE] = g.tilt_limit_deg, g.thrust_scale
    limits[FW_THRUST_BASE], limits[FW_THRUST_MIN] = g.thrust_base, g.thrust_min
    limits[FW_HI], limits[FW_SCALE], limits[FW_OFFSET] = tracker._motor_map
    return limits, mixer_matrix(tracker.params)


# ---------------------------------------------------------------- small pieces, as the reference writes them
@jit_kernel
def _clip_open(x: float, limit: float) -> float:
    """``x if -limit < x < limit else (limit if x > 0 else -limit)``: CascadedPID's clip (NaN gives ``-limit``)."""
    return x if -limit < x < limit else (limit if x > 0 else -limit)


@jit_kernel
def _clip(x: float, lo: float, hi: float) -> float:
    """``lo if x < lo else hi if x > hi else x``."""
    return lo if x < lo else (hi if x > hi else x)


@jit_kernel
def rotation(kin: np.ndarray, i: int, rot: np.ndarray) -> None:
    """:func:`~marlander_lite.rotations.quat_to_matrix_rows` of drone ``i``'s quaternion ``kin[i, 3:7]`` into
    ``rot[i]`` (9 entries, row by row)."""
    x, y, z, w = kin[i, 3], kin[i, 4], kin[i, 5], kin[i, 6]
    rot[i, 0] = 1.0 - 2.0 * (y * y + z * z)
    rot[i, 1] = 2.0 * (x * y - z * w)
    rot[i, 2] = 2.0 * (x * z + y * w)
    rot[i, 3] = 2.0 * (x * y + z * w)
    rot[i, 4] = 1.0 - 2.0 * (x * x + z * z)
    rot[i, 5] = 2.0 * (y * z - x * w)
    rot[i, 6] = 2.0 * (x * z - y * w)
    rot[i, 7] = 2.0 * (y * z + x * w)
    rot[i, 8] = 1.0 - 2.0 * (x * x + y * y)


@jit_kernel
def _mix_to_rpm(
    base: float,
    tx: float,
    ty: float,
    tz: float,
    mix: np.ndarray,
    scale: float,
    offset: float,
    lo: float,
    hi: float,
    out: np.ndarray,
    i: int,
) -> None:
    """:func:`~marlander_lite.crazyflie.control.mix_to_rpm` into ``out[i]`` (RPM)."""
    for m in range(4):
        pwm = base + mix[m, 0] * tx + mix[m, 1] * ty + mix[m, 2] * tz
        out[i, m] = scale * (lo if pwm < lo else (hi if pwm > hi else pwm)) + offset


@jit_kernel
def _pid_update(c: np.ndarray, memory: np.ndarray, i: int, k: int, error: float) -> float:
    """:func:`~marlander_lite.crazyflie.firmware.pid_update` of PID ``k`` of drone ``i`` (``c`` its constants)."""
    kp, ki, kd, dt, integral_limit, output_limit = c[k, 0], c[k, 1], c[k, 2], c[k, 3], c[k, 4], c[k, 5]
    deriv = (error - memory[i, k, 1]) / dt
    if c[k, 9] != 0.0:  # lpf2pApply, Direct Form II
        d1, d2 = memory[i, k, 2], memory[i, k, 3]
        d0 = deriv - d1 * c[k, 7] - d2 * c[k, 8]
        deriv = c[k, 6] * (d0 + 2.0 * d1 + d2)
        memory[i, k, 2], memory[i, k, 3] = d0, d1
    integral = memory[i, k, 0] + error * dt
    if integral_limit > 0.0:
        integral = _clip(integral, -integral_limit, integral_limit)
    memory[i, k, 0], memory[i, k, 1] = integral, error
    out = kp * error + kd * deriv + ki * integral
    if output_limit > 0.0:
        out = _clip(out, -output_limit, output_limit)
    return out


# ---------------------------------------------------------------- the two trackers, one drone
@jit_kernel
def _rows_of(rot: np.ndarray, i: int) -> tuple:
    """Drone ``i``'s rotation matrix as nine floats, row by row (the form of ``quat_to_matrix_rows``)."""
    return rot[i, 0], rot[i, 1], rot[i, 2], rot[i, 3], rot[i, 4], rot[i, 5], rot[i, 6], rot[i, 7], rot[i, 8]


@jit_kernel
def _torque(
    k: int,
    e: float,
    w: float,
    dt: float,
    att_gains: np.ndarray,
    limit_t: float,
    max_rate: float,
    state: np.ndarray,
    i: int,
) -> float:
    """CascadedPID's attitude law on axis ``k`` (rotation error ``e``, body rate ``w``): the torque command (PWM);
    updates the integral ``state[i, 3 + k]``."""
    acc = _clip_open(state[i, 3 + k] - e * dt, att_gains[k, 3])
    state[i, 3 + k] = acc
    # -K_R e - K_w w = K_w (w_d - w) with the demanded rate w_d = -(K_R / K_w) e, clipped.
    rate = _clip_open(att_gains[k, 0] * e, max_rate)
    return _clip_open(att_gains[k, 2] * (rate - w) + att_gains[k, 1] * acc, limit_t)


@jit_kernel
def pid_drone(
    i: int,
    kin: np.ndarray,
    rot: np.ndarray,
    target: np.ndarray,
    command: np.ndarray,
    pos_gains: np.ndarray,
    att_gains: np.ndarray,
    limits: np.ndarray,
    mix: np.ndarray,
    state: np.ndarray,
    out: np.ndarray,
) -> None:
    """:meth:`CascadedPID.update <marlander_lite.crazyflie.control.CascadedPID.update>` of drone ``i``: its rotor
    speeds into ``out[i]`` (RPM), its memory in ``state[i]`` (``CascadedPID.state``)."""
    dt = limits[PID_DT]
    thrust_min, thrust_max = limits[PID_THRUST_MIN], limits[PID_THRUST_MAX]
    # 1. position / velocity -> thrust vector F (world frame, N), integral clipped per axis.
    ex, ey, ez = target[i, 0] - kin[i, 0], target[i, 1] - kin[i, 1], target[i, 2] - kin[i, 2]
    ix = _clip_open(state[i, 0] + ex * dt, pos_gains[3, 0])
    iy = _clip_open(state[i, 1] + ey * dt, pos_gains[3, 1])
    iz = _clip_open(state[i, 2] + ez * dt, pos_gains[3, 2])
    fx = pos_gains[0, 0] * ex + pos_gains[1, 0] * ix + pos_gains[2, 0] * (command[i, 0] - kin[i, 7])
    fy = pos_gains[0, 1] * ey + pos_gains[1, 1] * iy + pos_gains[2, 1] * (command[i, 1] - kin[i, 8])
    fz = (
        pos_gains[0, 2] * ez + pos_gains[1, 2] * iz + pos_gains[2, 2] * (command[i, 2] - kin[i, 9]) + limits[PID_WEIGHT]
    )
    fz = thrust_min if fz < thrust_min else (thrust_max if fz > thrust_max else fz)
    horizontal = math.sqrt(fx * fx + fy * fy)
    cap = limits[PID_TAN_TILT] * fz
    if horizontal > cap:
        fx, fy = fx * cap / horizontal, fy * cap / horizontal
    # 2. attitude -> torques; desired axes d1 = (xx, xy, xz), d2 = (0, yy, yz), d3 = (zx, zy, zz).
    norm = math.sqrt(fx * fx + fy * fy + fz * fz)
    zx, zy, zz = fx / norm, fy / norm, fz / norm
    m = math.sqrt(zy * zy + zz * zz)
    yy, yz = zz / m, -zy / m
    xx, xy, xz = yy * zz - yz * zy, yz * zx, -yy * zx
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = _rows_of(rot, i)
    e0 = (zx * r01 + zy * r11 + zz * r21) - (yy * r12 + yz * r22)
    e1 = (xx * r02 + xy * r12 + xz * r22) - (zx * r00 + zy * r10 + zz * r20)
    e2 = (yy * r10 + yz * r20) - (xx * r01 + xy * r11 + xz * r21)
    wx, wy, wz = kin[i, 10], kin[i, 11], kin[i, 12]  # world_to_body(rot, ang_vel) below
    w0, w1, w2 = r00 * wx + r10 * wy + r20 * wz, r01 * wx + r11 * wy + r21 * wz, r02 * wx + r12 * wy + r22 * wz
    limit_t, max_rate = limits[PID_TORQUE_LIMIT], limits[PID_MAX_RATE]
    tx = _torque(0, e0, w0, dt, att_gains, limit_t, max_rate, state, i)
    ty = _torque(1, e1, w1, dt, att_gains, limit_t, max_rate, state, i)
    tz = _torque(2, e2, w2, dt, att_gains, limit_t, max_rate, state, i)
    state[i, 0], state[i, 1], state[i, 2] = ix, iy, iz
    state[i, 6], state[i, 7], state[i, 8] = fx, fy, fz
    # 3. mixer: collective thrust along the current body z axis, plus each motor's torque share.
    collective = fx * r02 + fy * r12 + fz * r22
    collective = 0.0 if collective < 0.0 else (thrust_max if collective > thrust_max else collective)
    scale, offset = limits[PID_SCALE], limits[PID_OFFSET]
    base = (math.sqrt(collective / (4.0 * limits[PID_KF])) - offset) / scale
    _mix_to_rpm(base, tx, ty, tz, mix, scale, offset, limits[PID_LO], limits[PID_HI], out, i)


@jit_kernel
def firmware_drone(
    i: int,
    kin: np.ndarray,
    rot: np.ndarray,
    command: np.ndarray,
    pids: np.ndarray,
    limits: np.ndarray,
    mix: np.ndarray,
    velocity_every: int,
    memory: np.ndarray,
    phase: np.ndarray,
    setpoint: np.ndarray,
    out: np.ndarray,
) -> None:
    """:meth:`FirmwareTracker.update <marlander_lite.crazyflie.firmware.FirmwareTracker.update>` of drone ``i``:
    rotor speeds into ``out[i]`` (RPM); memory in ``memory[i]``, ``phase[i]``, ``setpoint[i]`` (the tracker's
    ``pid_memory``, ``phase``, ``setpoint``); ``pids`` is its ``pid_constants``."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = _rows_of(rot, i)
    # euler_zyx: the clamp against rounding, then the C library's asin and atan2, as Python's math module calls them.
    pitch = math.asin(-r20 if -1.0 < -r20 < 1.0 else (1.0 if r20 < 0 else -1.0))
    roll, yaw = math.atan2(r21, r22), math.atan2(r10, r00)
    if phase[i] == 0:
        # 1. velocity loop: world error in the yaw-aligned body frame -> tilt setpoints (deg), thrust (PWM).
        c, s = math.cos(yaw), math.sin(yaw)
        ex, ey = command[i, 0] - kin[i, 7], command[i, 1] - kin[i, 8]
        limit = limits[FW_TILT]
        pitch_sp = _clip(_pid_update(pids, memory, i, 0, c * ex + s * ey), -limit, limit)
        roll_sp = _clip(-_pid_update(pids, memory, i, 1, c * ey - s * ex), -limit, limit)
        thrust = limits[FW_THRUST_SCALE] * _pid_update(pids, memory, i, 2, command[i, 2] - kin[i, 9])
        thrust = _clip(thrust + limits[FW_THRUST_BASE], limits[FW_THRUST_MIN], 65535.0)
        setpoint[i, 0], setpoint[i, 1], setpoint[i, 2] = roll_sp, pitch_sp, thrust
    phase[i] = (phase[i] + 1) % velocity_every
    roll_sp, pitch_sp, thrust = setpoint[i, 0], setpoint[i, 1], setpoint[i, 2]
    # 2. attitude loop: ZYX Euler angles (deg) -> body-rate setpoints (deg/s); yaw held at 0.
    roll_rate = _pid_update(pids, memory, i, 3, roll_sp - roll * DEG)
    pitch_rate = _pid_update(pids, memory, i, 4, pitch_sp - pitch * DEG)
    yaw_rate = _pid_update(pids, memory, i, 5, -yaw * DEG)
    # 3. rate loop on the body rates (deg/s) -> roll, pitch, yaw commands (PWM units), then the mixer.
    wx, wy, wz = kin[i, 10], kin[i, 11], kin[i, 12]
    tx = _pid_update(pids, memory, i, 6, roll_rate - (r00 * wx + r10 * wy + r20 * wz) * DEG)
    ty = _pid_update(pids, memory, i, 7, pitch_rate - (r01 * wx + r11 * wy + r21 * wz) * DEG)
    tz = _pid_update(pids, memory, i, 8, yaw_rate - (r02 * wx + r12 * wy + r22 * wz) * DEG)
    _mix_to_rpm(thrust, tx, ty, tz, mix, limits[FW_SCALE], limits[FW_OFFSET], 0.0, limits[FW_HI], out, i)
