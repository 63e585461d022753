"""The PyBullet Crazyflie swarm: physical laws, landing, the three faces, determinism, bad input.

Physical checks compare with the published figures written out here (not read from the code)
and with textbook laws: hover thrust balance, free fall, the published force models.
"""

import math

import gymnasium as gym
import numpy as np
import pybullet as p
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from pettingzoo.test import parallel_api_test, parallel_seed_test
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import marlander_lite
from marlander_lite.crazyflie import CF2XParams, CrazyflieSwarm, PhysicsConfig, PIDGains
from marlander_lite.crazyflie.control import (
    PUBLISHED_DSL_GAINS,
    CascadedPID,
    attitude_loop_spectral_radius,
    mixer_matrix,
)
from marlander_lite.crazyflie.envs import CrazyflieOptions
from marlander_lite.crazyflie.physics import MotorLag, downwash_push, ground_effect_gain, motor_wrench
from marlander_lite.crazyflie.ticks import ControlTick
from marlander_lite.crazyflie.world import CF2X_URDF
from marlander_lite.episodes import LandingEpisodes
from marlander_lite.platforms import PlatformConfig
from marlander_lite.rotations import tilt_deg
from marlander_lite.task import CONTACT_OTHER, TaskConfig

ENV_ID = "marlander_lite/CrazyflieLanding-v0"
# Published CF2X figures (docs/references.md), written out independently of params.py.
MASS, KF, G = 0.027, 3.16e-10, 9.81
HOVER_RPM = math.sqrt(MASS * G / (4 * KF))


def make_sim(num_drones=1, platform="static-floor", physics="bare", **task):
    config = PhysicsConfig.preset(physics) if isinstance(physics, str) else physics
    return CrazyflieSwarm(TaskConfig(num_drones=num_drones, **task), PlatformConfig(kind=platform), physics=config)


def fly(sim, velocity, steps):
    """Step with a constant velocity command ``(N, 3)`` m/s; returns positions and velocities ``(steps, N, 3)``."""
    command = np.asarray(velocity, dtype=float)[None]
    pos, vel = [], []
    for _ in range(steps):
        sim.step(command)
        pos.append(sim.pos[0].copy())
        vel.append(sim.vel[0].copy())
    return np.array(pos), np.array(vel)


# ---------------------------------------------------------------------------- the model


def test_urdf_holds_the_published_figures():
    client = p.connect(p.DIRECT)
    try:
        flags = p.URDF_USE_INERTIA_FROM_FILE | p.URDF_USE_IMPLICIT_CYLINDER
        body = p.loadURDF(str(CF2X_URDF), flags=flags, physicsClientId=client)
        mass, _, inertia, *_ = p.getDynamicsInfo(body, -1, physicsClientId=client)
        assert mass == pytest.approx(0.027)
        np.testing.assert_allclose(inertia, [1.4e-5, 1.4e-5, 2.17e-5])
        (shape,) = p.getCollisionShapeData(body, -1, physicsClientId=client)
        assert shape[2] == p.GEOM_CYLINDER
        np.testing.assert_allclose(shape[3][:2], [0.025, 0.06])  # height, radius
        discs = [v for v in p.getVisualShapeData(body, physicsClientId=client) if v[2] == p.GEOM_CYLINDER]
        props = sorted(tuple(np.round(v[5][:2], 4)) for v in discs if v[3][1] == pytest.approx(0.0231))
        assert props == sorted((sx * 0.028, sy * 0.028) for sx in (-1, 1) for sy in (-1, 1))
    finally:
        p.disconnect(client)


def test_motor_model_and_mixer_agree_on_every_axis():
    params = CF2XParams()
    fz, *_ = motor_wrench([HOVER_RPM] * 4, params)
    assert fz == pytest.approx(MASS * G)
    # A positive torque command through the mixer gives a positive torque through the motor model.
    for axis in range(3):
        pwm = 38000 + 1000 * mixer_matrix(params)[:, axis]
        rpm = params.pwm_to_rpm_scale * pwm + params.pwm_to_rpm_offset
        torque = motor_wrench(rpm, params)[1:]
        assert torque[axis] > 0 and all(abs(t) < 1e-12 for k, t in enumerate(torque) if k != axis)


