"""The firmware velocity tracker and the perturbations of the PyBullet Crazyflie ("Policies that transfer").

Checks against the firmware's published constants (written out here, not read from the code)
and textbook laws: thrust balance in hover, the per-axis 20 degree tilt clamp, the level-flight
acceleration bound ``g tan(tilt)``, free fall, and what each perturbation must do to a response.
Firmware runs sample at 240 Hz (``policy_hz = 240``: one action per tick) so no peak is missed.
"""

import dataclasses
import math

import gymnasium as gym
import numpy as np
import pybullet as p
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env

import marlander_lite
from marlander_lite.crazyflie import CONTROLLERS, CF2XParams, CrazyflieSwarm, Perturbation, PhysicsConfig
from marlander_lite.crazyflie.firmware import FirmwareGains, rate_loop_spectral_radius
from marlander_lite.platforms import PlatformConfig
from marlander_lite.task import TaskConfig

ENV_ID = "marlander_lite/CrazyflieLanding-v0"
G = 9.81
TILT_LIMIT_DEG = 20.0  # rpLimit in position_controller_pid.c
THRUST_BASE = 36000.0  # thrustBase, PWM
START = np.array([[0.0, 0.0, 2.0]])


def make_sim(controller="firmware", physics="bare", policy_hz=None, **perturbation):
    """One drone; by default sampled once per control tick (240 Hz firmware, 48 Hz PID)."""
    hz = policy_hz or (240.0 if controller == "firmware" else 48.0)
    return CrazyflieSwarm(
        TaskConfig(num_drones=1, policy_hz=hz),
        PlatformConfig(),
        physics=PhysicsConfig.preset(physics),
        controller=controller,
        perturbation=perturbation,
    )


def fly(sim, commands):
    """Place at START, then one action per row of ``commands`` ``(T, 3)`` m/s.

    Returns time (s), positions, velocities ``(T, 3)``, Euler roll and pitch (deg, ``(T, 2)``) and
    the collective thrust ``k_f sum w^2`` (N, ``(T,)``) after each action."""
    sim.place(0, START)
    pos, vel, euler, thrust = [], [], [], []
    for command in np.asarray(commands, dtype=float):
        sim.step(command[None, None])
        pos.append(sim.pos[0, 0].copy())
        vel.append(sim.vel[0, 0].copy())
        euler.append(p.getEulerFromQuaternion(sim.quat[0, 0].tolist())[:2])
        thrust.append(sim.params.kf * np.sum(np.square(sim.rpm[0])))
    t = np.arange(1, len(pos) + 1) * sim.task.dt
    return t, np.array(pos), np.array(vel), np.degrees(euler), np.array(thrust)


def crossing(t, y, level):
    """First time (s) ``y`` reaches ``level``, linearly interpolated between samples."""
    k = int(np.argmax(y >= level))
    assert y[k] >= level, "the response never reached the level"
    if k == 0:
        return t[0]
    return t[k - 1] + (level - y[k - 1]) / (y[k] - y[k - 1]) * (t[k] - t[k - 1])


def steps(command, seconds, hz):
    return np.repeat(np.asarray(command, dtype=float)[None], round(seconds * hz), axis=0)


# ---------------------------------------------------------------------------- the loops


def test_rate_loop_needs_its_d_filter_or_a_motor_lag_to_be_stable():
    params, gains = CF2XParams(), FirmwareGains()
    unfiltered = dataclasses.replace(gains, rate_d_cutoff_hz=0.0)
    # Instant rotors: the unfiltered discrete D term diverges at any rate, the firmware's 30 Hz filter fixes it.
    for hz in (240, 500):
        assert rate_loop_spectral_radius(params, unfiltered, hz)[:2].min() > 1.2
        assert rate_loop_spectral_radius(params, gains, hz).max() < 0.92
    # A real rotor lag (20 ms) makes the firmware's default (no filter) stable too.
    assert rate_loop_spectral_radius(params, unfiltered, 240, motor_time_constant=0.02).max() < 0.95


