"""The velocity tracker's time constant identified in flight (:mod:`marlander_lite.swarm.tracker_lag`), and the
latency compensation the safety filter and the deployment runner set from it (``identified_lag_share``).

The reference is the exact discrete response of a first-order tracker that holds each command for one policy period:
``v_{k+1} = u_k + exp(-dt / T) (v_k - u_k)``. Flying random commands through it, the identification must return ``T``.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
import yaml

from marlander_lite.deploy.config import EXAMPLE_CONFIG, ConfigError, LabConfig, load_lab_config
from marlander_lite.deploy.estimation import SwarmEstimate
from marlander_lite.deploy.rehearsal import rehearse
from marlander_lite.deploy.runner import PolicyRunner
from marlander_lite.swarm.filtered_policy import with_safety_filter
from marlander_lite.swarm.safety_filter import SafetyFilterConfig
from marlander_lite.swarm.tracker_lag import TIME_CONSTANT_RANGE, TrackerLag
from marlander_lite.task import TaskConfig

DT = 1.0 / 24.0
"""The policy period of every preset (s)."""
QUICK = "data/policies/quick-cpu-smooth-cone2-bench.safetensors"
"""The `quick-cpu-smooth` preset's own run."""


class FirstOrderTracker:
    """``E`` swarms of ``N`` drones 1 m above their goals whose horizontal velocity follows each held command with time
    constant ``T`` (one per swarm, s); optionally ``delay`` policy periods late. Positions follow by the trapezoid rule,
    so a position that moves by more than the velocities explain is a new episode and nothing else."""

    def __init__(self, time_constants: list[float], drones: int = 2, delay: int = 0) -> None:
        self.slope = np.exp(-DT / np.asarray(time_constants))[:, None, None]
        self.p = np.zeros((len(time_constants), drones, 3))
        self.p[..., 2] = 1.0
        self.v = np.zeros_like(self.p)
        self.queue = [np.zeros_like(self.p)] * delay

    def step(self, command: np.ndarray) -> None:
        self.queue.append(command)
        acting = self.queue.pop(0)
        v = acting + self.slope * (self.v - acting)
        v[..., 2] = 0.0  # level flight: only the horizontal axes are identified
        self.p = self.p + 0.5 * (self.v + v) * DT
        self.v = v


