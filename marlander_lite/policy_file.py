"""Trained policies as plain files: weights plus their observation/action contract, no pickle.

A policy file is one ``.safetensors`` file: the tensors of the actor network (and the
observation normalisation, if training used one) and, in the file's metadata, a JSON
*contract* saying what the network expects and what its outputs mean. Anything that can read
safetensors can run it; :class:`MLPPolicy` does so in numpy, which is what the deployment loop
uses. Loading checks the contract against what the caller is about to feed it and refuses a
mismatch, so a two-drone policy can never be flown on a three-drone config by accident.

Two kinds of policy share the format. A *centralised* policy (the paper's) reads every drone's
observation at once: ``num_drones`` says how many, ``neighbours`` is absent. A *shared* policy
(beyond the paper, :mod:`marlander_lite.swarm`) is one network applied to each drone in turn; it
reads the drone's own observation plus its ``neighbours`` nearest neighbours (7 numbers each, see
:mod:`marlander_lite.swarm.observation`) and flies a swarm of any size, so its ``num_drones`` is
``null``: the contract declares it N-free. Each kind is refused where the other is expected.

Nothing in a file is trusted. Loading checks, in order, and refuses with a
:class:`PolicyFileError` saying what is wrong:

1. the safetensors container and its metadata (format name and version);
2. the contract, validated by pydantic against :class:`PolicyContract`: no unknown or missing
   fields, strict types (``num_drones: "2"`` is refused, not compared as text), allowed values
   (``activation`` is ``relu`` or ``tanh``, never silently something else);
3. every tensor (:func:`check_tensors`): the expected names, finite values, the layer shapes
   chained from ``obs_dim`` through ``hidden_sizes`` to ``act_dim``, ``obs_mean``/``obs_var`` of
   length ``obs_dim`` with ``obs_var >= 0``;
4. a dry run (:func:`check_outputs`): the network is run on :data:`DRY_RUN_SAMPLES` seeded
   observations spread over the observation space, and must give finite actions for all.

Only then can a policy reach the deployment loop and a Crazyflie arm.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal, get_args

import numpy as np
from pydantic import ConfigDict, Field, Strict, TypeAdapter, ValidationError, with_config
from safetensors import SafetensorError, safe_open
from safetensors.numpy import load_file, save_file

from marlander_lite.task import (
    ACT_PER_DRONE,
    COMMAND_FRAMES,
    MAX_LEAD_SHARE,
    MAX_OBSERVATION_HISTORY,
    MAX_PAD_FRAME_LEAD,
    OBS_LIMITS,
    OBS_PER_DRONE,
    OBSERVATION_OPTIONS,
    TaskConfig,
    observation_limits,
)

FORMAT = "marlander_lite.policy"
FORMAT_VERSION = 1
OBSERVATION_LAYOUT = (
    "per drone: p (3, m, relative to own goal), q (4, x y z w), v (3, m/s, relative to platform), omega (3, rad/s)"
)
ACTION_LAYOUT = "per drone: velocity command (3, world x y z) as a fraction of max_speed, in [-1, 1]"
SHARED_OBSERVATION_LAYOUT = (
    "one drone: its own p, q, v, omega as above, then for each of its k nearest neighbours, nearest first: "
    "position minus its own (3, m), velocity minus its own (3, m/s), present flag (1; 0 with zeros when absent)"
)
SHARED_ACTION_LAYOUT = "one drone: velocity command (3, world x y z) as a fraction of max_speed, in [-1, 1]"
NEIGHBOUR_FEATURES = 7
"""Numbers per neighbour in a shared policy's input (``marlander_lite.swarm.observation``)."""
Activation = Literal["relu", "tanh"]
ACTIVATIONS: tuple[str, ...] = get_args(Activation)
ACTIVATION_FUNCTIONS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "relu": lambda x: np.maximum(x, 0.0),
    "tanh": np.tanh,
}
"""The numpy function of each activation name (one entry per name in ``ACTIVATIONS``)."""
DRY_RUN_SAMPLES = 512
"""Observations the network must map to finite actions before a policy file is accepted."""
DRY_RUN_SEED = 0
Real = Annotated[float, Strict()]
"""A finite number (an integer is accepted, text or a boolean is not)."""
Count = Annotated[int, Strict(), Field(ge=1, le=4096)]
"""A positive integer (not a boolean, not text)."""


