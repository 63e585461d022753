"""State estimation from poses, checked against motions whose velocities are known in closed form."""

import numpy as np
import pytest

from marlander_lite.deploy.config import EXAMPLE_CONFIG, load_lab_config
from marlander_lite.deploy.estimation import BodyTracks, EstimatorConfig, SwarmEstimator
from marlander_lite.deploy.pose_sources import PoseFrame, wxyz_to_xyzw
from marlander_lite.rotations import (
    angular_velocity_from_quats,
    quat_from_yaw,
    quat_multiply,
    quat_normalize,
    rotate_vector,
)


def test_quaternion_order_change():
    np.testing.assert_array_equal(wxyz_to_xyzw(np.array([0.9, 0.1, 0.2, 0.3])), [0.1, 0.2, 0.3, 0.9])
    np.testing.assert_array_equal(wxyz_to_xyzw(np.eye(4))[0], [0.0, 0.0, 0.0, 1.0])


def tilted_spin(t: float, rate: float) -> np.ndarray:
    """A constant tilt of 0.3 rad about x, spinning about world z at ``rate`` rad/s: omega = (0, 0, rate)."""
    tilt = np.array([np.sin(0.15), 0.0, 0.0, np.cos(0.15)])
    return quat_multiply(quat_from_yaw(rate * t), tilt)


def test_constant_velocity_and_spin_are_recovered_through_noise():
    """100 Hz poses of a body moving at v = (0.4, -0.3, 0.2) m/s and spinning at 1.5 rad/s about z."""
    rng = np.random.default_rng(0)
    tracks = BodyTracks(["cf1"], EstimatorConfig(tau=0.05))
    v, rate = np.array([0.4, -0.3, 0.2]), 1.5
    estimates = []
    for k in range(300):
        t = k / 100
        pos = np.array([0.0, 0.0, 1.0]) + v * t + rng.normal(0, 0.0005, 3)
        assert tracks.update(t, {"cf1": np.concatenate((pos, tilted_spin(t, rate)))}) == []
        estimates.append((tracks.vel[0].copy(), tracks.ang_vel[0].copy()))
    vel = np.array([e[0] for e in estimates[100:]])
    omega = np.array([e[1] for e in estimates[100:]])
    np.testing.assert_allclose(vel.mean(axis=0), v, atol=0.01)
    assert vel.std(axis=0).max() < 0.06  # 0.5 mm noise differenced at 100 Hz, filtered
    np.testing.assert_allclose(omega.mean(axis=0), [0.0, 0.0, rate], atol=0.01)
    assert tracks.age(3.5)[0] == pytest.approx(3.5 - 2.99)


def test_bad_poses_are_rejected_and_the_body_ages():
    tracks = BodyTracks(["cf1"], EstimatorConfig(max_body_speed=8.0))
    good = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])
    assert tracks.update(0.00, {"cf1": good}) == []
    nan = good.copy()
    nan[0] = np.nan
    assert tracks.update(0.01, {"cf1": nan}) == [("cf1", "non-finite pose")]
    assert tracks.invalid[0] and tracks.t_last[0] == 0.0
    [(_, why)] = tracks.update(0.02, {"cf1": good + np.array([0, 0, 0, 0, 0, 0, 5.0])})
    assert "out-of-range pose" in why
    [(_, why)] = tracks.update(0.03, {"cf1": good + np.array([1.0, 0, 0, 0, 0, 0, 0])})  # 33 m/s: a ghost
    assert why.startswith("jump of 33.3 m/s")
    assert tracks.update(0.04, {"cf1": good + np.array([0.004, 0, 0, 0, 0, 0, 0])}) == []
    assert not tracks.invalid[0]
    np.testing.assert_allclose(tracks.vel[0], [0.1, 0.0, 0.0])  # first difference after the gap: 4 mm / 40 ms
    assert tracks.update(0.04, {"cf1": good}) == []  # a repeated frame changes nothing
    assert tracks.t_last[0] == 0.04 and tracks.samples[0] == 2


def test_pad_goal_and_velocity_of_a_rotating_plate():
    """A plate turning about z at 0.5 rad/s around its centre: the pad at offset o moves at omega x R o."""
    lab = load_lab_config(EXAMPLE_CONFIG)
    est = SwarmEstimator(lab, EstimatorConfig(tau=0.0), landed_height=0.0125)
    omega, centre = 0.5, np.array([0.3, -0.2, 0.8])
    for k in range(50):
        t = k / 100
        q = quat_from_yaw(omega * t)
        bodies = {"plate": np.concatenate((centre, q))}
        for i, name in enumerate(lab.drone_names):
            bodies[name] = np.array([i, 1.0, 1.0, 0, 0, 0, 1.0])
        est.ingest([PoseFrame(t, bodies)])
    s = est.estimate(0.49)
    offsets = np.array([p.offset for p in lab.drone_pads()])
    arm = rotate_vector(quat_from_yaw(omega * 0.49), offsets)
    np.testing.assert_allclose(s.pad_pos, centre + arm, atol=1e-12)
    np.testing.assert_allclose(s.goal, centre + arm + [0, 0, 0.0125], atol=1e-12)
    expected_vel = np.cross([0.0, 0.0, omega], arm)
    np.testing.assert_allclose(s.pad_vel, expected_vel, atol=2e-3)  # finite differences of a rotation
    np.testing.assert_allclose(s.drone_age, [0.0, 0.0])
    assert not s.invalid.any()


def test_angular_velocity_matches_the_rotations_module():
    """The estimator's spelled-out quaternion difference equals rotations.angular_velocity_from_quats."""
    rng = np.random.default_rng(1)
    tracks = BodyTracks(["a", "b", "c"], EstimatorConfig(tau=0.0, max_body_speed=50.0))
    q = quat_normalize(rng.normal(size=(3, 4)))
    for k in range(20):
        t = k * 0.01
        turn = quat_normalize(np.concatenate((rng.normal(0, 0.02, (3, 3)), np.ones((3, 1))), axis=1))
        q_next = quat_normalize(quat_multiply(turn, q)) * rng.choice([-1.0, 1.0], size=(3, 1))  # random signs
        tracks.update(t, {n: np.concatenate(([0.0, 0.0, 1.0], q_next[j])) for j, n in enumerate("abc")})
        if k:
            np.testing.assert_allclose(tracks.ang_vel, angular_velocity_from_quats(q, q_next, 0.01), atol=1e-9)
        q = q_next
