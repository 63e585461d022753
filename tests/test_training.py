"""Training presets, the training loop, its files, determinism, a real learning threshold, the CLI."""

import json
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from safetensors.numpy import load_file
from stable_baselines3.common.callbacks import BaseCallback

from marlander_lite.cli import main
from marlander_lite.plotting import plot_training_curves, read_progress
from marlander_lite.policy_file import load_policy
from marlander_lite.task import OBSERVATION_OPTIONS
from marlander_lite.training.evaluation import run_episodes, summarise
from marlander_lite.training.presets import (
    LATE_COMMANDS_FAST_VERTICAL,
    MOVING_SLOW_TRACKERS_20M,
    PAPER_SLOW_TRACKERS_20M,
    PRESETS,
    QUICK_SLOW_TRACKERS_20M,
    SLOW_TRACKERS_FIRST_VERSION,
    TrainConfig,
    get_preset,
)
from marlander_lite.training.resume import TrainingInterrupted
from marlander_lite.training.train import resume, train

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
        dynamics={"randomization": 0.3},  # the PPO path on the simple randomisation; robustness is tested elsewhere
        sensing="vicon",
        checkpoint_every=0,
        torch_threads=1,
    )
    return base.replace(**changes)


def test_presets_are_valid_and_unknown_names_list_the_presets():
    assert {"quick-cpu", "paper"} <= set(PRESETS)
    assert get_preset("paper").net_arch == (512, 512, 256, 128)
    with pytest.raises(ValueError, match="available presets: quick-cpu"):
        get_preset("turbo")


def test_quick_cpu_smooth_is_the_recipe_its_shipped_cone2_runs_recorded():
    """The preset as it is now (the steeper approach cone) is what trained the shipped ``quick-cpu-smooth-cone2`` runs:
    exactly for ``-bench`` (the benchmark's run), apart from the seed for ``-seed2``, and apart from the thread count
    and the seed for the other two."""
    from pathlib import Path

    preset = get_preset("quick-cpu-smooth")
    assert preset.task["approach_cone_slope"] == 2.0 and preset.task["approach_cone_penalty"] == 1.0
    runs = Path(__file__).resolve().parents[1] / "data" / "runs"
    runs_of_preset = {
        "quick-cpu-smooth-cone2-bench": preset,
        "quick-cpu-smooth-cone2": preset.replace(torch_threads=1),
        "quick-cpu-smooth-cone2-seed1": preset.replace(torch_threads=1, seed=1),
        "quick-cpu-smooth-cone2-seed2": preset.replace(seed=2),
    }
    for name, expected in runs_of_preset.items():
        recorded = TrainConfig.from_dict(json.loads((runs / name / "config.json").read_text())["train"])
        assert recorded == expected, name
    before = TrainConfig.from_dict(json.loads((runs / "quick-cpu-smooth" / "config.json").read_text())["train"])
    assert before == preset.replace(task={k: v for k, v in preset.task.items() if k != "approach_cone_slope"})


