"""The policy runner: estimate -> eq. 2 observation -> exported policy -> clamped velocity setpoints.

The observation is built by :func:`marlander_lite.task.observe`, the function both simulators
use, from the estimated state: position relative to the goal point (pad centre raised by
``landed_height``), attitude, velocity relative to the pad, angular velocity. The centralised
policy gets every drone's observation flattened (:func:`marlander_lite.task.flatten_observations`)
and returns one normalised action per drone, which :func:`marlander_lite.task.action_to_velocity`
turns into m/s. The lab speed limit then scales each velocity down to at most ``max_speed`` (its
direction kept): the firmware does not clamp velocity setpoints.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from marlander_lite import task
from marlander_lite.deploy.estimation import SwarmEstimate
from marlander_lite.task import TaskConfig


class Policy(Protocol):
    """Anything that maps ``(1, 13 N)`` observations to ``(1, 3 N)`` actions in [-1, 1] (e.g. ``MLPPolicy``)."""

    def act(self, obs: np.ndarray) -> np.ndarray: ...


class InvalidAction(ValueError):
    """The policy returned something that is not a finite action in [-1, 1]."""


def clamp_speed(velocity: np.ndarray, max_speed: float) -> np.ndarray:
    """Scale each row of ``velocity`` ``(N, 3)`` (m/s) down to a norm of at most ``max_speed``, direction kept."""
    speed = np.linalg.norm(velocity, axis=-1, keepdims=True)
    return velocity * np.minimum(1.0, max_speed / np.maximum(speed, 1e-12))


class PolicyRunner:
    """Runs a policy on estimates.

    Args:
        policy: the exported policy (``marlander_lite.policy_file.load_policy``).
        task_config: the MDP constants the policy was trained with (``num_drones``, ``max_speed``).
        max_speed: lab speed limit (m/s).
    """

    def __init__(self, policy: Policy, task_config: TaskConfig, max_speed: float) -> None:
        self.policy, self.task, self.max_speed = policy, task_config, max_speed

    def observe(self, est: SwarmEstimate) -> np.ndarray:
        """Eq. 2 for every drone, ``(N, 13)`` (``(N, 16)`` when the policy also observes the platform velocity)."""
        pad_vel = est.pad_vel if self.task.observe_platform_velocity else None
        return task.observe(est.pos - est.goal, est.quat, est.vel - est.pad_vel, est.ang_vel, pad_vel)

    def act(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(action (3N,) in [-1, 1], clamped velocity (N, 3) m/s)``; raises :class:`InvalidAction`."""
        flat = task.flatten_observations(obs[None])
        try:
            action = np.asarray(self.policy.act(flat), dtype=float).reshape(-1)
        except (ValueError, FloatingPointError) as error:
            raise InvalidAction(f"the policy failed: {error}") from None
        n3 = self.task.act_dim
        if action.shape != (n3,):
            raise InvalidAction(f"the policy returned {action.size} numbers; {n3} expected")
        if not np.isfinite(action).all() or np.abs(action).max() > 1.0 + 1e-6:
            raise InvalidAction(f"the action {np.round(action, 3).tolist()} is not finite and within [-1, 1]")
        velocity = task.action_to_velocity(action, self.task.num_drones, self.task.max_speed)[0]
        return action, clamp_speed(velocity, self.max_speed)
