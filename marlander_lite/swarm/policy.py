"""The shared policy flying a whole swarm: one network, each drone's own input, any N.

:class:`SharedPolicy` takes the paper's centralised observation (``(..., 13 N)``, eq. 2 for every
drone, the layout every controller and the deployment loop already produce), builds each drone's
shared input (:mod:`marlander_lite.swarm.observation`), runs the one network on all drones as a
batch and returns the centralised action ``(..., 3 N)``. It is therefore a drop-in controller
(:class:`~marlander_lite.experiments.controllers.Controller`): ``reset()`` and ``act(obs)``.

:func:`export_shared_policy` writes a trained model as a policy file whose contract declares it
N-free (``num_drones: null``, ``neighbours: k``; see :mod:`marlander_lite.policy_file`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from marlander_lite.platforms import PlateGeometry
from marlander_lite.policy_file import MLPPolicy, PolicyContract, PolicyFileError, load_policy, save_policy
from marlander_lite.swarm.observation import shared_observations
from marlander_lite.task import ACT_PER_DRONE, TaskConfig


class SharedPolicy:
    """A shared (N-free) policy file, flown on a swarm of ``task.num_drones`` drones.

    Args:
        policy: a loaded shared policy (``load_policy(path, shared=True)``), or a path to one.
        task: the swarm's task (``num_drones``, ``max_speed``, ``policy_hz`` are checked against the file).
        geometry: the plate, for the pad offsets between drones (the default plate when None).

    Raises :class:`~marlander_lite.policy_file.PolicyFileError` for a centralised file or a mismatched task.
    """

    name = "shared"

    def __init__(self, policy: MLPPolicy | str | Path, task: TaskConfig, geometry: PlateGeometry | None = None) -> None:
        if isinstance(policy, str | Path):
            policy = load_policy(policy, task, shared=True)
        else:
            policy.contract.check_compatible(task, shared=True)
        self.policy, self.task = policy, task
        self.neighbours = int(policy.contract.neighbours)  # type: ignore[arg-type]  # set: checked as shared
        self.radius = policy.contract.neighbour_radius
        self.pad_offsets = (geometry or PlateGeometry()).pad_offsets(task.num_drones)

    def reset(self) -> None:
        """The network is feed-forward: nothing to reset."""

    def inputs(self, obs: np.ndarray) -> np.ndarray:
        """Each drone's input ``(..., N, 13 + 7 k)`` from the centralised observation ``(..., 13 N)``."""
        x = np.asarray(obs, dtype=np.float64)
        n, per = self.task.num_drones, self.policy.contract.obs_per_drone
        if x.shape[-1] != n * per:
            raise ValueError(f"Observation has {x.shape[-1]} entries; {n} drones x {per} = {n * per} expected.")
        return shared_observations(x.reshape(*x.shape[:-1], n, per), self.pad_offsets, self.neighbours, self.radius)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Centralised observation ``(..., 13 N)`` -> action ``(..., 3 N)`` in ``[-1, 1]`` (deterministic)."""
        actions = self.policy.act(self.inputs(obs))  # (..., N, 3): the same network for every drone
        return actions.reshape(*actions.shape[:-2], self.task.num_drones * ACT_PER_DRONE)

    __call__ = act


def export_shared_policy(
    model: Any,
    path: str | Path,
    task: TaskConfig,
    neighbours: int,
    normalizer: Any = None,
    extra: dict[str, Any] | None = None,
    neighbour_radius: float | None = None,
) -> Path:
    """Write a stable-baselines3 PPO ``model`` trained on :class:`~marlander_lite.swarm.vec_env.SharedSwarmVecEnv`
    as a shared policy file (its observation statistics from ``normalizer``, a ``VecNormalize``)."""
    from marlander_lite.training.export import actor_tensors  # torch only where a model is exported

    tensors, hidden, activation = actor_tensors(model)
    normalised = normalizer is not None and normalizer.norm_obs
    if normalised:
        tensors["obs_mean"] = normalizer.obs_rms.mean
        tensors["obs_var"] = normalizer.obs_rms.var
    contract = PolicyContract(
        num_drones=None,
        neighbours=int(neighbours),
        neighbour_radius=None if neighbour_radius is None else float(neighbour_radius),
        max_speed=task.max_speed,
        policy_hz=task.policy_hz,
        activation=activation,  # type: ignore[arg-type]
        obs_per_drone=task.obs_per_drone,  # type: ignore[arg-type]
        hidden_sizes=hidden,
        normalize_observations=bool(normalised),
        obs_clip=float(normalizer.clip_obs) if normalizer is not None else 10.0,
        obs_epsilon=float(normalizer.epsilon) if normalizer is not None else 1e-8,
        task={k: v for k, v in vars(task).items() if k != "num_drones"},
        extra=extra or {},
    )
    if contract.obs_dim != tensors["actor.0.weight"].shape[1]:
        raise PolicyFileError(
            f"The model takes {tensors['actor.0.weight'].shape[1]} inputs, a shared policy with {neighbours} "
            f"neighbours takes {contract.obs_dim}; was it trained with another number of neighbours?"
        )
    return save_policy(path, contract, tensors)