def test_firmware_hovers_with_the_thrust_balance_warm_and_after_a_cold_start():
    sim = make_sim()
    t, pos, _, _, thrust = fly(sim, steps((0, 0, 0), 5.0, 240))
    assert np.abs(pos - START).max() < 0.01
    assert thrust.mean() == pytest.approx(0.027 * G, rel=0.02)
    # Cold: the z integrator starts at the firmware's thrust base, 2,725 PWM short of our hover.
    sim.controller.warm_start_pwm = THRUST_BASE
    t, pos, _, _, thrust = fly(sim, steps((0, 0, 0), 8.0, 240))
    settled = t > 3.0
    assert 0.1 < START[0, 2] - pos[:, 2].min() < 0.3  # sinks 2725 / (1000 ki) = 18 cm, ki = 15
    assert np.ptp(pos[settled, 2]) < 0.04  # then holds its height within a few cm for 5 s (2.8 cm)
    assert thrust[settled].mean() == pytest.approx(0.027 * G, rel=0.02)


@pytest.mark.parametrize("controller", CONTROLLERS)
@pytest.mark.parametrize(("command", "axis"), [((1.0, 0, 0), 0), ((0, 1.0, 0), 1), ((0, 0, 0.5), 2), ((0, 0, -0.5), 2)])
def test_step_responses_are_tracked_within_fifteen_percent_after_one_and_a_half_seconds(controller, command, axis):
    sim = make_sim(controller, physics="aero")
    t, _, vel, _, _ = fly(sim, steps(command, 2.5, sim.task.policy_hz))
    y = vel[:, axis] / command[axis]
    assert np.abs(y[t >= 1.5] - 1.0).max() < 0.15
    rise = crossing(t, y, 0.9) - crossing(t, y, 0.1)
    assert rise < (0.5 if axis < 2 else 0.3)  # firmware 0.35 / 0.2 s, PID 0.2 / 0.08 s
    others = [k for k in range(3) if k != axis]
    assert np.abs(vel[:, others]).max() < 0.1


def test_tilt_stays_within_the_firmware_clamp_during_aggressive_commands():
    hz = 240.0
    level = np.concatenate([steps((3, 0, 0), 1, hz), steps((-3, 0, 0), 1, hz), steps((0, 3, 0), 1, hz)])
    combined = np.concatenate([steps((3, 3, 1), 1, hz), steps((-3, -3, -1), 1, hz), steps((0, 0, 0), 0.5, hz)])
    sim = make_sim()
    _, _, _, euler, _ = fly(sim, np.concatenate([level, combined]))
    # Roll and pitch setpoints are clamped to 20 deg each; the attitude loop overshoots them by < 2 deg.
    assert np.abs(euler).max() < TILT_LIMIT_DEG + 2.0
    assert np.abs(euler).max() > TILT_LIMIT_DEG - 1.0  # the clamp is reached
    # Along one axis that is the whole tilt (along a diagonal both add: up to 30 deg, as in the firmware).
    _, _, _, euler, _ = fly(sim, level)
    tilt = np.degrees(np.arccos(np.cos(np.radians(euler[:, 0])) * np.cos(np.radians(euler[:, 1]))))
    assert tilt.max() < TILT_LIMIT_DEG + 2.0


def test_horizontal_acceleration_is_bounded_by_g_tan_tilt_in_level_flight():
    hz = 240.0
    commands = np.concatenate([steps((3, 0, 0), 1, hz), steps((-3, 0, 0), 1, hz), steps((0, 0, 0), 1, hz)])
    sim = make_sim()
    _, pos, vel, _, _ = fly(sim, commands)
    accel = np.linalg.norm(np.diff(vel[:, :2], axis=0), axis=1) * hz
    bound = G * math.tan(math.radians(TILT_LIMIT_DEG))  # 3.57 m/s^2
    assert accel.max() > 0.9 * bound  # the reversal uses the full tilt
    assert accel.max() < 1.2 * bound  # measured 4.06: 1.6 deg of attitude overshoot, thrust transients
    assert np.ptp(pos[:, 2]) < 0.1  # level flight


