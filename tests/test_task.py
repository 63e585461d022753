"""The MDP of the paper (eqs. 2-6) against values worked by hand, and the simulators' fast layout against it."""

import math

import numpy as np
import pytest

from marlander_lite import task
from marlander_lite.episodes import LandingEpisodes
from marlander_lite.platforms import PlatformConfig
from marlander_lite.pointmass import PointMassSwarm
from marlander_lite.task import CONTACT_NONE, CONTACT_OTHER, CONTACT_OWN_PAD, TaskConfig

CFG = TaskConfig()  # alpha 10, beta -0.02, c 10, alpha_c 20, K 20


def test_observation_is_eq2_concatenation():
    p, q, v, w = [1.0, -2.0, 0.5], [0.0, 0.0, 0.0, 1.0], [0.1, 0.2, -0.3], [0.01, 0.02, 0.03]
    obs = task.observe(*(np.array([x]) for x in (p, q, v, w)))
    assert obs.shape == (1, 13)
    np.testing.assert_array_equal(obs[0], p + q + v + w)


def test_the_extras_follow_eq2_platform_velocity_first():
    p, q, v, w = [1.0, -2.0, 0.5], [0.0, 0.0, 0.0, 1.0], [0.1, 0.2, -0.3], [0.01, 0.02, 0.03]
    pad_vel, command = [0.4, 0.0, 0.0], [-1.0, 2.0, 0.5]
    obs = task.observe(*(np.array([x]) for x in (p, q, v, w, pad_vel, command)))
    np.testing.assert_array_equal(obs[0], p + q + v + w + pad_vel + command)
    only_command = task.observe(*(np.array([x]) for x in (p, q, v, w)), None, np.array([command]))
    np.testing.assert_array_equal(only_command[0], p + q + v + w + command)
    sizes = [
        TaskConfig(observe_platform_velocity=a, observe_previous_command=b).obs_per_drone
        for a in (0, 1)
        for b in (0, 1)
    ]
    assert sizes == [13, 16, 16, 19]
    both = {"observe_platform_velocity": True, "observe_platform_acceleration": True}
    assert TaskConfig(**both).obs_per_drone == 19
    assert TaskConfig(**both, observe_previous_command=True).obs_per_drone == 22
    accel = [2.5, -1.0, 0.0]
    every = task.observe(*(np.array([x]) for x in (p, q, v, w, pad_vel, command, accel)))
    np.testing.assert_array_equal(every[0], p + q + v + w + pad_vel + command + accel)
    with pytest.raises(ValueError, match=r"observe_platform_acceleration .* needs observe_platform_velocity=True"):
        TaskConfig(observe_platform_acceleration=True)


def test_a_history_multiplies_the_frame_and_is_bounded():
    stacked = TaskConfig(observe_platform_velocity=True, observation_history=3)
    assert (stacked.frame_per_drone, stacked.obs_per_drone, stacked.obs_dim) == (16, 48, 96)
    for bad in (0, 9, 2.0, True):
        with pytest.raises(ValueError, match=r"observation_history must be an integer from 1 to 8 \(frames\)"):
            TaskConfig(observation_history=bad)


def test_batched_observation_flattens_drone_by_drone():
    e, n = 3, 2
    rel_pos = np.arange(e * n * 3, dtype=float).reshape(e, n, 3)
    quat = np.zeros((e, n, 4))
    quat[..., 3] = 1
    obs = task.observe(rel_pos, quat, -rel_pos, 0 * rel_pos)
    flat = task.flatten_observations(obs)
    assert flat.shape == (e, 26)
    # drone 1 of env 2 starts at index 13: its p is rel_pos[2, 1]
    np.testing.assert_array_equal(flat[2, 13:16], rel_pos[2, 1])
    np.testing.assert_array_equal(flat[2, 20:23], -rel_pos[2, 1])


