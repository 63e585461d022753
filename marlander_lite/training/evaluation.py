"""Evaluate a policy file: run whole episodes in a batched env and summarise how the swarm landed."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from marlander_lite.make import make_vec_env
from marlander_lite.policy_file import MLPPolicy, load_policy
from marlander_lite.task import TaskConfig
from marlander_lite.training_aids import TRAINING_AIDS_OFF


@dataclass(frozen=True)
class EvaluationSummary:
    """How ``episodes`` episodes ended; errors and times over successful episodes only."""

    episodes: int
    success_rate: float
    """Fraction of episodes in which every drone landed on its own pad."""
    landing_error_mean_cm: float
    """Mean over successful episodes and drones of the horizontal distance from the pad centre."""
    landing_error_median_cm: float
    landing_time_mean_s: float
    """Mean time until the last drone touched down."""
    collision_rate: float
    """Fraction of episodes that ended with two drones closer than the collision distance."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def __str__(self) -> str:
        return (
            f"{self.episodes} episodes: success {100 * self.success_rate:.1f} %, landing error mean "
            f"{self.landing_error_mean_cm:.2f} cm (median {self.landing_error_median_cm:.2f} cm), landing time "
            f"{self.landing_time_mean_s:.2f} s, collisions {100 * self.collision_rate:.1f} %"
        )


def summarise(infos: list[dict[str, Any]], collision_distance: float) -> EvaluationSummary:
    """Summary of the final ``info`` dicts of finished episodes (point-mass or Crazyflie faces)."""
    success = np.array([bool(i["is_success"]) for i in infos])
    errors = np.array([np.nanmean(i["landing_error"]) for i in infos if i["is_success"]], dtype=float)
    times = np.array([np.nanmax(i["landing_time"]) for i in infos if i["is_success"]], dtype=float)
    collided = np.array([i["min_separation"] < collision_distance for i in infos])

    def stat(values: np.ndarray, fn: Any) -> float:
        return float(fn(values)) if values.size else float("nan")

    return EvaluationSummary(
        episodes=len(infos),
        success_rate=float(success.mean()),
        landing_error_mean_cm=100 * stat(errors, np.mean),
        landing_error_median_cm=100 * stat(errors, np.median),
        landing_time_mean_s=stat(times, np.mean),
        collision_rate=float(collided.mean()),
    )


def run_episodes(
    policy: MLPPolicy, simulator: str, episodes: int, seed: int, num_envs: int | None = None, **env_options: Any
) -> list[dict[str, Any]]:
    """The final info of the first ``episodes`` episodes of ``policy`` acting deterministically."""
    num_envs = num_envs or min(episodes, 256 if simulator == "pointmass" else 8)
    env = make_vec_env(simulator, num_envs=num_envs, seed=seed, num_drones=policy.contract.num_drones, **env_options)
    finished: list[dict[str, Any]] = []
    started = num_envs  # episodes begun so far: the env count at reset
    counted = np.ones(num_envs, dtype=bool)  # whether the episode running in each env will be counted
    obs = env.reset()
    try:
        while len(finished) < episodes:
            obs, _, done, infos = env.step(policy.act(obs).astype(np.float32))
            for i in np.flatnonzero(done):
                if counted[i]:
                    finished.append(dict(infos[i]))
                # Count only the first ``episodes`` episodes begun, so that fast episodes are not over-represented.
                counted[i] = started < episodes
                started += 1
    finally:
        env.close()
    return finished[:episodes]


def evaluate_policy_file(
    path: str | Path,
    simulator: str = "pointmass",
    episodes: int = 200,
    seed: int = 12345,
    **env_options: Any,
) -> EvaluationSummary:
    """Load ``path`` and run ``episodes`` deterministic episodes on the paper's random starts.

    The task is the one the policy was trained on, except that every training aid
    (:data:`~marlander_lite.training_aids.TRAINING_AIDS_OFF`) is switched off; ``env_options`` go to the env
    (``platform``, ``sensing``, ``task`` overrides...).
    """
    policy = load_policy(path)
    policy.contract.require_centralised("evaluate_policy_file")
    task = {**policy.contract.task, **TRAINING_AIDS_OFF, **env_options.pop("task", {})}
    infos = run_episodes(policy, simulator, episodes, seed, task=task, **env_options)
    return summarise(infos, TaskConfig().replace(**task).collision_distance)
