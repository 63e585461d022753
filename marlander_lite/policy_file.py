"""Trained policies as plain files: weights plus their observation/action contract, no pickle.

A policy file is one ``.safetensors`` file: the tensors of the actor network (and the
observation normalisation, if training used one) and, in the file's metadata, a JSON
*contract* saying what the network expects and what its outputs mean. Anything that can read
safetensors can run it; :class:`MLPPolicy` does so in numpy, which is what the deployment loop
uses. Loading checks the contract against what the caller is about to feed it and refuses a
mismatch, so a two-drone policy can never be flown on a three-drone config by accident.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from safetensors import SafetensorError, safe_open
from safetensors.numpy import load_file, save_file

from marlander_lite.task import ACT_PER_DRONE, OBS_PER_DRONE, TaskConfig

FORMAT = "marlander_lite.policy"
FORMAT_VERSION = 1
OBSERVATION_LAYOUT = (
    "per drone: p (3, m, relative to own goal), q (4, x y z w), v (3, m/s, relative to platform), omega (3, rad/s)"
)
ACTION_LAYOUT = "per drone: velocity command (3, world x y z) as a fraction of max_speed, in [-1, 1]"
ACTIVATIONS = ("relu", "tanh")


class PolicyFileError(ValueError):
    """The file is not a readable marlander_lite policy, or it does not fit the caller's contract."""


@dataclass(frozen=True)
class PolicyContract:
    """What a policy file promises: inputs, outputs and the task it was trained on."""

    num_drones: int
    """Drones whose observations are concatenated in the input (1 for a single-agent policy)."""
    max_speed: float
    """Action 1.0 means this speed (m/s)."""
    policy_hz: float
    """Rate the policy was trained to act at (Hz)."""
    activation: str
    """Hidden-layer activation, one of ``ACTIVATIONS``."""
    hidden_sizes: tuple[int, ...]
    """Widths of the hidden layers of the actor."""
    normalize_observations: bool
    """Whether ``obs_mean``/``obs_var`` tensors standardise the input (VecNormalize statistics)."""
    obs_per_drone: int = OBS_PER_DRONE
    """Numbers per drone in the input: 13 (eq. 2), or 16 when the platform velocity is observed."""
    obs_clip: float = 10.0
    """Standardised inputs are clipped to +-obs_clip."""
    obs_epsilon: float = 1e-8
    """Added to the variance before the square root."""
    task: dict[str, Any] = field(default_factory=dict)
    """The full TaskConfig the policy was trained with, for the record."""
    extra: dict[str, Any] = field(default_factory=dict)
    """Free-form notes: preset name, simulator, training steps, seed."""

    @property
    def obs_dim(self) -> int:
        return self.obs_per_drone * self.num_drones

    @property
    def act_dim(self) -> int:
        return ACT_PER_DRONE * self.num_drones

    def check_compatible(self, task: TaskConfig, *, per_drone: bool = False) -> None:
        """Raise :class:`PolicyFileError` if this policy cannot drive ``task``.

        ``per_drone=True`` accepts a single-drone policy applied to each drone in turn.
        """
        expected_drones = 1 if per_drone else task.num_drones
        problems = []
        if self.num_drones != expected_drones:
            problems.append(f"it takes {self.num_drones} drone(s), the task has {expected_drones}")
        if not np.isclose(self.max_speed, task.max_speed):
            problems.append(f"its max_speed is {self.max_speed} m/s, the task's is {task.max_speed} m/s")
        if self.obs_per_drone != task.obs_per_drone:
            problems.append(
                f"it takes {self.obs_per_drone} numbers per drone, the task gives {task.obs_per_drone} "
                "(TaskConfig.observe_platform_velocity differs)"
            )
        if not np.isclose(self.policy_hz, task.policy_hz):
            problems.append(f"it acts at {self.policy_hz} Hz, the task at {task.policy_hz} Hz")
        if problems:
            raise PolicyFileError("Policy does not fit this task: " + "; ".join(problems) + ".")


