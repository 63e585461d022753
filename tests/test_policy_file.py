"""Pickle-free policy files: export -> load gives the same actions, and bad files are refused."""

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.numpy import save_file
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecNormalize

import marlander_lite
from marlander_lite.policy_file import (
    FORMAT,
    FORMAT_VERSION,
    PolicyContract,
    PolicyFileError,
    load_policy,
    observation_bounds,
    read_contract,
    save_policy,
)
from marlander_lite.task import OBSERVATION_OPTIONS, TaskConfig
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


# ---------------------------------------------------------------------------- defects 3 and 4: nothing is trusted

SHIPPED = sorted((Path(__file__).parents[1] / "data" / "policies").glob("*.safetensors"))


def small_contract(**changes) -> dict:
    """A valid contract (2 drones, one hidden layer of 8, normalised inputs) as the JSON dict of a file."""
    contract = PolicyContract(
        num_drones=2, max_speed=3.0, policy_hz=24.0, activation="relu", hidden_sizes=(8,), normalize_observations=True
    )
    return {**asdict(contract), **changes}


def small_tensors(**changes) -> dict:
    rng = np.random.default_rng(0)
    tensors = {
        "actor.0.weight": rng.normal(size=(8, 26)),
        "actor.0.bias": rng.normal(size=8),
        "actor.1.weight": rng.normal(size=(6, 8)),
        "actor.1.bias": rng.normal(size=6),
        "obs_mean": rng.normal(size=26),
        "obs_var": rng.uniform(0.5, 2.0, size=26),
    }
    tensors.update(changes)
    return {k: v for k, v in tensors.items() if v is not None}


def write_raw(path: Path, contract: dict | str, tensors: dict) -> Path:
    """A policy file written without save_policy's checks, as a broken exporter or an edit by hand would."""
    meta = {"format": FORMAT, "format_version": str(FORMAT_VERSION)}
    meta["contract"] = contract if isinstance(contract, str) else json.dumps(contract)
    save_file({k: np.ascontiguousarray(v, dtype=np.float32) for k, v in tensors.items()}, str(path), metadata=meta)
    return path


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_every_shipped_policy_still_loads(path):
    policy = load_policy(path)
    assert np.isfinite(policy.act(np.zeros(policy.contract.obs_dim))).all()


def test_a_valid_small_file_loads(tmp_path):
    policy = load_policy(write_raw(tmp_path / "ok.safetensors", small_contract(), small_tensors()), TaskConfig())
    assert policy.act(np.zeros((4, 26))).shape == (4, 6)


@pytest.mark.parametrize(
    ("tensors", "message"),
    [
        ({"actor.0.weight": np.full((8, 26), np.nan)}, r"actor.0.weight has 208 NaN or infinite value\(s\)"),
        ({"actor.1.bias": np.array([np.inf, 0, 0, 0, 0, 0])}, r"actor.1.bias has 1 NaN or infinite"),
        ({"obs_var": -np.ones(26)}, r"obs_var has 26 negative value\(s\)"),
        ({"obs_mean": np.zeros(13)}, r"obs_mean has shape \[13\], the contract needs \[26\]"),
        ({"obs_var": np.zeros(27)}, r"obs_var has shape \[27\]"),
        ({"actor.1.weight": np.zeros((6, 7))}, r"actor.1.weight has shape \[6, 7\], the contract needs \[6, 8\]"),
        ({"actor.0.weight": np.zeros((8, 13))}, r"layers 26 -> 8 -> 6\).*actor.0.weight has shape \[8, 13\]"),
        ({"actor.1.bias": None}, r"missing tensor\(s\) \['actor.1.bias'\]"),
        ({"actor.2.weight": np.zeros((6, 6))}, r"unexpected tensor\(s\) \['actor.2.weight'\]"),
        ({"obs_mean": None, "obs_var": None}, r"missing tensor\(s\) \['obs_mean', 'obs_var'\]"),
    ],
)
def test_tensors_that_cannot_give_a_finite_action_are_refused(tmp_path, tensors, message):
    path = write_raw(tmp_path / "bad.safetensors", small_contract(), small_tensors(**tensors))
    with pytest.raises(PolicyFileError, match=message):
        load_policy(path)


