"""The CAPS-style smoothness regulariser: its pairs, its loss worked by hand, that it smooths, and that runs stay
seeded."""

import numpy as np
import pytest
import torch
from safetensors.numpy import load_file

from marlander_lite.plotting import read_progress
from marlander_lite.policy_file import load_policy
from marlander_lite.training.presets import get_preset
from marlander_lite.training.smoothness import (
    SmoothnessRegulariser,
    command_changes_near_pad,
    consecutive_pairs,
    smoothness_loss,
)
from marlander_lite.training.train import train


def test_pairs_skip_the_step_before_an_episode_start():
    starts = np.array([[1, 0], [0, 0], [1, 0], [0, 1]])  # env 0 restarts at t=2, env 1 at t=3
    steps, envs = consecutive_pairs(starts)
    assert sorted(zip(steps.tolist(), envs.tolist(), strict=True)) == [(0, 0), (0, 1), (1, 1), (2, 0)]
    with pytest.raises(ValueError, match="n_steps, n_envs"):
        consecutive_pairs(np.zeros(4))


def test_loss_by_hand_for_a_linear_mean():
    # mu(s) = 2 s: the temporal term is |2 (s_t - s_t+1)|^2, the spatial term with no noise is 0.
    now = torch.tensor([[0.0, 1.0], [1.0, 1.0]])
    nxt = torch.tensor([[0.0, 0.0], [1.0, 1.5]])
    loss = smoothness_loss(lambda s: 2 * s, now, nxt, temporal=0.5, spatial=3.0, noise=0.0)
    assert float(loss) == pytest.approx(0.5 * (4.0 + 1.0) / 2)


def test_the_regulariser_makes_the_mean_action_smoother():
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(4, 32), torch.nn.ReLU(), torch.nn.Linear(32, 2))
    obs = torch.randn(256, 4)
    nxt = obs + 0.05 * torch.randn(256, 4)
    before = float(smoothness_loss(net, obs, nxt, 1.0, 1.0, 0.05).detach())
    optimizer = torch.optim.Adam(net.parameters(), lr=3e-3)
    for _ in range(50):
        optimizer.zero_grad()
        smoothness_loss(net, obs, nxt, 1.0, 1.0, 0.05).backward()
        optimizer.step()
    torch.manual_seed(0)
    assert float(smoothness_loss(net, obs, nxt, 1.0, 1.0, 0.05).detach()) < 0.5 * before


def test_negative_weights_are_refused_with_the_allowed_range():
    with pytest.raises(ValueError, match="smoothness_temporal must be >= 0"):
        get_preset("quick-cpu").replace(smoothness_temporal=-1.0)
    with pytest.raises(ValueError, match=">= 0"):
        SmoothnessRegulariser(temporal=1.0, spatial=-0.1, noise=0.05, batch_size=64, seed=0)
    with pytest.raises(ValueError, match="smoothness_batch_size must be an integer >= 1 or None"):
        get_preset("quick-cpu").replace(smoothness_batch_size=0)


def _tiny(**changes):
    return get_preset("quick-cpu").replace(
        total_steps=4096,
        num_envs=64,
        n_steps=32,
        batch_size=512,
        net_arch=(32, 32),
        task={"spawn_near_pad_fraction": 1.0},
        dynamics={"randomization": 0.3},
        sensing="vicon",
        checkpoint_every=0,
        **changes,
    )


def test_a_regularised_run_is_seeded_and_differs_from_the_plain_run(tmp_path):
    smooth = {"smoothness_temporal": 1.0, "smoothness_spatial": 1.0}
    run = train(_tiny(seed=3, **smooth), tmp_path / "a")
    assert np.isfinite(read_progress(run.root)["train/smoothness_loss"]).any()
    a = load_file(str(run.policy))
    b = load_file(str(train(_tiny(seed=3, **smooth), tmp_path / "b").policy))
    plain = load_file(str(train(_tiny(seed=3), tmp_path / "plain").policy))
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    assert any(not np.array_equal(a[k], plain[k]) for k in a)
    # A smaller CAPS sample is another draw of pairs: another run, still a regularised one.
    small = train(_tiny(seed=3, smoothness_batch_size=64, **smooth), tmp_path / "small")
    assert np.isfinite(read_progress(small.root)["train/smoothness_loss"]).any()
    assert any(not np.array_equal(a[k], load_file(str(small.policy))[k]) for k in a)


def test_the_shipped_moving_policies_near_the_pad_cycle_without_the_aid_and_not_with_it():
    # moving-robust-16m (16 M steps, no aid) and moving-smooth-16m (the same recipe with the aid), docs/transfer.md
    cycling = command_changes_near_pad(load_policy("data/policies/moving-robust-16m.safetensors"), swarms=8)
    smooth = command_changes_near_pad(load_policy("data/policies/moving-smooth-16m.safetensors"), swarms=8)
    assert cycling.size > 100 and smooth.size > 100
    assert np.median(cycling) > 0.3 and np.median(smooth) < 0.1
