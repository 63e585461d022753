"""The three controllers the paper compares, behind one interface.

Every controller maps the centralised observation ``O_t`` (eq. 2, ``(13 N,)``: per drone its
position relative to its goal, quaternion, velocity relative to the platform, angular velocity)
to the normalised velocity action ``A_t`` (eq. 3, ``(3 N,)`` in ``[-1, 1]``, 1.0 = ``max_speed``).
The simulator's velocity tracking (point-mass lag, or the Crazyflie's cascaded PID) follows it.

==============================  =================================  ===============================
name                            paper                              what it needs
==============================  =================================  ===============================
``marlander``                   MARLander (Sec. III, IV-B/C)       a centralised N-drone policy file
``baseline``                    PID + APF baseline (Sec. IV-D)     nothing: gains in :class:`APFConfig`
``single-agent-apf``            MorphoLander-style (Sec. IV-E)     a 1-drone policy file
==============================  =================================  ===============================
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Protocol, get_args

import numpy as np

from marlander_lite.experiments import apf
from marlander_lite.experiments.apf import APFConfig
from marlander_lite.platforms import PlateGeometry
from marlander_lite.policy_file import MLPPolicy, load_policy, read_contract
from marlander_lite.task import ACT_PER_DRONE, TaskConfig

ControllerName = Literal["marlander", "baseline", "single-agent-apf", "marlander-plus", "baseline-tuned"]
CONTROLLERS: tuple[str, ...] = get_args(ControllerName)
PAPER_CONTROLLERS: tuple[str, ...] = ("marlander", "baseline", "single-agent-apf")
"""The controllers the paper compares; ``marlander-plus`` and ``baseline-tuned`` are ours (beyond the paper)."""
CONTROLLER_LABELS: dict[str, str] = {
    "marlander": "MARLander (centralised MARL policy)",
    "baseline": "Baseline (PID + APF, textbook)",
    "single-agent-apf": "Single-agent RL + APF (MorphoLander-style)",
    "marlander-plus": "MARLander + platform velocity (ours, beyond the paper)",
    "baseline-tuned": "PID + APF tuned: descent cone + platform-velocity observer (ours)",
}
"""How tables and figures name each controller."""
POLICY_CONTROLLERS: tuple[str, ...] = ("marlander", "single-agent-apf", "marlander-plus")
"""Controllers that fly a policy file."""
DEFAULT_POLICIES: dict[str, dict[str, Path]] = {
    "pointmass": {
        "marlander": Path("data/policies/paper.safetensors"),
        "single-agent-apf": Path("data/policies/single-agent.safetensors"),
        "marlander-plus": Path("data/policies/moving.safetensors"),
    },
    "crazyflie": {
        "marlander": Path("data/policies/paper-robust.safetensors"),
        "single-agent-apf": Path("data/policies/single-agent-smooth-8m.safetensors"),
        "marlander-plus": Path("data/policies/moving-smooth-16m.safetensors"),
    },
}
"""Shipped policy files per simulator and controller; ``--marlander-policy``, ``--single-agent-policy`` and
``--marlander-plus-policy`` override them. The point-mass rows fly the v0.1 policies trained against one nominal
tracker, as the paper trained in one simulator. The PyBullet rows fly policies trained on the point mass only,
against a family of trackers (docs/transfer.md): the point of the paper is a policy that lands where it was not
trained. The PyBullet fine-tunes they replaced are the comparison rows of ``data/results/crazyflie-finetunes``."""


class Controller(Protocol):
    """Observation in, normalised velocity action out; ``reset()`` at the start of every trial."""

    name: str

    def reset(self) -> None:
        """Forget everything from the previous trial (integrators, filters)."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Centralised observation ``(13 N,)`` -> action ``(3 N,)`` in ``[-1, 1]``."""


