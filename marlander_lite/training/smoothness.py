"""Smooth commands: a CAPS-style regulariser on the policy's mean action (a training aid, not in the paper).

Why. Trained long against the dynamics family, the robust policies learn a high-gain, period-3 limit cycle in
the last 15 cm above the pad: commands of -0.9, +0.2, -0.3, -0.9 m/s in turn. Sluggish trackers filter it out;
a tracker that answers at once (the nominal point mass) or one that answers 60 ms late does not, and the drone
touches down at 0.5-1 m/s. A reward on command changes (``TaskConfig.action_change_penalty``) penalises the
exploration noise itself and stopped learning; CAPS (Mysore et al., ICRA 2021; docs/references.md) instead
regularises the *mean* of the Gaussian policy, which is what flies:

    L = lambda_T E[ |mu(s_t) - mu(s_{t+1})|^2 ] + lambda_S E[ |mu(s) - mu(s + sigma eps)|^2 ],  eps ~ N(0, I)

``s`` are the rollout's normalised observations (consecutive pairs across an episode boundary are skipped) and
``mu`` the policy mean in the action space's units (1.0 = ``max_speed``). CAPS adds ``L`` to the PPO loss. So does
the :class:`SmoothnessRegulariser` callback, without editing stable-baselines3's PPO: before each of PPO's optimiser
steps it adds the gradient of ``L``, on a batch of consecutive pairs drawn from the same rollout, to the gradient of
PPO's loss. Evaluation and deployment fly the network as it is: nothing is added at run time.

A first version took separate Adam steps on ``L`` alone; Adam's steps keep their size however small ``L`` gets, and
that run's action noise grew from 0.12 to 0.27 while it learnt nothing in 7 M steps.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback

from marlander_lite.make import make_vec_env
from marlander_lite.policy_file import MLPPolicy
from marlander_lite.task import ACT_PER_DRONE, EQ2_POSITION, TaskConfig
from marlander_lite.training_aids import TRAINING_AIDS_OFF


def consecutive_pairs(episode_starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(t, env)`` of rollout steps whose next step belongs to the same episode.

    ``episode_starts`` is the rollout buffer's ``(n_steps, n_envs)`` array, 1 where step ``t`` begins an episode;
    the pair ``(t, t + 1)`` is kept when step ``t + 1`` does not begin one.
    """
    starts = np.asarray(episode_starts)
    if starts.ndim != 2:
        raise ValueError(f"episode_starts must have shape (n_steps, n_envs), got {starts.shape}.")
    steps, envs = np.nonzero(starts[1:] == 0)
    return steps, envs


def smoothness_loss(
    mean_action: Callable[[torch.Tensor], torch.Tensor],
    obs_now: torch.Tensor,
    obs_next: torch.Tensor,
    temporal: float,
    spatial: float,
    noise: float,
) -> torch.Tensor:
    """``L`` of the module docstring for a batch of consecutive observation pairs, each ``(batch, obs_dim)``.

    ``mean_action`` maps observations to the policy mean, ``(batch, act_dim)``.
    """
    now = mean_action(obs_now)
    loss = temporal * (now - mean_action(obs_next)).pow(2).sum(dim=-1).mean()
    if spatial > 0:
        jittered = mean_action(obs_now + noise * torch.randn_like(obs_now))
        loss = loss + spatial * (now - jittered).pow(2).sum(dim=-1).mean()
    return loss


