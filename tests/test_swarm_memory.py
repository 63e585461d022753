"""A shared run continued with the previous command in its input (marlander_lite/swarm/memory.py).

The reference is the shipped run ``data/runs/shared-quick-paired``: widened, its network must act and value exactly
as before whatever the new inputs read, because the new weights are zeros.
"""

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecNormalize

from marlander_lite.policy_file import read_contract
from marlander_lite.swarm import memory
from marlander_lite.swarm.evaluation import evaluate_cell
from marlander_lite.swarm.policy import SharedPolicy
from marlander_lite.swarm.train import SHARED_PRESETS, _new_model, make_shared_env, train_shared
from marlander_lite.task import EQ2_VELOCITY, OBS_PER_DRONE, TaskConfig

SOURCE = Path(__file__).resolve().parents[1] / "data" / "runs" / "shared-quick-paired"
SMALL = {"swarm_sizes": (2,), "drones_per_size": 32, "n_steps": 32, "batch_size": 256}


def widened(config):
    env = VecNormalize(make_shared_env(config), norm_obs=True, norm_reward=True, gamma=config.gamma)
    model = _new_model(config.replace(init_from=None), env)
    memory.widened_start(SOURCE, model, env)
    return model, env


def test_the_widened_network_acts_and_values_as_its_source_whatever_the_command_reads():
    config = SHARED_PRESETS["shared-quick-memory"].replace(init_from=str(SOURCE), **SMALL)
    model, env = widened(config)
    source = PPO.load(SOURCE / "model.zip", device="cpu")
    rng = np.random.default_rng(0)
    before = rng.normal(size=(64, source.observation_space.shape[0])).astype(np.float32)
    command = rng.normal(scale=3.0, size=(64, 3)).astype(np.float32)
    after = np.concatenate([before[:, :OBS_PER_DRONE], command, before[:, OBS_PER_DRONE:]], axis=1)
    assert env.observation_space.shape == (before.shape[1] + 3,)
    with torch.no_grad():
        source.policy.set_training_mode(False)
        model.policy.set_training_mode(False)
        old, new = (torch.as_tensor(before), torch.as_tensor(after))
        assert torch.equal(source.policy.get_distribution(old).mode(), model.policy.get_distribution(new).mode())
        assert torch.equal(source.policy.predict_values(old), model.policy.predict_values(new))
    assert model.num_timesteps == source.num_timesteps > 0
    assert torch.equal(model.policy.log_std, source.policy.log_std)  # the source's exploration noise goes on


def test_the_new_inputs_are_standardised_like_the_velocity_and_the_old_ones_as_before():
    config = SHARED_PRESETS["shared-quick-memory"].replace(init_from=str(SOURCE), **SMALL)
    _, env = widened(config)
    with open(SOURCE / "vecnormalize.pkl", "rb") as handle:
        stats = pickle.load(handle).obs_rms
    k = OBS_PER_DRONE
    for name in ("mean", "var"):
        old, new = getattr(stats, name), getattr(env.obs_rms, name)
        np.testing.assert_array_equal(new[:k], old[:k])
        np.testing.assert_array_equal(new[k : k + 3], old[EQ2_VELOCITY])
        np.testing.assert_array_equal(new[k + 3 :], old[k:])
    assert env.obs_rms.count == stats.count


def test_only_adding_the_previous_command_is_accepted():
    plain = TaskConfig()
    assert not memory.adds_previous_command(plain, plain)
    assert memory.adds_previous_command(plain, plain.replace(observe_previous_command=True))
    with pytest.raises(ValueError, match="only adding the previous command"):
        memory.adds_previous_command(plain, plain.replace(observe_platform_velocity=True))
    with pytest.raises(ValueError, match="only adding the previous command"):
        memory.adds_previous_command(plain, plain.replace(observe_previous_command=True, observation_history=2))


def test_a_source_that_is_not_a_finished_run_is_refused_before_anything_is_written(tmp_path):
    config = SHARED_PRESETS["shared-quick-memory"].replace(init_from=str(tmp_path / "nothing"), **SMALL)
    with pytest.raises(FileNotFoundError, match="give a finished shared run directory"):
        train_shared(config, tmp_path / "run")
    unfinished = tmp_path / "unfinished"
    unfinished.mkdir()
    (unfinished / "config.json").write_text((SOURCE / "config.json").read_text())
    with pytest.raises(FileNotFoundError, match=r"lacks model\.zip and vecnormalize\.pkl"):
        train_shared(config.replace(init_from=str(unfinished)), tmp_path / "run")
    assert not (tmp_path / "run").exists()  # the same --out still takes the corrected command


def test_a_memory_stage_continues_the_shipped_run_into_a_policy_that_flies_with_its_command(tmp_path):
    """One rollout at a step size of 1e-9: the exported policy must still act as the source's does (the command's
    weights near zero), read 16 numbers per drone, and fly an evaluation cell, which feeds it its commands."""
    config = SHARED_PRESETS["shared-quick-memory"].replace(
        init_from=str(SOURCE), total_steps=1024, learning_rate=1e-9, seed=0, **SMALL
    )
    files = train_shared(config, tmp_path / "run", preset="shared-quick-memory")
    reset = train_shared(config.replace(reset_log_std=True, log_std_init=-3.0), tmp_path / "reset")
    log_std = PPO.load(reset.model, device="cpu").policy.log_std
    assert torch.allclose(log_std, torch.full_like(log_std, -3.0), atol=1e-3)  # reset as a plain --init-from resets
    contract = read_contract(files.policy)
    assert contract.obs_per_drone == OBS_PER_DRONE + 3 and contract.observation_options()["observe_previous_command"]
    source_steps = read_contract(SOURCE / "policy.safetensors").extra["steps"]
    assert json.loads(files.config.read_text())["finished"]["steps"] > source_steps
    task = TaskConfig(num_drones=4)
    old = SharedPolicy(SOURCE / "policy.safetensors", task)
    new = SharedPolicy(files.policy, task.replace(observe_previous_command=True))
    rng = np.random.default_rng(1)
    obs = rng.normal(scale=0.5, size=(8, 4, OBS_PER_DRONE))
    with_command = np.concatenate([obs, rng.uniform(-1, 1, size=(8, 4, 3))], axis=-1)
    np.testing.assert_allclose(new.act(with_command.reshape(8, -1)), old.act(obs.reshape(8, -1)), atol=1e-3)
    row = evaluate_cell("shared", 2, trials=4, seed=0, policy_path=files.policy, num_envs=4)
    assert row.summary.trials == 4