class Still:
    """A centralised two-drone policy that commands nothing: the runner tests set the setpoints themselves."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros((1, 6))


def random_commands(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    command = rng.uniform(-1.0, 1.0, shape)
    command[..., 2] = 0.0
    return command


def fly(lag: TrackerLag, plant: FirstOrderTracker, steps: int, seed: int = 0) -> np.ndarray:
    """``steps`` policy periods of random commands (a new one every 6 periods); the identified time constants."""
    rng = np.random.default_rng(seed)
    command = random_commands(rng, plant.p.shape)
    time_constants = lag.time_constant()
    for k in range(steps):
        time_constants = lag.observe(plant.p, plant.v)
        if k % 6 == 0:
            command = random_commands(rng, plant.p.shape)
        lag.commanded(command)
        plant.step(command)
    return time_constants


def test_it_returns_the_time_constant_of_a_first_order_tracker() -> None:
    """Three swarms with trackers of 0.1, 0.3 and 0.8 s (the fast PyBullet PID to PyFlyt's slow one), 10 s each."""
    truth = [0.1, 0.3, 0.8]
    identified = fly(TrackerLag(prior=0.24, dt=DT), FirstOrderTracker(truth), steps=240)
    np.testing.assert_allclose(identified, truth, rtol=0.02)


def test_a_delay_reads_as_a_longer_lag() -> None:
    """A command that acts one period late is a tracker that answers later: the first-order fit is slower than the
    undelayed one, which is what the latency compensation has to cover."""
    prompt = fly(TrackerLag(0.24, DT), FirstOrderTracker([0.2]), steps=240)
    late = fly(TrackerLag(0.24, DT), FirstOrderTracker([0.2], delay=1), steps=240)
    assert late[0] > prompt[0] + DT / 2


def test_before_any_sample_and_after_a_new_episode_it_is_the_prior() -> None:
    lag, plant = TrackerLag(prior=0.24, dt=DT), FirstOrderTracker([0.8, 0.8])
    np.testing.assert_array_equal(lag.time_constant(), [0.24])
    identified = fly(lag, plant, steps=240)
    np.testing.assert_allclose(identified, 0.8, rtol=0.02)
    plant.p[1, :, :2] += 1.0  # swarm 1 starts a new episode a metre away; swarm 0 flies on
    lag.commanded(np.zeros_like(plant.p))
    plant.step(np.zeros_like(plant.p))
    plant.p[1, :, :2] += 1.0
    identified = lag.observe(plant.p, plant.v)
    assert identified[0] == pytest.approx(0.8, rel=0.02) and identified[1] == pytest.approx(0.24)


def test_drones_at_their_goal_height_give_no_sample() -> None:
    """A drone on its pad does not move whatever it is told: read as a tracker, it would be infinitely slow."""
    lag = TrackerLag(prior=0.24, dt=DT)
    on_pad = np.zeros((1, 2, 3))
    on_pad[..., 2] = 0.01
    for _ in range(50):
        lag.observe(on_pad, np.zeros_like(on_pad))
        lag.commanded(np.tile([1.0, -1.0, 0.0], (1, 2, 1)))
    assert lag.observe(on_pad, np.zeros_like(on_pad))[0] == pytest.approx(0.24)


def test_skip_takes_no_sample_across_a_pause() -> None:
    lag = TrackerLag(prior=0.24, dt=DT)
    still = np.zeros((1, 1, 3))
    still[..., 2] = 1.0
    lag.observe(still, np.zeros_like(still))
    lag.commanded(np.array([[[1.0, 0.0, 0.0]]]))
    lag.skip()  # the drone did not follow: without the skip that would read as the slowest tracker
    assert lag.observe(still, np.zeros_like(still))[0] == pytest.approx(0.24)
    lag.commanded(np.array([[[1.0, 0.0, 0.0]]]))
    assert lag.observe(still, np.zeros_like(still))[0] > 0.24


def test_bad_input_is_refused_with_what_is_allowed() -> None:
    low, high = TIME_CONSTANT_RANGE
    with pytest.raises(ValueError, match=rf"prior time constant within \[{low}, {high}\] s.*got prior=5.0"):
        TrackerLag(prior=5.0, dt=DT)
    lag = TrackerLag(prior=0.24, dt=DT)
    with pytest.raises(ValueError, match=r"records the command for the state of the last observe\(\) call"):
        lag.commanded(np.zeros((1, 2, 3)))
    with pytest.raises(ValueError, match=r"needs \(E, N, 3\) arrays of one shape"):
        lag.observe(np.zeros((2, 3)), np.zeros((2, 3)))
    lag.observe(np.ones((1, 2, 3)), np.zeros((1, 2, 3)))
    with pytest.raises(ValueError, match=r"of its shape \(1, 2, 3\); got \(2, 3\)"):
        lag.commanded(np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"identified_lag_share must be within \[0, 2\].*latency_compensation=0.0"):
        SafetyFilterConfig(identified_lag_share=0.5)  # no latency_compensation: no prior to start from
    with pytest.raises(ValueError, match=r"identified_lag_share must be within \[0, 2\].*Try identified_lag_share=0.5"):
        SafetyFilterConfig(latency_compensation=0.12, identified_lag_share=3.0)
    config = SafetyFilterConfig(latency_compensation=0.12, identified_lag_share=0.5)
    with pytest.raises(ValueError, match=r"needs the policy period \(policy_dt\)"):
        with_safety_filter(lambda obs: obs[:, :3], 1, np.zeros((1, 3)), 1.0, config)
    with pytest.raises(ValueError, match=r"on moving pads, each pad.s velocity \(the tracker is identified"):
        with_safety_filter(lambda obs: obs[:, :3], 1, np.zeros((1, 3)), 1.0, config, policy_dt=DT, pads_move=True)


def test_the_simulators_filter_predicts_by_the_share_of_the_identified_lag() -> None:
    """Through :func:`with_safety_filter` with ``identified_lag_share`` 0.5 the policy reads each env's ``p``
    predicted ``L`` ahead, ``p + v L``: ``L`` is 0.12 s (the setting) at the first step and, after 10 s of flight
    through 0.3 s and 0.8 s trackers, half of each (0.15 and 0.4 s). The commands sent are the policy's random ones
    (nothing near). A :class:`TrackerLag` passed in is the one it identifies with."""
    config = SafetyFilterConfig(latency_compensation=0.12, identified_lag_share=0.5, cone_slope=0.0)
    config = dataclasses.replace(config, touchdown_speed=0.0, centring_gain=0.0)
    plant, rng, seen = FirstOrderTracker([0.3, 0.8], drones=1), np.random.default_rng(1), []
    plant.p[..., 0] = 5.0  # far from its goal: only the latency compensation changes what the policy reads
    commands = random_commands(rng, plant.p.shape)

    def policy(obs: np.ndarray) -> np.ndarray:
        seen.append(obs.copy())
        return commands.reshape(len(obs), 3)

    lag = TrackerLag(prior=0.24, dt=DT)
    act = with_safety_filter(policy, 1, np.zeros((1, 3)), 1.0, config, policy_dt=DT, tracker_lag=lag)

    def lead() -> np.ndarray:
        """The ``L`` the last observation was predicted by, per env (s), from its horizontal ``p`` and ``v``."""
        obs = np.concatenate([plant.p, np.zeros((2, 1, 4)), plant.v, np.zeros((2, 1, 3))], axis=-1).reshape(2, 13)
        obs[:, 6] = 1.0
        sent = act(obs).reshape(plant.p.shape)
        moved = seen[-1][:, :2] - plant.p[:, 0, :2]
        return (moved * plant.v[:, 0, :2]).sum(axis=-1) / (plant.v[:, 0, :2] ** 2).sum(axis=-1), sent

    plant.v[..., :2] = 0.5
    first, sent = lead()
    np.testing.assert_allclose(first, [0.12, 0.12])
    for k in range(240):
        plant.step(sent)
        if k % 6 == 0:
            commands = random_commands(rng, plant.p.shape)
        latency, sent = lead()
    np.testing.assert_allclose(latency, [0.15, 0.4], rtol=0.03)
    np.testing.assert_allclose(lag.time_constant(), 2 * latency)


def test_the_runner_sets_its_latency_compensation_from_the_setpoints_it_sent() -> None:
    """The deployment runner identifies the tracker from :attr:`PolicyRunner.previous_command` (what the mission sent)
    and the estimates of successive policy steps. A 0.6 s tracker: ``L`` goes from the setting, 0.12 s, to 0.3 s. A
    step of two policy periods (a pause) gives no sample."""
    config = SafetyFilterConfig(latency_compensation=0.12, identified_lag_share=0.5)

    runner = PolicyRunner(Still(), TaskConfig(num_drones=2), 1.0, config)
    plant, rng = FirstOrderTracker([0.6]), np.random.default_rng(2)
    goals = np.zeros((2, 3))
    zeros = np.zeros((2, 3))

    def estimate(t: float) -> SwarmEstimate:
        return SwarmEstimate(
            t, plant.p[0] + goals, np.tile([0.0, 0.0, 0.0, 1.0], (2, 1)), plant.v[0], zeros, goals, zeros, goals,
            np.zeros(2), np.zeros(2), np.zeros(2, bool), np.zeros(2, bool),
        )  # fmt: skip

    assert runner.latency_compensation == 0.12
    runner.observe(estimate(0.0))
    runner.previous_command = np.tile([1.0, 0.0, 0.0], (2, 1))  # sent, but the drones did not follow: a pause
    runner.observe(estimate(3 * DT))  # three periods on: no sample, or the tracker would read as the slowest
    assert runner.latency_compensation == pytest.approx(0.12)
    for k in range(4, 244):
        if k % 6 == 0:
            runner.previous_command = random_commands(rng, (2, 3))
        plant.step(runner.previous_command[None])
        runner.observe(estimate(k * DT))
    assert runner.latency_compensation == pytest.approx(0.3, rel=0.03)


def test_the_lab_config_takes_the_share_and_says_what_it_needs() -> None:
    """``safety_filter.identified_lag_share`` in a lab config reaches the runner; without a latency compensation to
    start from it is refused with the section's name and what to set."""
    example = yaml.safe_load(EXAMPLE_CONFIG.read_text())
    example["safety_filter"] = {"latency_compensation": 0.12, "identified_lag_share": 0.5}
    config = LabConfig.from_dict(example).safety_filter.filter_config()
    assert (config.latency_compensation, config.identified_lag_share) == (0.12, 0.5)
    runner = PolicyRunner(None, TaskConfig(num_drones=2), 1.0, config)  # type: ignore[arg-type]
    assert runner.tracker_lag is not None and runner.tracker_lag.prior == pytest.approx(0.24)
    example["safety_filter"] = {"identified_lag_share": 0.5}
    with pytest.raises(ConfigError, match=r"safety_filter.*identified_lag_share.*latency_compensation=0.0"):
        LabConfig.from_dict(example)
    example["safety_filter"] = {"latency_compensation": 0.12, "identified_lag_share": 2.5}
    with pytest.raises(ConfigError, match=r"identified_lag_share: Input should be less than or equal to 2"):
        LabConfig.from_dict(example)


def test_a_rehearsal_logs_what_it_identified_and_lands() -> None:
    """The example lab through the PyBullet firmware tracker with ``identified_lag_share`` 0.5: the mission logs a
    ``tracker_lag`` event whenever the compensation has moved 0.05 s from the one last logged (the setting, 0.12 s, at
    first), each with ``L = 0.5 T``, and both drones land on their pads."""
    lab = load_lab_config(EXAMPLE_CONFIG)
    section = lab.safety_filter.with_settings({"latency_compensation": 0.12, "identified_lag_share": 0.5})
    result = rehearse(lab.replace(safety_filter=section), QUICK, simulator="crazyflie", seed=0)
    assert result.passed and all(result.mission.on_pad), result.summary()
    logged = [e for e in result.mission.events if e.kind == "tracker_lag"]
    assert logged, result.summary()
    values = [tuple(map(float, re.findall(r"(\d+\.\d+) s", e.message))) for e in logged]
    assert all(latency == pytest.approx(min(0.5 * lag, 0.5), abs=0.008) for lag, latency in values)  # 2 decimals
    steps = np.diff([0.12] + [latency for _, latency in values])  # from the setting, then event to event
    assert (np.abs(steps) >= 0.05 - 0.011).all(), values


def test_a_drone_motion_capture_lost_gives_no_sample() -> None:
    """A NaN position or velocity (a marker lost) is no sample, and the estimate stays finite: the other drone of the
    swarm still identifies the tracker."""
    lag, plant = TrackerLag(prior=0.24, dt=DT), FirstOrderTracker([0.6])
    rng = np.random.default_rng(3)
    for k in range(240):
        seen_p, seen_v = plant.p.copy(), plant.v.copy()
        if k % 3 == 0:
            seen_p[0, 1], seen_v[0, 1] = np.nan, np.nan
        identified = lag.observe(seen_p, seen_v)
        assert np.isfinite(identified).all()
        lag.commanded(command := random_commands(rng, plant.p.shape))
        plant.step(command)
    assert identified[0] == pytest.approx(0.6, rel=0.03)


def test_the_velocity_step_grows_with_the_identified_time_constant_by_hand() -> None:
    """``low_velocity_step * max(1, T / low_velocity_step_lag)``: 0.5 m/s at 0.45 s is 1.0 m/s at 0.9 s and stays 0.5
    m/s for a faster tracker; off, or before any time constant, it is ``low_velocity_step``. Without a step to scale,
    or with a reference outside the identifiable range, the setting is refused and says what to set."""
    config = SafetyFilterConfig(low_velocity_step=0.5, low_velocity_step_lag=0.45)
    np.testing.assert_allclose(config.velocity_step(np.array([0.3, 0.45, 0.9])), [0.5, 0.5, 1.0])
    assert config.velocity_step(None) == 0.5
    assert SafetyFilterConfig(low_velocity_step=0.5).velocity_step(0.9) == 0.5
    assert config.tracker_lag(DT) is not None and config.tracker_lag(DT).prior == pytest.approx(0.45)
    both = dataclasses.replace(config, latency_compensation=0.12, identified_lag_share=0.5)
    assert both.tracker_lag(DT).prior == pytest.approx(0.24)  # the share's prior: one identification serves both
    with pytest.raises(ValueError, match=r"low_velocity_step_lag must be 0 \(off\) or within .* low_velocity_step > 0"):
        SafetyFilterConfig(low_velocity_step_lag=0.45)
    with pytest.raises(ValueError, match=r"Try low_velocity_step=0.5 with low_velocity_step_lag=0.45"):
        SafetyFilterConfig(low_velocity_step=0.5, low_velocity_step_lag=3.0)


def test_the_simulators_filter_scales_the_step_by_the_tracker_it_identified() -> None:
    """A drone 0.1 m above its goal (below the guards' 0.3 m), at rest, told to fly off at 2 m/s: the filter lets its
    command differ from its velocity by 0.5 m/s when the tracker reads as 0.3 s, by 1.0 m/s when it reads as 0.9 s
    (the identification's prior, before any sample), and the speed of the filtered command says which."""
    config = SafetyFilterConfig(low_velocity_step=0.5, low_velocity_step_lag=0.45, centring_gain=0.0)
    obs = np.zeros((1, 13))
    obs[0, 2], obs[0, 6] = 0.1, 1.0
    speeds = {}
    for prior in (0.3, 0.9):
        act = with_safety_filter(
            lambda o: np.array([[2.0 / 3.0, 0.0, 0.0]]), 1, np.zeros((1, 3)), 3.0, config, policy_dt=DT,
            tracker_lag=TrackerLag(prior, DT),
        )  # fmt: skip
        speeds[prior] = float(np.hypot(*(act(obs)[0, :2] * 3.0)))
    assert speeds[0.3] == pytest.approx(0.5)
    assert speeds[0.9] == pytest.approx(1.0)


def test_the_runner_scales_its_velocity_step_by_the_tracker_it_identified() -> None:
    """The deployment runner identifies a 0.9 s tracker from the setpoints it sent (10 s of random ones) and grows the
    step from 0.5 to about 1.0 m/s; a drone low over its pad, at rest and told 2 m/s, is then sent about 1.0 m/s."""
    config = SafetyFilterConfig(low_velocity_step=0.5, low_velocity_step_lag=0.45, centring_gain=0.0)

    runner = PolicyRunner(Still(), TaskConfig(num_drones=2), 3.0, config)
    plant, rng = FirstOrderTracker([0.9]), np.random.default_rng(4)
    goals, zeros = np.array([[-0.5, 0.0, 0.0], [0.5, 0.0, 0.0]]), np.zeros((2, 3))

    def estimate(t: float, pos: np.ndarray, vel: np.ndarray) -> SwarmEstimate:
        return SwarmEstimate(
            t, pos, np.tile([0.0, 0.0, 0.0, 1.0], (2, 1)), vel, zeros, goals, zeros, goals,
            np.zeros(2), np.zeros(2), np.zeros(2, bool), np.zeros(2, bool),
        )  # fmt: skip

    assert runner.velocity_step == 0.5
    runner.observe(estimate(0.0, plant.p[0] + goals, plant.v[0]))
    for k in range(1, 241):
        if k % 6 == 1:
            runner.previous_command = random_commands(rng, (2, 3))
        plant.step(runner.previous_command[None])
        runner.observe(estimate(k * DT, plant.p[0] + goals, plant.v[0]))
    assert runner.velocity_step == pytest.approx(1.0, rel=0.05)
    low = estimate(241 * DT, goals + np.array([0.0, 0.0, 0.1]), zeros)
    sent, _ = runner.filter_velocity(np.array([[-2.0, 0.0, 0.0], [2.0, 0.0, 0.0]]), low, np.zeros(2, bool))  # apart
    np.testing.assert_allclose(np.abs(sent[:, 0]), runner.velocity_step, rtol=1e-9)


def test_a_rehearsal_logs_the_velocity_step_it_identified_and_lands() -> None:
    """With ``low_velocity_step_lag`` the mission logs a ``tracker_lag`` event whenever the step has moved 0.1 m/s from
    the one last logged (the setting at first), each with ``step = 0.5 max(1, T / 0.2 s)`` for the lag ``T`` it
    identified; the latency compensation stays the setting, and both drones land. (0.2 s, below the firmware tracker's
    lag, so that the step does move.)"""
    lab = load_lab_config(EXAMPLE_CONFIG)
    section = lab.safety_filter.with_settings({"low_velocity_step": 0.5, "low_velocity_step_lag": 0.2})
    result = rehearse(lab.replace(safety_filter=section), QUICK, simulator="crazyflie", seed=0)
    assert result.passed and all(result.mission.on_pad), result.summary()
    logged = [e.message for e in result.mission.events if e.kind == "tracker_lag"]
    assert logged, result.summary()
    for message in logged:
        lag, latency = map(float, re.findall(r"(\d+\.\d+) s", message))
        step = float(re.findall(r"velocity step (\d+\.\d+) m/s", message)[0])
        assert latency == 0.0
        assert step == pytest.approx(0.5 * max(1.0, lag / 0.2), abs=0.02)  # two decimals of each


def test_restart_begins_the_envs_given_afresh_and_keeps_the_others() -> None:
    """A new episode in one env of a batch (``LandingEpisodes.reset(ids)``): that env is the prior again and its next
    sample starts from its new state, as if the jump had been detected; the other env keeps its 0.8 s."""
    lag, plant = TrackerLag(prior=0.24, dt=DT), FirstOrderTracker([0.8, 0.8])
    fly(lag, plant, steps=240)
    plant.p[1, :, :2] += 0.1  # a start 10 cm away: too close for the jump detection to see a new episode
    plant.v[1] = 0.0
    lag.restart(np.array([1]), plant.p[1:], plant.v[1:])
    np.testing.assert_allclose(lag.time_constant(), [0.8, 0.24], rtol=0.02)
    identified = fly(lag, plant, steps=240, seed=1)
    np.testing.assert_allclose(identified, 0.8, rtol=0.02)


def test_restart_before_any_sample_must_name_every_env() -> None:
    still = np.zeros((2, 1, 3))
    still[..., 2] = 1.0
    lag = TrackerLag(prior=0.24, dt=DT)
    with pytest.raises(ValueError, match=r"before the first observe\(\) must restart every env"):
        lag.restart(np.array([1]), still[1:], still[1:])
    lag.restart(np.arange(2), still, np.zeros_like(still))
    lag.commanded(np.zeros_like(still))  # the state is recorded: a command may follow
    np.testing.assert_allclose(lag.time_constant(), [0.24, 0.24])