def test_ground_effect_and_downwash_follow_the_published_models_and_stay_bounded():
    params = CF2XParams()
    radius = 0.0231
    assert ground_effect_gain(0.1, params) == pytest.approx(1 + 11.36859 * (radius / 0.4) ** 2)
    assert ground_effect_gain(1e-9, params) == ground_effect_gain(0.025, params) < 1.7
    # Far below another drone the published peak c1 (R / 4 dz)^2 applies (it is under the thrust bound).
    assert downwash_push(1.0, 0.0, 0.265, params) == pytest.approx(-2267.18 * (radius / 4.0) ** 2)
    # Close below, the published formula explodes; ours never exceeds the upper drone's thrust.
    for dz in (1e-12, 1e-6, 1e-3, 0.05, 0.2):
        push = downwash_push(dz, 0.0, 0.265, params)
        assert math.isfinite(push) and -0.265 <= push <= 0.0
    assert downwash_push(0.0, 0.0, 0.265, params) == 0.0  # same height: not in the wake
    assert abs(downwash_push(1e-6, 0.2**2, 0.265, params)) < 1e-3  # and continuous there


def test_motor_wrench_sums_each_rotors_thrust_lever_and_drag_torque():
    # Unequal speeds and ground-effect gains, so that a rotor mixed up with another shows.
    params = CF2XParams()
    rpm = np.array([14000.0, 15000.0, 16000.0, 17000.0])
    gain = np.array([1.0, 1.1, 1.2, 1.3])
    xy = 0.028 * np.array([[1, -1], [-1, -1], [-1, 1], [1, 1]])  # M1..M4, the published layout
    thrust = KF * rpm**2 * gain
    expected = [
        thrust.sum(),  # F_z
        (xy[:, 1] * thrust).sum(),  # tau_x = sum y_i T_i
        -(xy[:, 0] * thrust).sum(),  # tau_y = -sum x_i T_i
        (np.asarray(params.yaw_signs) * params.km * rpm**2).sum(),  # tau_z = sum s_i k_m w_i^2
    ]
    np.testing.assert_allclose(motor_wrench(rpm.tolist(), params, gain.tolist()), expected, rtol=1e-12, atol=1e-18)


def test_the_swarm_downwash_sum_skips_only_pairs_that_add_nothing():
    # The tick sums downwash_push over the drones above only; the plain sum over every other drone, the
    # model's definition, must give the same bits: drones level, above, below, far away, motors off.
    params = CF2XParams()
    rng = np.random.default_rng(3)
    positions = rng.uniform(-0.4, 0.4, (12, 3)) + np.array([0.0, 0.0, 1.0])
    positions[3:6, 2] = positions[5, 2]
    positions[7] = positions[2] + np.array([0.01, 0.0, 0.3])
    positions[9] = (5.0, 5.0, 3.0)
    poses = [(tuple(q), (0.0, 0.0, 0.0, 1.0)) for q in positions.tolist()]
    thrusts = rng.uniform(0.0, 0.3, 12).tolist()
    thrusts[6] = 0.0
    pid = CascadedPID(params, PIDGains(), 12, 1 / 48)
    tick = ControlTick(PhysicsConfig.preset("aero"), params, pid, MotorLag(0.0, 1 / 48), (0.3, 0.3))
    pushes = []
    for i, (mine, _) in enumerate(poses):
        plain = 0.0
        for j, (other, _) in enumerate(poses):
            if j != i:
                d2 = (other[0] - mine[0]) ** 2 + (other[1] - mine[1]) ** 2
                plain += downwash_push(other[2] - mine[2], d2, thrusts[j], params)
        pushes.append(tick._downwash(mine, poses, thrusts))
        assert pushes[-1] == plain
    assert sum(push < 0.0 for push in pushes) >= 6 and pushes[int(np.argmax(positions[:, 2]))] == 0.0


# ---------------------------------------------------------------------------- flight


@pytest.mark.parametrize("physics", ["bare", "aero"])
def test_hover_rpm_is_the_thrust_balance_and_position_holds(physics):
    sim = make_sim(physics=physics)
    start = np.array([[0.3, -0.2, 1.5]])
    sim.place(0, start)
    pos, _ = fly(sim, np.zeros((1, 3)), 5 * 24)
    assert np.mean(sim.rpm[0]) == pytest.approx(HOVER_RPM, rel=0.01)
    assert np.abs(pos[:, 0] - start).max() < 0.02


