"""The PyFlyt simulator's options and three faces: gymnasium, stable-baselines3 VecEnv, PettingZoo."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from marlander_lite.envs.gym_env import SwarmLandingEnv
from marlander_lite.envs.options import EnvOptions
from marlander_lite.envs.parallel_env import SwarmParallelEnv
from marlander_lite.envs.vec_env import LandingVecEnv
from marlander_lite.pyflyt_sim.simulator import READ_STATES, PyFlytSwarm, ReadState, resolve_control_hz
from marlander_lite.pyflyt_sim.tuning import PyFlytTuning, build_tuning

DRONE_MODELS = ("cf2x",)
"""PyFlyt ``QuadX`` models offered: its Crazyflie 2.x (PyFlyt ships others, not Crazyflies)."""


@dataclass(frozen=True)
class PyFlytOptions(EnvOptions):
    """The options of the PyFlyt envs: the common :class:`~marlander_lite.envs.options.EnvOptions` and PyFlyt's."""

    control_hz: float | None = None
    """Rate of PyFlyt's flight controller (Hz): a whole multiple of the policy rate dividing its 240 Hz physics;
    ``None``, PyFlyt's own 120 Hz where the policy rate divides it, else 240 Hz."""
    drone_model: str = "cf2x"
    """The PyFlyt ``QuadX`` model: ``"cf2x"``, its Crazyflie 2.x."""
    read_state: ReadState = "after_physics"
    """When PyFlyt's controllers read the drone states: ``"after_physics"``, as PyFlyt does since 0.22, or
    ``"before_physics"``, one physics step late, as the pinned 0.21.0 does (``pyflyt_sim.simulator.aviary_class``)."""
    tuning: PyFlytTuning | Mapping[str, Any] | None = None
    """How every drone differs from PyFlyt's ``cf2x``: a :class:`~marlander_lite.pyflyt_sim.tuning.PyFlytTuning` or a
    mapping of its fields (``{"mass_scale": 1.15, "latency_s": 0.06}``); None, the ``cf2x`` as PyFlyt ships it."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.drone_model not in DRONE_MODELS:
            raise ValueError(f"drone_model must be one of {DRONE_MODELS}, got {self.drone_model!r}.")
        if self.read_state not in READ_STATES:
            raise ValueError(
                f"read_state must be one of {READ_STATES}, got {self.read_state!r}: "
                '"after_physics" flies PyFlyt as releases since 0.22 do, "before_physics" as 0.21.0 does.'
            )
        resolve_control_hz(self.control_hz, self.task_config.policy_hz)
        _ = self.tuning_config

    @property
    def tuning_config(self) -> PyFlytTuning:
        """``tuning`` as a :class:`~marlander_lite.pyflyt_sim.tuning.PyFlytTuning`."""
        return build_tuning(self.tuning)

    def make_simulator(self, num_envs: int = 1) -> PyFlytSwarm:
        """``num_envs`` PyFlyt swarms."""
        return PyFlytSwarm(
            self.task_config,
            self.platform_config,
            num_envs,
            self.control_hz,
            self.drone_model,
            self.read_state,
            self.tuning_config,
        )


class PyFlytLandingEnv(SwarmLandingEnv):
    """``marlander_lite/PyFlytLanding-v0``: land N PyFlyt Crazyflies on their own pads.

    ## Description
    The MARLander task (Aschu et al.) in a second simulator this project did not write: PyFlyt's Crazyflie 2.x
    (PyBullet rigid body, motor lag and noise, body drag) under PyFlyt's own cascaded PID in its ground-frame
    velocity mode (:mod:`marlander_lite.pyflyt_sim.simulator`). The plates, pads, starts and contacts are the
    point-mass simulator's. Meant for evaluating policies trained elsewhere.

    ## Action Space
    ``Box(-1, 1, (3N,), float32)``: for each drone in turn, a velocity command along world x, y, z as a fraction of
    ``max_speed`` (3 m/s) (eq. 3), PyFlyt's ``(vx, vy, vz)`` setpoint with zero yaw rate. Entries beyond [-1, 1] are
    clipped; NaN raises ``ValueError``.

    ## Observation Space
    ``Box((13N,), float32)``: for each drone in turn (eq. 2), its position relative to its goal point [m], its
    attitude quaternion (x, y, z, w), its velocity relative to the platform [m/s] and its angular velocity [rad/s],
    world frame.

    ## Rewards
    Eq. 4, with the constants of :class:`~marlander_lite.task.TaskConfig`.

    ## Starting State
    As the point-mass env: drones uniform in the arena, at rest and level; PyFlyt's controller and motors fresh.

    ## Episode End
    As the point-mass env: every drone landed, a crash, a collision, a drone out of the arena, or
    ``episode_seconds``.

    ## Arguments
    ``gymnasium.make("marlander_lite/PyFlytLanding-v0", **fields)`` with the fields of :class:`PyFlytOptions`
    (``num_drones, platform, platform_speed, task, sensing`` as every env, and ``control_hz=None,
    drone_model="cf2x", read_state="after_physics", tuning=None``), or ``options=PyFlytOptions(...)``. ``tuning``
    changes the drone (:class:`~marlander_lite.pyflyt_sim.tuning.PyFlytTuning`: mass, command latency, loop gains,
    tilt clamp, body drag).
    """

    def __init__(self, options: PyFlytOptions | None = None, **fields: Any) -> None:
        options = PyFlytOptions.from_keywords(fields, options, "PyFlytLanding-v0")
        super().__init__(*options.build())


def pyflyt_parallel_env(options: PyFlytOptions | None = None, **fields: Any) -> SwarmParallelEnv:
    """PettingZoo ``ParallelEnv`` of the PyFlyt swarm; options as :class:`PyFlytLandingEnv`."""
    options = PyFlytOptions.from_keywords(fields, options, "pyflyt_parallel_env")
    return SwarmParallelEnv(*options.build())


class PyFlytVecEnv(LandingVecEnv):
    """stable-baselines3 ``VecEnv`` of ``num_envs`` PyFlyt swarms in one process; options as
    :class:`PyFlytLandingEnv`, infos as :class:`~marlander_lite.envs.vec_env.LandingVecEnv`."""

    def __init__(
        self, num_envs: int = 1, seed: int | None = None, options: PyFlytOptions | None = None, **fields: Any
    ) -> None:
        options = PyFlytOptions.from_keywords(fields, options, "PyFlytVecEnv", ("num_envs", "seed"))
        super().__init__(*options.build(num_envs), seed)