def test_zero_variance_without_epsilon_and_overflowing_weights_are_refused(tmp_path):
    path = write_raw(
        tmp_path / "zero.safetensors", small_contract(obs_epsilon=0.0), small_tensors(obs_var=np.zeros(26))
    )
    with pytest.raises(PolicyFileError, match="obs_var \\+ obs_epsilon is 0"):
        load_policy(path)
    # finite float32 weights, but ten layers of 3e38 overflow float64: only running the network shows it
    hidden = (4,) * 10
    big = {f"actor.{i}.weight": np.full((4, 26 if i == 0 else 4), 3e38) for i in range(10)}
    big |= {f"actor.{i}.bias": np.zeros(4) for i in range(10)}
    big |= {"actor.10.weight": np.full((6, 4), 3e38), "actor.10.bias": np.zeros(6)}
    path = write_raw(
        tmp_path / "big.safetensors", small_contract(hidden_sizes=hidden, normalize_observations=False), big
    )
    with pytest.raises(PolicyFileError, match=r"NaN or infinite actions for \d+ of 515 test observations"):
        load_policy(path)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"activation": "gelu"}, r"activation: Input should be 'relu' or 'tanh' \(got 'gelu'\)"),
        ({"num_drones": "2"}, r"num_drones: Input should be a valid integer \(got '2'\)"),
        ({"num_drones": 2.0}, r"num_drones: Input should be a valid integer"),
        ({"num_drones": 0}, r"num_drones: Input should be greater than or equal to 1"),
        ({"max_speed": "3"}, r"max_speed: Input should be a valid number"),
        ({"policy_hz": None}, r"policy_hz: Input should be a valid number"),
        ({"normalize_observations": 1}, r"normalize_observations: Input should be a valid boolean"),
        ({"hidden_sizes": [8.5]}, r"hidden_sizes.0: Input should be a valid integer"),
        ({"hidden_sizes": "8"}, r"hidden_sizes: Input should be a valid tuple"),
        ({"obs_per_drone": 12}, r"obs_per_drone: Input should be greater than or equal to 13"),
        ({"obs_per_drone": 177}, r"obs_per_drone: Input should be less than or equal to 176"),
        ({"obs_per_drone": 14}, r"obs_per_drone is 14, but the task's .* make 16 numbers per drone"),
        ({"task": {"observation_history": 0}}, r"task.observation_history must be an integer from 1 to 8, got 0"),
        ({"obs_clip": -1.0}, r"obs_clip: Input should be greater than 0"),
        ({"surprise": 1}, r"surprise: unknown field"),
    ],
)
def test_every_contract_field_is_validated(tmp_path, changes, message):
    path = write_raw(tmp_path / "bad.safetensors", small_contract(**changes), small_tensors())
    with pytest.raises(PolicyFileError, match=message):
        load_policy(path)


def test_hidden_sizes_must_agree_with_the_tensors(tmp_path):
    path = write_raw(tmp_path / "bad.safetensors", small_contract(hidden_sizes=[16]), small_tensors())
    with pytest.raises(PolicyFileError, match=r"layers 26 -> 16 -> 6.*actor.0.weight has shape \[8, 26\]"):
        load_policy(path)
    path = write_raw(tmp_path / "bad.safetensors", small_contract(hidden_sizes=[8, 8]), small_tensors())
    with pytest.raises(PolicyFileError, match=r"missing tensor\(s\) \['actor.2.bias', 'actor.2.weight'\]"):
        load_policy(path)


def test_a_broken_contract_text_is_refused(tmp_path):
    fields = small_contract()
    for text, message in [
        (json.dumps(fields)[:-5], "not valid JSON"),
        ('{"num_drones": 2, "num_drones": 3}', r"repeats key\(s\) \['num_drones'\]"),
        ("[1, 2]", "Input should be a dictionary"),
        ("[" * 100_000 + "]" * 100_000, "not valid JSON"),
        (json.dumps({k: v for k, v in fields.items() if k != "max_speed"}), "max_speed: required field missing"),
    ]:
        with pytest.raises(PolicyFileError, match=message):
            load_policy(write_raw(tmp_path / "bad.safetensors", text, small_tensors()))