class PolicyFileError(ValueError):
    """The file is not a readable marlander_lite policy, or it does not fit the caller's contract."""


@with_config(ConfigDict(extra="forbid", allow_inf_nan=False))
@dataclass(frozen=True)
class PolicyContract:
    """What a policy file promises: inputs, outputs and the task it was trained on.

    The ``Annotated`` constraints are what a file's contract is validated against when read.
    """

    num_drones: Annotated[int, Strict(), Field(ge=1, le=64)] | None
    """Drones whose observations are concatenated in the input (1 for a single-agent policy); ``None`` for a
    shared policy, which flies any number of drones."""
    max_speed: Annotated[Real, Field(gt=0, le=20)]
    """Action 1.0 means this speed (m/s)."""
    policy_hz: Annotated[Real, Field(ge=1, le=1000)]
    """Rate the policy was trained to act at (Hz)."""
    activation: Activation
    """Hidden-layer activation, one of ``ACTIVATIONS``."""
    hidden_sizes: Annotated[tuple[Count, ...], Field(max_length=16)]
    """Widths of the hidden layers of the actor."""
    normalize_observations: Annotated[bool, Strict()]
    """Whether ``obs_mean``/``obs_var`` tensors standardise the input (VecNormalize statistics)."""
    obs_per_drone: Annotated[int, Strict(), Field(ge=OBS_PER_DRONE, le=22 * MAX_OBSERVATION_HISTORY)] = OBS_PER_DRONE
    """Numbers per drone in the input: one frame of 13 (eq. 2), 3 more for each of the platform velocity, the
    previous command and the platform acceleration, times the frames of ``observation_history`` (``task`` says
    which)."""
    obs_clip: Annotated[Real, Field(gt=0, le=1e6)] = 10.0
    """Standardised inputs are clipped to +-obs_clip."""
    obs_epsilon: Annotated[Real, Field(ge=0, le=1)] = 1e-8
    """Added to the variance before the square root."""
    task: Annotated[dict[str, Any], Field(max_length=256)] = field(default_factory=dict)
    """The full TaskConfig the policy was trained with, for the record."""
    extra: Annotated[dict[str, Any], Field(max_length=256)] = field(default_factory=dict)
    """Free-form notes: preset name, simulator, training steps, seed."""
    neighbours: Annotated[int, Strict(), Field(ge=1, le=64)] | None = None
    """Shared policy only: the ``k`` nearest neighbours in each drone's input; ``None`` for a centralised policy."""
    neighbour_radius: Annotated[Real, Field(gt=0, le=100)] | None = None
    """Shared policy only: neighbours farther than this (m) are left out of the input (zeros, flag 0); ``None``:
    the k nearest at any distance."""

    @property
    def is_shared(self) -> bool:
        """One network per drone, any swarm size (``neighbours`` set, ``num_drones`` None)."""
        return self.neighbours is not None

    @property
    def obs_dim(self) -> int:
        if self.neighbours is not None:
            return self.obs_per_drone + NEIGHBOUR_FEATURES * self.neighbours
        return self.obs_per_drone * int(self.num_drones or 0)

    @property
    def act_dim(self) -> int:
        return ACT_PER_DRONE * (1 if self.is_shared else int(self.num_drones or 0))

    def check_kind(self) -> None:
        """Raise :class:`PolicyFileError` unless exactly one of ``num_drones`` (centralised) and ``neighbours``
        (shared) is set."""
        if self.is_shared and self.num_drones is not None:
            raise PolicyFileError(
                f"a shared policy (neighbours={self.neighbours}) flies any number of drones: its num_drones must be "
                f"null, got {self.num_drones}"
            )
        if not self.is_shared and self.neighbour_radius is not None:
            raise PolicyFileError(
                "neighbour_radius is set but neighbours is not: only a shared policy senses neighbours"
            )
        if not self.is_shared and self.num_drones is None:
            raise PolicyFileError(
                "num_drones is null but neighbours is not set: neither a centralised nor a shared policy"
            )

    def observation_options(self) -> dict[str, bool | int]:
        """The ``TaskConfig`` fields that shape this policy's input (:data:`~marlander_lite.task.OBSERVATION_OPTIONS`
        and ``observation_history``), read from :attr:`task` (files written before the previous command, the
        platform acceleration or histories lack them: False, and one frame; a contract without ``task`` at all: 16
        numbers per drone mean the platform velocity)."""
        history = self.task.get("observation_history", 1)
        if isinstance(history, bool) or not isinstance(history, int) or not 1 <= history <= MAX_OBSERVATION_HISTORY:
            raise PolicyFileError(
                f"task.observation_history must be an integer from 1 to {MAX_OBSERVATION_HISTORY}, got {history!r}"
            )
        command = bool(self.task.get("observe_previous_command", False))
        acceleration = bool(self.task.get("observe_platform_acceleration", False))
        platform = self.task.get("observe_platform_velocity")
        if platform is None:
            platform = self.obs_per_drone // history - 3 * (command + acceleration) > OBS_PER_DRONE
        return {
            "observe_platform_velocity": bool(platform),
            "observe_previous_command": command,
            "observe_platform_acceleration": acceleration,
            "observation_history": history,
        }

    def interface_options(self) -> dict[str, bool | int | str | float]:
        """:meth:`observation_options` and the frame the policy's commands are read in (``TaskConfig.command_frame``,
        ``pad_frame_lead`` and ``pad_frame_lead_share``, the lead set in flight; files written before them:
        ``"world"``, the paper's, and no lead): every ``TaskConfig`` field a loop flying the policy must follow."""
        frame = self.task.get("command_frame", "world")
        if frame not in COMMAND_FRAMES:
            raise PolicyFileError(f"task.command_frame must be one of {', '.join(COMMAND_FRAMES)}, got {frame!r}")
        lead = self.task.get("pad_frame_lead", 0.0)
        if isinstance(lead, bool) or not isinstance(lead, int | float) or not 0.0 <= lead <= MAX_PAD_FRAME_LEAD:
            raise PolicyFileError(
                f"task.pad_frame_lead must be a number from 0 to {MAX_PAD_FRAME_LEAD:g} (s), got {lead!r}"
            )
        share = self.task.get("pad_frame_lead_share", 0.0)
        if isinstance(share, bool) or not isinstance(share, int | float) or not 0.0 <= share <= MAX_LEAD_SHARE:
            raise PolicyFileError(
                f"task.pad_frame_lead_share must be a number from 0 to {MAX_LEAD_SHARE:g}, got {share!r}"
            )
        if share > 0 and frame != "pad":
            raise PolicyFileError(
                f"task.pad_frame_lead_share is {share:g}, but task.command_frame is {frame!r}: a lead set in flight "
                "leads pad-frame commands only"
            )
        return {
            **self.observation_options(),
            "command_frame": frame,
            "pad_frame_lead": float(lead),
            "pad_frame_lead_share": float(share),
        }

    def check_observation(self) -> None:
        """Raise :class:`PolicyFileError` unless ``obs_per_drone`` is what :meth:`observation_options` ask for."""
        options = self.observation_options()
        history = int(options["observation_history"])
        expected = (OBS_PER_DRONE + 3 * sum(bool(options[name]) for name in OBSERVATION_OPTIONS)) * history
        if self.obs_per_drone != expected:
            frames = f" in {history} frames" if history > 1 else ""
            raise PolicyFileError(
                f"obs_per_drone is {self.obs_per_drone}, but the task's {options} make {expected} numbers per "
                f"drone{frames}"
            )

    def require_centralised(self, where: str) -> None:
        """Raise :class:`PolicyFileError` if this is a shared (N-free) policy, which ``where`` cannot fly."""
        if self.is_shared:
            raise PolicyFileError(
                f"{where} flies centralised policies; this is a shared policy for any swarm size "
                f"({self.neighbours} neighbours): evaluate it with 'python -m marlander_lite.swarm.evaluation'."
            )

    def check_compatible(self, task: TaskConfig, *, per_drone: bool = False, shared: bool = False) -> None:
        """Raise :class:`PolicyFileError` if this policy cannot drive ``task``.

        ``per_drone=True`` accepts a single-drone policy applied to each drone in turn; ``shared=True``
        asks for a shared policy (any N), ``False`` (the default) for a centralised one.
        """
        if shared != self.is_shared:
            kind = (
                f"a shared policy (N-free, {self.neighbours} neighbours)" if self.is_shared else "a centralised policy"
            )
            use = (
                "fly it with marlander_lite.swarm.SharedPolicy"
                if self.is_shared
                else "a shared policy comes from the 'shared-quick' preset (marlander_lite.swarm.train)"
            )
            raise PolicyFileError(f"Policy does not fit this use: it is {kind}; {use}.")
        expected_drones = 1 if per_drone else task.num_drones
        problems = []
        if not self.is_shared and self.num_drones != expected_drones:
            problems.append(f"it takes {self.num_drones} drone(s), the task has {expected_drones}")
        if not np.isclose(self.max_speed, task.max_speed):
            problems.append(f"its max_speed is {self.max_speed} m/s, the task's is {task.max_speed} m/s")
        # Compared by name, not only by count: 16 numbers may be the platform velocity or the previous command.
        wanted = self.observation_options()
        given = {name: getattr(task, name) for name in wanted}
        if wanted != given:
            differ = ", ".join(
                f"{name} (policy {wanted[name]}, task {given[name]})" for name in wanted if wanted[name] != given[name]
            )
            problems.append(
                f"it takes {self.obs_per_drone} numbers per drone, the task gives {task.obs_per_drone}: "
                f"TaskConfig.{differ} differs"
            )
        if not np.isclose(self.policy_hz, task.policy_hz):
            problems.append(f"it acts at {self.policy_hz} Hz, the task at {task.policy_hz} Hz")
        if problems:
            raise PolicyFileError("Policy does not fit this task: " + "; ".join(problems) + ".")