def test_observation_is_clipped_to_its_limits():
    big = np.array([[100.0, -100.0, 0.0]])
    obs = task.observe(big, np.array([[0, 0, 0, 1.0]]), big, big * 10)
    p_max, _, v_max, w_max = task.OBS_LIMITS
    assert obs[0, 0] == p_max and obs[0, 1] == -p_max
    assert obs[0, 7] == v_max and obs[0, 10] == w_max


def eq2_drone_by_drone(rel_pos, quat, rel_vel, ang_vel) -> np.ndarray:
    """Eq. 2 written element by element in Python floats: an independent reference for task.observe."""
    p_max, _, v_max, w_max = task.OBS_LIMITS

    def clip(x, limit):
        return [min(max(float(c), -limit), limit) for c in x]

    rows = [
        clip(p, p_max) + [float(c) for c in q] + clip(v, v_max) + clip(w, w_max)
        for p, q, v, w in zip(*(a.reshape(-1, a.shape[-1]) for a in (rel_pos, quat, rel_vel, ang_vel)), strict=True)
    ]
    return np.array(rows).reshape(*rel_pos.shape[:-1], task.OBS_PER_DRONE)


@pytest.mark.parametrize("order", ["C", "F"])
def test_observation_equals_the_elementwise_reference_in_any_memory_layout(order):
    rng = np.random.default_rng(2)
    scales = ((30, 3), (1, 4), (80, 3), (300, 3))  # beyond the limits of p, v and omega
    parts = [np.asarray(rng.normal(0, scale, (6, 3, k)), order=order) for scale, k in scales]
    np.testing.assert_array_equal(task.observe(*parts), eq2_drone_by_drone(*parts))


def test_point_mass_observations_are_eq2_of_its_state_to_the_last_bit():
    """The point mass keeps its state in Fortran order (its fast layout); eq. 2 of that state must be bit for
    bit the observation built from each drone's numbers one at a time."""
    sim = PointMassSwarm(TaskConfig(num_drones=3), PlatformConfig(kind="moving-arc"), num_envs=5)
    episodes = LandingEpisodes(sim, seed=4)
    episodes.reset()
    rng = np.random.default_rng(4)
    for _ in range(5):
        outcome = episodes.step(rng.uniform(-1, 1, (5, 9)))
        s = sim.state()
        assert s.pos.flags.f_contiguous  # the fast layout this test is about
        rel_pos = s.pos - (s.pad_pos + np.array([0.0, 0.0, sim.task.landed_height]))
        expected = eq2_drone_by_drone(rel_pos, s.quat, s.vel - s.pad_vel, s.ang_vel)
        np.testing.assert_array_equal(outcome.obs, expected)


def test_point_mass_steps_identically_from_row_major_and_fortran_commands():
    """Commands may come in either memory layout (task.action_to_velocity returns the simulators' own when numba
    runs, row-major otherwise); the layout must not change a single bit of the flight."""
    sims = [PointMassSwarm(TaskConfig(num_drones=2), PlatformConfig(kind="moving-linear"), num_envs=7) for _ in "CF"]
    for sim in sims:
        sim.reset(np.arange(7), np.random.default_rng(5))
    rng = np.random.default_rng(6)
    for _ in range(20):
        velocity = task.action_to_velocity(rng.uniform(-1.5, 1.5, (7, 6)), 2, 3.0)
        sims[0].step(np.ascontiguousarray(velocity))
        sims[1].step(np.asfortranarray(velocity))
        for name in ("pos", "vel", "quat", "ang_vel", "contact"):
            np.testing.assert_array_equal(getattr(sims[0], name), getattr(sims[1], name))


def test_action_to_velocity_equals_the_elementwise_reference():
    rng = np.random.default_rng(3)
    action = rng.normal(0, 1.5, (4, 2, 3)).astype(np.float32)
    expected = [3.0 * min(max(float(a), -1.0), 1.0) for a in action.ravel()]
    np.testing.assert_array_equal(task.action_to_velocity(action, 2, 3.0).ravel(), expected)


