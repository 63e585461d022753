"""marlander_lite.rotations against scipy.spatial.transform.Rotation, the independent reference."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from marlander_lite import rotations


@pytest.fixture
def quats() -> np.ndarray:
    """Random unit quaternions ``(5, 3, 4)``, ``(x, y, z, w)`` (scipy's order too)."""
    return Rotation.random(15, random_state=0).as_quat().reshape(5, 3, 4)


def test_vector_norm_and_cross_match_numpy(quats):
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(2, 5, 3, 3))
    np.testing.assert_allclose(rotations.vector_norm(a), np.linalg.norm(a, axis=-1), rtol=1e-15)
    # The same products and differences as np.cross: equal to the last bit.
    np.testing.assert_array_equal(rotations.cross(a, b), np.cross(a, b))
    np.testing.assert_array_equal(rotations.cross(a[0, 0], b), np.cross(a[0, 0], b))


def test_rotate_vector_is_scipys_apply(quats):
    v = np.random.default_rng(1).normal(size=(5, 3, 3))
    expected = Rotation.from_quat(quats.reshape(-1, 4)).apply(v.reshape(-1, 3)).reshape(v.shape)
    np.testing.assert_allclose(rotations.rotate_vector(quats, v), expected, atol=1e-14)
    # One quaternion broadcasts over many vectors.
    np.testing.assert_allclose(
        rotations.rotate_vector(quats[0, 0], v),
        Rotation.from_quat(quats[0, 0]).apply(v.reshape(-1, 3)).reshape(v.shape),
    )


def test_quat_normalize_gives_the_same_attitude_with_w_positive(quats):
    scaled = quats * np.array([2.0, -0.5, 3.0]).reshape(1, 3, 1)  # sign flipped in the middle column
    unit = rotations.quat_normalize(scaled)
    np.testing.assert_allclose(np.linalg.norm(unit, axis=-1), 1.0, rtol=1e-15)
    assert (unit[..., 3] >= 0).all()
    same = Rotation.from_quat(unit.reshape(-1, 4)) * Rotation.from_quat(quats.reshape(-1, 4)).inv()
    np.testing.assert_allclose(same.magnitude(), 0.0, atol=1e-7)


def test_quat_multiply_composes_like_scipy(quats):
    q1, q2 = quats[0], quats[1]
    product = rotations.quat_multiply(q1, q2)
    expected = (Rotation.from_quat(q1) * Rotation.from_quat(q2)).as_quat()
    np.testing.assert_allclose(product * np.sign(product[:, 3:]), expected * np.sign(expected[:, 3:]), atol=1e-14)


def test_quat_from_yaw_is_a_rotation_about_world_z():
    yaw = np.array([-2.5, 0.0, 0.3, 3.1])
    expected = Rotation.from_euler("z", yaw[:, None]).as_quat()
    np.testing.assert_allclose(rotations.quat_from_yaw(yaw), expected, atol=1e-15)


def test_angular_velocity_from_quats_is_the_turn_rate():
    """q_next = R(omega dt) q_prev in the world frame; the first-order formula 2 vec(dq) / dt gives
    exactly ``2 sin(|omega| dt / 2) / dt`` along the rotation axis, whichever sign q_next has."""
    rng = np.random.default_rng(2)
    dt = 0.01
    omega = rng.normal(0.0, 3.0, (6, 3))
    q_prev = Rotation.random(6, random_state=1)
    q_next = (Rotation.from_rotvec(omega * dt) * q_prev).as_quat()
    angle = np.linalg.norm(omega * dt, axis=-1, keepdims=True)
    expected = 2.0 * np.sin(angle / 2.0) / dt * omega / np.linalg.norm(omega, axis=-1, keepdims=True)
    for sign in (1.0, -1.0):
        got = rotations.angular_velocity_from_quats(q_prev.as_quat(), sign * q_next, dt)
        np.testing.assert_allclose(got, expected, atol=1e-10)
    np.testing.assert_allclose(got, omega, rtol=1e-3)  # omega itself, to second order: theta^2 / 24 < 1e-3


def test_turn_angle_is_arctan2_to_four_units_in_the_last_place():
    """Angles over [0, pi], tiny ones and ones near pi, from (sin, cos) pairs of any scale, against numpy's arctan2."""
    rng = np.random.default_rng(3)
    tiny = 10.0 ** rng.uniform(-12, 0, 100_000)
    theta = np.concatenate([rng.uniform(0.0, np.pi, 200_000), tiny, np.pi - tiny])
    scale = rng.uniform(0.5, 2.0, theta.size)
    sin, cos = np.abs(np.sin(theta)) * scale, np.cos(theta) * scale
    expected = np.arctan2(sin, cos)
    got = rotations.turn_angle(sin, cos)
    assert np.abs(got - expected).max() <= 4 * np.spacing(expected).max()
    assert (np.abs(got - expected) <= 4 * np.spacing(expected)).all()
    sin, cos = np.array([0.0, 0.0, 0.0, 1.0, 2.0, np.nan]), np.array([0.0, 1.0, -1.0, 0.0, -0.0, 1.0])
    edges = rotations.turn_angle(sin, cos)
    np.testing.assert_array_equal(edges[:3], [0.0, 0.0, math.pi])  # no turn, no turn, a reversal
    np.testing.assert_allclose(edges[3:5], math.pi / 2, rtol=0, atol=4 * np.spacing(math.pi / 2))
    assert np.isnan(edges[5])


def test_tilt_is_the_angle_between_body_z_and_world_z(quats):
    body_z = Rotation.from_quat(quats.reshape(-1, 4)).apply([0.0, 0.0, 1.0])
    expected = np.degrees(np.arccos(body_z[:, 2])).reshape(quats.shape[:-1])
    np.testing.assert_allclose(rotations.tilt_deg(quats), expected, atol=1e-6)
    assert rotations.tilt_deg(rotations.IDENTITY_QUAT) == 0.0


# ----------------------------------------------------------------------------- scalar functions


def test_matrix_rows_are_scipys_matrix(quats):
    for q in quats.reshape(-1, 4):
        rows = rotations.quat_to_matrix_rows(q.tolist())
        assert all(isinstance(r, float) for r in rows)
        np.testing.assert_allclose(rows, Rotation.from_quat(q).as_matrix().ravel(), atol=1e-15)


def test_world_to_body_is_the_inverse_rotation(quats):
    v = (0.3, -1.2, 2.0)
    for q in quats.reshape(-1, 4):
        got = rotations.world_to_body(rotations.quat_to_matrix_rows(q.tolist()), v)
        np.testing.assert_allclose(got, Rotation.from_quat(q).inv().apply(v), atol=1e-14)


def test_euler_zyx_matches_scipys_intrinsic_zyx(quats):
    for q in quats.reshape(-1, 4):
        yaw, pitch, roll = Rotation.from_quat(q).as_euler("ZYX")
        got = rotations.euler_zyx(rotations.quat_to_matrix_rows(q.tolist()))
        np.testing.assert_allclose(got, (roll, pitch, yaw), atol=1e-12)


def test_euler_zyx_survives_rounding_past_straight_up():
    """At pitch = +-90 degrees rounding can put |r20| a hair above 1; asin must not raise."""
    rows = (0.0, 0.0, 1.0, 0.0, 1.0, 0.0, -1.0 - 1e-15, 0.0, 0.0)
    assert rotations.euler_zyx(rows)[1] == math.pi / 2
    rows = (0.0, 0.0, -1.0, 0.0, 1.0, 0.0, 1.0 + 1e-15, 0.0, 0.0)
    assert rotations.euler_zyx(rows)[1] == -math.pi / 2