def test_motors_off_the_firmware_drone_falls_freely():
    sim = make_sim(policy_hz=24.0)
    sim.place(0, START)
    sim.stop_motors(np.array([[True]]))
    for k in range(1, 8):
        sim.step(np.zeros((1, 1, 3)))
        t = k * sim.task.dt
        assert sim.pos[0, 0, 2] == pytest.approx(2.0 - 0.5 * G * t * t, abs=0.01)
    np.testing.assert_allclose(sim.pos[0, 0, :2], [0.0, 0.0], atol=1e-9)


# ---------------------------------------------------------------------------- perturbations


def test_heavier_drone_still_hovers_its_integrator_absorbs_the_weight():
    sim = make_sim(mass_scale=1.15)
    mass, _, inertia, *_ = p.getDynamicsInfo(sim.world.drones[0], -1, physicsClientId=sim.client)
    assert mass == pytest.approx(1.15 * 0.027)
    np.testing.assert_allclose(inertia, 1.15 * np.array([1.4e-5, 1.4e-5, 2.17e-5]))
    assert sim.controller.params.mass == 0.027  # the tracker is not told
    t, pos, _, _, thrust = fly(sim, steps((0, 0, 0), 3.0, 240))
    assert np.abs(pos - START).max() < 0.01  # warm integrator: the drone flew before the episode
    assert thrust.mean() == pytest.approx(1.15 * 0.027 * G, rel=0.02)
    sim.controller.warm_start_pwm = sim.controller.hover_pwm  # cold for the extra 15 %
    t, pos, vel, _, _ = fly(sim, steps((0, 0, 0), 8.0, 240))
    assert 0.1 < START[0, 2] - pos[:, 2].min() < 0.5
    assert np.abs(vel[t > 6.0, 2]).max() < 0.02  # the integrator caught up


@pytest.mark.parametrize("controller", CONTROLLERS)
def test_latency_delays_the_response_by_the_latency(controller):
    hz = 240.0 if controller == "firmware" else 48.0
    times = []
    for latency in (0.0, 0.06):
        t, _, vel, _, _ = fly(make_sim(controller, latency_s=latency), steps((1, 0, 0), 1.0, hz))
        times.append([crossing(t, vel[:, 0], level) for level in (0.1, 0.5)])
    delay = np.diff(times, axis=0)[0]
    tick = 1.0 / hz  # the command line runs at the tick resolution: 14 ticks at 240 Hz, 3 at 48 Hz
    np.testing.assert_allclose(delay, 0.06, atol=tick / 2 + 1e-3)
    if controller == "pid":
        return  # its target p + u dt, computed when sent, is stale on arrival: no pure shift
    # At the policy's 24 Hz (10 ticks per action) the velocity tracker's delayed run is the same run, shifted.
    sims = [make_sim(controller, policy_hz=24.0, latency_s=latency) for latency in (0.0, 1 / 24)]
    commands = np.random.default_rng(1).uniform(-1, 1, (24, 3))
    fast, late = (fly(sim, np.concatenate([commands, np.zeros((1, 3))]))[2] for sim in sims)
    np.testing.assert_allclose(late[1:], fast[:-1], atol=0.03)


@pytest.mark.parametrize("controller", CONTROLLERS)
def test_gain_scale_changes_the_response_speed_in_the_right_direction(controller):
    hz = 240.0 if controller == "firmware" else 48.0
    for command, axis in (((0.3, 0, 0), 0), ((0, 0, 0.3), 2)):  # small steps: below the tilt clamp
        t90 = []
        for gain in (0.7, 1.0, 1.3):
            t, _, vel, _, _ = fly(make_sim(controller, gain_scale=gain), steps(command, 1.5, hz))
            t90.append(crossing(t, vel[:, axis] / command[axis], 0.9))
        assert t90[0] > 1.05 * t90[1] > 1.05 * t90[2], (command, t90)


