"""The point-mass simulator's options and three faces: gymnasium, stable-baselines3 VecEnv, PettingZoo."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from marlander_lite.envs.gym_env import SwarmLandingEnv
from marlander_lite.envs.options import EnvOptions, config_from_mapping
from marlander_lite.envs.parallel_env import SwarmParallelEnv
from marlander_lite.envs.vec_env import LandingVecEnv
from marlander_lite.pointmass.kernels import Engine, resolve_engine
from marlander_lite.pointmass.simulator import PointMassParams, PointMassSwarm
from marlander_lite.sensing import SensingConfig


@dataclass(frozen=True)
class PointMassOptions(EnvOptions):
    """The options of the point-mass envs: the common :class:`~marlander_lite.envs.options.EnvOptions` and
    the velocity tracker's dynamics."""

    dynamics: PointMassParams | Mapping[str, Any] | None = None
    """A :class:`~marlander_lite.pointmass.simulator.PointMassParams`, a mapping of its fields, or ``None``
    for the defaults (fitted to the PyBullet Crazyflie)."""
    engine: Engine = "auto"
    """``"numpy"`` (the reference), ``"numba"`` (compiled, the same results bit for bit, faster) or ``"auto"``
    (numba when installed, unless ``MARLANDER_LITE_ENGINE=numpy``); see :mod:`marlander_lite.pointmass.kernels`."""

    def __post_init__(self) -> None:
        super().__post_init__()
        _ = self.dynamics_params
        resolve_engine(self.engine)

    @property
    def dynamics_params(self) -> PointMassParams | None:
        """``dynamics`` as a :class:`PointMassParams` (``None``: the simulator's defaults)."""
        if isinstance(self.dynamics, Mapping):
            return config_from_mapping(PointMassParams, self.dynamics, "dynamics (PointMassParams)")
        return self.dynamics

    def make_simulator(self, num_envs: int = 1) -> PointMassSwarm:
        """``num_envs`` point-mass swarms in one set of numpy arrays."""
        return PointMassSwarm(self.task_config, self.platform_config, num_envs, self.dynamics_params, self.engine)


def build_simulator(num_envs: int = 1, **options: Any) -> tuple[PointMassSwarm, SensingConfig]:
    """``(simulator, sensing)`` from :class:`PointMassOptions` fields given as keywords."""
    return PointMassOptions.from_keywords(options, where="pointmass build_simulator").build(num_envs)


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
    Terminated when every drone has landed (success), when a drone crashes, when two drones come
    closer than 0.15 m (collision), or when a drone leaves the arena. A touchdown is a landing when
    the drone touches its own pad, within the pad radius and slower than 0.5 m/s relative to the pad;
    any other contact (the floor, the plate, another pad, too fast, off-centre) is a crash. Truncated after
    ``episode_seconds`` (10 s, 240 steps at 24 Hz).

    ## Arguments
    ``gymnasium.make("marlander_lite/PointMassLanding-v0", **fields)`` with the fields of
    :class:`PointMassOptions` (``num_drones=2, platform="static-floor", platform_speed=None, task=None,
    sensing=None, dynamics=None, engine="auto"``), or ``options=PointMassOptions(...)``: ``platform`` is one of
    ``static-floor``, ``static-elevated``, ``moving-linear``, ``moving-arc``, ``moving-mixed`` (line or
    arc per episode); ``platform_speed`` the moving tool speed (m/s, default 0.35); ``task`` a
    :class:`TaskConfig` or dict of fields to change;
    ``sensing`` a :class:`SensingConfig` or ``"vicon"`` for motion-capture noise and latency;
    ``dynamics`` a :class:`~marlander_lite.pointmass.simulator.PointMassParams` or a dict of its fields.
    """

    def __init__(self, options: PointMassOptions | None = None, **fields: Any) -> None:
        options = PointMassOptions.from_keywords(fields, options, "PointMassLanding-v0")
        super().__init__(*options.build())


def pointmass_parallel_env(options: PointMassOptions | None = None, **fields: Any) -> SwarmParallelEnv:
    """PettingZoo ``ParallelEnv`` of the point-mass swarm; options as :class:`PointMassLandingEnv`."""
    options = PointMassOptions.from_keywords(fields, options, "pointmass_parallel_env")
    return SwarmParallelEnv(*options.build())


class PointMassVecEnv(LandingVecEnv):
    """Natively batched stable-baselines3 ``VecEnv`` of the point-mass swarm: ``num_envs`` swarms in one
    set of numpy arrays, no Python loop over environments. Same task, spaces and options as
    :class:`PointMassLandingEnv`; infos as :class:`~marlander_lite.envs.vec_env.LandingVecEnv`.
    """

    def __init__(
        self, num_envs: int = 1, seed: int | None = None, options: PointMassOptions | None = None, **fields: Any
    ) -> None:
        options = PointMassOptions.from_keywords(fields, options, "PointMassVecEnv", ("num_envs", "seed"))
        super().__init__(*options.build(num_envs), seed)
