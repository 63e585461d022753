"""Pickle-free policy files: export -> load gives the same actions, and bad files are refused."""

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecNormalize

import marlander_lite
from marlander_lite.policy_file import PolicyFileError, load_policy, read_contract
from marlander_lite.task import TaskConfig
from marlander_lite.training.export import export_policy


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    env = VecNormalize(marlander_lite.make_vec_env("pointmass", num_envs=8, num_drones=2, seed=0), norm_reward=False)
    policy_kwargs = {"net_arch": {"pi": [32, 16], "vf": [32]}, "activation_fn": torch.nn.ReLU}
    model = PPO(
        "MlpPolicy", env, n_steps=16, batch_size=64, n_epochs=1, seed=0, device="cpu", policy_kwargs=policy_kwargs
    )
    model.learn(256)
    path = export_policy(model, tmp_path_factory.mktemp("p") / "policy.safetensors", TaskConfig(), env)
    return model, env, path


def test_exported_policy_acts_exactly_like_sb3(trained):
    model, env, path = trained
    policy = load_policy(path, TaskConfig())
    raw = env.get_original_obs() if env.get_original_obs() is not None else env.venv.reset()
    raw = np.random.default_rng(0).normal(size=(50, 26)).astype(np.float32) + raw[:1]
    expected, _ = model.predict(env.normalize_obs(raw), deterministic=True)
    np.testing.assert_allclose(policy.act(raw), np.clip(expected, -1, 1), atol=1e-5)
    contract = read_contract(path)
    assert contract.hidden_sizes == (32, 16) and contract.activation == "relu" and contract.normalize_observations


def test_contract_mismatch_is_refused(trained):
    _, _, path = trained
    with pytest.raises(PolicyFileError, match="takes 2 drone"):
        load_policy(path, TaskConfig(num_drones=3))
    with pytest.raises(PolicyFileError, match="max_speed"):
        load_policy(path, TaskConfig(max_speed=1.0))


def test_corrupted_or_foreign_files_are_refused(trained, tmp_path):
    _, _, path = trained
    truncated = tmp_path / "truncated.safetensors"
    truncated.write_bytes(path.read_bytes()[:200])
    with pytest.raises(PolicyFileError, match="truncated or corrupted"):
        load_policy(truncated)
    pickle_zip = tmp_path / "model.zip"
    pickle_zip.write_bytes(b"PK\x03\x04not a policy")
    with pytest.raises(PolicyFileError):
        load_policy(pickle_zip)
    with pytest.raises(FileNotFoundError):
        load_policy(tmp_path / "missing.safetensors")


def test_bad_observations_are_refused(trained):
    policy = load_policy(trained[2])
    with pytest.raises(ValueError, match="takes 26"):
        policy.act(np.zeros(13))
    with pytest.raises(ValueError, match="NaN"):
        policy.act(np.full(26, np.nan))