class MLPPolicy:
    """Numpy inference of an exported actor: ``act(obs) -> action`` (deterministic, the mean).

    ``obs`` is ``(..., 13 N)`` in the layout of eq. 2; the result is ``(..., 3 N)`` in [-1, 1].
    """

    def __init__(self, contract: PolicyContract, tensors: dict[str, np.ndarray]) -> None:
        self.contract = contract
        n_layers = len(contract.hidden_sizes) + 1
        self.weights = [tensors[f"actor.{i}.weight"].astype(np.float64) for i in range(n_layers)]
        self.biases = [tensors[f"actor.{i}.bias"].astype(np.float64) for i in range(n_layers)]
        if self.weights[0].shape[1] != contract.obs_dim or self.weights[-1].shape[0] != contract.act_dim:
            raise PolicyFileError(
                f"Network shape {self.weights[0].shape[1]} -> {self.weights[-1].shape[0]} does not match the "
                f"contract {contract.obs_dim} -> {contract.act_dim}; the file is inconsistent."
            )
        self.obs_mean = tensors.get("obs_mean")
        self.obs_std = None if self.obs_mean is None else np.sqrt(tensors["obs_var"] + contract.obs_epsilon)
        self._activation = np.tanh if contract.activation == "tanh" else (lambda x: np.maximum(x, 0.0))

    def act(self, obs: np.ndarray) -> np.ndarray:
        x = np.asarray(obs, dtype=np.float64)
        if x.shape[-1] != self.contract.obs_dim:
            raise ValueError(f"Observation has {x.shape[-1]} entries; this policy takes {self.contract.obs_dim}.")
        if not np.isfinite(x).all():
            raise ValueError("Observation contains NaN or infinite values; the policy cannot act on it.")
        if self.obs_mean is not None:
            clip = self.contract.obs_clip
            x = np.clip((x - self.obs_mean) / self.obs_std, -clip, clip)
        for w, b in zip(self.weights[:-1], self.biases[:-1], strict=True):
            x = self._activation(x @ w.T + b)
        return np.clip(x @ self.weights[-1].T + self.biases[-1], -1.0, 1.0)

    __call__ = act


def save_policy(path: str | Path, contract: PolicyContract, tensors: dict[str, np.ndarray]) -> Path:
    """Write ``tensors`` (``actor.{i}.weight``/``bias``, optional ``obs_mean``/``obs_var``) and the contract."""
    path = Path(path)
    if contract.activation not in ACTIVATIONS:
        raise ValueError(f"activation must be one of {ACTIVATIONS}, got {contract.activation!r}.")
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        "format": FORMAT,
        "format_version": str(FORMAT_VERSION),
        "observation_layout": OBSERVATION_LAYOUT,
        "action_layout": ACTION_LAYOUT,
        "contract": json.dumps(asdict(contract)),
    }
    save_file({k: np.ascontiguousarray(v, dtype=np.float32) for k, v in tensors.items()}, str(path), metadata=meta)
    return path


def read_contract(path: str | Path) -> PolicyContract:
    """The contract of a policy file, without loading its weights."""
    return _read(path)[0]


def load_policy(path: str | Path, task: TaskConfig | None = None, *, per_drone: bool = False) -> MLPPolicy:
    """Load a policy file for numpy inference; with ``task``, refuse it if the contract does not fit."""
    contract, tensors = _read(path)
    if task is not None:
        contract.check_compatible(task, per_drone=per_drone)
    try:
        return MLPPolicy(contract, tensors)
    except KeyError as missing:
        raise PolicyFileError(f"{path}: the tensor {missing} is missing; the file is incomplete.") from None


def _read(path: str | Path) -> tuple[PolicyContract, dict[str, np.ndarray]]:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"No policy file at {path}.")
    try:
        with safe_open(str(path), framework="numpy") as handle:
            meta = handle.metadata() or {}
        tensors = load_file(str(path))
    except (SafetensorError, OSError, ValueError) as error:
        raise PolicyFileError(
            f"{path} is not a readable safetensors file ({error}); it may be truncated or corrupted."
        ) from None
    if meta.get("format") != FORMAT:
        raise PolicyFileError(
            f"{path} is a safetensors file but not a marlander_lite policy (format={meta.get('format')!r})."
        )
    if meta.get("format_version") != str(FORMAT_VERSION):
        raise PolicyFileError(
            f"{path} has policy format version {meta.get('format_version')}; this marlander_lite reads version "
            f"{FORMAT_VERSION}. Re-export it with the matching marlander_lite."
        )
    try:
        fields = json.loads(meta["contract"])
        fields["hidden_sizes"] = tuple(fields["hidden_sizes"])
        contract = PolicyContract(**fields)
    except (KeyError, TypeError, json.JSONDecodeError) as error:
        raise PolicyFileError(f"{path}: its contract cannot be read ({error}).") from None
    return contract, tensors
