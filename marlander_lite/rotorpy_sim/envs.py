"""The RotorPy simulator's options and three faces: gymnasium, stable-baselines3 VecEnv, PettingZoo."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from marlander_lite.envs.gym_env import SwarmLandingEnv
from marlander_lite.envs.options import EnvOptions
from marlander_lite.envs.parallel_env import SwarmParallelEnv
from marlander_lite.envs.vec_env import LandingVecEnv
from marlander_lite.pointmass.hosted import control_periods
from marlander_lite.rotorpy_sim.simulator import RotorPySwarm, crazyflie_params
from marlander_lite.rotorpy_sim.tuning import RotorPyTuning, build_tuning


@dataclass(frozen=True)
class RotorPyOptions(EnvOptions):
    """The options of the RotorPy envs: the common :class:`~marlander_lite.envs.options.EnvOptions` and RotorPy's."""

    control_hz: float = 96.0
    """Rate of RotorPy's velocity controller and integration periods (Hz), a whole multiple of the policy rate."""
    quad_params: Mapping[str, Any] | None = None
    """Changes to RotorPy's Crazyflie parameters (``{"k_v": 7.0}``); ``None``: as RotorPy publishes them."""
    aero: bool = True
    """RotorPy's rotor drag and induced inflow."""
    tuning: RotorPyTuning | Mapping[str, Any] | None = None
    """How every drone differs from the published Crazyflie: a :class:`~marlander_lite.rotorpy_sim.tuning.RotorPyTuning`
    or a mapping of its fields (``{"mass_scale": 1.15, "latency_s": 0.06}``); None, as RotorPy publishes it."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.aero, bool):
            raise TypeError(f"aero must be True or False, got {self.aero!r}.")
        if self.quad_params is not None and not isinstance(self.quad_params, Mapping):
            kind = type(self.quad_params).__name__
            raise TypeError(f"quad_params must be a mapping of RotorPy parameter names to values, got {kind}.")
        crazyflie_params(self.quad_params)
        control_periods(self.control_hz, self.task_config.policy_hz)
        _ = self.tuning_config

    @property
    def tuning_config(self) -> RotorPyTuning:
        """``tuning`` as a :class:`~marlander_lite.rotorpy_sim.tuning.RotorPyTuning`."""
        return build_tuning(self.tuning)

    def make_simulator(self, num_envs: int = 1) -> RotorPySwarm:
        """``num_envs`` RotorPy swarms."""
        return RotorPySwarm(
            self.task_config,
            self.platform_config,
            num_envs,
            self.control_hz,
            self.quad_params,
            self.aero,
            self.tuning_config,
        )


class RotorPyLandingEnv(SwarmLandingEnv):
    """``marlander_lite/RotorPyLanding-v0``: land N RotorPy Crazyflies on their own pads.

    ## Description
    The MARLander task (Aschu et al.) in a simulator this project did not write: RotorPy's Crazyflie (rigid body,
    rotor lag, rotor drag) under RotorPy's own velocity controller (:mod:`marlander_lite.rotorpy_sim.simulator`).
    The plates, pads, starts and contacts are the point-mass simulator's. Meant for evaluating policies trained
    elsewhere: one 24 Hz step of two drones takes about 20 ms on a 2-core machine, over a thousand times the point
    mass's.

    ## Action Space
    ``Box(-1, 1, (3N,), float32)``: for each drone in turn, a velocity command along world x, y, z as a fraction of
    ``max_speed`` (3 m/s) (eq. 3), RotorPy's ``cmd_v``. Entries beyond [-1, 1] are clipped; NaN raises ``ValueError``.

    ## Observation Space
    ``Box((13N,), float32)``: for each drone in turn (eq. 2), its position relative to its goal point [m], its
    attitude quaternion (x, y, z, w), its velocity relative to the platform [m/s] and its angular velocity [rad/s],
    world frame.

    ## Rewards
    Eq. 4, with the constants of :class:`~marlander_lite.task.TaskConfig`.

    ## Starting State
    As the point-mass env: drones uniform in the arena, at rest and level, rotors at hover speed.

    ## Episode End
    As the point-mass env: every drone landed, a crash, a collision, a drone out of the arena, or
    ``episode_seconds``.

    ## Arguments
    ``gymnasium.make("marlander_lite/RotorPyLanding-v0", **fields)`` with the fields of :class:`RotorPyOptions`
    (``num_drones, platform, platform_speed, task, sensing`` as every env, and ``control_hz=96.0, quad_params=None,
    aero=True, tuning=None``), or ``options=RotorPyOptions(...)``.
    """

    def __init__(self, options: RotorPyOptions | None = None, **fields: Any) -> None:
        options = RotorPyOptions.from_keywords(fields, options, "RotorPyLanding-v0")
        super().__init__(*options.build())


def rotorpy_parallel_env(options: RotorPyOptions | None = None, **fields: Any) -> SwarmParallelEnv:
    """PettingZoo ``ParallelEnv`` of the RotorPy swarm; options as :class:`RotorPyLandingEnv`."""
    options = RotorPyOptions.from_keywords(fields, options, "rotorpy_parallel_env")
    return SwarmParallelEnv(*options.build())


class RotorPyVecEnv(LandingVecEnv):
    """stable-baselines3 ``VecEnv`` of ``num_envs`` RotorPy swarms in one process; options as
    :class:`RotorPyLandingEnv`, infos as :class:`~marlander_lite.envs.vec_env.LandingVecEnv`."""

    def __init__(
        self, num_envs: int = 1, seed: int | None = None, options: RotorPyOptions | None = None, **fields: Any
    ) -> None:
        options = RotorPyOptions.from_keywords(fields, options, "RotorPyVecEnv", ("num_envs", "seed"))
        super().__init__(*options.build(num_envs), seed)