class SmoothnessRegulariser(BaseCallback):
    """Adds ``grad L`` (a batch of the current rollout's consecutive pairs) before every PPO optimiser step.

    Args:
        temporal: lambda_T, weight of the change of the mean action between consecutive steps.
        spatial: lambda_S, weight of its change under observation noise of standard deviation ``noise``.
        noise: sigma, in units of the normalised observation (standard deviations).
        batch_size: pairs per optimiser step (PPO's minibatch size).
        seed: seeds the choice of pairs.
    """

    def __init__(self, temporal: float, spatial: float, noise: float, batch_size: int, seed: int) -> None:
        super().__init__()
        if temporal < 0 or spatial < 0 or noise < 0:
            raise ValueError(
                f"smoothness weights and noise must be >= 0 (0 switches a term off), got temporal={temporal}, "
                f"spatial={spatial}, noise={noise}."
            )
        self.temporal, self.spatial, self.noise, self.batch_size = temporal, spatial, noise, batch_size
        self.rng = np.random.default_rng(seed)
        self.pairs: tuple[np.ndarray, np.ndarray] | None = None
        """``s_t`` and ``s_{t+1}`` of the current rollout's consecutive pairs, each ``(pairs, obs_dim)``."""
        self.losses: list[float] = []
        self._ppo_step: Any = None

    def _mean_action(self, obs: torch.Tensor) -> torch.Tensor:
        return self.model.policy.get_distribution(obs).distribution.mean

    def _on_training_start(self) -> None:
        optimizer = self.model.policy.optimizer
        self._ppo_step = optimizer.step

        def step_with_smoothness(*args: Any, **kwargs: Any) -> Any:
            self._add_gradient()
            return self._ppo_step(*args, **kwargs)

        optimizer.step = step_with_smoothness

    def _on_training_end(self) -> None:
        if self._ppo_step is not None:
            self.model.policy.optimizer.step = self._ppo_step
            self._ppo_step = None

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        if self.losses:
            self.logger.record("train/smoothness_loss", float(np.mean(self.losses)))
        self.losses = []
        buffer = self.model.rollout_buffer
        steps, envs = consecutive_pairs(buffer.episode_starts)
        # Copied now: PPO's update flattens the buffer's arrays in place.
        obs = buffer.observations
        self.pairs = (obs[steps, envs].copy(), obs[steps + 1, envs].copy()) if steps.size else None

    def _add_gradient(self) -> None:
        """Accumulate ``grad L`` into the actor's ``.grad``, on top of PPO's loss gradient."""
        if self.pairs is None or not self.model.policy.action_net.weight.requires_grad:
            return  # no pairs yet, or the actor is frozen (warm_start.CriticWarmup)
        obs_now, obs_next = self.pairs
        pick = self.rng.integers(len(obs_now), size=min(self.batch_size, len(obs_now)))
        device = self.model.policy.device
        now = torch.as_tensor(obs_now[pick], device=device)
        nxt = torch.as_tensor(obs_next[pick], device=device)
        loss = smoothness_loss(self._mean_action, now, nxt, self.temporal, self.spatial, self.noise)
        loss.backward()
        self.losses.append(float(loss.detach()))


def regulariser_for(config: Any) -> list[BaseCallback]:
    """``[SmoothnessRegulariser]`` with a :class:`~marlander_lite.training.presets.TrainConfig`'s smoothness fields,
    or ``[]`` when both weights are 0. A resumed run draws other pairs: close to, not bit-equal with, an uninterrupted
    run."""
    if config.smoothness_temporal <= 0 and config.smoothness_spatial <= 0:
        return []
    return [
        SmoothnessRegulariser(
            config.smoothness_temporal,
            config.smoothness_spatial,
            config.smoothness_noise,
            batch_size=config.smoothness_batch_size or config.batch_size,
            seed=config.seed,
        )
    ]


def command_changes_near_pad(
    policy: MLPPolicy,
    *,
    swarms: int = 64,
    steps: int = 100,
    seed: int = 0,
    height: float = 0.2,
    radius: float = 0.1,
    **env_options: Any,
) -> np.ndarray:
    """How much the vertical command jumps from one step to the next while a drone is about to touch down.

    Flies ``policy`` (an :class:`~marlander_lite.policy_file.MLPPolicy` with a centralised contract)
    deterministically on the point mass, every training aid off, ``swarms`` swarms for ``steps`` steps, and returns
    ``|u_z(t) - u_z(t-1)|`` (m/s), a 1-D array, for every drone and step that is at most ``height`` above and
    ``radius`` beside its goal (eq. 2's ``p``). A period-3 cycle shows as a median of 0.4 m/s and more; smooth
    commands stay below 0.1.
    """
    contract = policy.contract
    contract.require_centralised("command_changes_near_pad")
    n = contract.num_drones
    task = {**contract.task, **TRAINING_AIDS_OFF, **env_options.pop("task", {})}
    env = make_vec_env("pointmass", num_envs=swarms, seed=seed, num_drones=n, task=task, **env_options)
    scale = TaskConfig().replace(**task).max_speed
    changes: list[np.ndarray] = []
    try:
        obs = env.reset()
        previous = None
        for _ in range(steps):
            action = np.asarray(policy.act(obs), dtype=np.float64)
            goal_offset = obs.reshape(swarms, n, -1)[:, :, EQ2_POSITION]
            near = (goal_offset[..., 2] > 0) & (goal_offset[..., 2] < height)
            near &= np.linalg.norm(goal_offset[..., :2], axis=-1) < radius
            vertical = scale * action.reshape(swarms, n, ACT_PER_DRONE)[..., 2]
            if previous is not None:
                step_change = np.abs(vertical - previous)
                changes.append(step_change[near & np.isfinite(step_change)])
            obs, _, done, _ = env.step(action.astype(np.float32))
            previous = vertical.copy()
            previous[done] = np.nan  # a new episode starts: no pair across the reset
    finally:
        env.close()
    return np.concatenate(changes) if changes else np.zeros(0)