def test_nominal_perturbation_leaves_the_pid_bit_identical():
    rng = np.random.default_rng(0)
    commands = rng.uniform(-2, 2, (48, 3))
    plain = CrazyflieSwarm(TaskConfig(num_drones=1), PlatformConfig())
    nominal = CrazyflieSwarm(TaskConfig(num_drones=1), PlatformConfig(), controller="pid", perturbation=Perturbation())
    for a, b in zip(fly(plain, commands), fly(nominal, commands), strict=True):
        np.testing.assert_array_equal(a, b)


# ---------------------------------------------------------------------------- options and faces


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        ({"controller": "mellinger"}, ValueError, "'mellinger'.*allowed: 'pid', 'firmware'"),
        ({"perturbation": {"latency_s": -0.01}}, ValueError, "latency_s must be >= 0"),
        ({"perturbation": {"latency_s": float("nan")}}, ValueError, "latency_s must be a finite number"),
        ({"perturbation": {"latency_s": 0.6}}, ValueError, "latency_s must be >= 0 s and <= 0.5 s"),
        ({"perturbation": {"mass_scale": 0}}, ValueError, r"mass_scale must be in \[0.5, 2\]"),
        ({"perturbation": {"gain_scale": 0.0}}, ValueError, r"gain_scale must be in \(0, 5\]"),
        ({"perturbation": {"wind": 3.0}}, TypeError, r"\['wind'\].*allowed: mass_scale, latency_s, gain_scale"),
        ({"perturbation": 1.15}, TypeError, "perturbation must be a Perturbation"),
    ],
)
def test_bad_controller_and_perturbation_options_raise_clear_errors(kwargs, error, message):
    with pytest.raises(error, match=message):
        gym.make(ENV_ID, **kwargs)
    with pytest.raises(error, match=message):
        marlander_lite.make_vec_env("crazyflie", num_envs=1, vectorization="subprocess", **kwargs)


def test_gymnasium_checker_passes_on_the_firmware_env_and_it_is_deterministic():
    env = gym.make(ENV_ID, num_drones=2, controller="firmware", perturbation={"mass_scale": 1.15, "latency_s": 0.02})
    gym_check_env(env.unwrapped, skip_render_check=True)
    env.close()
    traces = []
    for _ in range(2):
        env = gym.make(ENV_ID, num_drones=2, controller="firmware").unwrapped
        env.action_space.seed(3)
        trace = [env.reset(seed=3)[0]]
        for _ in range(30):
            trace.append(env.step(env.action_space.sample())[0])
        env.close()
        traces.append(np.array(trace))
    np.testing.assert_array_equal(traces[0], traces[1])
    assert env.simulator.controller_kind == "firmware"


def test_vec_and_parallel_faces_take_the_new_options():
    vec = marlander_lite.make_vec_env(
        "crazyflie", num_envs=2, seed=0, num_drones=2, controller="firmware", perturbation={"gain_scale": 1.3}
    )
    obs = vec.reset()
    obs, *_ = vec.step(np.zeros((2, 6), dtype=np.float32))
    assert obs.shape == (2, 26) and np.isfinite(obs).all()
    swarm = vec.simulator.swarms[0]
    assert swarm.controller_kind == "firmware" and swarm.perturbation == Perturbation(gain_scale=1.3)
    vec.close()
    env = marlander_lite.make_parallel_env("crazyflie", num_drones=2, controller="firmware")
    env.reset(seed=0)
    env.step({agent: np.zeros(3, dtype=np.float32) for agent in env.agents})
    env.close()