def test_motor_lag_holds_the_mean_thrust_of_the_lagging_rotors_and_still_hovers():
    tau = 0.03
    sim = make_sim(physics=PhysicsConfig(motor_time_constant=tau))
    effective, now = MotorLag(tau, sim.control_dt).step([15000.0] * 4, [10000.0] * 4)
    t = np.linspace(0.0, sim.control_dt, 200001)
    w = 15000.0 + (10000.0 - 15000.0) * np.exp(-t / tau)  # first-order lag towards the command
    assert effective[0] ** 2 == pytest.approx(np.trapezoid(w * w, t) / sim.control_dt, rel=1e-6)
    assert now[0] == pytest.approx(w[-1])
    start = np.array([[0.0, 0.0, 1.5]])
    sim.place(0, start)
    pos, _ = fly(sim, np.zeros((1, 3)), 2 * 24)
    assert np.abs(pos[:, 0] - start).max() < 0.02


def test_motors_off_the_drone_falls_as_z0_minus_half_g_t_squared():
    sim = make_sim(num_drones=2)
    sim.place(0, np.array([[0.0, 0.0, 2.0], [1.0, 1.0, 1.0]]))
    sim.stop_motors(np.array([[True, False]]))
    for k in range(1, 8):  # 7 steps of 1/24 s: 0.29 s
        sim.step(np.zeros((1, 2, 3)))
        t = k * sim.task.dt
        assert sim.pos[0, 0, 2] == pytest.approx(2.0 - 0.5 * G * t * t, abs=0.01)
    np.testing.assert_allclose(sim.pos[0, 0, :2], [0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(sim.pos[0, 1], [1.0, 1.0, 1.0], atol=0.01)  # the other drone hovers


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_one_metre_per_second_is_tracked_within_ten_percent_after_one_second(axis):
    sim = make_sim(physics="aero")
    sim.place(0, np.array([[0.0, 0.0, 1.5]]))
    command = np.zeros((1, 3))
    command[0, axis] = 1.0
    _, vel = fly(sim, command, 36)
    assert vel[23, 0, axis] == pytest.approx(1.0, rel=0.1)
    assert vel[:, 0, axis].max() < 1.2  # bounded overshoot
    others = [k for k in range(3) if k != axis]
    assert np.abs(vel[:, 0, others]).max() < 0.1


def test_attitude_loop_recovers_from_a_tilt_and_published_damping_would_not_at_48_hz():
    params = CF2XParams()
    assert attitude_loop_spectral_radius(params, PIDGains(), 48.0).max() < 1.0
    assert attitude_loop_spectral_radius(params, PIDGains(att_d=(20000, 20000, 12000)), 48.0).max() > 1.0

    def rate_after_tilt(gains):
        sim = CrazyflieSwarm(TaskConfig(num_drones=1), PlatformConfig(), physics=PhysicsConfig(), gains=gains)
        sim.place(0, np.array([[0.0, 0.0, 2.0]]))
        quat = p.getQuaternionFromEuler([0.2, 0.0, 0.0])
        p.resetBasePositionAndOrientation(sim.world.drones[0], [0, 0, 2], quat, physicsClientId=sim.client)
        sim._read_state()
        rates = []
        for _ in range(36):
            sim.step(np.zeros((1, 1, 3)))
            rates.append(np.abs(sim.ang_vel[0, 0]).max())
        return max(rates[24:]), np.abs(sim.quat[0, 0, :3]).max()

    rate, tilt = rate_after_tilt(PIDGains())
    assert rate < 0.05 and tilt < 0.005
    rate, _ = rate_after_tilt(PIDGains(att_d=(20000, 20000, 12000)))
    assert rate > 0.2  # still oscillating 1 to 1.5 s after the tilt


def test_the_held_out_published_gains_hover_and_tilt_far_past_the_default_limit():
    """The transfer matrix's held-out tracker: gym-pybullet-drones' published attitude gains and torque clip
    (docs/references.md, written out here) and no tilt limit. Over bare physics at 48 Hz it hovers at the thrust
    balance; chasing 3 m/s sideways our default tracker stops at its 30 degrees, the held-out one tilts twice as far."""
    assert PUBLISHED_DSL_GAINS.att_p == (70000, 70000, 60000) and PUBLISHED_DSL_GAINS.att_d == (20000, 20000, 12000)
    assert PUBLISHED_DSL_GAINS.torque_limit == 3200 and PUBLISHED_DSL_GAINS.pos_p == (0.4, 0.4, 1.25)

    def hover_and_tilt(gains):
        sim = CrazyflieSwarm(
            TaskConfig(num_drones=1), PlatformConfig(), physics=PhysicsConfig.preset("bare"), gains=gains
        )
        try:
            start = np.array([[0.3, -0.2, 1.5]])
            sim.place(0, start)
            pos, _ = fly(sim, np.zeros((1, 3)), 5 * 24)
            drift, rpm = np.abs(pos[:, 0] - start).max(), np.mean(sim.rpm[0])
            sim.place(0, np.array([[0.0, 0.0, 1.5]]))
            tilts = []
            for _ in range(24):
                sim.step(np.array([[[3.0, 0.0, 0.0]]]))
                tilts.append(tilt_deg(sim.quat[0, 0]))
            return drift, rpm, max(tilts)
        finally:
            sim.close()

    drift, rpm, tilt = hover_and_tilt(PUBLISHED_DSL_GAINS)
    assert drift < 0.02 and rpm == pytest.approx(HOVER_RPM, rel=0.01)
    assert tilt > 45.0
    assert hover_and_tilt(PIDGains())[2] < 31.0


def test_drones_side_by_side_stay_put_with_downwash_and_one_below_sinks():
    sim = make_sim(num_drones=2, physics="aero")
    start = np.array([[0.0, 0.0, 1.0], [0.2, 0.0, 1.0]])
    sim.place(0, start)
    pos, _ = fly(sim, np.zeros((2, 3)), 5 * 24)
    assert np.isfinite(pos).all() and np.abs(pos - start).max() < 0.02
    # Directly below another drone, the wake pushes down: with the velocity PID the drone sinks.
    sinking = {}
    for physics in ("bare", "aero"):
        sim = make_sim(num_drones=2, physics=physics)
        sim.place(0, np.array([[0.0, 0.0, 1.0], [0.05, 0.0, 1.3]]))
        pos, _ = fly(sim, np.zeros((2, 3)), 24)
        sinking[physics] = pos[-1, 0, 2] - 1.0
    assert abs(sinking["bare"]) < 0.005 and sinking["aero"] < -0.05


@pytest.mark.parametrize("engine", ["numpy", "auto"])
def test_the_published_state_is_pybullets_own_with_one_sign_per_attitude(engine):
    """pos, quat, vel and ang_vel are what PyBullet reports for each body, the quaternion's sign chosen so that w >= 0
    (q and -q are one attitude); a command array the caller reuses after the step changes nothing in flight, even
    when the commands wait in a latency line."""
    sims = [
        CrazyflieSwarm(
            TaskConfig(num_drones=4),
            PlatformConfig(),
            physics=PhysicsConfig.preset("bare"),
            perturbation={"latency_s": 0.05},
            engine=engine,
        )
        for _ in range(2)
    ]
    # Drone 1 turned 190 degrees about z: PyBullet's quaternion (0, 0, sin 95, cos 95) has w < 0.
    turned = (0.0, 0.0, math.sin(math.radians(95.0)), math.cos(math.radians(95.0)))
    for sim in sims:
        sim.place(0, np.array([[0.0, 0.0, 1.0], [0.5, 0.0, 1.0], [0.0, 0.5, 1.0], [0.5, 0.5, 1.0]]))
        p.resetBasePositionAndOrientation(sim.world.drones[1], [0.5, 0.0, 1.0], turned, physicsClientId=sim.client)
    reused, sim = np.zeros((1, 4, 3)), sims[0]
    rng, flips = np.random.default_rng(3), 0
    for _ in range(12):
        command = rng.uniform(-0.5, 0.5, (1, 4, 3))
        reused[:] = command
        sims[0].step(reused)
        reused[:] = 9.0  # the caller overwrites its array: what is still in the latency line must not change
        sims[1].step(command.copy())
        assert np.array_equal(sims[0].pos, sims[1].pos) and np.array_equal(sims[0].vel, sims[1].vel)
        for i, body in enumerate(sim.world.drones):
            pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=sim.client)
            vel, ang_vel = p.getBaseVelocity(body, physicsClientId=sim.client)
            sign = -1.0 if quat[3] < 0.0 else 1.0
            flips += sign < 0.0
            assert sim.pos[0, i].tolist() == list(pos) and sim.vel[0, i].tolist() == list(vel)
            assert sim.quat[0, i].tolist() == [sign * q for q in quat] and sim.ang_vel[0, i].tolist() == list(ang_vel)
    assert flips > 0 and (sim.quat[0, :, 3] >= 0.0).all()
    for sim in sims:
        sim.close()


# ---------------------------------------------------------------------------- landing


def descend_onto(sim, episodes, target_xy, speed=0.3, steps=48):
    outcome = None
    for _ in range(steps):
        goal = sim.pad_pos[0, 0] if target_xy is None else np.append(target_xy, sim.pad_pos[0, 0, 2])
        error = goal[:2] - sim.pos[0, 0, :2]
        commands = np.zeros((1, sim.num_drones, 3))  # drone 0 descends, the others hover
        commands[0, 0] = np.append(sim.pad_vel[0, 0, :2] + 3.0 * error, -speed)
        outcome = episodes.step(commands / sim.task.max_speed)
        if outcome.done[0]:
            break
    return outcome


@pytest.mark.parametrize("platform", ["static-elevated", "moving-linear"])
def test_landing_on_the_own_pad_latches_the_drone_to_it(platform):
    sim = make_sim(platform=platform, physics="aero")
    episodes = LandingEpisodes(sim, seed=1)
    episodes.reset()
    sim.place(0, sim.pad_pos[0] + [0.0, 0.0, 0.15])
    outcome = descend_onto(sim, episodes, None)
    assert outcome.success[0] and outcome.landed[0, 0]
    assert outcome.landing_error[0, 0] < 0.02
    offset = sim.pos[0, 0] - sim.pad_pos[0, 0]
    sim.step(np.zeros((1, 1, 3)))
    sim.step(np.zeros((1, 1, 3)))
    np.testing.assert_allclose(sim.pos[0, 0] - sim.pad_pos[0, 0], offset, atol=1e-6)
    np.testing.assert_allclose(sim.state().vel[0, 0], sim.pad_vel[0, 0])


def test_touching_another_pad_or_landing_too_fast_is_a_crash():
    sim = make_sim(num_drones=2)
    episodes = LandingEpisodes(sim, seed=2)
    episodes.reset()
    # Drone 0 lands on drone 1's pad.
    sim.place(0, np.vstack([sim.pad_pos[0, 1] + [0.0, 0.0, 0.1], sim.pad_pos[0, 1] + [1.0, 1.0, 1.0]]))
    outcome = descend_onto(sim, episodes, sim.pad_pos[0, 1, :2])
    assert outcome.crashed[0, 0] and not outcome.landed[0, 0] and sim.contact[0, 0] == CONTACT_OTHER
    # Drone 0 hits its own pad at the speed limit: PyBullet stops it, the touchdown speed says crash.
    episodes.reset()
    sim.place(0, np.vstack([sim.pad_pos[0, 0] + [0.0, 0.0, 0.6], sim.pad_pos[0, 1] + [1.0, 1.0, 1.0]]))
    outcome = descend_onto(sim, episodes, None, speed=3.0)
    assert outcome.crashed[0, 0] and not outcome.landed[0, 0]


@pytest.mark.parametrize("sink", [0.0, 0.004, 0.006])
def test_a_drone_sunk_into_its_pad_touches_its_pad_not_the_plate_under_it(sink):
    """The pad is 2.5 mm proud of the plate: a drone that settles deeper also meets the plate's collision box,
    but under its own pad. That contact is the pad; 0.2 m off the pad, on the bare plate, it is not."""
    from marlander_lite.task import CONTACT_OWN_PAD

    sim = make_sim(num_drones=2)
    LandingEpisodes(sim, seed=0).reset()
    rest = sim.task.landed_height - sink
    on_pad, off_pad = sim.pad_pos[0, 0] + [0.03, 0.0, rest], sim.pad_pos[0, 1] + [0.0, 0.2, rest]
    sim.place(0, np.vstack([on_pad, off_pad]))
    sim.contact[...] = 0
    sim.stop_motors(np.array([[True, True]]))
    sim.step(np.zeros((1, 2, 3)))
    assert sim.contact[0].tolist() == [CONTACT_OWN_PAD, CONTACT_OTHER]


def test_an_inclined_plate_in_pybullet_is_tilted_where_the_point_mass_says():
    """Beyond the paper: a plate tilted by 15 degrees about x (its +y edge up). A drone sinking onto its pad lands
    there; one sinking 0.2 m up the slope from the plate centre meets the plate sin(15 deg) x 0.2 m = 5.2 cm higher
    than the plate centre, and crashes (it is off its pad)."""
    from marlander_lite.platforms import PlateGeometry
    from marlander_lite.task import CONTACT_OWN_PAD

    geometry = PlateGeometry(inclination_deg=15.0)
    sim = CrazyflieSwarm(
        TaskConfig(num_drones=2),
        PlatformConfig(kind="static-floor", geometry=geometry),
        physics=PhysicsConfig.preset("bare"),
    )
    episodes = LandingEpisodes(sim, seed=0)
    episodes.reset()
    plate = np.array(sim._plate_pos)
    up_slope = plate + 0.2 * geometry.rotation()[:, 1]
    assert up_slope[2] - plate[2] == pytest.approx(0.2 * np.sin(np.radians(15.0)))
    sim.place(0, np.vstack([sim.pad_pos[0, 0] + [0.0, 0.0, 0.08], up_slope + np.array([0.0, 0.0, 0.08])]))
    touched = {}
    for _ in range(60):
        outcome = episodes.step(np.array([[[0.0, 0.0, -0.1], [0.0, 0.0, -0.1]]]))  # 0.3 m/s down
        for i in range(2):
            if (outcome.landed_now[0, i] or outcome.crashed[0, i]) and i not in touched:
                touched[i] = (sim.pos[0, i].copy(), int(sim.contact[0, i]), float(outcome.landing_error[0, i]))
        if len(touched) == 2:
            break
    (_, contact0, error0), (pos1, contact1, _) = touched[0], touched[1]
    assert contact0 == CONTACT_OWN_PAD and outcome.landed[0, 0] and error0 < 0.02
    assert contact1 == CONTACT_OTHER and not outcome.landed[0, 1]
    # It touches the tilted face above that point (the Crazyflie's lowest corner is 1-3 cm below its centre).
    assert 0.0 < pos1[2] - up_slope[2] < 0.03


def go_to_pad(obs, num_drones, gain=2.0, speed=1.0, below=0.15):
    """A hand-written controller: fly to a cone above the pad, then descend along it at about 0.3 m/s."""
    p = obs.reshape(num_drones, 13)[:, 0:3].copy()
    horizontal = np.linalg.norm(p[:, :2], axis=-1)
    p[:, 2] -= np.minimum(2.0 * horizontal, 1.0) - below
    v = -gain * p
    v *= np.minimum(1.0, speed / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-9))
    return (v / 3.0).reshape(-1).astype(np.float32)


