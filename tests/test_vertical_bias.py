"""The vertical bias identified in flight: against a first-order tracker worked by hand, then against the point mass's
and RotorPy's own steady errors, and through the command line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from marlander_lite.episodes import LandingEpisodes
from marlander_lite.pointmass.family import DynamicsFamily
from marlander_lite.simulators import simulator_entry
from marlander_lite.swarm import vertical_bias
from marlander_lite.swarm.vertical_bias import MAX_BIAS, WARMUP_SAMPLES, VerticalBias

DT = 1 / 24
GRAVITY = 9.81


def _fly_first_order(estimator: VerticalBias, bias: float, time_constant: float, steps: int, height: float = 1.0):
    """A vertical first-order tracker with a steady bias, commanded by a varying ``u``; returns the last velocity."""
    rng = np.random.default_rng(0)
    a = np.exp(-DT / time_constant)
    v = np.zeros((1, 1, 3))
    position = np.array([[[0.0, 0.0, height]]])
    for _ in range(steps):
        estimator.observe(position, v)
        command = estimator.compensate(np.array([[[0.0, 0.0, rng.uniform(-0.5, 0.5)]]]))
        estimator.commanded(command)
        v = v.copy()
        v[..., 2] = command[..., 2] + bias + a * (v[..., 2] - command[..., 2] - bias)
    return v


def test_the_bias_of_a_first_order_tracker_is_found():
    """``v_{k+1} - u_k - b = a (v_k - u_k - b)`` exactly: the fit recovers ``b`` up to its prior's small pull."""
    estimator = VerticalBias(DT)
    _fly_first_order(estimator, bias=0.15, time_constant=0.1, steps=240)
    assert estimator.bias()[0, 0] == pytest.approx(0.15, rel=0.03)
    unbiased = VerticalBias(DT)
    _fly_first_order(unbiased, bias=0.0, time_constant=0.3, steps=240)
    assert abs(unbiased.bias()[0, 0]) < 0.005


def test_nothing_is_cancelled_before_the_warm_up_and_beyond_the_clamp():
    estimator = VerticalBias(DT)
    _fly_first_order(estimator, bias=0.2, time_constant=0.1, steps=WARMUP_SAMPLES)  # one sample short
    assert estimator.bias()[0, 0] == 0.0
    np.testing.assert_array_equal(estimator.compensate(np.ones((1, 1, 3))), np.ones((1, 1, 3)))
    _fly_first_order(estimator, bias=0.2, time_constant=0.1, steps=2)
    assert estimator.bias()[0, 0] > 0.1
    runaway = VerticalBias(DT)
    _fly_first_order(runaway, bias=-1.5, time_constant=0.1, steps=120)
    assert runaway.bias()[0, 0] == -MAX_BIAS


def test_samples_near_the_ground_and_across_a_reset_are_left_out():
    grounded = VerticalBias(DT)
    _fly_first_order(grounded, bias=0.2, time_constant=0.1, steps=120, height=vertical_bias.MIN_HEIGHT / 2)
    assert grounded.bias()[0, 0] == 0.0
    estimator = VerticalBias(DT)
    _fly_first_order(estimator, bias=0.2, time_constant=0.1, steps=120)
    estimator.reset(np.array([0]))
    assert estimator.bias()[0, 0] == 0.0  # a new episode: nothing identified


def test_bad_input_says_what_was_wrong():
    with pytest.raises(ValueError, match="dt > 0"):
        VerticalBias(0.0)
    estimator = VerticalBias(DT)
    with pytest.raises(ValueError, match=r"\(E, N, 3\)"):
        estimator.observe(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"\(E, N, 3\)"):
        estimator.commanded(np.zeros(3))


def _hover(simulator: str, compensate: bool, seconds: float, **options) -> tuple[LandingEpisodes, np.ndarray]:
    """Two drones of ``simulator`` told to hold still (zero world-frame commands) for ``seconds``; returns the
    episodes and the vertical velocities at the end."""
    task = {"vertical_bias_compensation": compensate, "episode_seconds": 30.0}
    options = dict(num_drones=2, platform="static-floor", task=task, sensing="perfect", **options)
    built = simulator_entry(simulator).options_class().from_keywords(options, where="test").build(1)
    world = LandingEpisodes(*built)
    world.seed(0)
    world.reset()
    for _ in range(round(seconds / DT)):
        outcome = world.step(np.zeros((1, 6)))
        assert not outcome.done[0]
    return world, world.sim.state().vel[0, :, 2]