class MLPPolicy:
    """Numpy inference of an exported actor: ``act(obs) -> action`` (deterministic, the mean).

    ``obs`` is ``(..., 13 N)`` in the layout of eq. 2; the result is ``(..., 3 N)`` in [-1, 1].
    The tensors are checked first (:func:`check_tensors`); a bad set raises :class:`PolicyFileError`.
    """

    def __init__(self, contract: PolicyContract, tensors: dict[str, np.ndarray]) -> None:
        check_tensors(contract, tensors)
        self.contract = contract
        n_layers = len(contract.hidden_sizes) + 1
        self.weights = [tensors[f"actor.{i}.weight"].astype(np.float64) for i in range(n_layers)]
        self.biases = [tensors[f"actor.{i}.bias"].astype(np.float64) for i in range(n_layers)]
        self.obs_mean = self.obs_std = None
        if contract.normalize_observations:
            self.obs_mean = tensors["obs_mean"].astype(np.float64)
            self.obs_std = np.sqrt(tensors["obs_var"].astype(np.float64) + contract.obs_epsilon)
        self._activation = ACTIVATION_FUNCTIONS[contract.activation]

    def act(self, obs: np.ndarray) -> np.ndarray:
        x = np.asarray(obs, dtype=np.float64)
        if x.shape[-1] != self.contract.obs_dim:
            raise ValueError(f"Observation has {x.shape[-1]} entries; this policy takes {self.contract.obs_dim}.")
        if not np.isfinite(x).all():
            raise ValueError("Observation contains NaN or infinite values; the policy cannot act on it.")
        return np.clip(self.forward(x), -1.0, 1.0)

    __call__ = act

    def forward(self, x: np.ndarray) -> np.ndarray:
        """The network's raw output (before the clip to [-1, 1]) for observations ``(..., obs_dim)``."""
        if self.obs_mean is not None:
            clip = self.contract.obs_clip
            x = np.clip((x - self.obs_mean) / self.obs_std, -clip, clip)
        for w, b in zip(self.weights[:-1], self.biases[:-1], strict=True):
            x = self._activation(x @ w.T + b)
        return x @ self.weights[-1].T + self.biases[-1]