class MARLanderController:
    """The paper's method: one centralised policy (512-512-256-128 ReLU MLP) for all drones.

    Args:
        policy: a loaded N-drone policy (:func:`~marlander_lite.policy_file.load_policy`).
        name: ``marlander``, or ``marlander-plus`` for a policy that also observes the platform velocity.
    """

    def __init__(self, policy: MLPPolicy, name: str = "marlander") -> None:
        self.policy, self.name = policy, name

    def reset(self) -> None:
        """The policy is a feed-forward network: nothing to reset."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.policy.act(obs)


class PIDAPFController:
    """Baseline of Sec. IV-D: APF planner (attraction + repulsion) with a PID on the position error.

    The velocity it outputs goes through the simulator's velocity tracking exactly like the
    policy's. See :mod:`marlander_lite.experiments.apf` for the potentials and
    :class:`~marlander_lite.experiments.apf.APFConfig` for the gains.

    Args:
        task: the task (``num_drones``, ``max_speed`` to normalise, ``dt`` for the integral).
        config: gains; the tuned defaults unless given (``APFConfig.textbook()`` is the paper's kind).
        geometry: plate geometry, for the pad offsets between drones.
        name: ``baseline`` (textbook gains) or ``baseline-tuned``.
    """

    def __init__(
        self,
        task: TaskConfig,
        config: APFConfig | None = None,
        geometry: PlateGeometry | None = None,
        name: str = "baseline-tuned",
    ):
        self.task, self.name = task, name
        self.config = config or APFConfig()
        self.offsets = apf.plate_offsets(task.num_drones, geometry)
        self.reset()

    def reset(self) -> None:
        """Zero the integral and the observer: every trial starts with the drones at rest."""
        n = self.task.num_drones
        self.integral = np.zeros((n, 2))
        self.command = np.zeros((n, 3))
        self.drone_vel = np.zeros((n, 3))
        self.platform_vel = np.zeros((n, 3))

    def velocity(self, obs: np.ndarray) -> np.ndarray:
        """Commanded velocity of every drone, ``(N, 3)`` m/s; advances the integral and the observer one step.

        ``u = ff * v_platform_hat (horizontal) + u_att + u_rep`` (see :mod:`~marlander_lite.experiments.apf`).
        """
        cfg, dt = self.config, self.task.dt
        p, v = apf.split_observation(obs, self.task.num_drones)
        self.drone_vel, self.platform_vel = apf.observe_platform_velocity(
            self.drone_vel, self.platform_vel, self.command, v, dt, cfg
        )
        e = apf.cone_error(p, cfg)
        self.integral = apf.update_integral(self.integral, e, dt, cfg)
        u = apf.attraction_velocity(e, v, self.integral, cfg) + apf.repulsion_velocity(p, self.offsets, cfg)
        return u + apf.feedforward_velocity(self.platform_vel, e, cfg)

    def act(self, obs: np.ndarray) -> np.ndarray:
        action = np.clip(self.velocity(obs) / self.task.max_speed, -1.0, 1.0)
        self.command = action * self.task.max_speed  # what the drones are really told, for the observer
        return action.reshape(-1)


class SingleAgentAPFController:
    """MorphoLander-style (Sec. IV-E): a 1-drone policy flies each drone, APF repulsion keeps them apart.

    Drone ``i``'s own 13 numbers go through the single-agent policy; the APF repulsion of the
    other drones (m/s, normalised by ``max_speed``) is added to its action, which is then clipped
    to ``[-1, 1]``.

    Args:
        policy: a loaded 1-drone policy (``load_policy(path, task, per_drone=True)``).
        task: the swarm's task (``num_drones``, ``max_speed``).
        config: repulsion gains (``eta``, ``influence_distance``, ``max_repulsion_speed``).
        geometry: plate geometry, for the pad offsets between drones.
    """

    name = "single-agent-apf"

    def __init__(
        self,
        policy: MLPPolicy,
        task: TaskConfig,
        config: APFConfig | None = None,
        geometry: PlateGeometry | None = None,
    ) -> None:
        if policy.contract.num_drones != 1:
            raise ValueError(
                f"The single-agent + APF controller needs a 1-drone policy; this one takes "
                f"{policy.contract.num_drones} drones. Use the policy of the 'single-agent' training preset."
            )
        self.policy, self.task = policy, task
        self.config = config or APFConfig()
        self.offsets = apf.plate_offsets(task.num_drones, geometry)

    def reset(self) -> None:
        """The policy is feed-forward and the repulsion memoryless: nothing to reset."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        n = self.task.num_drones
        per_drone = np.asarray(obs).reshape(n, -1)
        actions = self.policy.act(per_drone)  # (N, 3): the same policy on each drone's own observation
        p, _ = apf.split_observation(obs, n)
        actions = actions + apf.repulsion_velocity(p, self.offsets, self.config) / self.task.max_speed
        return np.clip(actions.reshape(n * ACT_PER_DRONE), -1.0, 1.0)


@dataclass(frozen=True)
class ControllerSpec:
    """Everything needed to build a controller in a worker process (picklable)."""

    name: ControllerName
    """One of ``CONTROLLERS``."""
    policy_path: Path | None = None
    """Policy file of a policy controller; the simulator's default in ``DEFAULT_POLICIES`` if None."""
    apf: APFConfig = field(default_factory=APFConfig)
    """Gains of the baseline, and the repulsion of ``single-agent-apf``."""

    simulator: str = "pointmass"
    """Simulator whose default policy files to use."""

    def __post_init__(self) -> None:
        check_controller_name(self.name)

    def interface_options(self) -> dict[str, bool | int | str]:
        """What this controller's policy file asks for in the observation beyond eq. 2, and the frame its commands are
        read in (``TaskConfig`` fields; see ``PolicyContract.interface_options``); nothing for the baseline."""
        path = self.resolved_policy_path
        if path is None or not path.is_file():
            return {}
        return read_contract(path).interface_options()

    @property
    def resolved_policy_path(self) -> Path | None:
        """The policy file this controller loads (None for the baseline)."""
        if self.name not in POLICY_CONTROLLERS:
            return None
        return Path(self.policy_path) if self.policy_path is not None else DEFAULT_POLICIES[self.simulator][self.name]


def check_controller_name(name: str) -> None:
    """Raise a ``ValueError`` listing the allowed controllers if ``name`` is not one."""
    if name not in CONTROLLERS:
        raise ValueError(f"Unknown controller {name!r}; allowed: {', '.join(CONTROLLERS)}.")


def build_controller(spec: ControllerSpec, task: TaskConfig, geometry: PlateGeometry | None = None) -> Controller:
    """Instantiate the controller ``spec`` describes for ``task``.

    Raises ``FileNotFoundError`` naming the missing policy file and how to get one, and
    :class:`~marlander_lite.policy_file.PolicyFileError` if the file does not fit ``task``.
    """
    if spec.name == "baseline":
        return PIDAPFController(task, APFConfig.textbook(), geometry, name="baseline")
    if spec.name == "baseline-tuned":
        return PIDAPFController(task, spec.apf, geometry, name="baseline-tuned")
    path = spec.resolved_policy_path
    assert path is not None
    if not path.is_file():
        preset = {"single-agent-apf": "single-agent", "marlander-plus": "moving"}.get(spec.name, "quick-cpu")
        raise FileNotFoundError(
            f"The {spec.name!r} controller needs the policy file {path}, which does not exist. Train one "
            f"(training preset {preset!r}) or pass its path; the baseline needs none (--controllers baseline)."
        )
    if spec.name in ("marlander", "marlander-plus"):
        return MARLanderController(load_policy(path, task), name=spec.name)
    return SingleAgentAPFController(load_policy(path, task, per_drone=True), task, spec.apf, geometry)