def test_hand_written_controller_lands_both_drones_through_the_mdp():
    env = gym.make(ENV_ID, num_drones=2, platform="static-elevated").unwrapped
    results = []
    for seed in range(4):
        obs, _ = env.reset(seed=seed)
        while True:
            obs, _, terminated, truncated, info = env.step(go_to_pad(obs, 2))
            if terminated or truncated:
                break
        results.append(info)
    env.close()
    assert sum(info["is_success"] for info in results) >= 3
    errors = np.concatenate([info["landing_error"] for info in results if info["is_success"]])
    assert errors.max() < 0.02  # within 2 cm of the pad centre


def test_drone_placed_on_the_floor_rests_there_and_reports_the_contact():
    sim = make_sim(num_drones=2)
    rest = sim.task.landed_height
    sim.place(0, np.array([[1.5, 1.5, rest], [-1.5, -1.5, rest]]))
    sim.stop_motors(np.array([[True, True]]))
    pos, vel = fly(sim, np.zeros((2, 3)), 12)
    np.testing.assert_allclose(pos[-1, :, 2], rest, atol=2e-3)
    assert np.abs(vel[-1]).max() < 1e-3 and (sim.contact[0] == CONTACT_OTHER).all()


# ---------------------------------------------------------------------------- faces


MOVING_EXTRAS = {"observe_platform_velocity": True, "observe_platform_acceleration": True}


