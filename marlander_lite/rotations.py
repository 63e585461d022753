"""Rotations: the one home of quaternion and rotation-matrix arithmetic in marlander_lite.

Every quaternion here is **scalar-last** ``(x, y, z, w)``: the order PyBullet returns, cflib's
``send_extpose`` expects and ``scipy.spatial.transform.Rotation.from_quat`` reads. Rotation
matrices ``R`` map body-frame vectors to the world frame.

Only what a hot loop needs is written out here, in two flavours:

* **batched numpy** (:func:`vector_norm` to :func:`tilt_deg`): broadcast over leading axes, so a
  ``(num_envs, N, 4)`` array works as well as one ``(4,)`` quaternion. The point mass, the
  motion-capture noise model and the lab estimator call them every step.
* **scalar floats** (:func:`quat_to_matrix_rows` to :func:`euler_zyx`): one drone at a time, for the
  PyBullet Crazyflie's controllers, which tick hundreds of times per simulated second; a numpy call
  costs about 1 us whatever its size, a float operation about 0.05 us (``crazyflie/physics.py``).

Anything else (composing rotations, Euler angles for a plot, random attitudes) is not worth
hand-written code: use :class:`scipy.spatial.transform.Rotation`. ``tests/test_rotations.py`` checks
every function here against it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

IDENTITY_QUAT = np.array([0.0, 0.0, 0.0, 1.0])
"""The quaternion of no rotation, ``(x, y, z, w)``."""

# ----------------------------------------------------------------------------- batched numpy


def vector_norm(v: np.ndarray) -> np.ndarray:
    """Euclidean norm over the last axis of ``(..., 3)`` vectors.

    Written per component because that is several times faster than ``np.linalg.norm`` on
    the small trailing axis, and fastest when ``v`` is a view of component-major memory.
    """
    return np.sqrt(v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1] + v[..., 2] * v[..., 2])


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product ``a x b`` over the last axis of ``(..., 3)`` vectors.

    The same products and differences as ``np.cross`` (so the same bits), without its ~20 us of
    set-up, which dominates on the few rows the lab estimator handles per frame.
    """
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return np.stack((ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx), axis=-1)