def test_quick_cpu_slow_trackers_is_quick_cpu_smooth_on_an_opening_slow_tracker_family_and_its_run_recorded_it():
    from pathlib import Path

    twenty_million = QUICK_SLOW_TRACKERS_20M  # the preset until 2026-12-01
    family = twenty_million.dynamics["family"]
    assert family["velocity_time_constant"] == [0.08, 1.2] and family["ground_cushion"] == [0.0, 0.1]
    assert family["max_tilt_deg"] == [12.0, 35.0] and family["max_sink_acceleration"] == [3.0, 9.6]
    assert family["velocity_integral_gain"] == [0.0, 0.8]
    assert (twenty_million.family_opening, twenty_million.family_opening_gate) == (0.15, 0.05)
    assert twenty_million.total_steps == 20_000_000
    twelve_million = twenty_million.replace(total_steps=get_preset("quick-cpu-smooth").total_steps)
    same_otherwise = twelve_million.replace(
        dynamics=get_preset("quick-cpu-smooth").dynamics, family_opening=0.0, family_opening_gate=0.0
    )
    assert same_otherwise == get_preset("quick-cpu-smooth")
    first_version = twelve_million.replace(dynamics=SLOW_TRACKERS_FIRST_VERSION, family_opening=0.3)
    assert "velocity_integral_gain" not in first_version.dynamics["family"]
    runs = Path(__file__).resolve().parents[1] / "data" / "runs"
    for name, expected in (
        ("quick-cpu-slow-trackers", first_version),
        ("quick-cpu-slow-trackers-seed1", first_version.replace(seed=1)),
        ("quick-cpu-slow-trackers-integral", twelve_million),
        ("quick-cpu-slow-trackers-integral-seed1", twelve_million.replace(seed=1)),
        ("quick-cpu-slow-trackers-integral-seed2", twelve_million.replace(seed=2)),
        ("quick-cpu-slow-trackers-20m", twenty_million),
        ("quick-cpu-slow-trackers-20m-seed1", twenty_million.replace(seed=1)),
        ("quick-cpu-slow-trackers-20m-seed2", twenty_million.replace(seed=2)),
    ):
        record = json.loads((runs / name / "config.json").read_text())
        assert TrainConfig.from_dict(record["train"]) == expected and record["preset"] == "quick-cpu-slow-trackers"


def test_quick_cpu_slow_trackers_is_the_20m_version_on_late_commands_and_a_fast_vertical_loop_and_its_runs_record_it():
    from pathlib import Path

    preset = get_preset("quick-cpu-slow-trackers")
    family = preset.dynamics["family"]
    assert family["latency_s"] == [0.0, 0.08] and family["vertical_time_constant"] == [0.04, 0.2]
    assert family["ground_cushion"] == [0.0, 0.02]
    changed = {k for k, v in family.items() if v != QUICK_SLOW_TRACKERS_20M.dynamics["family"][k]}
    assert changed == set(LATE_COMMANDS_FAST_VERTICAL) == {"latency_s", "vertical_time_constant", "ground_cushion"}
    assert preset == QUICK_SLOW_TRACKERS_20M.replace(dynamics=preset.dynamics)  # nothing else changed
    assert preset.total_steps == 20_000_000 and preset.torch_threads == 2
    runs = Path(__file__).resolve().parents[1] / "data" / "runs"
    for seed in (0, 1, 2):  # trained as `marlander train --preset quick-cpu-slow-trackers --seed S`, from scratch
        name = "quick-cpu-slow-trackers-fast-vertical-20m" + (f"-seed{seed}" if seed else "")
        record = json.loads((runs / name / "config.json").read_text())
        assert TrainConfig.from_dict(record["train"]) == preset.replace(seed=seed), name
        assert record["preset"] == "quick-cpu-slow-trackers" and record["finished"]["steps"] >= 20_000_000, name


def test_paper_slow_trackers_is_the_quickstart_preset_with_the_papers_network_and_its_runs_recorded_it():
    from pathlib import Path

    preset = get_preset("paper-slow-trackers")
    assert preset.net_arch == (512, 512, 256, 128)  # the paper's Fig. 3 network, written out
    assert preset == get_preset("quick-cpu-slow-trackers").replace(net_arch=preset.net_arch)  # nothing else changed
    assert PAPER_SLOW_TRACKERS_20M == QUICK_SLOW_TRACKERS_20M.replace(net_arch=preset.net_arch)  # until 2026-12-01
    runs = Path(__file__).resolve().parents[1] / "data" / "runs"
    # Trained as `marlander train --preset quick-cpu-slow-trackers --net-arch 512 512 256 128`, before either preset.
    record = json.loads((runs / "paper-slow-trackers" / "config.json").read_text())
    assert TrainConfig.from_dict(record["train"]) == PAPER_SLOW_TRACKERS_20M
    assert record["preset"] == "quick-cpu-slow-trackers"
    # Trained as `marlander train --preset paper-slow-trackers` with the three late-command ranges on the command line
    # (`--dynamics.family.latency-s 0 0.08 ...`), before the preset had them.
    record = json.loads((runs / "paper-slow-trackers-fast-vertical" / "config.json").read_text())
    assert TrainConfig.from_dict(record["train"]) == preset and record["preset"] == "paper-slow-trackers"
    assert record["finished"]["steps"] >= 20_000_000
    # Its seeds 1 and 2: `marlander train --preset paper-slow-trackers --seed S`, the preset exactly.
    for seed in (1, 2):
        record = json.loads((runs / f"paper-slow-trackers-fast-vertical-seed{seed}" / "config.json").read_text())
        assert TrainConfig.from_dict(record["train"]) == preset.replace(seed=seed)
        assert record["preset"] == "paper-slow-trackers" and record["finished"]["steps"] >= 20_000_000