def observation_bounds(contract: PolicyContract) -> np.ndarray:
    """``(obs_dim,)`` half-widths of the observation space: observations are clipped to ``task.OBS_LIMITS``."""
    p, _, v, _ = OBS_LIMITS
    history = int(contract.observation_options()["observation_history"])
    per_drone = observation_limits(contract.obs_per_drone // history, history)
    if contract.neighbours is not None:  # neighbours' relative position and velocity span twice the bounds
        neighbour = np.repeat([2 * p, 2 * v, 1.0], [3, 3, 1])
        return np.concatenate([per_drone, np.tile(neighbour, contract.neighbours)])
    return np.tile(per_drone, contract.num_drones)


def check_tensors(contract: PolicyContract, tensors: dict[str, np.ndarray]) -> None:
    """Refuse tensors that cannot be the contract's network: names, dtypes, shapes chained layer to layer,
    finite values, ``obs_mean``/``obs_var`` of length ``obs_dim`` with ``obs_var >= 0``."""
    sizes = [contract.obs_dim, *contract.hidden_sizes, contract.act_dim]
    expected = {f"actor.{i}.{part}" for i in range(len(sizes) - 1) for part in ("weight", "bias")}
    if contract.normalize_observations:
        expected |= {"obs_mean", "obs_var"}
    missing, unknown = sorted(expected - set(tensors)), sorted(set(tensors) - expected)
    problems = [f"missing tensor(s) {missing}"] if missing else []
    if unknown:
        problems.append(
            f"unexpected tensor(s) {unknown[:5]} (normalize_observations={contract.normalize_observations})"
        )
    shapes = {f"actor.{i}.weight": (sizes[i + 1], sizes[i]) for i in range(len(sizes) - 1)}
    shapes |= {f"actor.{i}.bias": (sizes[i + 1],) for i in range(len(sizes) - 1)}
    shapes |= {"obs_mean": (contract.obs_dim,), "obs_var": (contract.obs_dim,)}
    for name in sorted(expected & set(tensors)):
        value = tensors[name]
        if not np.issubdtype(value.dtype, np.floating):
            problems.append(f"{name} has dtype {value.dtype}, not a float type")
        elif value.shape != shapes[name]:
            problems.append(f"{name} has shape {list(value.shape)}, the contract needs {list(shapes[name])}")
        elif not np.isfinite(value).all():
            problems.append(f"{name} has {int((~np.isfinite(value)).sum())} NaN or infinite value(s)")
        elif name == "obs_var" and (value < 0).any():
            problems.append(f"obs_var has {int((value < 0).sum())} negative value(s); a variance is >= 0")
        elif name == "obs_var" and (value.astype(np.float64) + contract.obs_epsilon <= 0).any():
            problems.append("obs_var + obs_epsilon is 0 somewhere; the standardisation would divide by 0")
    if problems:
        layers = " -> ".join(map(str, sizes))
        raise PolicyFileError(f"Tensors do not fit the contract (layers {layers}): " + "; ".join(problems) + ".")


def check_outputs(policy: MLPPolicy, samples: int = DRY_RUN_SAMPLES, seed: int = DRY_RUN_SEED) -> None:
    """Run ``policy`` on seeded observations spread over the observation space; refuse non-finite outputs.

    Half the samples are uniform in the observation box, half are typical flight values (a tenth
    of each bound); the box's centre and corners are included.
    """
    high = observation_bounds(policy.contract)
    rng = np.random.default_rng(seed)
    half = samples // 2
    obs = np.concatenate(
        [
            rng.uniform(-high, high, size=(half, high.size)),
            rng.uniform(-high, high, size=(samples - half, high.size)) * 0.1,
            np.stack([np.zeros_like(high), high, -high]),
        ]
    )
    with np.errstate(all="ignore"):
        out = policy.forward(obs)
    bad = ~np.isfinite(out).all(axis=-1)
    if bad.any():
        raise PolicyFileError(
            f"The network gives NaN or infinite actions for {int(bad.sum())} of {len(obs)} test observations "
            f"(seed {seed}); the weights are broken."
        )


def save_policy(path: str | Path, contract: PolicyContract, tensors: dict[str, np.ndarray]) -> Path:
    """Write ``tensors`` (``actor.{i}.weight``/``bias``, optional ``obs_mean``/``obs_var``) and the contract.

    The contract is validated as a reader would (a :class:`PolicyFileError` if it would be refused).
    """
    path = Path(path)
    text = json.dumps(asdict(contract))
    parse_contract(text, where="the contract to save")
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        "format": FORMAT,
        "format_version": str(FORMAT_VERSION),
        "observation_layout": SHARED_OBSERVATION_LAYOUT if contract.is_shared else OBSERVATION_LAYOUT,
        "action_layout": SHARED_ACTION_LAYOUT if contract.is_shared else ACTION_LAYOUT,
        "contract": text,
    }
    save_file({k: np.ascontiguousarray(v, dtype=np.float32) for k, v in tensors.items()}, str(path), metadata=meta)
    return path