def test_save_policy_refuses_a_contract_no_reader_would_accept(tmp_path):
    contract = PolicyContract(**{**small_contract(), "hidden_sizes": (8,), "activation": "gelu"})
    with pytest.raises(PolicyFileError, match="activation"):
        save_policy(tmp_path / "p.safetensors", contract, small_tensors())


# ---------------------------------------------------------------------------- shared (N-free) policies, issue 13


def shared_tensors(neighbours: int = 2) -> dict:
    """A valid shared policy's tensors: input 13 + 7 k, one hidden layer of 8, output 3."""
    size = 13 + 7 * neighbours
    return small_tensors(
        **{
            "actor.0.weight": np.random.default_rng(1).normal(size=(8, size)),
            "actor.1.weight": np.random.default_rng(2).normal(size=(3, 8)),
            "actor.1.bias": np.zeros(3),
            "obs_mean": np.zeros(size),
            "obs_var": np.ones(size),
        }
    )


def test_a_shared_policy_declares_itself_n_free_and_fits_any_swarm(tmp_path):
    path = write_raw(tmp_path / "shared.safetensors", small_contract(num_drones=None, neighbours=2), shared_tensors())
    contract = read_contract(path)
    assert contract.is_shared and contract.num_drones is None
    assert (contract.obs_dim, contract.act_dim) == (27, 3)
    for n in (1, 2, 16):
        policy = load_policy(path, TaskConfig(num_drones=n), shared=True)
        assert policy.act(np.zeros((n, 27))).shape == (n, 3)
    # Each kind is refused where the other is expected, saying what to use instead.
    with pytest.raises(PolicyFileError, match=r"it is a shared policy \(N-free, 2 neighbours\).*SharedPolicy"):
        load_policy(path, TaskConfig(num_drones=2))
    centralised = write_raw(tmp_path / "central.safetensors", small_contract(), small_tensors())
    with pytest.raises(PolicyFileError, match=r"it is a centralised policy.*shared-quick"):
        load_policy(centralised, TaskConfig(num_drones=2), shared=True)
    with pytest.raises(PolicyFileError, match="max_speed"):
        load_policy(path, TaskConfig(num_drones=4, max_speed=1.0), shared=True)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"num_drones": 2, "neighbours": 2}, r"a shared policy \(neighbours=2\).*num_drones must be null, got 2"),
        ({"num_drones": None}, "num_drones is null but neighbours is not set"),
        ({"num_drones": None, "neighbours": 0}, r"neighbours: Input should be greater than or equal to 1"),
        ({"num_drones": None, "neighbours": "2"}, r"neighbours: Input should be a valid integer"),
        ({"num_drones": None, "neighbours": True}, r"neighbours: Input should be a valid integer"),
        ({"neighbour_radius": 0.2}, "neighbour_radius is set but neighbours is not"),
        ({"num_drones": None, "neighbours": 2, "neighbour_radius": 0.0}, r"neighbour_radius: Input should be greater"),
        (
            {"num_drones": None, "neighbours": 2, "neighbour_radius": "0.2"},
            r"neighbour_radius: Input should be a valid",
        ),
    ],
)
def test_mixed_up_shared_contracts_are_refused(tmp_path, changes, message):
    path = write_raw(tmp_path / "bad.safetensors", small_contract(**changes), shared_tensors())
    with pytest.raises(PolicyFileError, match=message):
        load_policy(path)


def test_a_shared_policy_with_the_wrong_neighbour_count_is_refused(tmp_path):
    path = write_raw(tmp_path / "bad.safetensors", small_contract(num_drones=None, neighbours=3), shared_tensors(2))
    with pytest.raises(PolicyFileError, match=r"layers 34 -> 8 -> 3.*actor.0.weight has shape \[8, 27\]"):
        load_policy(path)


