"""The point-mass simulator and its three faces: physics, API checkers, determinism, bad input."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from pettingzoo.test import parallel_api_test, parallel_seed_test
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import marlander_lite
from marlander_lite.episodes import LandingEpisodes
from marlander_lite.platforms import PlatformConfig
from marlander_lite.pointmass import PointMassParams, PointMassSwarm, PointMassVecEnv
from marlander_lite.rotations import rotate_vector
from marlander_lite.sensing import SensingConfig
from marlander_lite.swarm.pad_acceleration import PadAcceleration
from marlander_lite.task import TaskConfig

ENV_ID = "marlander_lite/PointMassLanding-v0"


def go_to_pad(obs: np.ndarray, num_drones: int, gain: float = 2.0, speed: float = 1.0) -> np.ndarray:
    """A hand-written controller: fly to a cone above the pad, then descend along it.

    The target height above the goal is twice the horizontal distance to it (at most 1 m), so
    the drone arrives from above; it aims 5 cm under the goal so that it really touches the pad.
    """
    p = obs.reshape(-1, num_drones, 13)[..., 0:3].copy()
    horizontal = np.linalg.norm(p[..., :2], axis=-1)
    p[..., 2] -= np.minimum(2.0 * horizontal, 1.0) - 0.05
    v = -gain * p
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    v *= np.minimum(1.0, speed / np.maximum(norm, 1e-9))
    return (v / 3.0).reshape(len(p), -1)


def make_episodes(num_envs=1, num_drones=1, platform="static-floor", params=None, sensing=None, **task):
    sim = PointMassSwarm(TaskConfig(num_drones=num_drones, **task), PlatformConfig(kind=platform), num_envs, params)
    episodes = LandingEpisodes(sim, sensing, seed=0)
    episodes.reset()
    return sim, episodes


# ---------------------------------------------------------------------------- physics


def test_small_vertical_command_follows_the_vertical_velocity_loop():
    params = PointMassParams(vertical_time_constant=0.1)
    sim, episodes = make_episodes(params=params)
    sim.pos[0, 0] = (0.0, 0.0, 2.0)
    dt = sim.task.dt
    for k in range(1, 13):
        episodes.step(np.array([[0.0, 0.0, 0.1]]))  # 0.3 m/s up: 3 m/s^2 asked for, within the thrust
        # v_k = v_(k-1) + (u - v_(k-1)) dt / tau, so v_k = u (1 - (1 - dt / tau)^k); the attitude stays level.
        assert sim.vel[0, 0, 2] == pytest.approx(0.3 * (1 - (1 - dt / 0.1) ** k), rel=1e-9)
    np.testing.assert_allclose(sim.quat[0, 0], [0, 0, 0, 1], atol=1e-12)


@pytest.mark.parametrize(("command", "acceleration"), [(-1.0, -5.0), (1.0, 10.0)])
def test_vertical_acceleration_is_limited_by_the_thrust(command, acceleration):
    params = PointMassParams(max_sink_acceleration=5.0, max_climb_acceleration=10.0)
    sim, episodes = make_episodes(params=params)
    sim.pos[0, 0] = (0.0, 0.0, 2.0)
    episodes.step(np.array([[0.0, 0.0, command]]))
    dt = sim.task.dt
    assert sim.vel[0, 0, 2] == pytest.approx(acceleration * dt)
    assert sim.pos[0, 0, 2] == pytest.approx(2.0 + 0.5 * acceleration * dt**2)


def test_level_flight_accelerates_at_g_tan_tilt_within_the_tilt_limit():
    sim, episodes = make_episodes(params=PointMassParams(max_tilt_deg=30.0))
    sim.pos[0, 0] = (0.0, 0.0, 2.0)
    up = np.array([0.0, 0.0, 1.0])
    tilts = []
    for _ in range(12):
        vel_before = sim.vel[0, 0].copy()
        episodes.step(np.array([[1.0, 0.0, 0.0]]))
        accel = (sim.vel[0, 0] - vel_before) / sim.task.dt
        body_z = rotate_vector(sim.quat[0, 0], up)
        tilt = np.arccos(body_z[2])
        tilts.append(tilt)
        # Thrust along body z holding the height: no vertical acceleration, a_x = g tan(tilt).
        assert accel[2] == pytest.approx(0.0, abs=1e-9)
        assert accel[0] == pytest.approx(9.81 * np.tan(tilt), rel=1e-9)
        assert body_z[0] > 0 and abs(body_z[1]) < 1e-12
    # The tilt builds up (attitude lag) towards the 30 degree limit and never exceeds it.
    assert np.all(np.diff(tilts) >= -1e-12) and max(tilts) <= np.radians(30.0) + 1e-9
    assert max(tilts) > np.radians(29.0)
    # Tilting the thrust from +z towards +x is a positive rotation about +y.
    assert sim.ang_vel[0, 0, 1] >= 0 and abs(sim.ang_vel[0, 0, 0]) < 1e-12


def test_angular_velocity_is_the_tilt_rate():
    sim, episodes = make_episodes()
    sim.pos[0, 0] = (0.0, 0.0, 2.0)
    up = np.array([0.0, 0.0, 1.0])
    before = np.arccos(rotate_vector(sim.quat[0, 0], up)[2])
    episodes.step(np.array([[0.0, -1.0, 0.0]]))
    after = np.arccos(rotate_vector(sim.quat[0, 0], up)[2])
    # Tilting towards -y is a positive rotation about +x, at the rate the tilt angle changed.
    assert sim.ang_vel[0, 0, 0] == pytest.approx((after - before) / sim.task.dt, rel=1e-9)


def test_sinking_fast_leaves_little_thrust_to_move_sideways():
    sim, episodes = make_episodes(params=PointMassParams(max_tilt_deg=34.0, max_sink_acceleration=5.39))
    sim.pos[0, 0] = (0.0, 0.0, 3.5)
    for _ in range(12):
        episodes.step(np.array([[1.0, 0.0, -1.0]]))
    sideways_then = sim.vel[0, 0, 0]
    assert sideways_then < 1.2 and sim.vel[0, 0, 2] < -2.0
    # The same sideways command in level flight gets much further in the same time.
    sim2, episodes2 = make_episodes(params=PointMassParams(max_tilt_deg=34.0, max_sink_acceleration=5.39))
    sim2.pos[0, 0] = (0.0, 0.0, 3.5)
    for _ in range(12):
        episodes2.step(np.array([[1.0, 0.0, 0.0]]))
    assert sim2.vel[0, 0, 0] > 1.5 * sideways_then


def test_touching_the_floor_away_from_the_plate_is_a_crash():
    sim, episodes = make_episodes()
    sim.motion.anchor[0] = (1.5, 1.5, 0.005)
    sim._update_platform()
    sim.pos[0, 0] = (-1.0, -1.0, 0.3)
    for _ in range(20):
        outcome = episodes.step(np.array([[0.0, 0.0, -0.3]]))
        if outcome.done[0]:
            break
    assert outcome.crashed[0, 0] and outcome.terminated[0] and not outcome.success[0]
    assert sim.pos[0, 0, 2] == pytest.approx(sim.task.landed_height)  # stopped at the floor


def test_collision_ends_the_episode_with_alpha_c_penalty():
    sim, episodes = make_episodes(num_drones=2)
    sim.pos[0] = [(0.0, 0.0, 2.0), (0.1, 0.0, 2.0)]
    episodes.prev_dist[:] = np.linalg.norm(sim.pos[0] - (sim._pads[0] + [0, 0, sim.task.landed_height]), axis=-1)
    outcome = episodes.step(np.zeros((1, 6)))
    assert outcome.collided[0] and outcome.terminated[0]
    np.testing.assert_allclose(outcome.reward[0], -20.0 + outcome.drone_rewards[0].sum())


@pytest.mark.parametrize("platform", ["static-floor", "static-elevated"])
def test_hand_written_controller_lands_both_drones_precisely(platform):
    env = PointMassVecEnv(num_envs=32, num_drones=2, platform=platform, seed=3)
    obs = env.reset()
    finished = []
    for _ in range(400):
        obs, _, done, infos = env.step(go_to_pad(obs, 2))
        finished += [infos[i] for i in np.flatnonzero(done)]
        if len(finished) >= 32:
            break
    success = np.mean([f["is_success"] for f in finished])
    errors = [f["landing_error"] for f in finished if f["is_success"]]
    # Straight-line flights may cross; most must still land, within 1 cm of the pad centre.
    assert success >= 0.85
    assert max(errors) < 0.01


def test_a_landed_drone_rides_with_a_moving_platform():
    sim, episodes = make_episodes(platform="moving-linear")
    pad = sim._pads[0, 0].copy()
    sim.pos[0, 0] = pad + np.array([0.0, 0.0, sim.task.landed_height + 0.01])
    sim.vel[0, 0] = sim._pad_vel[0, 0] + (0.0, 0.0, -0.2)
    for _ in range(10):
        outcome = episodes.step((sim._pad_vel[:, :1] + (0.0, 0.0, -0.2)) / 3.0)
        if outcome.done[0]:
            break
    assert outcome.landed[0, 0] and outcome.success[0]
    offset = sim.pos[0, 0] - sim._pads[0, 0]
    sim.step(np.zeros((1, 1, 3)))
    sim.step(np.zeros((1, 1, 3)))
    np.testing.assert_allclose(sim.pos[0, 0] - sim._pads[0, 0], offset)
    np.testing.assert_allclose(sim.vel[0, 0], sim._pad_vel[0, 0])


# ---------------------------------------------------------------------------- sensing


def test_latency_of_one_step_returns_the_previous_observation():
    task = TaskConfig(num_drones=1)
    _, episodes = make_episodes(sensing=SensingConfig(latency_s=task.dt))
    seen, truth = [], []
    for _ in range(5):
        truth.append(episodes.true_observations().copy())
        seen.append(episodes.step(np.array([[0.3, 0.1, -0.2]])).obs.copy())
    for k in range(1, 5):
        np.testing.assert_allclose(seen[k], truth[k], atol=1e-12)


def test_the_previous_command_is_observed_exactly_and_at_once():
    # Sensing noise and a one-step delay degrade eq. 2 and the platform velocity, never the policy's own command.
    sensing = SensingConfig(pos_noise_std=0.01, vel_noise_std=0.02, latency_s=TaskConfig().dt)
    _, episodes = make_episodes(
        num_envs=3, num_drones=2, platform="moving-linear", sensing=sensing,
        observe_platform_velocity=True, observe_previous_command=True,
    )  # fmt: skip
    first = episodes.reset()
    assert first.shape == (3, 2, 19)
    np.testing.assert_array_equal(first[..., 16:], 0.0)  # nothing commanded yet
    rng = np.random.default_rng(1)
    for _ in range(4):
        action = rng.uniform(-1, 1, (3, 6))
        truth_before = episodes.true_observations()
        outcome = episodes.step(action)
        np.testing.assert_array_equal(outcome.obs[..., 16:], action.reshape(3, 2, 3) * 3.0)
        np.testing.assert_array_equal(episodes.true_observations()[..., 16:], action.reshape(3, 2, 3) * 3.0)
        # the measured part is a step late: near the state before this step, not the one after it
        late = np.abs(outcome.obs[..., 0:3] - truth_before[..., 0:3]).max()
        assert late < 0.06
    episodes.reset(np.array([1]))
    np.testing.assert_array_equal(episodes.previous_command[1], 0.0)
    np.testing.assert_array_equal(episodes.true_observations()[1, :, 16:], 0.0)


def test_the_pad_acceleration_is_estimated_from_the_observed_pad_velocities():
    # Perfect sensing: the estimate is zero while the plate cruises and approaches the plate's 1 m/s^2 at its
    # reversals (an average that takes 0.3 of each new difference: 1 - 0.7^k of it after k steps).
    accel = {"observe_platform_velocity": True, "observe_platform_acceleration": True}
    _, episodes = make_episodes(num_envs=2, platform="moving-linear", **accel)
    seen = [episodes.reset()]
    np.testing.assert_array_equal(seen[0][..., 16:19], 0.0)  # nothing to difference yet
    for _ in range(200):
        outcome = episodes.step(np.zeros((2, 3)))
        seen.append(outcome.obs)
        assert not outcome.terminated.any() and not outcome.truncated.any()
    seen = np.array(seen)
    pad_vel, estimate = seen[:, 0, 0, 13:16], seen[:, 0, 0, 16:19]
    size = np.linalg.norm(estimate, axis=-1)
    assert size.max() == pytest.approx(1.0, abs=0.03) and size.max() <= 1.0 + 1e-9
    # cruised[k]: the pad velocity did not change from observation k to k + 1; after 30 such steps in a row the
    # estimate holds 0.7^30 of what it had.
    cruised = np.linalg.norm(np.diff(pad_vel, axis=0), axis=-1) < 1e-12
    window = np.lib.stride_tricks.sliding_window_view(cruised, 30).all(axis=-1)
    assert window.any() and (size[30:][window] < 0.03).all()
    # Vicon noise: the estimate is what the deployment loop's estimator makes of the same observed velocities.
    _, noisy = make_episodes(num_envs=3, num_drones=2, platform="moving-arc", sensing=SensingConfig.vicon(), **accel)
    first = noisy.reset()
    estimators = [PadAcceleration() for _ in range(3)]
    for k in range(60):
        obs = first if k == 0 else noisy.step(np.full((3, 6), 0.1)).obs
        for env, estimator in enumerate(estimators):
            expected = estimator.update(obs[env, :, 13:16], k * TaskConfig().dt)
            np.testing.assert_allclose(obs[env, :, 16:19], expected, atol=1e-12)
    noisy.reset(np.array([1]))
    np.testing.assert_array_equal(noisy.pad_acceleration[1], 0.0)
    assert np.abs(noisy.pad_acceleration[0]).max() > 0  # the other envs keep theirs


def test_a_history_holds_the_frames_the_policy_saw_newest_first():
    # Two twins with the same seed, one frame and three: the history consumes no random numbers, so the stacked
    # observation is the single-frame twin's last three observations, the first one repeated after a reset.
    extras = {"observe_platform_velocity": True, "observe_previous_command": True}
    twins = [
        make_episodes(3, 2, "moving-arc", sensing=SensingConfig.vicon(), **extras, observation_history=h)[1]
        for h in (1, 3)
    ]
    single, stacked = (twin.reset() for twin in twins)
    assert stacked.shape == (3, 2, 57)
    frames = [single] * 3  # after a reset every slot holds the first frame
    actions = np.random.default_rng(0).uniform(-1, 1, (40, 3, 6))
    for k, action in enumerate(actions):
        if k == 25:  # env 1 starts over in both twins: its history restarts, the others' goes on
            reset_single, reset_stacked = (twin.reset(np.array([1])) for twin in twins)
            np.testing.assert_array_equal(reset_stacked, np.tile(reset_single, 3))
            frames = [f.copy() for f in frames]
            for f in frames:
                f[1] = reset_single[0]
        single, stacked = (twin.step(action).obs for twin in twins)
        frames = [single, *frames[:2]]
        np.testing.assert_array_equal(stacked, np.concatenate(frames, axis=-1))


def test_position_noise_has_the_configured_spread():
    _, episodes = make_episodes(num_envs=2000, sensing=SensingConfig(pos_noise_std=0.01))
    outcome = episodes.step(np.zeros((2000, 3)))
    error = outcome.obs[..., 0:3] - episodes.true_observations()[..., 0:3]
    assert error.std() == pytest.approx(0.01, rel=0.05)


# ---------------------------------------------------------------------------- API checkers


@pytest.mark.parametrize(
    "extras",
    [
        {},
        {"observe_platform_velocity": True, "observe_previous_command": True},
        {"observe_platform_velocity": True, "observe_platform_acceleration": True},
        {"observe_platform_velocity": True, "observation_history": 3},
    ],
)
def test_gymnasium_and_sb3_checkers_pass(extras):
    env = gym.make(ENV_ID, num_drones=2, platform="moving-arc", task=extras)
    gym_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped)


def test_pettingzoo_checkers_pass():
    parallel_api_test(
        marlander_lite.make_parallel_env("pointmass", num_drones=3, task={"observe_previous_command": True}),
        num_cycles=300,
    )
    parallel_api_test(marlander_lite.make_parallel_env("pointmass", num_drones=3), num_cycles=300)
    parallel_api_test(
        marlander_lite.make_parallel_env("pointmass", num_drones=3, task={"observation_history": 2}), num_cycles=100
    )
    parallel_seed_test(lambda: marlander_lite.make_parallel_env("pointmass", num_drones=3))


@pytest.mark.parametrize("platform", ["static-elevated", "moving-arc"])
def test_gym_env_rollout_is_deterministic_with_a_seed(platform):
    def rollout():
        env = gym.make(ENV_ID, num_drones=2, platform=platform, sensing="vicon")
        obs, _ = env.reset(seed=7)
        env.action_space.seed(7)
        trace = [obs]
        for _ in range(60):
            obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
            trace += [obs, np.array([reward])]
            if terminated or truncated:
                obs, _ = env.reset()
                trace.append(obs)
        return np.concatenate(trace)

    np.testing.assert_array_equal(rollout(), rollout())


def test_vec_env_rollout_is_deterministic_with_a_seed():
    def rollout(seed):
        env = marlander_lite.make_vec_env("pointmass", num_envs=16, num_drones=2, seed=seed, platform="moving-linear")
        rng = np.random.default_rng(0)
        obs = [env.reset()]
        for _ in range(80):
            o, r, _, _ = env.step(rng.uniform(-1, 1, (16, 6)).astype(np.float32))
            obs += [o, r[:, None]]
        return np.concatenate(obs, axis=1)

    a, b, c = rollout(5), rollout(5), rollout(6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_vec_env_resets_finished_envs_the_sb3_way():
    env = marlander_lite.make_vec_env("pointmass", num_envs=8, num_drones=2, seed=0)
    env.reset()
    down = np.tile([0.0, 0.0, -1.0], 2).astype(np.float32)
    for _ in range(200):
        obs, _, done, infos = env.step(np.tile(down, (8, 1)))
        if done.any():
            break
    i = int(np.flatnonzero(done)[0])
    assert infos[i]["terminal_observation"].shape == (26,)
    assert not infos[i]["is_success"] and "episode" in infos[i]
    assert env.episodes.steps[i] == 0  # the returned observation starts a new episode
    assert not np.array_equal(obs[i], infos[i]["terminal_observation"])
    assert dict(infos[int(np.flatnonzero(~done)[0])]) == {} if (~done).any() else True


def test_vec_env_trains_with_sb3_ppo():
    from stable_baselines3 import PPO

    env = marlander_lite.make_vec_env("pointmass", num_envs=8, num_drones=2, seed=0)
    model = PPO("MlpPolicy", env, n_steps=16, batch_size=64, n_epochs=1, seed=0, device="cpu")
    model.learn(256)
    assert model.num_timesteps >= 256


# ---------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        ({"platform": "trampoline"}, ValueError, "allowed: static-floor"),
        ({"num_drones": 0}, ValueError, "num_drones"),
        ({"platform": "moving-arc", "platform_speed": -0.3}, ValueError, ">= 0"),
        ({"wind": 3.0}, TypeError, "allowed options"),
        ({"task": {"gamma": 0.9}}, TypeError, "allowed"),
        ({"sensing": "optitrack"}, ValueError, "vicon"),
        ({"dynamics": {"tau": 0.1}}, TypeError, r"\['tau'\]; allowed options: velocity_time_constant"),
        ({"options": marlander_lite.EnvOptions(), "physics": "bare"}, TypeError, "allowed options: .*dynamics"),
    ],
)
def test_bad_env_options_raise_clear_errors(kwargs, error, message):
    with pytest.raises(error, match=message):
        gym.make(ENV_ID, **kwargs)


def test_bad_actions_raise_and_leave_the_episode_usable():
    env = gym.make(ENV_ID, num_drones=2).unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.full(6, np.nan, dtype=np.float32))
    with pytest.raises(ValueError, match=r"takes \(6,\) or \(2, 3\)"):
        env.step(np.zeros(4, dtype=np.float32))
    env.step(np.zeros(6, dtype=np.float32))  # still steps after the rejected actions


def test_domain_randomization_varies_the_response_per_episode():
    params = PointMassParams(velocity_time_constant=0.1, max_tilt_deg=30.0, randomization=0.5)
    sim, _ = make_episodes(num_envs=500, params=params)
    tau = 1.0 / sim._gain[:, 0, 0]
    tan_tilt = sim._tan_tilt[:, 0]
    # Log-uniform within [1/1.5, 1.5] of the nominal values, median near the nominal.
    assert tau.min() >= 0.1 / 1.5 - 1e-9 and tau.max() <= 0.1 * 1.5 + 1e-9
    nominal = np.tan(np.radians(30.0))
    assert tan_tilt.min() >= nominal / 1.5 - 1e-9 and tan_tilt.max() <= nominal * 1.5 + 1e-9
    assert np.median(tau) == pytest.approx(0.1, rel=0.1) and np.median(tan_tilt) == pytest.approx(nominal, rel=0.1)
    # The thrust limits scale with the same authority factor as the tilt.
    authority = tan_tilt / nominal
    np.testing.assert_allclose(sim._thrust_max[:, 0] - 9.81, params.max_climb_acceleration * authority)


def test_near_pad_starts_are_near_the_pads():
    sim, _ = make_episodes(num_envs=400, num_drones=2, spawn_near_pad_fraction=0.5)
    offset = sim.pos - sim._pads
    near = (np.linalg.norm(offset[..., :2], axis=-1) <= 0.3).all(axis=1) & (offset[..., 2] <= 1.0).all(axis=1)
    assert 0.4 < near.mean() < 0.65  # half by design, plus a few uniform starts that happen to be close


def test_vec_env_rejects_bad_num_envs():
    with pytest.raises(ValueError, match="num_envs"):
        marlander_lite.make_vec_env("pointmass", num_envs=0)
    with pytest.raises(ValueError, match="allowed: pointmass, crazyflie"):
        marlander_lite.make_vec_env("mujoco")


def test_drone_with_motors_stopped_falls_as_z0_minus_half_g_t_squared():
    sim, _ = make_episodes(num_drones=2)
    sim.place(0, np.array([[0.0, 0.0, 2.0], [1.0, 1.0, 1.0]]))
    sim.stop_motors(np.array([[True, False]]))
    for k in range(1, 9):
        sim.step(np.zeros((1, 2, 3)))
        t = k * sim.task.dt
        assert sim.pos[0, 0, 2] == pytest.approx(2.0 - 0.5 * 9.81 * t * t, abs=1e-12)
    np.testing.assert_allclose(sim.pos[0, 1], [1.0, 1.0, 1.0])  # the other drone hovers


def test_place_rejects_bad_positions():
    sim, _ = make_episodes(num_drones=2)
    with pytest.raises(ValueError, match=r"\(2, 3\)"):
        sim.place(0, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="finite"):
        sim.place(0, np.full((2, 3), np.nan))


def test_a_drone_resting_with_motors_off_stays_at_rest():
    sim, _ = make_episodes(num_drones=1)
    sim.place(0, np.array([[1.0, 1.0, 0.3]]))
    sim.vel[0, 0] = (0.5, 0.0, 0.0)  # cut while moving sideways: it lands and friction stops it
    sim.stop_motors(np.array([[True]]))
    for _ in range(48):  # 2 s: falls 0.29 m in about 0.24 s, then rests
        sim.step(np.zeros((1, 1, 3)))
    assert sim.pos[0, 0, 2] == pytest.approx(sim.task.landed_height)
    np.testing.assert_array_equal(sim.vel[0, 0], 0.0)


def test_a_diagonal_touchdown_stops_where_the_path_crosses_the_pad():
    sim, episodes = make_episodes()
    pad = sim._pads[0, 0]
    h = sim.task.landed_height
    # 2 cm above the rest height, moving 0.3 m/s sideways and 0.3 m/s down: it crosses after 2/30 s
    # (1.6 policy steps), 2 cm to the side; continuing the free flight would end 2.5 cm to the side.
    sim.pos[0, 0] = pad + np.array([0.0, 0.0, h + 0.02])
    sim.vel[0, 0] = (0.3, 0.0, -0.3)
    for _ in range(3):
        outcome = episodes.step(np.array([[0.1, 0.0, -0.1]]))  # the drone's own velocity: it keeps it
        if outcome.done[0]:
            break
    assert outcome.landed[0, 0]
    assert outcome.landing_error[0, 0] == pytest.approx(0.02, abs=1e-3)
