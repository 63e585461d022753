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
"""

from __future__ import annotations

import json
import platform as python_platform
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
from stable_baselines3.common.logger import configure
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

import marlander_lite
from marlander_lite.envs.options import build_configs
from marlander_lite.make import make_vec_env
from marlander_lite.platforms import PlatformConfig
from marlander_lite.task import TaskConfig
from marlander_lite.training.export import export_policy
from marlander_lite.training.presets import TrainConfig

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
    return build_configs(config.num_drones, config.platform, config.platform_speed, config.task, config.sensing)[0]


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
    }
    files.config.write_text(json.dumps(record, indent=2))


def continue_from(config: TrainConfig, run_dir: str | Path) -> TrainConfig:
    """``config`` set to fine-tune the run in ``run_dir``: its drone count, observation layout and networks are kept."""
    files = RunFiles(Path(run_dir))
    if not files.config.is_file() or not files.model.is_file():
        raise FileNotFoundError(
            f"{run_dir} is not a finished training run (it needs config.json and model.zip); "
            "pass a directory written by 'marlander train'."
        )
    source = TrainConfig.from_dict(json.loads(files.config.read_text())["train"])
    observe = bool(source.task.get("observe_platform_velocity", False))
    task = {**config.task, "observe_platform_velocity": observe}
    # The model is loaded whole from model.zip, so its networks are the source's; the saved config must say so.
    networks = {"net_arch": source.net_arch, "critic_arch": source.critic_arch, "activation": source.activation}
    return config.replace(init_from=str(run_dir), num_drones=source.num_drones, task=task, **networks)


def train(
    config: TrainConfig, out_dir: str | Path, *, preset: str | None = None, progress_bar: bool = False
) -> RunFiles:
    """Train a MARLander policy with PPO and write the run directory ``out_dir``.

    Refuses a directory that already holds a run, so no earlier result is overwritten.
    """
    files = RunFiles(Path(out_dir))
    if files.config.exists():
        raise FileExistsError(f"{files.root} already holds a training run; choose another --out directory.")
    files.root.mkdir(parents=True, exist_ok=True)
    _write_config(files, config, preset)
    torch.set_num_threads(config.torch_threads)

    # 1. Environments, with running observation/reward normalisation.
    env = make_training_env(config)
    if config.init_from:
        source = RunFiles(Path(config.init_from))
        env = VecNormalize.load(str(source.normalizer), env)
        env.training, env.norm_reward = True, config.normalize_rewards
    else:
        env = VecNormalize(
            env,
            norm_obs=config.normalize_observations,
            norm_reward=config.normalize_rewards,
            gamma=config.gamma,
            epsilon=config.obs_norm_epsilon,
        )

    # 2. The PPO model: the actor and critic are separate MLPs of the preset's shape.
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
    if config.init_from:
        model = PPO.load(
            RunFiles(Path(config.init_from)).model, env=env, device="cpu", seed=config.seed, custom_objects=hyper
        )
    else:
        critic = config.net_arch if config.critic_arch is None else config.critic_arch
        policy_kwargs = {
            "net_arch": {"pi": list(config.net_arch), "vf": list(critic)},
            "activation_fn": ACTIVATIONS[config.activation],
            "log_std_init": config.log_std_init,
        }
        model = PPO("MlpPolicy", env, policy_kwargs=policy_kwargs, seed=config.seed, device="cpu", **hyper)

    # 3. Learn, logging every rollout to CSV and TensorBoard.
    model.set_logger(configure(str(files.progress.parent), ["csv", "tensorboard"]))
    callbacks = CallbackList([LandingStatsCallback(), CheckpointEvery(files.checkpoints, config.checkpoint_every)])
    started = time.perf_counter()
    model.learn(
        config.total_steps, callback=callbacks, progress_bar=progress_bar, reset_num_timesteps=not config.init_from
    )
    seconds = time.perf_counter() - started

    # 4. Save: the SB3 model for resuming, and the pickle-free policy for everything else.
    model.save(files.model)
    env.save(str(files.normalizer))
    extra = {"preset": preset, "simulator": config.simulator, "steps": int(model.num_timesteps), "seed": config.seed}
    export_policy(
        model, files.policy, task_config_of(config), env if config.normalize_observations else None, extra=extra
    )
    record = json.loads(files.config.read_text())
    record["finished"] = {"seconds": round(seconds, 1), "steps": int(model.num_timesteps)}
    files.config.write_text(json.dumps(record, indent=2))
    env.close()
    return files