def test_action_scaling_clipping_and_shapes():
    v = task.action_to_velocity([0.5, -1.0, 2.0, 0.0, 0.1, -3.0], num_drones=2, max_speed=3.0)
    assert v.shape == (1, 2, 3)
    np.testing.assert_allclose(v[0], [[1.5, -3.0, 3.0], [0.0, 0.3, -3.0]])
    batch = task.action_to_velocity(np.zeros((5, 2, 3)), 2, 3.0)
    assert batch.shape == (5, 2, 3)


def test_action_to_velocity_does_not_modify_its_input():
    a = np.asfortranarray(np.full((4, 2, 3), 5.0))
    task.action_to_velocity(a, 2, 3.0)
    assert (a == 5.0).all()


@pytest.mark.parametrize("bad", [[np.nan, 0, 0, 0, 0, 0], [0, 0, np.inf, 0, 0, 0]])
def test_non_finite_action_raises(bad):
    with pytest.raises(ValueError, match="NaN or infinite"):
        task.action_to_velocity(bad, 2, 3.0)


def test_wrong_action_shape_names_the_allowed_shapes():
    with pytest.raises(ValueError, match=r"expected \(6,\), \(2, 3\)"):
        task.action_to_velocity(np.zeros(5), 2, 3.0)


def test_next_target_position_is_p_plus_v_dt():
    np.testing.assert_allclose(
        task.next_target_position(np.array([1.0, 2, 3]), np.array([3.0, 0, -1.5]), 0.5), [2.5, 2, 2.25]
    )


def test_drone_reward_eq5_by_hand():
    # Drone 0 approached from 2.0 m to 1.5 m at 1 m/s: 10 * 0.5 - 0.02 * 1 = 4.98.
    # Drone 1 landed at an earlier step (not active): it earns nothing, whatever its numbers.
    r = task.drone_rewards(
        prev_dist=np.array([[2.0, 1.0]]),
        dist=np.array([[1.5, 1.1]]),
        rel_speed=np.array([[1.0, 2.0]]),
        landed_now=np.array([[False, False]]),
        active=np.array([[True, False]]),
        config=CFG,
    )
    np.testing.assert_allclose(r, [[4.98, 0.0]])


def test_landing_pays_c_once():
    # 0.05 m of approach at 0.3 m/s while touching down: 10 * 0.05 - 0.02 * 0.3 + 10 = 10.494
    r = task.drone_rewards(
        np.array([[0.06]]), np.array([[0.01]]), np.array([[0.3]]), np.array([[True]]), np.array([[True]]), CFG
    )
    np.testing.assert_allclose(r, [[10.494]])


def test_team_reward_eq4_with_collision_and_final_bonus():
    r_drones = np.array([[4.98, -1.0], [1.0, 2.0]])
    collided = np.array([True, False])
    all_landed_now = np.array([False, True])
    np.testing.assert_allclose(task.team_reward(r_drones, collided, all_landed_now, CFG), [3.98 - 20.0, 3.0 + 20.0])


def test_collision_penalty_eq6():
    np.testing.assert_array_equal(task.collision_penalty(np.array([True, False]), CFG), [-20.0, 0.0])


def test_min_separation_matches_brute_force():
    rng = np.random.default_rng(1)
    pos = rng.normal(size=(7, 5, 3))
    brute = [min(np.linalg.norm(p[i] - p[j]) for i in range(5) for j in range(i + 1, 5)) for p in pos]
    np.testing.assert_allclose(task.min_separation(pos), brute)
    assert np.isinf(task.min_separation(pos[:, :1])).all()