def rotate_vector(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` ``(..., 3)`` from the body frame to the world frame by ``q`` ``(..., 4)``.

    ``R(q) v = v + 2 w (u x v) + 2 u x (u x v)`` for ``q = (u, w)``, as ``t = 2 u x v``,
    ``v + w t + u x t``: no matrix is formed.
    """
    u, w = q[..., :3], q[..., 3:4]
    t = 2.0 * cross(u, v)
    return v + w * t + cross(u, t)


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Scale quaternions to unit norm and make ``w >= 0`` (``q`` and ``-q`` are one attitude: pick one sign)."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0.0, -q, q)


def quat_multiply(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Hamilton product ``q1 * q2`` (apply ``q2`` first, then ``q1``), ``(..., 4)``."""
    x1, y1, z1, w1 = np.moveaxis(q1, -1, 0)
    x2, y2, z2, w2 = np.moveaxis(q2, -1, 0)
    return np.stack(
        (
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        ),
        axis=-1,
    )


def quat_from_yaw(yaw: np.ndarray | float) -> np.ndarray:
    """Quaternion of a rotation by ``yaw`` radians about the world z axis, ``(..., 4)``."""
    half = 0.5 * np.asarray(yaw, dtype=float)
    zeros = np.zeros_like(half)
    return np.stack((zeros, zeros, np.sin(half), np.cos(half)), axis=-1)


def angular_velocity_from_quats(q_prev: np.ndarray, q_next: np.ndarray, dt: float | np.ndarray) -> np.ndarray:
    """World-frame angular velocity (rad/s) that turns ``q_prev`` into ``q_next`` in ``dt`` s, ``(..., 3)``.

    With ``dq = q_next conj(q_prev)`` taken on the ``w >= 0`` hemisphere, ``omega = 2 vec(dq) / dt``:
    exact to first order in the rotation angle, which is small at the rates the estimator runs at.
    Written out, for ``q_prev = (p, p_w)`` and ``q_next = (q, q_w)``,
    ``vec(dq) = p_w q - q_w p - q x p`` and ``w(dq) = q_prev . q_next``.
    """
    p, p_w = q_prev[..., :3], q_prev[..., 3:]
    q, q_w = q_next[..., :3], q_next[..., 3:]
    sign = np.where((q_prev * q_next).sum(axis=-1, keepdims=True) < 0.0, -1.0, 1.0)
    return 2.0 * sign * (p_w * q - q_w * p - cross(q, p)) / dt


ARCTAN_SERIES = tuple(1.0 / k if k % 4 == 1 else -1.0 / k for k in range(1, 41, 2))
"""Taylor coefficients of ``atan(t) / t`` in powers of ``t^2``: ``1, -1/3, 1/5, ..., -1/39``."""


def turn_angle(sin: np.ndarray, cos: np.ndarray) -> np.ndarray:
    """``arctan2(sin, cos)`` for ``sin >= 0`` (an angle in ``[0, pi]``), from square roots, divisions and products only.

    The angle a thrust axis turns in one step (``PointMassSwarm._set_attitude``). Written out because numba has no
    vectorised ``atan2`` and the C library's costs 18-29 ns per call, as much as the rest of a point-mass drone's
    physics step. Built from correctly rounded operations alone, it gives the same bits in numpy and in a compiled loop
    (``pointmass/kernels.py``), and agrees with ``np.arctan2`` to 4 units in the last place
    (``tests/test_rotations.py``). The steps, exact in real arithmetic:

    * half angle: with ``r = hypot(sin, cos)``, ``theta = 2 atan(sin / (r + cos))`` when ``cos >= 0`` and
      ``theta = pi - 2 atan(sin / (r - cos))`` when ``cos < 0``: both are ``2 atan(sin / (r + |cos|))``, an
      argument in ``[0, 1]`` whose denominator cancels nothing;
    * one halving, ``atan(t) = 2 atan(t / (1 + sqrt(1 + t^2)))``, brings it to at most ``tan(pi / 8)``;
    * there 20 terms of ``atan(t) = t - t^3/3 + t^5/5 - ...`` leave an error below ``2e-17`` relative.

    ``sin = cos = 0`` gives 0, as ``np.arctan2(0, 0)`` does.
    """
    r = np.sqrt(sin * sin + cos * cos)
    denominator = r + np.abs(cos)
    t = sin / np.where(denominator > 0.0, denominator, 1.0)
    t = t / (1.0 + np.sqrt(1.0 + t * t))
    angle = 4.0 * (t * arctan_series(t * t))
    return np.where(cos < 0.0, np.pi - angle, angle)


def arctan_series(z: np.ndarray | float) -> np.ndarray | float:
    """``atan(t) / t`` at ``z = t^2``: Horner's rule on :data:`ARCTAN_SERIES`, arrays or floats.

    Written out term by term, because the compiled kernels inline this very function (``pointmass/kernels.py``) and
    LLVM vectorises no loop over a tuple.
    """
    c = ARCTAN_SERIES
    series = c[19]
    series = series * z + c[18]
    series = series * z + c[17]
    series = series * z + c[16]
    series = series * z + c[15]
    series = series * z + c[14]
    series = series * z + c[13]
    series = series * z + c[12]
    series = series * z + c[11]
    series = series * z + c[10]
    series = series * z + c[9]
    series = series * z + c[8]
    series = series * z + c[7]
    series = series * z + c[6]
    series = series * z + c[5]
    series = series * z + c[4]
    series = series * z + c[3]
    series = series * z + c[2]
    series = series * z + c[1]
    series = series * z + c[0]
    return series


def tilt_deg(quat: np.ndarray) -> np.ndarray:
    """Angle between body z and world z (degrees) of ``(..., 4)`` quaternions.

    The world z component of body z is ``R_22 = 1 - 2 (x^2 + y^2)``, clipped against rounding.
    """
    cos = 1.0 - 2.0 * (quat[..., 0] ** 2 + quat[..., 1] ** 2)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


# ----------------------------------------------------------------------------- scalar floats

RotationRows = tuple[float, float, float, float, float, float, float, float, float]
"""A rotation matrix as 9 floats, row by row: ``(r00, r01, r02, r10, ..., r22)``, body to world."""


def quat_to_matrix_rows(quat: Sequence[float]) -> RotationRows:
    """Rotation matrix (body to world) of a unit quaternion ``(x, y, z, w)``, row by row."""
    x, y, z, w = quat
    return (
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - z * w),
        2.0 * (x * z + y * w),
        2.0 * (x * y + z * w),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - x * w),
        2.0 * (x * z - y * w),
        2.0 * (y * z + x * w),
        1.0 - 2.0 * (x * x + y * y),
    )


def world_to_body(rot: RotationRows, v: Sequence[float]) -> tuple[float, float, float]:
    """``R^T v``: a world-frame vector ``v`` in body axes, for ``rot`` from :func:`quat_to_matrix_rows`."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rot
    vx, vy, vz = v
    return (r00 * vx + r10 * vy + r20 * vz, r01 * vx + r11 * vy + r21 * vz, r02 * vx + r12 * vy + r22 * vz)


def euler_zyx(rot: RotationRows) -> tuple[float, float, float]:
    """``(roll, pitch, yaw)`` (rad) of ``R = R_z(yaw) R_y(pitch) R_x(roll)``, the Crazyflie firmware's angles.

    ``pitch = asin(-r20)`` (clamped to ``[-pi/2, pi/2]`` against rounding), ``roll = atan2(r21, r22)``,
    ``yaw = atan2(r10, r00)``.
    """
    r00, _, _, r10, _, _, r20, r21, r22 = rot
    pitch = math.asin(-r20 if -1.0 < -r20 < 1.0 else (1.0 if r20 < 0 else -1.0))
    return math.atan2(r21, r22), pitch, math.atan2(r10, r00)
