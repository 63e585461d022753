"""Training presets, the training loop, its files, determinism, a real learning threshold, the CLI."""

import json

import numpy as np
import pytest
from safetensors.numpy import load_file

from marlander_lite.cli import main
from marlander_lite.plotting import plot_training_curves, read_progress
from marlander_lite.policy_file import load_policy
from marlander_lite.training.evaluation import run_episodes, summarise
from marlander_lite.training.presets import PRESETS, TrainConfig, get_preset
from marlander_lite.training.train import train

# Every drone starts within 1 m above its own pad: landing is learnt in tens of thousands of steps.
EASY_TASK = {"spawn_near_pad_fraction": 1.0}


def tiny(steps: int, **changes) -> TrainConfig:
    base = get_preset("quick-cpu").replace(
        total_steps=steps,
        num_envs=64,
        n_steps=32,
        batch_size=512,
        n_epochs=5,
        learning_rate=1e-3,
        net_arch=(64, 64),
        task=EASY_TASK,
        checkpoint_every=0,
        torch_threads=1,
    )
    return base.replace(**changes)


def test_presets_are_valid_and_unknown_names_list_the_presets():
    assert {"quick-cpu", "paper"} <= set(PRESETS)
    assert get_preset("paper").net_arch == (512, 512, 256, 128)
    with pytest.raises(ValueError, match="available presets: quick-cpu"):
        get_preset("turbo")


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"simulator": "mujoco"}, "simulator"),
        ({"platform": "roof"}, "platform"),
        ({"num_envs": 0}, "num_envs"),
        ({"gamma": 1.5}, "gamma"),
        ({"dynamics": {"randomization": 0.1}, "simulator": "crazyflie"}, "point-mass"),
        ({"warp": 9}, "allowed"),
    ],
)
def test_invalid_training_configs_say_what_is_wrong(change, message):
    with pytest.raises(ValueError, match=message):
        get_preset("quick-cpu").replace(**change)


def test_config_round_trips_through_json():
    config = get_preset("paper").replace(platform_speed=(0.2, 0.5))
    assert TrainConfig.from_dict(json.loads(json.dumps(config.to_dict()))) == config


def test_a_run_writes_its_files_and_refuses_to_overwrite(tmp_path):
    files = train(tiny(4096), tmp_path / "run")
    for path in (files.config, files.progress, files.model, files.normalizer, files.policy):
        assert path.is_file(), path
    record = json.loads(files.config.read_text())
    assert record["train"]["total_steps"] == 4096 and record["task"]["spawn_near_pad_fraction"] == 1.0
    assert record["finished"]["steps"] >= 4096
    assert "rollout/ep_rew_mean" in read_progress(files.root)
    plot_training_curves([files.root], out=tmp_path / "curves.png")
    assert (tmp_path / "curves.png").stat().st_size > 0
    with pytest.raises(FileExistsError, match="already holds"):
        train(tiny(4096), tmp_path / "run")


def test_same_seed_gives_the_same_short_run(tmp_path):
    a = load_file(str(train(tiny(4096, seed=3), tmp_path / "a").policy))
    b = load_file(str(train(tiny(4096, seed=3), tmp_path / "b").policy))
    c = load_file(str(train(tiny(4096, seed=4), tmp_path / "c").policy))
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    assert any(not np.array_equal(a[k], c[k]) for k in a)


@pytest.mark.slow
def test_short_training_lands_far_more_often_than_a_random_policy(tmp_path):
    files = train(tiny(60_000), tmp_path / "learn")
    policy = load_policy(files.policy)
    trained = summarise(run_episodes(policy, "pointmass", 200, seed=7, task=EASY_TASK), 0.15)

    class RandomPolicy:
        contract = policy.contract
        rng = np.random.default_rng(0)

        def act(self, obs):
            return self.rng.uniform(-1, 1, (len(obs), 6))

    random = summarise(run_episodes(RandomPolicy(), "pointmass", 200, seed=7, task=EASY_TASK), 0.15)
    assert random.success_rate < 0.05
    assert trained.success_rate > 0.6


def test_cli_errors_list_what_is_allowed(capsys, tmp_path):
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--preset", "turbo", "--out", str(tmp_path / "x")])
    assert exit_info.value.code == 2
    assert "available presets: quick-cpu" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        main(["evaluate", str(tmp_path / "missing.safetensors")])
    assert exit_info.value.code == 2 and "No policy file" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        main(["evaluate", "p.safetensors", "--platform", "roof"])
    assert exit_info.value.code == 2 and "invalid choice" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        main(["plot", "curves", str(tmp_path / "nothing")])
    assert exit_info.value.code == 2 and "No training log" in capsys.readouterr().err


def test_cli_lists_presets(capsys):
    assert main(["train", "--list"]) == 0
    assert "quick-cpu" in capsys.readouterr().out


def test_fine_tuning_continues_a_run_with_its_drones_observation_and_networks(tmp_path):
    from marlander_lite.training.train import continue_from

    task = {**EASY_TASK, "observe_platform_velocity": True}
    source = train(tiny(2048, num_drones=1, task=task, net_arch=(32, 16)), tmp_path / "one")
    config = continue_from(tiny(2048), source.root)  # the preset says 64-64; the loaded model is 32-16
    assert config.num_drones == 1 and config.task["observe_platform_velocity"] and config.init_from == str(source.root)
    assert tuple(config.net_arch) == (32, 16)
    files = train(config, tmp_path / "more")
    assert json.loads(files.config.read_text())["train"]["net_arch"] == [32, 16]
    contract = load_policy(files.policy).contract
    assert contract.obs_dim == 16 and contract.hidden_sizes == (32, 16)
    assert json.loads(files.config.read_text())["finished"]["steps"] >= 4096  # counted on from the source run
    with pytest.raises(FileNotFoundError, match="not a finished training run"):
        continue_from(tiny(2048), tmp_path / "nothing")
