"""One entry point per face for both simulators: ``make_vec_env`` and ``make_parallel_env``."""

from __future__ import annotations

import importlib
from typing import Any, Literal, get_args

from pettingzoo import ParallelEnv
from stable_baselines3.common.vec_env import VecEnv

SimulatorName = Literal["pointmass", "crazyflie"]
SIMULATORS: tuple[str, ...] = get_args(SimulatorName)

ENV_IDS = {
    "pointmass": "marlander_lite/PointMassLanding-v0",
    "crazyflie": "marlander_lite/CrazyflieLanding-v0",
}
"""Versioned gymnasium ids of the two simulators."""

# Where each simulator's faces live; imported on first use so that the point-mass env never
# loads PyBullet.
_VEC_FACTORIES = {
    "pointmass": "marlander_lite.pointmass.envs:PointMassVecEnv",
    "crazyflie": "marlander_lite.crazyflie.envs:make_crazyflie_vec_env",
}
_PARALLEL_FACTORIES = {
    "pointmass": "marlander_lite.pointmass.envs:pointmass_parallel_env",
    "crazyflie": "marlander_lite.crazyflie.envs:crazyflie_parallel_env",
}


def _load(path: str) -> Any:
    module, name = path.split(":")
    return getattr(importlib.import_module(module), name)


def _check_simulator(simulator: str) -> None:
    if simulator not in SIMULATORS:
        raise ValueError(f"Unknown simulator {simulator!r}; allowed: {', '.join(SIMULATORS)}.")


def make_vec_env(
    simulator: SimulatorName = "pointmass", num_envs: int = 1, seed: int | None = None, **options: Any
) -> VecEnv:
    """A stable-baselines3 ``VecEnv`` of ``num_envs`` swarms.

    ``"pointmass"`` is natively batched (one process, no loop over environments);
    ``"crazyflie"`` keeps every PyBullet world in this process and steps them as one batch by default
    (``vectorization="subprocess"`` runs one world per subprocess instead, see
    :func:`~marlander_lite.crazyflie.envs.make_crazyflie_vec_env`). ``options`` are the env options
    (``num_drones``, ``platform``, ``platform_speed``, ``task``, ``sensing``, and each
    simulator's own), e.g. ``make_vec_env("pointmass", num_envs=256, num_drones=2, seed=0)``.
    """
    _check_simulator(simulator)
    return _load(_VEC_FACTORIES[simulator])(num_envs=num_envs, seed=seed, **options)


def make_parallel_env(simulator: SimulatorName = "pointmass", **options: Any) -> ParallelEnv:
    """A PettingZoo ``ParallelEnv`` with one agent per drone; options as :func:`make_vec_env`."""
    _check_simulator(simulator)
    return _load(_PARALLEL_FACTORIES[simulator])(**options)
