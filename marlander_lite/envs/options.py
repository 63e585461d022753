"""Keyword options shared by every environment face, turned into validated configs."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from gymnasium import spaces

from marlander_lite.platforms import PLATFORM_KINDS, PlatformConfig
from marlander_lite.sensing import SensingConfig
from marlander_lite.task import ACT_PER_DRONE, OBS_LIMITS, TaskConfig

COMMON_OPTIONS = ("num_drones", "platform", "platform_speed", "task", "sensing")
"""Keyword options every environment of both simulators accepts."""

# Bounds of one drone's observation; the optional platform velocity has the velocity bound.
_OBS_HIGH = np.repeat(np.array((*OBS_LIMITS, OBS_LIMITS[2]), dtype=np.float32), (3, 4, 3, 3, 3))


def reject_unknown(unknown: Mapping[str, Any], allowed: tuple[str, ...], where: str) -> None:
    """Raise a ``TypeError`` naming unknown keyword options and the allowed ones."""
    if unknown:
        raise TypeError(f"{where} got unknown option(s) {sorted(unknown)}; allowed options: {', '.join(allowed)}.")


def check_num_envs(num_envs: object) -> None:
    """Raise a ``ValueError`` unless ``num_envs`` is an integer >= 1."""
    if isinstance(num_envs, bool) or not isinstance(num_envs, int | np.integer) or num_envs < 1:
        raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}.")


def build_configs(
    num_drones: int = 2,
    platform: str | PlatformConfig = "static-floor",
    platform_speed: float | tuple[float, float] | None = None,
    task: TaskConfig | Mapping[str, Any] | None = None,
    sensing: SensingConfig | str | None = None,
) -> tuple[TaskConfig, PlatformConfig, SensingConfig]:
    """Validate the common options and return ``(task, platform, sensing)`` configs.

    Args:
        num_drones: drones per swarm, N >= 1.
        platform: one of ``PLATFORM_KINDS`` or a full :class:`PlatformConfig`.
        platform_speed: tool speed of a moving platform (m/s), or a ``(low, high)`` range drawn per episode.
        task: a :class:`TaskConfig`, or a mapping of fields to override in the default one.
        sensing: a :class:`SensingConfig`, ``"vicon"`` for the lab's noise and latency, ``"noisy"`` for the
            training aid :meth:`SensingConfig.noisy`, or
            ``None``/``"perfect"`` for none.
    """
    if isinstance(num_drones, bool) or not isinstance(num_drones, int | np.integer) or num_drones < 1:
        raise ValueError(f"num_drones must be an integer >= 1, got {num_drones!r}.")
    if task is None:
        task_config = TaskConfig(num_drones=int(num_drones))
    elif isinstance(task, TaskConfig):
        task_config = task.replace(num_drones=int(num_drones)) if task.num_drones != num_drones else task
    elif isinstance(task, Mapping):
        task_config = TaskConfig().replace(**{"num_drones": int(num_drones), **task})
    else:
        raise TypeError(f"task must be a TaskConfig or a mapping of its fields, got {type(task).__name__}.")
    if isinstance(platform, PlatformConfig):
        platform_config = platform
        if platform_speed is not None:
            raise ValueError("Give platform_speed inside the PlatformConfig, not next to it.")
    elif isinstance(platform, str):
        if platform not in PLATFORM_KINDS:
            raise ValueError(f"Unknown platform {platform!r}; allowed: {', '.join(PLATFORM_KINDS)}.")
        platform_config = PlatformConfig(kind=platform, speed=platform_speed)  # type: ignore[arg-type]
    else:
        raise TypeError(f"platform must be a name in {PLATFORM_KINDS} or a PlatformConfig, got {platform!r}.")
    if sensing is None or sensing == "perfect":
        sensing_config = SensingConfig()
    elif sensing == "vicon":
        sensing_config = SensingConfig.vicon()
    elif sensing == "noisy":
        sensing_config = SensingConfig.noisy()
    elif isinstance(sensing, SensingConfig):
        sensing_config = sensing
    else:
        raise ValueError(f"sensing must be a SensingConfig, 'vicon', 'noisy', 'perfect' or None, got {sensing!r}.")
    return task_config, platform_config, sensing_config


def drone_observation_space(task: TaskConfig) -> spaces.Box:
    """One drone's eq. 2 observation: ``(13,)`` float32 (``(16,)`` with ``observe_platform_velocity``)."""
    high = _OBS_HIGH[: task.obs_per_drone]
    return spaces.Box(-high, high, dtype=np.float32)


def drone_action_space() -> spaces.Box:
    """One drone's eq. 3 action: normalised velocity ``(3,)`` in ``[-1, 1]``."""
    return spaces.Box(-1.0, 1.0, shape=(ACT_PER_DRONE,), dtype=np.float32)


def centralised_observation_space(task: TaskConfig) -> spaces.Box:
    """The paper's flattened input: ``(13 N,)`` float32 (``(16 N,)`` with ``observe_platform_velocity``)."""
    high = np.tile(_OBS_HIGH[: task.obs_per_drone], task.num_drones)
    return spaces.Box(-high, high, dtype=np.float32)


def centralised_action_space(num_drones: int) -> spaces.Box:
    """The paper's output: 3 velocity components per drone, ``(3 N,)`` in ``[-1, 1]``."""
    return spaces.Box(-1.0, 1.0, shape=(ACT_PER_DRONE * num_drones,), dtype=np.float32)


def policy_input(obs: np.ndarray) -> np.ndarray:
    """``(num_envs, N, 13)`` observations as a float32 ``(num_envs, 13 N)`` array, same memory layout."""
    return obs.astype(np.float32, order="K").reshape(obs.shape[0], -1)
