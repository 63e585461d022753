"""One PPO training run, start to finish, in one readable function (CleanRL style).

:func:`train` builds the vectorised environment, wraps it in observation/reward normalisation,
creates (or loads, to fine-tune) a stable-baselines3 PPO model with the preset's network, and
trains it while logging to CSV and TensorBoard. The run directory ends up holding::

    config.json           the resolved TrainConfig, TaskConfig and library versions
    logs/progress.csv     one row per rollout: reward, episode length, success rate, landing error
    logs/events.*         the same for TensorBoard
    checkpoints/          model and normaliser every ``checkpoint_every`` steps
    model.zip             the final SB3 model (pickle: for resuming training only)
    vecnormalize.pkl      the final observation/reward statistics (pickle: ditto)
    policy.safetensors    the pickle-free policy file for evaluation and deployment
    resume/               only while a run is interrupted: what :func:`resume` needs (see ``resume.py``)

Ctrl-C (or SIGTERM) stops a run at the next rollout boundary with a checkpoint, and
:func:`resume` (``marlander train --resume RUN``) finishes it with the same files as a run that
never stopped. A start that fails before learning begins removes what it wrote, so the same
``--out`` can simply be tried again.
"""

from __future__ import annotations

import json
import platform as python_platform
import shutil
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import stable_baselines3
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

import marlander_lite
from marlander_lite.envs.options import EnvOptions
from marlander_lite.make import make_vec_env
from marlander_lite.platforms import PlatformConfig
from marlander_lite.task import OBSERVATION_OPTIONS, TaskConfig
from marlander_lite.training import warm_start
from marlander_lite.training.export import export_policy
from marlander_lite.training.family_curriculum import opening_for
from marlander_lite.training.presets import TrainConfig
from marlander_lite.training.provenance import code_version, policy_digest
from marlander_lite.training.resume import (
    RESUME_DIR,
    CheckpointOnStop,
    StopOnSignal,
    TrainingInterrupted,
    has_checkpoint,
    load_checkpoint,
    make_logger,
)
from marlander_lite.training.smoothness import regulariser_for

ACTIVATIONS = {"relu": torch.nn.ReLU, "tanh": torch.nn.Tanh}


@dataclass(frozen=True)
class RunFiles:
    """Where a run keeps its files."""

    root: Path

    @property
    def config(self) -> Path:
        return self.root / "config.json"

    @property
    def progress(self) -> Path:
        return self.root / "logs" / "progress.csv"

    @property
    def model(self) -> Path:
        return self.root / "model.zip"

    @property
    def normalizer(self) -> Path:
        return self.root / "vecnormalize.pkl"

    @property
    def policy(self) -> Path:
        return self.root / "policy.safetensors"

    @property
    def checkpoints(self) -> Path:
        return self.root / "checkpoints"


def task_config_of(config: TrainConfig) -> TaskConfig:
    """The :class:`TaskConfig` a training config resolves to."""
    options = EnvOptions(config.num_drones, config.platform, config.platform_speed, config.task, config.sensing)
    return options.task_config


def make_training_env(config: TrainConfig, num_envs: int | None = None, seed: int | None = None) -> VecEnv:
    """The vectorised environment a config trains on (without normalisation)."""
    platform: str | PlatformConfig = config.platform
    speed = config.platform_speed
    if config.platform_height is not None:
        platform = PlatformConfig(kind=config.platform, speed=speed, elevated_height=config.platform_height)  # type: ignore[arg-type]
        speed = None
    options: dict[str, Any] = {
        "num_drones": config.num_drones,
        "platform": platform,
        "platform_speed": speed,
        "task": config.task,
        "sensing": config.sensing,
    }
    if config.dynamics:
        options["dynamics"] = config.dynamics
    return make_vec_env(
        config.simulator, num_envs=num_envs or config.num_envs, seed=config.seed if seed is None else seed, **options
    )