def test_the_task_says_what_the_observation_holds_beyond_eq2(tmp_path):
    def contract(obs_per_drone: int, **task: bool) -> PolicyContract:
        return PolicyContract(
            num_drones=1, max_speed=3.0, policy_hz=24.0, activation="relu", hidden_sizes=(),
            normalize_observations=False, obs_per_drone=obs_per_drone, task=task,
        )  # fmt: skip

    def options(platform: bool, command: bool, acceleration: bool = False, history: int = 1) -> dict[str, bool | int]:
        return {
            "observe_platform_velocity": platform,
            "observe_previous_command": command,
            "observe_platform_acceleration": acceleration,
            "observation_history": history,
        }

    # a file of v0.2 and earlier: 16 numbers per drone and no word on the previous command mean the platform velocity
    assert contract(16).observation_options() == options(True, False)
    assert contract(16, observe_platform_velocity=True).observation_options() == options(True, False)
    assert contract(16, observe_previous_command=True).observation_options() == options(False, True)
    both = contract(19, observe_platform_velocity=True, observe_previous_command=True)
    assert both.observation_options() == options(True, True)
    task = TaskConfig(num_drones=1, **both.observation_options())
    assert task.obs_per_drone == 19
    both.check_compatible(task)
    every = contract(22, **dict.fromkeys(OBSERVATION_OPTIONS, True))
    assert every.observation_options() == options(True, True, True)
    every.check_compatible(TaskConfig(num_drones=1, **every.observation_options()))
    with pytest.raises(PolicyFileError, match=r"observe_platform_acceleration \(policy True, task False\) differs"):
        every.check_compatible(task)
    # a file without the word, 19 numbers: velocity and command, as files written before the acceleration
    assert contract(19, observe_previous_command=True).observation_options() == options(True, True)
    with pytest.raises(PolicyFileError, match=r"observe_previous_command \(policy True, task False\) differs"):
        both.check_compatible(TaskConfig(num_drones=1, observe_platform_velocity=True))
    # the same count, other numbers: a policy reading its previous command is not fed the platform velocity
    with pytest.raises(PolicyFileError, match=r"observe_platform_velocity \(policy False, task True\)"):
        contract(16, observe_previous_command=True).check_compatible(
            TaskConfig(num_drones=1, observe_platform_velocity=True)
        )
    tensors = {"actor.0.weight": np.zeros((3, 16)), "actor.0.bias": np.zeros(3)}
    fields = asdict(contract(16, observe_platform_velocity=True, observe_previous_command=True))
    path = write_raw(tmp_path / "bad.safetensors", fields, tensors)
    with pytest.raises(PolicyFileError, match=r"obs_per_drone is 16, but the task's .* make 19 numbers per drone"):
        load_policy(path)


def test_a_history_of_frames_multiplies_the_input_and_must_match_the_task(tmp_path):
    fields = dict(
        num_drones=1, max_speed=3.0, policy_hz=24.0, activation="relu", hidden_sizes=(),
        normalize_observations=False,
    )  # fmt: skip
    task = {"observe_platform_velocity": True, "observation_history": 3}
    stacked = PolicyContract(**fields, obs_per_drone=48, task=task)
    assert stacked.observation_options()["observation_history"] == 3
    stacked.check_observation()
    stacked.check_compatible(TaskConfig(num_drones=1, observe_platform_velocity=True, observation_history=3))
    with pytest.raises(PolicyFileError, match=r"observation_history \(policy 3, task 1\) differs"):
        stacked.check_compatible(TaskConfig(num_drones=1, observe_platform_velocity=True))
    # a file with three frames of velocity and 16 numbers per drone cannot be what the task says
    tensors = {"actor.0.weight": np.zeros((3, 16)), "actor.0.bias": np.zeros(3)}
    path = write_raw(
        tmp_path / "bad.safetensors", asdict(PolicyContract(**fields, obs_per_drone=16, task=task)), tensors
    )
    with pytest.raises(PolicyFileError, match=r"obs_per_drone is 16, .* make 48 numbers per drone in 3 frames"):
        load_policy(path)
    # the bounds of the input repeat one frame's, frame after frame
    bounds = observation_bounds(stacked)
    assert (
        bounds.shape == (48,)
        and np.array_equal(bounds[:16], bounds[16:32])
        and np.array_equal(bounds[:16], bounds[32:])
    )
