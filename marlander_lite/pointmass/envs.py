"""The point-mass simulator's three faces: gymnasium, stable-baselines3 VecEnv, PettingZoo."""

from __future__ import annotations

from collections.abc import Sequence
from types import MappingProxyType
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from marlander_lite.envs.gym_env import SwarmLandingEnv
from marlander_lite.envs.options import (
    COMMON_OPTIONS,
    build_configs,
    centralised_action_space,
    centralised_observation_space,
    policy_input,
    reject_unknown,
)
from marlander_lite.envs.parallel_env import SwarmParallelEnv
from marlander_lite.episodes import LandingEpisodes
from marlander_lite.platforms import PlatformConfig
from marlander_lite.pointmass.simulator import PointMassParams, PointMassSwarm
from marlander_lite.sensing import SensingConfig
from marlander_lite.task import TaskConfig

POINTMASS_OPTIONS = (*COMMON_OPTIONS, "dynamics")
_NO_INFO = MappingProxyType({})


def _params(dynamics: PointMassParams | dict | None) -> PointMassParams | None:
    if isinstance(dynamics, dict):
        known = set(PointMassParams.__dataclass_fields__)
        unknown = sorted(set(dynamics) - known)
        if unknown:
            raise TypeError(f"Unknown dynamics field(s) {unknown}; allowed: {sorted(known)}.")
        return PointMassParams(**dynamics)
    return dynamics


class PointMassLandingEnv(SwarmLandingEnv):
    """``marlander_lite/PointMassLanding-v0``: land N point-mass drones on their own pads.

    ## Description
    The MARLander task (Aschu et al.) in its lightweight simulator. N drones start at random in a
    4 x 4 x 4 m arena and must each land on their own pad of a plate that lies on the floor, is
    held up by a UR10 arm, or is moved by it. One centralised policy sees every drone and
    commands every drone's velocity, as in the paper. Each drone is a point mass that tracks its
    velocity command through a first-order lag with an acceleration limit; its attitude follows
    the thrust direction.

    ## Action Space
    ``Box(-1, 1, (3N,), float32)``: for each drone in turn, a velocity command along world x, y, z
    as a fraction of ``max_speed`` (3 m/s) (eq. 3). Entries beyond [-1, 1] are clipped; NaN
    raises ``ValueError``.

    ## Observation Space
    ``Box((13N,), float32)``: for each drone in turn (eq. 2), its position relative to its goal
    point (pad centre raised by ``landed_height``) [m], its attitude quaternion (x, y, z, w), its
    velocity relative to the platform [m/s] and its angular velocity [rad/s], world frame.

    ## Rewards
    Eq. 4: ``R_t = sum_i [alpha (|p_{t-1}| - |p_t|) + beta |v_t| + c 1(lands now)] - alpha_c
    1(collision) + K 1(all landed now)``, with the constants of :class:`~marlander_lite.task.TaskConfig`.

    ## Starting State
    Platform placed uniformly where its whole path fits in the arena (height 0 on the floor,
    0.5-1.0 m on the UR10, random phase when moving); drones uniform in the arena, at least
    0.3 m above the plate and 0.5 m apart, at rest and level.

    ## Episode End
    Terminated when every drone has landed (success), or when a drone touches anything other than
    its own pad slowly (slower than 0.5 m/s relative) and within the pad radius (crash), two drones
    come closer than 0.15 m (collision), or a drone leaves the arena. Truncated after
    ``episode_seconds`` (10 s, 240 steps at 24 Hz).

    ## Arguments
    ``gymnasium.make("marlander_lite/PointMassLanding-v0", num_drones=2, platform="static-floor",
    platform_speed=None, task=None, sensing=None, dynamics=None)``: ``platform`` is one of
    ``static-floor``, ``static-elevated``, ``moving-linear``, ``moving-arc``; ``platform_speed`` the
    moving tool speed (m/s, default 0.35); ``task`` a :class:`TaskConfig` or dict of fields to change;
    ``sensing`` a :class:`SensingConfig` or ``"vicon"`` for motion-capture noise and latency;
    ``dynamics`` a :class:`~marlander_lite.pointmass.simulator.PointMassParams` or a dict of its fields.
    """

    def __init__(
        self,
        num_drones: int = 2,
        platform: str | PlatformConfig = "static-floor",
        platform_speed: float | None = None,
        task: TaskConfig | dict | None = None,
        sensing: SensingConfig | str | None = None,
        dynamics: PointMassParams | dict | None = None,
        **unknown: Any,
    ) -> None:
        reject_unknown(unknown, POINTMASS_OPTIONS, "PointMassLanding-v0")
        task_config, platform_config, sensing_config = build_configs(
            num_drones, platform, platform_speed, task, sensing
        )
        super().__init__(PointMassSwarm(task_config, platform_config, 1, _params(dynamics)), sensing_config)