@pytest.mark.parametrize(
    "options",
    [{}, {"platform": "moving-arc", "task": MOVING_EXTRAS}, {"task": {**MOVING_EXTRAS, "observation_history": 3}}],
)
def test_gymnasium_and_sb3_checkers_pass(options):
    env = gym.make(ENV_ID, num_drones=2, **options)
    gym_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped)
    env.close()


def test_pettingzoo_checkers_pass():
    parallel_api_test(marlander_lite.make_parallel_env("crazyflie", num_drones=2), num_cycles=60)
    parallel_seed_test(lambda: marlander_lite.make_parallel_env("crazyflie", num_drones=2))


def test_gym_env_is_deterministic_and_instances_do_not_interfere():
    def make():
        env = gym.make(ENV_ID, num_drones=2, platform="moving-arc", sensing="vicon").unwrapped
        env.action_space.seed(7)
        return env, [env.reset(seed=7)[0]]

    def advance(env, trace):
        obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        trace += [obs, np.array([reward])]
        if terminated or truncated:
            trace.append(env.reset()[0])

    (a, trace_a), (b, trace_b) = make(), make()
    for _ in range(40):  # two worlds in one process, stepped in turn
        advance(a, trace_a)
        advance(b, trace_b)
    c, trace_c = make()
    for _ in range(40):  # and one alone
        advance(c, trace_c)
    np.testing.assert_array_equal(np.concatenate(trace_a), np.concatenate(trace_b))
    np.testing.assert_array_equal(np.concatenate(trace_a), np.concatenate(trace_c))


