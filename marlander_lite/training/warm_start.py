"""Fine-tuning from a policy file: when the run that made a policy is not shipped, only its actor is.

A shipped policy whose run folder holds no ``model.zip`` (the paper's 512-wide network: its SB3 model with Adam
state is 6.4 MB) can still be trained further. ``marlander train --init-from POLICY.safetensors`` builds a fresh PPO
model of the policy's shape and copies into it what the file holds:

* the actor's layers (``actor.{i}.weight/bias``), bit for bit, so the mean action is the shipped policy's;
* the observation statistics (``obs_mean``, ``obs_var``), given the weight of the steps the policy trained for, so
  the running normaliser keeps feeding the actor the inputs it was trained on instead of relearning them.

What the file does not hold starts afresh: the critic (the value network), the log standard deviation
(``log_std_init``) and the reward scale. A random critic makes every advantage noise, and PPO would spend its
first updates moving a good actor at random; ``critic_warmup_steps`` (a training aid of the fine-tune, not in the
paper) freezes the actor while the critic learns the policy's values, then trains both.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from safetensors.numpy import load_file
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecNormalize

from marlander_lite.policy_file import PolicyContract, load_policy

if TYPE_CHECKING:
    from marlander_lite.training.presets import TrainConfig

POLICY_SUFFIX = ".safetensors"


def is_policy_file(source: str | Path | None) -> bool:
    """Whether an ``init_from`` names a policy file (rather than a run directory)."""
    return source is not None and Path(source).suffix == POLICY_SUFFIX


def continue_from_policy(config: TrainConfig, policy_path: str | Path) -> TrainConfig:
    """``config`` set to fine-tune the centralised policy in ``policy_path``: its drones, observation and actor
    shape are kept; the critic is ``config``'s. Refuses a shared policy or one trained without normalisation."""
    policy = load_policy(policy_path)
    contract = policy.contract
    contract.require_centralised("marlander train --init-from")
    if not contract.normalize_observations or not config.normalize_observations:
        raise ValueError(
            f"--init-from {policy_path}: fine-tuning from a policy file needs observation normalisation on both "
            "sides (the file's statistics seed the normaliser); train from its run directory instead."
        )
    task = {**config.task, **contract.observation_options()}
    return config.replace(
        init_from=str(policy_path),
        num_drones=int(contract.num_drones or 1),
        task=task,
        net_arch=tuple(contract.hidden_sizes),
        activation=contract.activation,
        obs_norm_epsilon=contract.obs_epsilon,
    )


def checked_tensors(policy_path: str | Path) -> tuple[PolicyContract, dict[str, np.ndarray]]:
    """The contract and the tensors of a policy file, as stored, once :func:`load_policy` has accepted it."""
    contract = load_policy(policy_path).contract
    return contract, load_file(str(policy_path))


def seed_normaliser(env: VecNormalize, policy_path: str | Path) -> None:
    """Set ``env``'s observation statistics to the policy file's, weighted as the steps it trained for."""
    contract, tensors = checked_tensors(policy_path)
    steps = contract.extra.get("steps")
    env.obs_rms.mean = tensors["obs_mean"].astype(np.float64)
    env.obs_rms.var = tensors["obs_var"].astype(np.float64)
    # The running statistics weigh new samples against this count: the source's own step count keeps them put.
    env.obs_rms.count = float(steps) if isinstance(steps, int) and steps > 0 else 1e6
    env.clip_obs = contract.obs_clip


def load_actor(model: PPO, policy_path: str | Path) -> None:
    """Copy the policy file's actor layers into ``model``'s actor (same shapes, checked)."""
    tensors = checked_tensors(policy_path)[1]
    layers = [m for m in model.policy.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
    layers.append(model.policy.action_net)
    with torch.no_grad():
        for i, layer in enumerate(layers):
            weight, bias = tensors[f"actor.{i}.weight"], tensors[f"actor.{i}.bias"]
            if tuple(weight.shape) != tuple(layer.weight.shape):
                raise ValueError(f"actor layer {i} is {weight.shape} in the file, {tuple(layer.weight.shape)} here.")
            layer.weight.copy_(torch.as_tensor(weight))
            layer.bias.copy_(torch.as_tensor(bias))


class CriticWarmup(BaseCallback):
    """Freeze the actor (layers and log standard deviation) for the first ``steps`` environment steps of a run.

    ``run_start`` is the model's step count when the run began (a fine-tune of a run directory counts on from its
    source; a run resumed after an interrupt is still judged from its own start). Frozen parameters get no
    gradient, so PPO's update changes only the critic (the actor and critic are separate networks here). The actor
    is released at the first rollout that starts ``steps`` or more after ``run_start``.
    """

    def __init__(self, steps: int, run_start: int = 0) -> None:
        super().__init__()
        self.steps, self.run_start, self.frozen = steps, run_start, False

    def _actor_parameters(self) -> list[torch.nn.Parameter]:
        policy = self.model.policy
        return [*policy.mlp_extractor.policy_net.parameters(), *policy.action_net.parameters(), policy.log_std]

    def _set(self, frozen: bool) -> None:
        for parameter in self._actor_parameters():
            parameter.requires_grad_(not frozen)
        self.frozen = frozen

    def _warming_up(self) -> bool:
        return self.num_timesteps - self.run_start < self.steps

    def _on_training_start(self) -> None:
        self._set(self._warming_up())

    def _on_rollout_start(self) -> None:
        if self.frozen and not self._warming_up():
            self._set(False)

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        if self.frozen:
            self._set(False)
