"""One entry point per face for every simulator: ``make_vec_env`` and ``make_parallel_env``.

Both look the simulator up in :mod:`marlander_lite.simulators`; the gymnasium face is
``gymnasium.make(ENV_IDS[name], ...)``. Options are the fields of the simulator's options dataclass
(:class:`~marlander_lite.envs.options.EnvOptions` and its simulator's subclass), given as keywords, as
an ``options=`` object, or both (keywords win).
"""

from __future__ import annotations

from typing import Any

from pettingzoo import ParallelEnv
from stable_baselines3.common.vec_env import VecEnv

from marlander_lite.envs.options import EnvOptions
from marlander_lite.simulators import REGISTRY, SIMULATORS, SimulatorName, simulator_entry

__all__ = ["ENV_IDS", "SIMULATORS", "SimulatorName", "make_parallel_env", "make_vec_env"]

ENV_IDS: dict[str, str] = {name: REGISTRY[name].env_id for name in SIMULATORS}
"""Versioned gymnasium ids of the built-in simulators, e.g. ``"marlander_lite/PointMassLanding-v0"``."""


def make_vec_env(
    simulator: SimulatorName = "pointmass",
    num_envs: int = 1,
    seed: int | None = None,
    options: EnvOptions | None = None,
    **fields: Any,
) -> VecEnv:
    """A stable-baselines3 ``VecEnv`` of ``num_envs`` swarms.

    ``"pointmass"`` is natively batched (one process, no loop over environments);
    ``"crazyflie"`` keeps every PyBullet world in this process and steps them as one batch by default
    (``vectorization="subprocess"`` runs one world per subprocess instead, see
    :func:`~marlander_lite.crazyflie.envs.make_crazyflie_vec_env`). ``fields`` are the env options
    (``num_drones``, ``platform``, ``platform_speed``, ``task``, ``sensing``, and each simulator's own),
    e.g. ``make_vec_env("pointmass", num_envs=256, num_drones=2, seed=0)``; ``options`` the same as an
    object, e.g. ``options=PointMassOptions(num_drones=2)``.
    """
    factory = simulator_entry(simulator).vec_env_factory()
    return factory(num_envs=num_envs, seed=seed, options=options, **fields)


def make_parallel_env(
    simulator: SimulatorName = "pointmass", options: EnvOptions | None = None, **fields: Any
) -> ParallelEnv:
    """A PettingZoo ``ParallelEnv`` with one agent per drone; options as :func:`make_vec_env`."""
    return simulator_entry(simulator).parallel_env_factory()(options=options, **fields)