def pointmass_parallel_env(
    num_drones: int = 2,
    platform: str | PlatformConfig = "static-floor",
    platform_speed: float | None = None,
    task: TaskConfig | dict | None = None,
    sensing: SensingConfig | str | None = None,
    dynamics: PointMassParams | dict | None = None,
    **unknown: Any,
) -> SwarmParallelEnv:
    """PettingZoo ``ParallelEnv`` of the point-mass swarm; options as :class:`PointMassLandingEnv`."""
    reject_unknown(unknown, POINTMASS_OPTIONS, "pointmass_parallel_env")
    task_config, platform_config, sensing_config = build_configs(num_drones, platform, platform_speed, task, sensing)
    return SwarmParallelEnv(PointMassSwarm(task_config, platform_config, 1, _params(dynamics)), sensing_config)


class PointMassVecEnv(VecEnv):
    """Natively batched stable-baselines3 ``VecEnv``: ``num_envs`` swarms in one set of numpy arrays.

    Same task, spaces and options as :class:`PointMassLandingEnv`. Stepping costs a fixed number
    of numpy operations whatever ``num_envs`` is. Finished environments are reset at once, the
    SB3 way: the returned observation is the new episode's first one, and ``infos[i]`` holds
    ``terminal_observation``, ``TimeLimit.truncated``, ``is_success``, ``landing_error`` (mean
    over the drones that landed, m; NaN if none did), ``landing_time`` (s until the last drone
    landed; NaN unless all did), ``min_separation`` (m) and ``episode`` (``r``, ``l``, ``t``), so no
    ``VecMonitor`` is needed. ``infos`` of unfinished envs are one shared, read-only empty mapping.
    """

    def __init__(
        self,
        num_envs: int = 1,
        num_drones: int = 2,
        platform: str | PlatformConfig = "static-floor",
        platform_speed: float | None = None,
        task: TaskConfig | dict | None = None,
        sensing: SensingConfig | str | None = None,
        dynamics: PointMassParams | dict | None = None,
        seed: int | None = None,
        **unknown: Any,
    ) -> None:
        reject_unknown(unknown, (*POINTMASS_OPTIONS, "num_envs", "seed"), "PointMassVecEnv")
        if isinstance(num_envs, bool) or not isinstance(num_envs, int | np.integer) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}.")
        task_config, platform_config, sensing_config = build_configs(
            num_drones, platform, platform_speed, task, sensing
        )
        self.task, self.platform, self.render_mode = task_config, platform_config, None
        self.simulator = PointMassSwarm(task_config, platform_config, int(num_envs), _params(dynamics))
        self.episodes = LandingEpisodes(self.simulator, sensing_config, seed)
        self._actions: np.ndarray | None = None
        self._elapsed = 0.0
        super().__init__(int(num_envs), centralised_observation_space(num_drones), centralised_action_space(num_drones))
        if seed is not None:
            self.seed(seed)

    def reset(self) -> np.ndarray:
        if self._seeds[0] is not None:
            self.episodes.seed(self._seeds[0])
        self._reset_seeds()
        self._reset_options()
        return policy_input(self.episodes.reset())

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async().")
        outcome = self.episodes.step(self._actions)
        self._actions = None
        self._elapsed += self.task.dt
        obs = policy_input(outcome.obs)
        done = outcome.done
        # Unfinished envs share one immutable empty mapping: building 4096 fresh dicts per step
        # would cost more than the physics, and immutability means no wrapper can pollute it.
        infos: list[Any] = [_NO_INFO] * self.num_envs
        if done.any():
            ids = np.flatnonzero(done)
            landed = outcome.landed[ids]
            count = np.maximum(landed.sum(axis=1), 1)
            mean_error = np.where(
                landed.any(axis=1), np.where(landed, outcome.landing_error[ids], 0.0).sum(axis=1) / count, np.nan
            )
            last_landing = np.where(
                landed.all(axis=1), np.nanmax(np.where(landed, outcome.landing_time[ids], -1.0), axis=1), np.nan
            )
            columns = zip(
                ids.tolist(),
                obs[ids],
                outcome.truncated[ids].tolist(),
                outcome.success[ids].tolist(),
                mean_error.tolist(),
                last_landing.tolist(),
                outcome.min_separation[ids].tolist(),
                outcome.episode_return[ids].tolist(),
                outcome.episode_length[ids].tolist(),
                strict=True,
            )
            for i, terminal, truncated, success, error, landing_time, separation, ret, length in columns:
                infos[i] = {
                    "terminal_observation": terminal,
                    "TimeLimit.truncated": truncated,
                    "is_success": success,
                    "landing_error": error,
                    "landing_time": landing_time,
                    "min_separation": separation,
                    "episode": {"r": ret, "l": length, "t": self._elapsed},
                }
            obs[ids] = policy_input(self.episodes.reset(ids))
        return obs, outcome.reward.astype(np.float32), done, infos

    def close(self) -> None:
        self.simulator.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        method = getattr(self, method_name)
        return [method(*method_args, **method_kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None for _ in range(self.num_envs)]
