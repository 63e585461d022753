"""The stable-baselines3 face of a batched simulator: all environments in one set of arrays."""

from __future__ import annotations

from collections.abc import Sequence
from types import MappingProxyType
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from marlander_lite.envs.options import centralised_action_space, centralised_observation_space, policy_input
from marlander_lite.episodes import LandingEpisodes, Simulator
from marlander_lite.sensing import SensingConfig
from marlander_lite.task import compiled_kernels

_NO_INFO = MappingProxyType({})


def episode_summaries(
    env_ids: np.ndarray, landed: np.ndarray, landing_error: np.ndarray, landing_time: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """For the ended envs ``env_ids`` ``(k,)``: the mean landing error over the drones that landed (m; NaN if none
    did) and the time the last drone landed (s; NaN unless all did), each ``(k,)``. ``landed``, ``landing_error`` and
    ``landing_time`` are ``(num_envs, N)`` records of :class:`~marlander_lite.episodes.StepOutcome`. The numpy lines
    are the reference; with numba one compiled pass gives the same numbers (``task_kernels.episode_summaries``).
    """
    # The kernel adds a row as numpy does up to 128 drones; beyond that numpy splits the row further.
    kernel_fits = landed.shape[1] <= 128 and landed.dtype == bool and landing_error.dtype == landing_time.dtype == float
    if compiled_kernels() is not None and kernel_fits:
        # Imported here: task_kernels imports marlander_lite.pointmass, whose envs import this module.
        from marlander_lite import task_kernels

        out = np.empty((len(env_ids), 2))
        task_kernels.episode_summaries(np.asarray(env_ids, dtype=np.int64), landed, landing_error, landing_time, out)
        return out[:, 0], out[:, 1]
    landed = landed[env_ids]
    count = np.maximum(landed.sum(axis=1), 1)
    mean_error = np.where(landed.any(axis=1), np.where(landed, landing_error[env_ids], 0.0).sum(axis=1) / count, np.nan)
    last_landing = np.where(
        landed.all(axis=1), np.nanmax(np.where(landed, landing_time[env_ids], -1.0), axis=1), np.nan
    )
    return mean_error, last_landing


class InProcessVecEnv(VecEnv):
    """The SB3 ``VecEnv`` methods of an env whose swarms all live in this process as one object.

    Attribute and method calls go to that one object, once per requested index; no sub-env is ever
    wrapped and none renders. Both the centralised :class:`LandingVecEnv` and the shared-policy
    ``swarm.vec_env.SharedSwarmVecEnv`` build on it.
    """

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


class LandingVecEnv(InProcessVecEnv):
    """SB3 ``VecEnv`` over a :class:`~marlander_lite.episodes.Simulator` holding ``num_envs`` swarms.

    One :class:`~marlander_lite.episodes.LandingEpisodes` evaluates every env at once, so the
    MDP costs a fixed number of numpy operations whatever ``num_envs`` is. Finished environments
    are reset at once, the SB3 way: the returned observation is the new episode's first one, and
    ``infos[i]`` holds ``terminal_observation``, ``TimeLimit.truncated``, ``is_success``,
    ``landing_error`` (mean over the drones that landed, m; NaN if none did), ``landing_time`` (s
    until the last drone landed; NaN unless all did), ``min_separation`` (m) and ``episode``
    (``r``, ``l``, ``t``), so no ``VecMonitor`` is needed. ``infos`` of unfinished envs are one
    shared, read-only empty mapping.
    """

    def __init__(self, simulator: Simulator, sensing: SensingConfig, seed: int | None = None) -> None:
        self.simulator = simulator
        self.task, self.platform, self.render_mode = simulator.task, simulator.platform, None
        self.episodes = LandingEpisodes(simulator, sensing, seed)
        self._actions: np.ndarray | None = None
        self._elapsed = 0.0
        task = simulator.task
        super().__init__(
            simulator.num_envs, centralised_observation_space(task), centralised_action_space(task.num_drones)
        )
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
            mean_error, last_landing = episode_summaries(
                ids, outcome.landed, outcome.landing_error, outcome.landing_time
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