@pytest.mark.parametrize(
    ("run", "source", "seed", "threads", "lead_share"),
    [
        ("moving-slow-trackers", "quick-cpu-slow-trackers-20m", 0, 1, 0.0),
        ("moving-slow-trackers-seed1", "quick-cpu-slow-trackers-20m-seed1", 1, 1, 0.0),
        ("paper-moving-slow-trackers", "paper-slow-trackers", 0, 2, 0.0),
        ("moving-slow-trackers-fast-vertical", "quick-cpu-slow-trackers-fast-vertical-20m", 0, 2, 0.0),
        ("moving-slow-trackers-fast-vertical-seed1", "quick-cpu-slow-trackers-fast-vertical-20m-seed1", 1, 2, 0.0),
        ("paper-moving-slow-trackers-fast-vertical", "paper-slow-trackers-fast-vertical", 0, 2, 0.0),
        ("paper-moving-slow-trackers-fast-vertical-auto-lead", "paper-slow-trackers-fast-vertical", 0, 2, 0.6),
        ("paper-moving-slow-trackers-fast-vertical-seed1", "paper-slow-trackers-fast-vertical-seed1", 1, 2, 0.0),
        ("paper-moving-slow-trackers-fast-vertical-seed2", "paper-slow-trackers-fast-vertical-seed2", 2, 2, 0.0),
    ],
)
def test_the_shipped_moving_slow_trackers_runs_are_their_preset_continued_from_a_shipped_run(
    run, source, seed, threads, lead_share
):
    from pathlib import Path

    # Trained as `marlander train --preset moving-slow-trackers --init-from data/runs/SOURCE --seed S` (the first two
    # with --torch-threads 1): 6 M steps on top of the source's 20 M, commands in the pad frame led by 0.5 s; the
    # networks are the source's (the paper's 512-512-256-128 actor for paper-slow-trackers). The first three by the
    # preset until 2026-12-01 (MOVING_SLOW_TRACKERS_20M), the fast-vertical ones by the preset since, whose family is
    # their source's. The auto-lead one with --task.pad-frame-lead-share 0.6 as well: the lead set in flight.
    runs = Path(__file__).resolve().parents[1] / "data" / "runs"
    record = json.loads((runs / run / "config.json").read_text())
    preset = get_preset("moving-slow-trackers") if "fast-vertical" in run else MOVING_SLOW_TRACKERS_20M
    observation = {f: False for f in OBSERVATION_OPTIONS} | {"observation_history": 1}  # the source's, kept
    source_train = TrainConfig.from_dict(json.loads((runs / source / "config.json").read_text())["train"])
    assert preset.dynamics == source_train.dynamics  # the fine-tune keeps the family its source learnt
    expected = preset.replace(
        init_from=f"data/runs/{source}",
        torch_threads=threads,
        task={**preset.task, **observation, **({"pad_frame_lead_share": lead_share} if lead_share else {})},
        seed=seed,
        net_arch=source_train.net_arch,
        critic_arch=source_train.critic_arch,
    )
    assert TrainConfig.from_dict(record["train"]) == expected and record["preset"] == "moving-slow-trackers"
    assert record["task"]["command_frame"] == "pad" and record["task"]["pad_frame_lead"] == 0.5
    assert record["task"].get("pad_frame_lead_share", 0.0) == lead_share  # runs before the field: none
    assert record["finished"]["steps"] == 26_017_792  # the source's 20 M steps and 6 M more