def test_vec_env_is_deterministic_and_reports_success_and_episodes():
    env = marlander_lite.make_vec_env("crazyflie", num_envs=2, seed=5, task={"episode_seconds": 0.5})

    def rollout(seed):
        env.seed(seed)  # each subprocess env i is reset with seed + i
        rng = np.random.default_rng(0)
        obs, ends = [env.reset()], []
        for _ in range(16):
            o, r, done, infos = env.step(rng.uniform(-1, 1, (2, 6)).astype(np.float32))
            obs += [o, r[:, None]]
            ends += [info for info, d in zip(infos, done, strict=True) if d]
        return np.concatenate(obs, axis=1), ends

    try:
        (a, ends), (b, _), (c, _) = rollout(5), rollout(5), rollout(6)
    finally:
        env.close()
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert not np.array_equal(a[0], a[1])  # the two envs got different seeds
    assert ends and all("is_success" in e and {"r", "l", "t"} <= set(e["episode"]) for e in ends)


def test_rgb_array_render_and_video_recording(tmp_path):
    env = gym.make(
        ENV_ID,
        num_drones=2,
        render_mode="rgb_array",
        video_path=tmp_path / "flight.gif",
        task={"episode_seconds": 0.25},
    )
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (360, 480, 3) and frame.dtype == np.uint8 and frame.std() > 5
    for _ in range(6):
        *_, terminated, truncated, _ = env.step(np.zeros(6, dtype=np.float32))
        if terminated or truncated:
            break
    env.close()
    assert (tmp_path / "flight-000.gif").stat().st_size > 1000


