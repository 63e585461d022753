"""Several PyBullet swarms in one process, behind one batched :class:`~marlander_lite.episodes.Simulator`.

Each swarm keeps its own PyBullet world (:class:`~marlander_lite.crazyflie.simulator.CrazyflieSwarm`);
what is shared is everything above the physics: one :class:`~marlander_lite.episodes.LandingEpisodes`
evaluates the MDP for all of them with batched numpy, and the policy acts on all of them in one call.
On a small machine that beats one subprocess per swarm, whose per-step messaging costs as much
as the physics of a two-drone swarm (``benchmarks/bench_crazyflie.py``).
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np

from marlander_lite.crazyflie.control import PIDGains
from marlander_lite.crazyflie.firmware import FirmwareGains
from marlander_lite.crazyflie.params import CF2XParams, PhysicsConfig
from marlander_lite.crazyflie.perturb import Controller, Perturbation
from marlander_lite.crazyflie.simulator import CrazyflieSwarm
from marlander_lite.episodes import SwarmState
from marlander_lite.platforms import PlatformConfig
from marlander_lite.pointmass.kernels import Engine
from marlander_lite.task import TaskConfig

_ONE = np.zeros(1, dtype=int)


class CrazyflieBatch:
    """``num_envs`` Crazyflie swarms stepped in turn; state arrays are ``(num_envs, N, ...)``.

    Implements :class:`~marlander_lite.episodes.Simulator`. Arguments as :class:`CrazyflieSwarm`.
    """

    def __init__(
        self,
        task_config: TaskConfig,
        platform: PlatformConfig,
        num_envs: int = 1,
        physics: PhysicsConfig | None = None,
        drone: CF2XParams | None = None,
        gains: PIDGains | None = None,
        controller: Controller = "pid",
        perturbation: Perturbation | None = None,
        engine: Engine = "auto",
        firmware_gains: FirmwareGains | None = None,
    ) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}.")
        self.task, self.platform, self.num_envs = task_config, platform, num_envs
        self.swarms = [
            CrazyflieSwarm(
                task_config, platform, 1, physics, drone, gains, False, controller, perturbation, firmware_gains, engine
            )
            for _ in range(num_envs)
        ]

    def reset(self, env_ids: np.ndarray, rng: np.random.Generator) -> None:
        for i in np.asarray(env_ids):
            self.swarms[i].reset(_ONE, rng)

    def step(self, velocity: np.ndarray) -> None:
        for k, swarm in enumerate(self.swarms):
            swarm.step(velocity[k : k + 1])

    def state(self) -> SwarmState:
        states = [swarm.state() for swarm in self.swarms]
        return SwarmState(**{f.name: np.concatenate([getattr(s, f.name) for s in states]) for f in fields(SwarmState)})

    def land(self, landed: np.ndarray) -> None:
        for k in np.flatnonzero(landed.any(axis=1)):
            self.swarms[k].land(landed[k : k + 1])

    def close(self) -> None:
        for swarm in self.swarms:
            swarm.close()