def test_touchdown_outcomes():
    contact = np.array([[CONTACT_OWN_PAD, CONTACT_OWN_PAD, CONTACT_OWN_PAD, CONTACT_OTHER, CONTACT_NONE]])
    horizontal = np.array([[0.02, 0.15, 0.02, 0.0, 0.0]])  # second: outside the 0.1 m pad
    speed = np.array([[0.2, 0.2, 0.9, 0.1, 3.0]])  # third: too fast
    landed_now, crashed = task.touchdown_outcome(contact, horizontal, speed, np.zeros((1, 5), bool), 0.1, CFG)
    np.testing.assert_array_equal(landed_now, [[True, False, False, False, False]])
    np.testing.assert_array_equal(crashed, [[False, True, True, True, False]])


def test_outside_arena():
    pos = np.array([[[0, 0, 1], [2.1, 0, 1], [0, -2.5, 1], [0, 0, 4.2], [1.9, 1.9, 3.9]]], dtype=float)
    np.testing.assert_array_equal(task.outside_arena(pos, CFG), [[False, True, True, True, False]])


def test_spawn_positions_respect_arena_height_and_separation():
    rng = np.random.default_rng(0)
    cfg = TaskConfig(num_drones=8)
    plate_top = np.full(500, 0.9)
    pos = task.sample_spawn_positions(rng, plate_top, cfg)
    assert pos.shape == (500, 8, 3)
    assert (np.abs(pos[..., :2]) <= 2.0).all()
    assert (pos[..., 2] >= 0.9 + cfg.spawn_clearance).all() and (pos[..., 2] <= 4.0 - cfg.spawn_ceiling_margin).all()
    assert task.min_separation(pos).min() >= cfg.spawn_separation


def test_near_pad_starts_are_within_their_stated_box():
    rng = np.random.default_rng(1)
    cfg = TaskConfig(num_drones=2, spawn_near_pad_fraction=1.0, spawn_near_pad_height_min=0.05, spawn_separation=0.2)
    pads = np.zeros((400, 2, 3))
    pads[:, 1, 0] = 0.4
    pos = task.sample_spawn_positions(rng, np.zeros(400), cfg, pads)
    offset = pos - pads
    assert (np.hypot(offset[..., 0], offset[..., 1]) <= 0.3).all()
    assert offset[..., 2].min() >= 0.05 and offset[..., 2].max() <= 1.0
    assert offset[..., 2].min() < 0.1  # the new low starts are drawn, not just allowed


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("num_drones", 0, "num_drones"),
        ("max_speed", -1.0, "max_speed"),
        ("beta", 0.5, "beta"),
        ("alpha", math.nan, "finite"),
        ("collision_distance", -0.1, "collision_distance"),
        ("spawn_near_pad_height_min", 0.0, "spawn_near_pad_height_min must be above 0 m and below 1 m"),
        ("spawn_near_pad_height_min", 1.0, "spawn_near_pad_height_min"),
    ],
)
def test_invalid_task_config_names_the_problem(field, value, message):
    with pytest.raises(ValueError, match=message):
        TaskConfig(**{field: value})


def test_replace_rejects_unknown_fields():
    with pytest.raises(TypeError, match="allowed"):
        CFG.replace(gamma=0.9)


def test_timing_properties():
    assert CFG.dt == pytest.approx(1 / 24)
    assert CFG.max_steps == 240
    assert CFG.obs_dim == 26 and CFG.act_dim == 6


def test_landing_tolerance_is_a_stricter_pad_for_training():
    strict = CFG.replace(landing_tolerance=0.03)
    contact = np.full((1, 2), CONTACT_OWN_PAD)
    horizontal, speed, none = np.array([[0.02, 0.05]]), np.array([[0.2, 0.2]]), np.zeros((1, 2), bool)
    landed, crashed = task.touchdown_outcome(contact, horizontal, speed, none, 0.1, strict)
    np.testing.assert_array_equal(landed, [[True, False]])
    np.testing.assert_array_equal(crashed, [[False, True]])
    landed, _ = task.touchdown_outcome(contact, horizontal, speed, none, 0.1, CFG)
    assert landed.all()