# ---------------------------------------------------------------------------- bad input


@pytest.mark.filterwarnings("ignore:.*render_mode")
@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        ({"physics": {"wind": True}}, TypeError, r"\['wind'\].*allowed: physics_hz"),
        ({"physics": "turbulent"}, ValueError, "'turbulent'.*allowed: bare, aero"),
        ({"physics": {"control_hz": 50}}, ValueError, "control_hz=50 Hz must divide physics_hz=240"),
        ({"task": {"policy_hz": 20}}, ValueError, "policy_hz=20 Hz must divide control_hz=48"),
        ({"physics": {"drag": "yes"}}, TypeError, "drag must be True or False"),
        ({"render_mode": "ascii"}, ValueError, "allowed: None, rgb_array, human"),
        ({"propellers": 6}, TypeError, "allowed options"),
        ({"platform": "trampoline"}, ValueError, "allowed: static-floor"),
        ({"controller": "lqr"}, ValueError, "allowed: 'pid', 'firmware'"),
        ({"drone": "cf21"}, TypeError, "drone must be a CF2XParams"),
    ],
)
def test_bad_env_options_raise_clear_errors(kwargs, error, message):
    with pytest.raises(error, match=message):
        gym.make(ENV_ID, **kwargs)


def test_an_options_object_with_face_keywords_builds_the_same_env_as_keywords():
    options = CrazyflieOptions(num_drones=3, physics="bare", controller="firmware", task={"episode_seconds": 1.0})
    by_object = gym.make(ENV_ID, options=options, render_mode="rgb_array").unwrapped
    by_keywords = gym.make(ENV_ID, render_mode="rgb_array", **vars(options)).unwrapped
    for env in (by_object, by_keywords):
        assert env.num_drones == 3 and env.render_mode == "rgb_array" and env.task.episode_seconds == 1.0
        assert env.simulator.controller_kind == "firmware" and env.simulator.physics.aero_effects == ()
    obs = [env.reset(seed=4)[0] for env in (by_object, by_keywords)]
    steps = [env.step(np.full(9, 0.3, dtype=np.float32))[0] for env in (by_object, by_keywords)]
    np.testing.assert_array_equal(obs[0], obs[1])
    np.testing.assert_array_equal(steps[0], steps[1])
    for env in (by_object, by_keywords):
        env.close()
    with pytest.raises(
        TypeError, match=r"\['gui'\]; allowed options: num_drones.*perturbation, firmware_gains, num_envs, seed"
    ):
        marlander_lite.make_vec_env("crazyflie", options=options, gui=True)


