"""Batched quaternion helpers.

Every quaternion in marlander_lite is **scalar-last** ``(x, y, z, w)``, the order PyBullet
returns and cflib's ``send_extpose`` expects. All functions broadcast over leading axes, so a
``(num_envs, num_drones, 4)`` array works as well as a single ``(4,)`` quaternion.
"""

from __future__ import annotations

import numpy as np

IDENTITY_QUAT = np.array([0.0, 0.0, 0.0, 1.0])


def vector_norm(v: np.ndarray) -> np.ndarray:
    """Euclidean norm over the last axis of ``(..., 3)`` vectors.

    Written per component because that is several times faster than ``np.linalg.norm`` on
    the small trailing axis, and fastest when ``v`` is a view of component-major memory.
    """
    return np.sqrt(v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1] + v[..., 2] * v[..., 2])


def quat_multiply(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Hamilton product ``q1 * q2`` (apply ``q2`` first, then ``q1``)."""
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


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Inverse of a unit quaternion."""
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Scale quaternions to unit norm and make ``w >= 0`` (one canonical sign)."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0.0, -q, q)


def rotate_vector(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) from the body frame to the world frame by ``q``."""
    u = q[..., :3]
    w = q[..., 3:4]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4)."""
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack(
        (
            np.stack((1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)), -1),
            np.stack((2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)), -1),
            np.stack((2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)), -1),
        ),
        axis=-2,
    )


def quat_from_yaw(yaw: np.ndarray | float) -> np.ndarray:
    """Quaternion of a rotation by ``yaw`` radians about the world z axis."""
    half = 0.5 * np.asarray(yaw, dtype=float)
    zeros = np.zeros_like(half)
    return np.stack((zeros, zeros, np.sin(half), np.cos(half)), axis=-1)


def angular_velocity_from_quats(q_prev: np.ndarray, q_next: np.ndarray, dt: float) -> np.ndarray:
    """World-frame angular velocity (rad/s) that turns ``q_prev`` into ``q_next`` in ``dt`` s.

    Uses ``dq = q_next * conj(q_prev)`` and ``omega = 2 vec(dq) / dt`` with ``dq`` on the
    ``w >= 0`` hemisphere: exact to first order in the rotation angle, which is small at
    the control rates used here.
    """
    dq = quat_multiply(q_next, quat_conjugate(q_prev))
    sign = np.where(dq[..., 3:4] < 0.0, -1.0, 1.0)
    return 2.0 * sign * dq[..., :3] / dt
