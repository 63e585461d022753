"""Give a trained shared policy a memory of its last command, without forgetting what it learnt.

Under command latency a drone's state alone does not say what its tracker is still about to do; the command it sent
one step ago (1/24 s), still on its way, says part of it. A policy that reads its previous command
(``TaskConfig.observe_previous_command``, beyond the paper) could use that. Adding those 3 numbers to a trained
network's input would normally mean training from scratch, through every stage of the shared recipe. Instead
:func:`widened_start` continues a finished shared run with the wider input:

* the first layer of the actor and of the critic gets 3 new input columns, all zeros, at the place the command takes
  in each drone's input (after its own observation, before the neighbour features); every other weight is copied.
  So the widened network's actions and values are the source's, bit for bit, whatever the command reads;
* the observation normaliser of the new inputs starts from the statistics of the drone's velocity (eq. 2's ``v``),
  which the command it follows resembles, with the source's count, so that the known inputs stay standardised as
  before and the new ones start in range.

PPO then learns how much to use the new inputs. ``marlander swarm train --preset shared-quick-memory --init-from RUN``
does this when ``RUN`` did not observe its previous command and the preset does. Tried from ``shared-quick-paired``, it
did not teach the network to brake early under latency (docs/scaling.md, "A memory of the last command").
"""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecNormalize

from marlander_lite.task import ACT_PER_DRONE, EQ2_VELOCITY, TaskConfig

INPUT_FIELDS = (
    "observe_platform_velocity",
    "observe_previous_command",
    "observe_platform_acceleration",
    "observation_history",
)
"""The ``TaskConfig`` fields that shape each drone's own observation."""
FIRST_LAYERS = ("mlp_extractor.policy_net.0.weight", "mlp_extractor.value_net.0.weight")
"""The SB3 ``MlpPolicy`` weights that read the observation (actor, critic): ``(hidden, inputs)``."""


def source_task(run_dir: str | Path) -> TaskConfig:
    """The task a run was trained on, from its ``config.json`` (as ``train_shared`` records it)."""
    record_file = Path(run_dir) / "config.json"
    if not record_file.is_file():
        raise FileNotFoundError(
            f"--init-from {run_dir}: no config.json there; give a finished shared run directory (config.json, "
            "model.zip and vecnormalize.pkl, as marlander swarm train writes them)."
        )
    return TaskConfig().replace(**json.loads(record_file.read_text())["task"])


def adds_previous_command(source: TaskConfig, target: TaskConfig) -> bool:
    """Whether continuing ``source``'s run with ``target`` adds the previous command, and nothing else, to the input.

    Raises ``ValueError`` when the two inputs differ in any other way (a change this module cannot bridge).
    """
    before = {name: getattr(source, name) for name in INPUT_FIELDS}
    after = {name: getattr(target, name) for name in INPUT_FIELDS}
    if before == after:
        return False
    if {**before, "observe_previous_command": True} != after or target.observation_history != 1:
        raise ValueError(
            f"Cannot continue a run whose drones read {source.obs_per_drone} numbers with {target.obs_per_drone}: only "
            "adding the previous command (observe_previous_command=True, one frame, nothing else changed) is supported."
        )
    return True


def widen_state_dict(state: dict[str, torch.Tensor], at: int, width: int) -> dict[str, torch.Tensor]:
    """``state`` with ``width`` zero input columns inserted before column ``at`` of :data:`FIRST_LAYERS`."""
    out = dict(state)
    for key in FIRST_LAYERS:
        weight = state[key]
        zeros = torch.zeros((weight.shape[0], width), dtype=weight.dtype)
        out[key] = torch.cat([weight[:, :at], zeros, weight[:, at:]], dim=1)
    return out


def widen_statistics(values: np.ndarray, at: int, fill: np.ndarray) -> np.ndarray:
    """``values`` ``(inputs,)`` with ``fill`` inserted before index ``at``."""
    return np.concatenate([values[:at], fill, values[at:]])


def widened_start(source_dir: str | Path, model: PPO, env: VecNormalize) -> None:
    """Load ``source_dir``'s finished run into ``model`` and ``env``, whose inputs add the previous command.

    ``model`` is a fresh PPO model of the same network shapes built on ``env``, a fresh ``VecNormalize`` over the
    wider shared VecEnv; both are changed in place. The command's columns sit after the source's own
    observation (``at = source.obs_per_drone``): :func:`marlander_lite.task.observe` appends it there.
    """
    source_dir = Path(source_dir)
    at = source_task(source_dir).obs_per_drone
    source = PPO.load(source_dir / "model.zip", device="cpu")
    state = widen_state_dict(source.policy.state_dict(), at, ACT_PER_DRONE)
    target = model.policy.state_dict()
    mismatched = {k: (tuple(state[k].shape), tuple(v.shape)) for k, v in target.items() if k in state}
    mismatched = {k: shapes for k, shapes in mismatched.items() if shapes[0] != shapes[1]}
    if mismatched or state.keys() != target.keys():
        raise ValueError(
            f"{source_dir}: its network does not match the new run's once widened ({mismatched or 'other layers'}); "
            "keep net_arch, critic_arch and activation of the source run."
        )
    model.policy.load_state_dict(state)
    model.num_timesteps = source.num_timesteps
    with open(source_dir / "vecnormalize.pkl", "rb") as handle:
        statistics = pickle.load(handle)
    rms = statistics.obs_rms
    env.obs_rms.mean = widen_statistics(rms.mean, at, rms.mean[EQ2_VELOCITY])
    env.obs_rms.var = widen_statistics(rms.var, at, rms.var[EQ2_VELOCITY])
    env.obs_rms.count = rms.count
    env.ret_rms = statistics.ret_rms
    env.clip_obs, env.clip_reward = statistics.clip_obs, statistics.clip_reward