def _continued_run(run: str, source: str, preset_name: str) -> tuple[dict, TrainConfig, TrainConfig]:
    """A shipped corner run's config record, what its preset continued from ``source`` resolves to, and the source's."""
    from pathlib import Path

    runs = Path(__file__).resolve().parents[1] / "data" / "runs"
    record = json.loads((runs / run / "config.json").read_text())
    source_train = TrainConfig.from_dict(json.loads((runs / source / "config.json").read_text())["train"])
    preset = get_preset(preset_name)
    observation = {f: False for f in OBSERVATION_OPTIONS} | {"observation_history": 1}  # the source's, kept
    expected = preset.replace(
        init_from=f"data/runs/{source}",
        task={**preset.task, **observation},
        net_arch=source_train.net_arch,
        critic_arch=source_train.critic_arch,
    )
    return record, expected, source_train


def test_the_shipped_stiff_loops_run_is_its_preset_continued_from_the_shipped_moving_fine_tune():
    # Trained on 2026-12-02 as `marlander train --preset moving-slow-trackers --init-from
    # data/runs/paper-moving-slow-trackers-fast-vertical --dynamics JSON`, the JSON being the moving-stiff-loops
    # preset's dynamics, which was named after the run: the same resolved config but the preset's name.
    source = "paper-moving-slow-trackers-fast-vertical"
    record, expected, source_train = _continued_run("paper-moving-stiff-loops", source, "moving-stiff-loops")
    corner = expected.dynamics["corner"]
    assert expected.dynamics == {**source_train.dynamics, "corner": corner, "corner_fraction": 0.3}
    assert TrainConfig.from_dict(record["train"]) == expected and record["preset"] == "moving-slow-trackers"
    assert record["finished"]["steps"] == 32_030_720  # the source's 26.0 M steps and 6 M more


@pytest.mark.parametrize(("run", "seed"), [("paper-moving-two-corners", 0), ("paper-moving-two-corners-seed1", 1)])
def test_the_shipped_two_corners_run_is_its_preset_continued_from_the_shipped_stiff_loops_run(run, seed):
    # Trained on 2026-12-02 as `marlander train --preset moving-two-corners --init-from
    # data/runs/paper-moving-stiff-loops` (and on 2026-12-03 with `--seed 1`): the preset itself, continued from the
    # stiff-loops run.
    record, expected, source_train = _continued_run(run, "paper-moving-stiff-loops", "moving-two-corners")
    expected = expected.replace(seed=seed)
    corners = expected.dynamics["corner"]
    assert expected.dynamics == {**source_train.dynamics, "corner": corners, "corner_fraction": [0.2, 0.2]}
    assert corners[0] == source_train.dynamics["corner"]  # the stiff corner kept, the slow one added
    assert TrainConfig.from_dict(record["train"]) == expected and record["preset"] == "moving-two-corners"
    assert record["finished"]["steps"] == 32_030_720 + 5_013_504  # the source's steps and 5 M more (whole rollouts)


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


def test_a_dynamics_range_the_simulator_cannot_fly_fails_at_the_start_and_leaves_nothing(tmp_path):
    """A latency range beyond two policy periods (0.083 s at 24 Hz) is refused before the first rollout, so the same
    --out can be used again at once (it used to fail at the first reset, leaving a run folder that refused a retry)."""
    too_late = {"family": {**PRESETS["quick-cpu"].dynamics["family"], "latency_s": (0.0, 0.1)}}
    with pytest.raises(ValueError, match="more than two policy periods"):
        train(tiny(4096).replace(dynamics=too_late), tmp_path / "run")
    assert not (tmp_path / "run").exists()
    assert train(tiny(4096), tmp_path / "run").policy.is_file()


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