class LandingStatsCallback(BaseCallback):
    """Adds landing error (cm) and landing time (s) of the last 100 episodes to the SB3 log.

    SB3 already logs ``rollout/ep_rew_mean`` (Fig. 5), ``rollout/ep_len_mean`` (Fig. 6) and
    ``rollout/success_rate`` from the ``is_success`` info.
    """

    def __init__(self) -> None:
        super().__init__()
        self.errors: deque[float] = deque(maxlen=100)
        self.times: deque[float] = deque(maxlen=100)

    def _on_step(self) -> bool:
        for i in np.flatnonzero(self.locals["dones"]):
            info = self.locals["infos"][i]
            if info.get("is_success"):
                self.errors.append(float(np.nanmean(info["landing_error"])))
                self.times.append(float(np.nanmax(info["landing_time"])))
        return True

    def _on_rollout_end(self) -> None:
        if self.errors:
            self.logger.record("rollout/landing_error_cm", 100.0 * float(np.mean(self.errors)))
            self.logger.record("rollout/landing_time_s", float(np.mean(self.times)))


class CheckpointEvery(BaseCallback):
    """Saves model and normaliser every ``every`` steps under ``folder``."""

    def __init__(self, folder: Path, every: int) -> None:
        super().__init__()
        self.folder, self.every, self._next = folder, every, every

    def _on_training_start(self) -> None:
        # A fine-tuned or resumed model starts with steps already counted: aim at the next multiple.
        if self.every:
            self._next = (self.num_timesteps // self.every + 1) * self.every

    def _on_step(self) -> bool:
        if self.every and self.num_timesteps >= self._next:
            self._next += self.every
            self.folder.mkdir(parents=True, exist_ok=True)
            self.model.save(self.folder / f"model_{self.num_timesteps}.zip")
            normalizer = self.model.get_vec_normalize_env()
            if normalizer is not None:
                normalizer.save(str(self.folder / f"vecnormalize_{self.num_timesteps}.pkl"))
        return True


def _learning_rate(config: TrainConfig) -> float | Any:
    if config.lr_schedule == "linear":
        return lambda progress_remaining: config.learning_rate * progress_remaining
    return config.learning_rate


def _write_config(files: RunFiles, config: TrainConfig, preset: str | None) -> None:
    record = {
        "preset": preset,
        "train": config.to_dict(),
        "task": vars(task_config_of(config)),
        "versions": {
            "marlander_lite": marlander_lite.__version__,
            "stable_baselines3": stable_baselines3.__version__,
            "torch": torch.__version__,
            "gymnasium": gymnasium.__version__,
            "numpy": np.__version__,
            "python": python_platform.python_version(),
        },
        "started": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "provenance": code_version(),
    }
    files.config.write_text(json.dumps(record, indent=2))


def read_run_record(files: RunFiles, option: str) -> dict[str, Any]:
    """A run's ``config.json``; ``option`` (e.g. ``--resume``) names where the path came from in errors."""
    if not files.config.is_file():
        raise FileNotFoundError(f"{option} {files.root} is not a training run directory (no config.json).")
    try:
        record = json.loads(files.config.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"{option} {files.root}: config.json is not a readable JSON file ({error}).") from None
    if not isinstance(record, dict) or not isinstance(record.get("train"), dict):
        raise ValueError(f"{option} {files.root}: config.json holds no 'train' section; was it written by train?")
    return record


def continue_from(config: TrainConfig, run_dir: str | Path) -> TrainConfig:
    """``config`` set to fine-tune the run in ``run_dir``: its drone count, observation layout and networks are kept.

    ``run_dir`` may also be a policy file (``.safetensors``): see :func:`warm_start.continue_from_policy`.
    """
    if warm_start.is_policy_file(run_dir):
        return warm_start.continue_from_policy(config, run_dir)
    files = RunFiles(Path(run_dir))
    if not files.config.is_file() or not files.model.is_file():
        raise FileNotFoundError(
            f"{run_dir} is not a finished training run (it needs config.json and model.zip); "
            "pass a directory written by 'marlander train'."
        )
    source = TrainConfig.from_dict(read_run_record(files, "--init-from")["train"])
    observe: dict[str, bool | int] = {name: bool(source.task.get(name, False)) for name in OBSERVATION_OPTIONS}
    observe["observation_history"] = int(source.task.get("observation_history", 1))
    task = {**config.task, **observe}
    # The model is loaded whole from model.zip, so its networks are the source's; the saved config must say so.
    networks = {"net_arch": source.net_arch, "critic_arch": source.critic_arch, "activation": source.activation}
    return config.replace(init_from=str(run_dir), num_drones=source.num_drones, task=task, **networks)


def check_new_run(config: TrainConfig, out_dir: str | Path) -> RunFiles:
    """Everything :func:`train` can refuse before it writes anything: raises ``ValueError`` / ``FileExistsError``."""
    files = RunFiles(Path(out_dir))
    if files.root.exists() and not files.root.is_dir():
        raise FileExistsError(f"--out {files.root} is a file, not a run directory; choose another --out.")
    if files.config.exists():
        raise FileExistsError(
            f"--out {files.root} already holds a training run; choose another --out "
            f"(or 'marlander train --resume {files.root}' if it was interrupted)."
        )
    if not isinstance(config.seed, int) or config.seed < 0:
        raise ValueError(f"--seed must be a non-negative integer, got {config.seed!r}.")
    return files


def train(
    config: TrainConfig,
    out_dir: str | Path,
    *,
    preset: str | None = None,
    progress_bar: bool = False,
    callbacks: tuple[BaseCallback, ...] = (),
) -> RunFiles:
    """Train a MARLander policy with PPO and write the run directory ``out_dir``.

    Refuses a directory that already holds a run, so no earlier result is overwritten. Extra SB3
    ``callbacks`` run after the library's own. Raises :class:`TrainingInterrupted` after saving a
    checkpoint when SIGINT or SIGTERM arrives; :func:`resume` continues from it.
    """
    files = check_new_run(config, out_dir)
    created, had_logs = not files.root.exists(), files.progress.parent.exists()
    env: VecNormalize | None = None
    try:
        files.root.mkdir(parents=True, exist_ok=True)
        _write_config(files, config, preset)
        torch.set_num_threads(config.torch_threads)
        env = _normalised_env(config)
        model = _new_model(config, env)
        model.set_logger(make_logger(files.progress.parent, append=False))
    except BaseException:  # Ctrl-C included: leave nothing that blocks trying the same --out again
        if env is not None:
            env.close()
        if created:
            shutil.rmtree(files.root, ignore_errors=True)
        else:
            files.config.unlink(missing_ok=True)
            if not had_logs:
                shutil.rmtree(files.progress.parent, ignore_errors=True)
        raise
    return _learn(model, config, files, preset, progress_bar, callbacks, target=None)


def resume(run_dir: str | Path, *, progress_bar: bool = False, callbacks: tuple[BaseCallback, ...] = ()) -> RunFiles:
    """Continue an interrupted run to its configured total steps; ends with the files of an uninterrupted run.

    The config is the run's own ``config.json``; the CSV log is continued, not rewritten.
    """
    files = RunFiles(Path(run_dir))
    record = read_run_record(files, "--resume")
    if "finished" in record:
        raise ValueError(f"--resume {run_dir}: that run already finished ({record['finished']['steps']:,} steps).")
    folder = files.root / RESUME_DIR
    if not has_checkpoint(folder):
        raise FileNotFoundError(
            f"--resume {run_dir}: no interrupt checkpoint in {folder} (only a run stopped with Ctrl-C or "
            "SIGTERM can be resumed)."
        )
    config = TrainConfig.from_dict(record["train"])
    torch.set_num_threads(config.torch_threads)
    model, target = load_checkpoint(
        folder, lambda: make_training_env(config), {"learning_rate": _learning_rate(config)}, config.seed
    )
    model.set_logger(make_logger(files.progress.parent, append=True))
    record.setdefault("resumed", []).append(
        {"steps": int(model.num_timesteps), "at": time.strftime("%Y-%m-%dT%H:%M:%S")}
    )
    files.config.write_text(json.dumps(record, indent=2))
    print(f"Resuming {files.root} at {model.num_timesteps:,} of {target:,} steps.")
    return _learn(model, config, files, record.get("preset"), progress_bar, callbacks, target=target)


def _normalised_env(config: TrainConfig) -> VecNormalize:
    """The training environments, with running observation/reward normalisation."""
    env = make_training_env(config)
    if config.init_from and not warm_start.is_policy_file(config.init_from):
        source = RunFiles(Path(config.init_from))
        env = VecNormalize.load(str(source.normalizer), env)
        env.training, env.norm_reward = True, config.normalize_rewards
        return env
    normalised = VecNormalize(
        env,
        norm_obs=config.normalize_observations,
        norm_reward=config.normalize_rewards,
        gamma=config.gamma,
        epsilon=config.obs_norm_epsilon,
    )
    if config.init_from:  # a policy file: its observation statistics
        warm_start.seed_normaliser(normalised, config.init_from)
    return normalised


def _new_model(config: TrainConfig, env: VecNormalize) -> PPO:
    """The PPO model: the actor and critic are separate MLPs of the preset's shape (or the source run's)."""
    hyper = {
        "n_steps": config.n_steps,
        "batch_size": config.batch_size,
        "n_epochs": config.n_epochs,
        "learning_rate": _learning_rate(config),
        "gamma": config.gamma,
        "gae_lambda": config.gae_lambda,
        "clip_range": config.clip_range,
        "ent_coef": config.ent_coef,
        "vf_coef": config.vf_coef,
        "max_grad_norm": config.max_grad_norm,
        "target_kl": config.target_kl,
    }
    if config.init_from and not warm_start.is_policy_file(config.init_from):
        loaded = PPO.load(
            RunFiles(Path(config.init_from)).model, env=env, device="cpu", seed=config.seed, custom_objects=hyper
        )
        if config.reset_log_std:
            with torch.no_grad():
                loaded.policy.log_std.fill_(config.log_std_init)
        return loaded
    critic = config.net_arch if config.critic_arch is None else config.critic_arch
    policy_kwargs = {
        "net_arch": {"pi": list(config.net_arch), "vf": list(critic)},
        "activation_fn": ACTIVATIONS[config.activation],
        "log_std_init": config.log_std_init,
    }
    model = PPO("MlpPolicy", env, policy_kwargs=policy_kwargs, seed=config.seed, device="cpu", **hyper)
    if config.init_from:  # a policy file: its actor, a fresh critic
        warm_start.load_actor(model, config.init_from)
    return model


def _learn(
    model: PPO,
    config: TrainConfig,
    files: RunFiles,
    preset: str | None,
    progress_bar: bool,
    callbacks: tuple[BaseCallback, ...],
    target: int | None,
) -> RunFiles:
    """Learn (up to ``target`` steps when resuming), then save the final model, normaliser and policy file."""
    env = model.get_vec_normalize_env()
    assert env is not None
    stop = StopOnSignal()
    on_stop = CheckpointOnStop(stop, files.root / RESUME_DIR, config.simulator)
    checkpoints = CheckpointEvery(files.checkpoints, config.checkpoint_every)
    own: list[BaseCallback] = [LandingStatsCallback(), checkpoints, on_stop, *regulariser_for(config)]
    run_start = model.num_timesteps if target is None else target - config.total_steps
    if config.critic_warmup_steps:  # counted from the run's first step, also when it is resumed
        own.append(warm_start.CriticWarmup(config.critic_warmup_steps, run_start))
    resumed_log = None if target is None else files.progress
    own += opening_for(config, env, run_start, resumed_log, now=model.num_timesteps)
    everything = CallbackList([*own, *callbacks])
    started = time.perf_counter()
    with stop:
        if target is None:
            steps, reset = config.total_steps, not config.init_from
        else:
            steps, reset = target - model.num_timesteps, False
        model.learn(steps, callback=everything, progress_bar=progress_bar, reset_num_timesteps=reset)
    seconds = time.perf_counter() - started
    record = json.loads(files.config.read_text())
    record["seconds_so_far"] = round(record.get("seconds_so_far", 0.0) + seconds, 1)
    if on_stop.saved_at is not None:
        files.config.write_text(json.dumps(record, indent=2))
        env.close()
        raise TrainingInterrupted(files.root, on_stop.saved_at)

    # Save: the SB3 model for resuming, and the pickle-free policy for everything else.
    model.save(files.model)
    env.save(str(files.normalizer))
    extra = {"preset": preset, "simulator": config.simulator, "steps": int(model.num_timesteps), "seed": config.seed}
    export_policy(
        model, files.policy, task_config_of(config), env if config.normalize_observations else None, extra=extra
    )
    record["finished"] = {"seconds": record.pop("seconds_so_far"), "steps": int(model.num_timesteps)}
    record.setdefault("provenance", {})["policy_digest"] = policy_digest(files.policy)
    files.config.write_text(json.dumps(record, indent=2))
    for leftover in (RESUME_DIR, RESUME_DIR + ".partial"):  # the run is whole: no checkpoint to resume from
        shutil.rmtree(files.root / leftover, ignore_errors=True)
    env.close()
    return files
