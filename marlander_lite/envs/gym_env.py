"""Gymnasium face: one swarm, the paper's centralised observation and action."""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from marlander_lite.envs.options import centralised_action_space, centralised_observation_space, policy_input
from marlander_lite.episodes import LandingEpisodes, Simulator, StepOutcome
from marlander_lite.sensing import SensingConfig


def step_info(outcome: StepOutcome, env: int = 0) -> dict[str, Any]:
    """The ``info`` dict of one environment after a step, SI units.

    Every step: ``landed``, ``crashed``, ``out_of_arena`` (per drone), ``collided`` and
    ``min_separation`` (m, so far). At the episode's last step also ``is_success``,
    ``landing_error`` (m, per drone, NaN where a drone did not land) and ``landing_time`` (s).
    """
    info: dict[str, Any] = {
        "landed": outcome.landed[env].copy(),
        "crashed": outcome.crashed[env].copy(),
        "out_of_arena": outcome.out_of_arena[env].copy(),
        "collided": bool(outcome.collided[env]),
        "min_separation": float(outcome.min_separation[env]),
    }
    if outcome.done[env]:
        info["is_success"] = bool(outcome.success[env])
        info["landing_error"] = outcome.landing_error[env].copy()
        info["landing_time"] = outcome.landing_time[env].copy()
    return info


class SwarmLandingEnv(gym.Env):
    """Centralised landing env over any :class:`~marlander_lite.episodes.Simulator` with one env.

    Subclasses build the simulator and document the env (see :class:`PointMassLandingEnv`).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": []}

    def __init__(self, simulator: Simulator, sensing: SensingConfig) -> None:
        if simulator.num_envs != 1:
            raise ValueError("A gymnasium env drives one swarm; use make_vec_env for batches.")
        self.simulator = simulator
        self.task = simulator.task
        self.platform = simulator.platform
        self.num_drones = self.task.num_drones
        self.episodes = LandingEpisodes(simulator, sensing)
        self.observation_space = centralised_observation_space(self.task)
        self.action_space = centralised_action_space(self.num_drones)
        self._started = False

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        if options:
            raise ValueError(f"reset() takes no options, got {sorted(options)}; set options when making the env.")
        self.episodes.rng = self.np_random
        obs = self.episodes.reset()
        self._started = True
        return policy_input(obs)[0], {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self._started:
            raise RuntimeError("The episode has not started or has ended: call reset() before step().")
        a = np.asarray(action)
        n = self.num_drones
        if a.shape not in ((3 * n,), (n, 3)):
            raise ValueError(f"Action has shape {a.shape}; this env takes ({3 * n},) or ({n}, 3), entries in [-1, 1].")
        outcome = self.episodes.step(a[None, ...])
        if outcome.done[0]:
            self._started = False
        obs = policy_input(outcome.obs)[0]
        return (
            obs,
            float(outcome.reward[0]),
            bool(outcome.terminated[0]),
            bool(outcome.truncated[0]),
            step_info(outcome),
        )

    def close(self) -> None:
        self.simulator.close()
