"""Training aids: what the robust presets add to the MDP while training, and what evaluation switches off.

None of this is in the paper. Each aid is a :class:`~marlander_lite.task.TaskConfig` field whose docstring says
what it does; the shaping penalties below are subtracted from eq. 5's per-drone reward by
:class:`~marlander_lite.episodes.LandingEpisodes` when any of them is on. Every evaluation, the reproduction and
the deployment loop fly the task with :data:`TRAINING_AIDS_OFF` applied. Why each aid exists: docs/transfer.md.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from marlander_lite.rotations import vector_norm
from marlander_lite.task import TaskConfig

TRAINING_AIDS_OFF: dict[str, Any] = {
    "spawn_near_pad_fraction": 0.0,
    "landing_tolerance": None,
    "training_touchdown_speed": None,
    "approach_cone_penalty": 0.0,
    "command_speed_penalty": 0.0,
    "command_error_penalty": 0.0,
    "action_change_penalty": 0.0,
    "landing_precision_bonus": 0.0,
}
"""Every training aid of :class:`TaskConfig` switched off: what evaluation, the reproduction and deployment fly."""


def uses_training_penalties(config: TaskConfig) -> bool:
    """Whether any shaping aid of :func:`training_aid_penalty` is switched on."""
    return bool(
        config.approach_cone_penalty
        or config.command_speed_penalty
        or config.command_error_penalty
        or config.action_change_penalty
    )


def training_aid_penalty(
    command: np.ndarray,
    rel_pos: np.ndarray,
    vel: np.ndarray,
    pad_vel: np.ndarray,
    config: TaskConfig,
    previous_command: np.ndarray | None = None,
) -> np.ndarray:
    """Reward each drone loses this step to the shaping aids (not in the paper), ``(num_envs, N)`` >= 0.

    They ask for flight that any reasonable velocity tracker can follow, so that a policy trained
    on the point mass lands on other simulators and on the real Crazyflie:

    * approach cone: ``approach_cone_penalty * max(0, min(slope r, h_max) - z)`` with ``r`` the horizontal
      and ``z`` the vertical offset from the goal: descend over the pad, not beside it;
    * braking: ``command_speed_penalty * max(0, |u - v_pad| - sqrt(v_f^2 + 2 a d))``: never command a speed
      from which the drone cannot stop at its goal ``d`` metres away;
    * following: ``command_error_penalty * max(0, |u - v| - e_free)``: no command far from the current velocity;
    * smoothness: ``action_change_penalty * |u - u_prev|``: no jitter from one step to the next.

    Args:
        command: velocity commands ``u``, ``(num_envs, N, 3)`` m/s.
        rel_pos: position minus goal, ``(num_envs, N, 3)`` m.
        vel: drone velocity, ``(num_envs, N, 3)`` m/s.
        pad_vel: velocity of each drone's pad, ``(num_envs, N, 3)`` m/s.
        previous_command: the commands of the step before, ``(num_envs, N, 3)`` m/s (zeros after a reset);
            needed only with ``action_change_penalty``.
    """
    penalty = np.zeros(rel_pos.shape[:-1])
    if config.approach_cone_penalty:
        horizontal = np.sqrt(rel_pos[..., 0] ** 2 + rel_pos[..., 1] ** 2)
        wanted = np.minimum(config.approach_cone_slope * horizontal, config.approach_cone_height)
        penalty += config.approach_cone_penalty * np.maximum(wanted - rel_pos[..., 2], 0.0)
    if config.command_speed_penalty:
        allowed = np.sqrt(config.final_approach_speed**2 + 2.0 * config.braking_deceleration * vector_norm(rel_pos))
        excess = vector_norm(command - pad_vel) - allowed
        penalty += config.command_speed_penalty * np.maximum(excess, 0.0)
    if config.command_error_penalty:
        excess = vector_norm(command - vel) - config.command_error_free
        penalty += config.command_error_penalty * np.maximum(excess, 0.0)
    if config.action_change_penalty:
        if previous_command is None:
            raise ValueError("action_change_penalty needs the previous commands.")
        penalty += config.action_change_penalty * vector_norm(command - previous_command)
    return penalty


def landing_precision_reward(
    horizontal_error: np.ndarray, landed_now: np.ndarray, pad_radius: float, config: TaskConfig
) -> np.ndarray:
    """The ``landing_precision_bonus`` aid, ``(num_envs, N)``: ``bonus * (1 - e / r)`` for drones landing this step.

    ``horizontal_error`` ``e`` (m) is each drone's distance from its pad centre in the pad plane; ``r`` is the
    landing radius, ``landing_tolerance`` when set, else ``pad_radius`` (m).
    """
    radius = pad_radius if config.landing_tolerance is None else min(pad_radius, config.landing_tolerance)
    closeness = np.clip(1.0 - horizontal_error / radius, 0.0, 1.0)
    return np.where(landed_now, config.landing_precision_bonus * closeness, 0.0)