def read_contract(path: str | Path) -> PolicyContract:
    """The validated contract of a policy file (its tensors are not checked: use :func:`load_policy`)."""
    return _read(path)[0]


def load_policy(
    path: str | Path, task: TaskConfig | None = None, *, per_drone: bool = False, shared: bool = False
) -> MLPPolicy:
    """Load a policy file for numpy inference, checked as the module docstring says; with ``task``, refuse it
    if the contract does not fit (``shared=True``: a shared, N-free policy is wanted). Every refusal is a
    :class:`PolicyFileError`."""
    contract, tensors = _read(path)
    if task is not None:
        contract.check_compatible(task, per_drone=per_drone, shared=shared)
    try:
        policy = MLPPolicy(contract, tensors)
        check_outputs(policy)
    except PolicyFileError as error:
        raise PolicyFileError(f"{path}: {error}") from None
    return policy


@functools.cache
def _contract_adapter() -> TypeAdapter:
    return TypeAdapter(PolicyContract)


def _no_duplicate_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    keys = [k for k, _ in pairs]
    duplicates = sorted({k for k in keys if keys.count(k) > 1})
    if duplicates:
        raise PolicyFileError(f"the contract repeats key(s) {duplicates}")
    return dict(pairs)


def parse_contract(text: str, where: str = "contract") -> PolicyContract:
    """A :class:`PolicyContract` from its JSON text, validated field by field; :class:`PolicyFileError` if not."""
    try:
        fields = json.loads(text, object_pairs_hook=_no_duplicate_keys)
        contract = _contract_adapter().validate_python(fields)
        contract.check_kind()
        contract.check_observation()
        return contract
    except (json.JSONDecodeError, RecursionError) as error:
        raise PolicyFileError(f"{where} is not valid JSON ({type(error).__name__}: {error}).") from None
    except PolicyFileError as error:
        raise PolicyFileError(f"{where}: {error}.") from None
    except ValidationError as error:
        problems = [_describe(e) for e in error.errors(include_url=False)]
        raise PolicyFileError(f"{where} is invalid: " + "; ".join(problems[:6]) + ".") from None


def _describe(error: dict[str, Any]) -> str:
    """One pydantic error as ``field: what is wrong (got ...)``."""
    where = ".".join(str(part) for part in error["loc"]) or "contract"
    if error["type"] == "missing":
        return f"{where}: required field missing"
    if error["type"] == "unexpected_keyword_argument":
        return f"{where}: unknown field"
    got = repr(error.get("input"))
    return f"{where}: {error['msg']} (got {got[:40] + '...' if len(got) > 40 else got})"


def _read(path: str | Path) -> tuple[PolicyContract, dict[str, np.ndarray]]:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"No policy file at {path}.")
    try:
        with safe_open(str(path), framework="numpy") as handle:
            meta = handle.metadata() or {}
        tensors = load_file(str(path))
    except (SafetensorError, OSError, ValueError, TypeError, OverflowError, MemoryError) as error:
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
    if "contract" not in meta:
        raise PolicyFileError(f"{path} has no contract in its metadata; the file is incomplete.")
    return parse_contract(meta["contract"], where=f"{path}: its contract"), tensors