@pytest.mark.slow
def test_quickstart_trains_evaluates_on_both_simulators_and_plots(capsys, tmp_path, monkeypatch):
    """The README's main job on CI's small budget: every step runs and writes what it says."""
    monkeypatch.setenv("MARLANDER_BUDGET", "small")
    out = tmp_path / "quick"
    assert main(["quickstart", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    config = json.loads((out / "config.json").read_text())
    assert config["preset"] == "quick-cpu-slow-trackers"
    assert config["train"]["smoothness_temporal"] == 1.0 and config["train"]["platform_height"] == [0.005, 1.0]
    assert config["train"]["task"]["approach_cone_slope"] == 2.0
    assert config["train"]["dynamics"]["family"]["velocity_integral_gain"] == [0.0, 0.8]
    for name in ("static-floor", "static-elevated", "crazyflie-firmware"):
        summary = json.loads((out / f"evaluation-{name}.json").read_text())
        assert 0.0 <= summary["success_rate"] <= 1.0 and summary["episodes"] > 0
    assert "firmware tracker" in printed and (out / "training_curves.png").stat().st_size > 10_000


def test_cli_lists_presets(capsys):
    assert main(["train", "--list"]) == 0
    assert "quick-cpu" in capsys.readouterr().out


def test_fine_tuning_continues_a_run_with_its_drones_observation_and_networks(tmp_path):
    from marlander_lite.training.train import continue_from

    extras = ("observe_platform_velocity", "observe_previous_command", "observe_platform_acceleration")
    task = {**EASY_TASK, **dict.fromkeys(extras, True), "observation_history": 2}
    source = train(tiny(2048, num_drones=1, task=task, net_arch=(32, 16)), tmp_path / "one")
    config = continue_from(tiny(2048), source.root)  # the preset says 64-64; the loaded model is 32-16
    assert config.num_drones == 1 and config.init_from == str(source.root)
    assert all(config.task[name] for name in extras) and config.task["observation_history"] == 2
    assert tuple(config.net_arch) == (32, 16)
    files = train(config, tmp_path / "more")
    assert json.loads(files.config.read_text())["train"]["net_arch"] == [32, 16]
    contract = load_policy(files.policy).contract
    assert contract.obs_dim == 44 and contract.hidden_sizes == (32, 16)
    assert json.loads(files.config.read_text())["finished"]["steps"] >= 4096  # counted on from the source run
    with pytest.raises(FileNotFoundError, match="not a finished training run"):
        continue_from(tiny(2048), tmp_path / "nothing")


class ActorWatch(BaseCallback):
    """The actor's first weight at the start of every rollout, with the step count."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: list[tuple[int, np.ndarray]] = []

    def _on_rollout_start(self) -> None:
        weight = self.model.policy.mlp_extractor.policy_net[0].weight.detach().numpy().copy()
        self.seen.append((self.num_timesteps, weight))

    def _on_step(self) -> bool:
        return True


def torch_first_weight(run) -> np.ndarray:
    """The first actor layer's weight of a finished run's model, as the model holds it (float32)."""
    from stable_baselines3 import PPO

    return PPO.load(run.model, device="cpu").policy.mlp_extractor.policy_net[0].weight.detach().numpy()


def test_fine_tuning_from_a_policy_file_starts_from_its_actor_and_statistics(tmp_path):
    """A policy file holds no critic: the fine-tune starts with the file's actor and observation statistics (the
    same actions to float32 precision), trains only the critic while warming up, then the actor too."""
    from marlander_lite.training import warm_start
    from marlander_lite.training.train import _new_model, _normalised_env, continue_from

    task = {**EASY_TASK, "observe_previous_command": True}
    source = train(tiny(2048, net_arch=(32, 16), task=task), tmp_path / "one")
    config = continue_from(tiny(4096, critic_warmup_steps=2048), source.policy)
    assert config.init_from == str(source.policy) and tuple(config.net_arch) == (32, 16)
    assert config.task["observe_previous_command"] and not config.task["observe_platform_velocity"]
    env = _normalised_env(config)
    model = _new_model(config, env)
    shipped = load_policy(source.policy)
    obs = np.random.default_rng(0).normal(size=(16, shipped.contract.obs_dim))
    mean_action = model.policy.predict(env.normalize_obs(obs), deterministic=True)[0]
    np.testing.assert_allclose(mean_action, shipped.act(obs), atol=1e-5)
    env.close()

    watch = ActorWatch()
    files = train(config, tmp_path / "tuned", callbacks=(watch,))
    start = load_policy(source.policy).weights[0]
    frozen = [w for steps, w in watch.seen if steps <= 2048]
    assert len(frozen) == 2 and all(np.array_equal(w, start.astype(np.float32)) for w in frozen)
    assert not np.array_equal(load_policy(files.policy).weights[0], start)  # then the actor learnt
    assert json.loads(files.config.read_text())["train"]["init_from"] == str(source.policy)
    with pytest.raises(ValueError, match="observation normalisation"):
        continue_from(tiny(2048, normalize_observations=False), source.policy)
    with pytest.raises(ValueError, match="critic_warmup_steps"):
        tiny(2048, critic_warmup_steps=-1)
    assert warm_start.is_policy_file(source.policy) and not warm_start.is_policy_file(source.root)


def test_critic_warmup_counts_from_the_runs_own_start(tmp_path):
    """A fine-tune of a run directory counts its steps on from the source's: the warm-up still starts at zero."""
    from marlander_lite.training.train import continue_from

    source = train(tiny(2048), tmp_path / "one")
    start = torch_first_weight(source)
    watch = ActorWatch()
    config = continue_from(tiny(4096, critic_warmup_steps=2048), source.root)
    tuned = train(config, tmp_path / "tuned", callbacks=(watch,))
    # Rollouts start at 2048 (frozen: only the critic learns from it) and 4096 (released): both see the source's actor.
    assert [steps for steps, _ in watch.seen] == [2048, 4096]
    assert all(np.array_equal(w, start) for _, w in watch.seen)
    assert not np.array_equal(torch_first_weight(tuned), start)  # the update after the second rollout moved it


def test_reset_log_std_sets_a_fine_tune_back_to_log_std_init(tmp_path):
    from marlander_lite.training.train import _new_model, _normalised_env, continue_from

    source = train(tiny(2048, log_std_init=-1.0), tmp_path / "one")
    for reset, expected in ((False, -1.0), (True, -2.5)):
        config = continue_from(tiny(2048, log_std_init=-2.5, reset_log_std=reset), source.root)
        env = _normalised_env(config)
        log_std = _new_model(config, env).policy.log_std.detach().numpy()
        env.close()
        if reset:
            np.testing.assert_array_equal(log_std, expected)
        else:  # 2048 steps of learning moved it a little from where it started
            np.testing.assert_allclose(log_std, expected, atol=0.05)


def test_periodic_checkpoints_of_a_fine_tuned_run_start_after_the_source_steps(tmp_path):
    from marlander_lite.training.train import continue_from

    source = train(tiny(2048), tmp_path / "source")  # 2048 steps
    files = train(continue_from(tiny(4096, checkpoint_every=2048), source.root), tmp_path / "tuned")
    saved = sorted(int(p.stem.split("_")[1]) for p in files.checkpoints.glob("model_*.zip"))
    assert saved == [4096, 6144]  # not one checkpoint per step until the counter passed 2048


# ---------------------------------------------------------------------------- interrupt and resume


class SignalAt(BaseCallback):
    """Sends this process ``signum`` once training passes ``step`` steps, as Ctrl-C would."""

    def __init__(self, step: int, signum: int = signal.SIGINT) -> None:
        super().__init__()
        self.step, self.signum, self.sent = step, signum, False

    def _on_step(self) -> bool:
        if not self.sent and self.num_timesteps >= self.step:
            self.sent = True
            signal.raise_signal(self.signum)
        return True


def progress_rows(run) -> list[str]:
    return (run / "logs" / "progress.csv").read_text().splitlines()


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_interrupted_run_saves_a_checkpoint_and_resumes_to_the_uninterrupted_result(tmp_path, signum):
    config = tiny(8192, seed=5)  # 4 rollouts of 64 envs x 32 steps
    # What the process had before the run (a background job started by a shell ignores SIGINT).
    handlers_before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    with pytest.raises(TrainingInterrupted, match="--resume") as stopped:
        train(config, tmp_path / "run", callbacks=(SignalAt(3000, signum),))
    assert stopped.value.steps == 4096  # the next rollout boundary after the signal
    checkpoint = tmp_path / "run" / "resume"
    for name in ("model.zip", "vecnormalize.pkl", "state.pkl"):
        assert (checkpoint / name).is_file(), name
    assert not (tmp_path / "run" / "policy.safetensors").exists()
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == handlers_before  # put back
    rows_before = progress_rows(tmp_path / "run")
    assert len(rows_before) == 1 + 2  # header + 2 rollouts

    files = resume(tmp_path / "run")
    record = json.loads(files.config.read_text())
    assert record["finished"]["steps"] == 8192 and record["resumed"][0]["steps"] == 4096
    assert not checkpoint.exists()
    rows = progress_rows(tmp_path / "run")
    assert rows[: len(rows_before)] == rows_before and len(rows) == 1 + 4  # continued, one header
    steps = read_progress(files.root)["time/total_timesteps"]
    np.testing.assert_array_equal(steps, [2048, 4096, 6144, 8192])

    # Every random state was restored: the weights are those of a run that never stopped.
    whole = train(config, tmp_path / "whole")
    a, b = load_file(str(files.policy)), load_file(str(whole.policy))
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    with pytest.raises(ValueError, match="already finished"):
        resume(tmp_path / "run")


def test_a_run_whose_environments_cannot_be_saved_resumes_with_fresh_episodes(tmp_path, monkeypatch):
    """The PyBullet path: no environment snapshot, so the envs restart with a new seed on resume."""
    import marlander_lite.training.resume as resume_module

    monkeypatch.setattr(resume_module, "SNAPSHOT_SIMULATORS", ())
    with pytest.raises(TrainingInterrupted):
        train(tiny(8192, seed=5), tmp_path / "run", callbacks=(SignalAt(1000),))
    files = resume(tmp_path / "run")
    assert json.loads(files.config.read_text())["finished"]["steps"] == 8192
    np.testing.assert_array_equal(read_progress(files.root)["time/total_timesteps"], [2048, 4096, 6144, 8192])


@pytest.mark.slow
def test_ctrl_c_on_the_command_line_saves_a_checkpoint_and_resume_finishes_the_run(tmp_path):
    """The real thing: ``marlander train`` in a subprocess, SIGINT after the first logged rollout, ``--resume``.

    quick-cpu with smaller rollouts (64 envs x 32 steps = 2048 steps; 16,384 steps -> 8 rollouts), so that the
    subprocesses spend their time starting and stopping, which is what this test checks, not training."""
    run = tmp_path / "run"
    command = [sys.executable, "-m", "marlander_lite.cli", "train"]
    small_rollouts = ["--num-envs", "64", "--n-steps", "32", "--batch-size", "1024", "--steps", "16384"]
    child = subprocess.Popen(
        [*command, "--preset", "quick-cpu", *small_rollouts, "--out", str(run), "--no-progress"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    log = run / "logs" / "progress.csv"
    deadline = time.monotonic() + 300
    while not (log.is_file() and len(log.read_text().splitlines()) >= 2):
        assert child.poll() is None and time.monotonic() < deadline, child.communicate()
        time.sleep(0.02)
    child.send_signal(signal.SIGINT)
    _, err = child.communicate(timeout=300)
    assert child.returncode == 130, err
    assert "Traceback" not in err and f"marlander train --resume {run}" in err
    assert {p.name for p in (run / "resume").iterdir()} == {"model.zip", "vecnormalize.pkl", "state.pkl"}
    assert "finished" not in json.loads((run / "config.json").read_text())

    done = subprocess.run([*command, "--resume", str(run), "--no-progress"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    record = json.loads((run / "config.json").read_text())
    stopped_at = record["resumed"][0]["steps"]  # the rollout boundary after the signal: the first, or one soon after
    assert record["finished"]["steps"] == 16_384 and stopped_at % 2048 == 0 and 2048 <= stopped_at < 16_384
    lines = log.read_text().splitlines()
    assert len(lines) == 1 + 8 and lines.count(lines[0]) == 1  # one header, one row per rollout
    np.testing.assert_array_equal(read_progress(run)["time/total_timesteps"], 2048 * np.arange(1, 9))
    assert load_policy(run / "policy.safetensors").contract.extra["steps"] == 16_384


@pytest.mark.parametrize(
    ("name", "starts_from"),
    [
        ("quick-cpu-smooth-cone2-slow-trackers", "data/runs/quick-cpu-smooth-cone2"),
        ("quick-cpu-smooth-cone5-slow-trackers", "data/runs/quick-cpu-smooth-cone2-slow-trackers"),
    ],
)
def test_the_slow_tracker_policies_record_every_stage_of_their_chains(name: str, starts_from: str):
    """The slow-tracker policies are fine-tuned in stages: ``quick-cpu-smooth-cone2-slow-trackers`` from
    ``quick-cpu-smooth-cone2`` in five, ``quick-cpu-smooth-cone5-slow-trackers`` from that one's shipped run in two
    more with a steeper cone and a precision bonus. Each ``chain.json`` names its stages; each shipped stage config
    continues the one before with the family and task changes the chain states, only the last stage's model is
    shipped, and the last family covers PyFlyt's identified horizontal loop
    (benchmarks/results/identify_simulators_2026-11-27-pyflyt-0.22.txt: tau 0.762 s, tilt 12.74 deg), which the
    default family does not (PyFlyt's sink, 9.618 m/s^2, lies just past the widened 9.6)."""
    from pathlib import Path

    from marlander_lite.pointmass.family import DynamicsFamily

    root = Path(__file__).resolve().parents[1]
    chain = json.loads((root / "data/runs" / name / "chain.json").read_text())["chain"]
    previous = chain[0]["init_from"]
    assert previous.endswith(starts_from) and (root / starts_from / "model.zip").is_file()
    for stage in chain:
        recorded = TrainConfig.from_dict(json.loads((root / stage["run"] / "config.json").read_text())["train"])
        assert recorded.init_from == previous and recorded.total_steps == stage["total_steps"], stage["run"]
        family = recorded.dynamics["family"]
        assert all(family[key] == list(value) for key, value in stage["family_changed"].items()), stage["run"]
        assert all(recorded.task[key] == value for key, value in stage.get("task_changed", {}).items()), stage["run"]
        assert (root / stage["run"] / "model.zip").is_file() == stage["model_shipped"], stage["run"]
        previous = stage["trained_at"]
    assert chain[-1]["run"] == f"data/runs/{name}" and chain[-1]["model_shipped"]
    family = DynamicsFamily.from_mapping(family)
    for key, identified in (("velocity_time_constant", 0.762), ("max_tilt_deg", 12.74)):
        low, high = getattr(family, key)
        assert low <= identified <= high, key
        default_low, default_high = getattr(DynamicsFamily(), key)
        assert not default_low <= identified <= default_high, key