def test_a_light_point_mass_is_held_level():
    """A point mass 15 % lighter than its tracker assumes (vertical time constant 0.2 s, no other effect) climbs at
    ``tau g (1 - m)`` = 0.294 m/s when told to hold (its thrust ``((u - v) / tau + g) / m - g`` is zero there); with the
    bias identified and cancelled it holds still."""
    nominal = {name: low for name, (low, _) in DynamicsFamily().to_dict().items()}
    member = DynamicsFamily.fixed(
        **nominal
        | {
            "mass_scale": 0.85,
            "vertical_time_constant": 0.2,
            "latency_s": 0.0,
            "drag": 0.0,
            "ground_cushion": 0.0,
            "command_gain": 1.0,
            "max_climb_acceleration": 12.0,
        }
    ).to_dict()
    climb = 0.2 * GRAVITY * (1 - 0.85)
    _, free = _hover("pointmass", False, 3.0, dynamics={"family": member})
    np.testing.assert_allclose(free, climb, rtol=0.01)
    world, held = _hover("pointmass", True, 3.0, dynamics={"family": member})
    assert world.vertical_bias is not None
    np.testing.assert_allclose(world.vertical_bias.bias()[0], climb, rtol=0.05)
    assert np.abs(held).max() < 0.02


def test_a_light_rotorpy_crazyflie_is_held_level():
    """RotorPy's proportional loop asks for ``m0 (k_v (u - v) + g)``: a drone of ``0.87 m0`` told to hold climbs at
    ``g (1 - 0.87) / k_v`` = 0.128 m/s; with the bias identified and cancelled it holds still."""
    pytest.importorskip("rotorpy")
    tuning = {"mass_scale": 0.87}
    climb = GRAVITY * (1 - 0.87) / 10.0
    _, free = _hover("rotorpy", False, 3.0, tuning=tuning)
    np.testing.assert_allclose(free, climb, rtol=0.03)
    world, held = _hover("rotorpy", True, 3.0, tuning=tuning)
    np.testing.assert_allclose(world.vertical_bias.bias()[0], climb, rtol=0.1)
    assert np.abs(held).max() < 0.02


def test_the_transfer_command_flies_and_records_it(tmp_path):
    from marlander_lite.cli import main

    out = tmp_path / "matrix"
    main(
        [
            "transfer",
            "data/policies/quick-cpu-slow-trackers-fast-vertical-20m.safetensors",
            "--episodes",
            "1",
            "--columns",
            "point mass",
            "--rows",
            "floor",
            "--workers",
            "1",
            "--vertical-bias",
            "--out",
            str(out),
        ]
    )
    assert json.loads((out / "transfer.json").read_text())["config"]["vertical_bias"] is True
    assert "vertical bias identified in flight" in (out / "transfer.md").read_text()


def test_the_deployment_runner_cancels_the_bias_it_identifies():
    """``limits.vertical_bias: true`` in the example lab; the runner's estimates come from a first-order vertical
    tracker of 0.1 s that climbs 0.12 m/s above every setpoint it is sent: after a few seconds of changing setpoints
    the runner takes 0.12 m/s off each policy setpoint, and nothing without the key."""
    import dataclasses

    from marlander_lite.deploy.config import EXAMPLE_CONFIG, load_lab_config
    from marlander_lite.deploy.estimation import SwarmEstimate
    from marlander_lite.deploy.runner import PolicyRunner
    from marlander_lite.policy_file import load_policy

    policy = load_policy("data/policies/quick-cpu-slow-trackers-fast-vertical-20m.safetensors")
    lab = load_lab_config(EXAMPLE_CONFIG)
    assert PolicyRunner(policy, lab.task_config(), lab.limits.policy_max_speed).vertical_bias is None
    lab = lab.replace(limits=dataclasses.replace(lab.limits, vertical_bias=True))
    runner = PolicyRunner(policy, lab.task_config(), lab.limits.policy_max_speed)
    rng, dt, slope, bias = np.random.default_rng(0), runner.task.dt, np.exp(-runner.task.dt / 0.1), 0.12
    goals, zeros = np.array([[0.0, 0.0, 0.03], [0.5, 0.0, 0.03]]), np.zeros((2, 3))
    pos, vel = goals + np.array([0.0, 0.0, 1.0]), np.zeros((2, 3))
    wanted = zeros
    for k in range(120):
        est = SwarmEstimate(
            k * dt, pos.copy(), np.tile([0.0, 0.0, 0.0, 1.0], (2, 1)), vel.copy(), zeros, goals, zeros, goals,
            np.zeros(2), np.zeros(2), np.zeros(2, bool), np.zeros(2, bool),
        )  # fmt: skip
        runner.observe(est)
        wanted = rng.uniform(-0.3, 0.3, (2, 3)) if k % 6 == 0 else wanted
        command = runner.cancel_vertical_bias(wanted)
        runner.previous_command = command
        new_vel = command + [0.0, 0.0, bias] + slope * (vel - command - [0.0, 0.0, bias])
        pos, vel = pos + 0.5 * (vel + new_vel) * dt, new_vel
    np.testing.assert_allclose(wanted - runner.cancel_vertical_bias(wanted), [[0, 0, bias]] * 2, atol=0.005)