def test_bad_actions_and_positions_raise_and_leave_the_env_usable():
    env = gym.make(ENV_ID, num_drones=2).unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([0, 0, np.nan, 0, 0, 0], dtype=np.float32))
    with pytest.raises(ValueError, match=r"\(2, 3\)"):
        env.simulator.place(0, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="one environment"):
        env.simulator.place(1, np.zeros((2, 3)))
    env.step(np.zeros(6, dtype=np.float32))
    with pytest.raises(ValueError, match="num_envs"):
        marlander_lite.make_vec_env("crazyflie", num_envs=0)
    with pytest.raises(TypeError, match="allowed options"):
        marlander_lite.make_vec_env("crazyflie", num_envs=1, gui=True)


def test_the_swarm_reads_its_physics_option_as_the_envs_do():
    """A preset name or a mapping of changes, as ``CrazyflieOptions.physics`` takes them; anything else is refused."""
    for physics, expected in (
        ("bare", PhysicsConfig.preset("bare")),
        ({"control_hz": 24.0}, PhysicsConfig.preset("aero", control_hz=24.0)),
    ):
        sim = CrazyflieSwarm(TaskConfig(num_drones=1), PlatformConfig(), physics=physics)
        try:
            assert sim.physics == expected
        finally:
            sim.close()
    with pytest.raises(TypeError, match="physics must be a PhysicsConfig"):
        CrazyflieSwarm(TaskConfig(num_drones=1), PlatformConfig(), physics=42)


def test_controller_rejects_gains_it_cannot_use():
    with pytest.raises(ValueError, match="att_d"):
        CascadedPID(CF2XParams(), PIDGains(att_d=(0.0, 1.0, 1.0)), 1, 1 / 48)
    with pytest.raises(ValueError, match="mass"):
        CF2XParams(mass=-1.0)


def test_the_bare_step_loop_runs_the_swarms_physics_without_gravity_and_puts_gravity_back():
    """``timing.bare_step_loop``, what the speed target is measured against: one policy step of physics in which a drone
    at rest stays put (no gravity, no thrust), after which gravity acts again (a drone without thrust falls)."""
    from marlander_lite.crazyflie.timing import bare_step_loop, hover_grid

    sim = make_sim(num_drones=2)
    grid = hover_grid(2)
    assert grid.shape == (2, 3) and np.all(grid[:, 2] == 1.5) and np.linalg.norm(grid[0] - grid[1]) == 0.5
    sim.place(0, grid)
    loop = bare_step_loop(sim)
    for _ in range(24):
        loop()
    for body, start in zip(sim.world.drones, grid, strict=True):
        pos, _ = p.getBasePositionAndOrientation(body, physicsClientId=sim.client)
        assert np.allclose(pos, start, atol=1e-9)
    p.stepSimulation(physicsClientId=sim.client)  # 1/48 s with gravity and no force: v = -g t
    vel, _ = p.getBaseVelocity(sim.world.drones[0], physicsClientId=sim.client)
    assert vel[2] == pytest.approx(-G / sim.physics.control_hz, rel=1e-6)
    sim.close()
