"""Touchdown speeds of lone drones, checked against a first-order velocity loop worked by hand."""

import numpy as np
import pytest

from marlander_lite.pointmass.family import GRAVITY, NOMINAL, DynamicsFamily
from marlander_lite.policy_file import PolicyContract, save_policy
from marlander_lite.swarm.observation import NEIGHBOUR_FEATURES
from marlander_lite.swarm.touchdowns import touchdown_speeds

SINK = 0.3
"""m/s: the constant descent the test policy asks for (action -0.1 of the 3 m/s limit)."""


@pytest.fixture(scope="module")
def sinking_policy(tmp_path_factory):
    """A shared policy that ignores its input and commands (0, 0, -SINK) m/s: a drone drops straight down."""
    contract = PolicyContract(
        num_drones=None, neighbours=3, max_speed=3.0, policy_hz=24.0, activation="relu", hidden_sizes=(),
        normalize_observations=False,
    )  # fmt: skip
    weight = np.zeros((3, 13 + NEIGHBOUR_FEATURES * 3))
    path = tmp_path_factory.mktemp("sink") / "sink.safetensors"
    return save_policy(path, contract, {"actor.0.weight": weight, "actor.0.bias": np.array([0.0, 0.0, -SINK / 3.0])})


def test_a_constant_descent_touches_down_at_the_commanded_speed(sinking_policy):
    """The nominal point mass follows a constant command with a first-order loop (tau 0.056 s): long before the
    drone reaches the floor it sinks at the commanded 0.3 m/s. A delay does not change a constant command."""
    for latency in (0.0, 0.06):
        speeds = touchdown_speeds(sinking_policy, DynamicsFamily.fixed(latency_s=latency), episodes=20, seed=1)
        assert np.isfinite(speeds).all()
        np.testing.assert_allclose(speeds, SINK, atol=0.005)


def test_a_ground_cushion_slows_the_touchdown_by_at_most_the_loops_error_at_the_surface(sinking_policy):
    """A cushion of 0.25 g pushes up with 0.25 g (r / (r + h))^2 near the floor, growing as the drone sinks. A
    proportional velocity loop (time constant tau) pushed by ``a`` settles ``tau a`` below its command and lags behind
    while ``a`` grows, so the drone touches down slower than commanded, but by less than tau times the push at the
    surface itself: 0.056 s x 0.25 x 9.81 m/s^2 = 0.136 m/s."""
    speeds = touchdown_speeds(sinking_policy, DynamicsFamily.fixed(ground_cushion=0.25), episodes=20, seed=1)
    largest_slowing = NOMINAL["vertical_time_constant"] * 0.25 * GRAVITY
    assert np.isfinite(speeds).all()
    assert (speeds >= SINK - largest_slowing).all() and (speeds < SINK - 0.05).all(), speeds


def test_a_policy_that_reads_its_previous_command_gets_it(tmp_path):
    """The task follows the file's observation options: a policy whose input holds its previous command (16 numbers
    of its own) is fed 16, and sinks as the 13-number one does."""
    contract = PolicyContract(
        num_drones=None, neighbours=3, max_speed=3.0, policy_hz=24.0, activation="relu", hidden_sizes=(),
        normalize_observations=False, obs_per_drone=16, task={"observe_previous_command": True},
    )  # fmt: skip
    weight = np.zeros((3, 16 + NEIGHBOUR_FEATURES * 3))
    bias = np.array([0.0, 0.0, -SINK / 3.0])
    path = save_policy(tmp_path / "sink16.safetensors", contract, {"actor.0.weight": weight, "actor.0.bias": bias})
    speeds = touchdown_speeds(path, DynamicsFamily.fixed(), episodes=10, seed=1)
    np.testing.assert_allclose(speeds, SINK, atol=0.005)


def test_touchdown_speeds_are_seeded_and_refuse_no_episodes(sinking_policy):
    family = DynamicsFamily()
    a, b = (touchdown_speeds(sinking_policy, family, episodes=8, seed=3) for _ in range(2))
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="episodes must be >= 1"):
        touchdown_speeds(sinking_policy, family, episodes=0)
