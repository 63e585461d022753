"""From a trained stable-baselines3 PPO model to a pickle-free policy file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecNormalize

from marlander_lite.policy_file import PolicyContract, save_policy
from marlander_lite.task import TaskConfig

_ACTIVATION_NAMES = {torch.nn.ReLU: "relu", torch.nn.Tanh: "tanh"}


def actor_tensors(model: PPO) -> tuple[dict[str, np.ndarray], tuple[int, ...], str]:
    """The actor's linear layers as ``actor.{i}.weight/bias`` arrays, its hidden sizes and activation."""
    policy = model.policy
    activation = _ACTIVATION_NAMES.get(policy.activation_fn)
    if activation is None:
        raise ValueError(f"Cannot export activation {policy.activation_fn.__name__}; use ReLU or Tanh.")
    layers = [m for m in policy.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)] + [policy.action_net]
    tensors: dict[str, np.ndarray] = {}
    for i, layer in enumerate(layers):
        tensors[f"actor.{i}.weight"] = layer.weight.detach().cpu().numpy()
        tensors[f"actor.{i}.bias"] = layer.bias.detach().cpu().numpy()
    return tensors, tuple(layer.out_features for layer in layers[:-1]), activation


def export_policy(
    model: PPO,
    path: str | Path,
    task: TaskConfig,
    normalizer: VecNormalize | None = None,
    *,
    num_drones: int | None = None,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write ``model``'s deterministic actor (and ``normalizer``'s observation statistics) to ``path``.

    ``num_drones`` defaults to ``task.num_drones``; pass 1 for a single-drone policy.
    """
    tensors, hidden, activation = actor_tensors(model)
    if normalizer is not None and normalizer.norm_obs:
        tensors["obs_mean"] = normalizer.obs_rms.mean
        tensors["obs_var"] = normalizer.obs_rms.var
    contract = PolicyContract(
        num_drones=task.num_drones if num_drones is None else num_drones,
        max_speed=task.max_speed,
        policy_hz=task.policy_hz,
        activation=activation,
        obs_per_drone=task.obs_per_drone,
        hidden_sizes=hidden,
        normalize_observations=normalizer is not None and normalizer.norm_obs,
        obs_clip=float(normalizer.clip_obs) if normalizer is not None else 10.0,
        obs_epsilon=float(normalizer.epsilon) if normalizer is not None else 1e-8,
        task={k: v for k, v in vars(task).items()},
        extra=extra or {},
    )
    return save_policy(path, contract, tensors)
