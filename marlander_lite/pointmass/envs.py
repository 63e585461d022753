"""The point-mass simulator's three faces: gymnasium, stable-baselines3 VecEnv, PettingZoo."""

from __future__ import annotations

from typing import Any

from marlander_lite.envs.gym_env import SwarmLandingEnv
from marlander_lite.envs.options import COMMON_OPTIONS, build_configs, check_num_envs, reject_unknown
from marlander_lite.envs.parallel_env import SwarmParallelEnv
from marlander_lite.envs.vec_env import LandingVecEnv
from marlander_lite.platforms import PlatformConfig
from marlander_lite.pointmass.simulator import PointMassParams, PointMassSwarm
from marlander_lite.sensing import SensingConfig
from marlander_lite.task import TaskConfig

POINTMASS_OPTIONS = (*COMMON_OPTIONS, "dynamics")


def build_simulator(
    num_envs: int = 1,
    num_drones: int = 2,
    platform: str | PlatformConfig = "static-floor",
    platform_speed: float | tuple[float, float] | None = None,
    task: TaskConfig | dict | None = None,
    sensing: SensingConfig | str | None = None,
    dynamics: PointMassParams | dict | None = None,
) -> tuple[PointMassSwarm, SensingConfig]:
    """Validate the options (see :class:`PointMassLandingEnv`) and build the simulator."""
    check_num_envs(num_envs)
    task_config, platform_config, sensing_config = build_configs(num_drones, platform, platform_speed, task, sensing)
    if isinstance(dynamics, dict):
        known = set(PointMassParams.__dataclass_fields__)
        unknown = sorted(set(dynamics) - known)
        if unknown:
            raise TypeError(f"Unknown dynamics field(s) {unknown}; allowed: {sorted(known)}.")
        dynamics = PointMassParams(**dynamics)
    return PointMassSwarm(task_config, platform_config, int(num_envs), dynamics), sensing_config


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
        platform_speed: float | tuple[float, float] | None = None,
        task: TaskConfig | dict | None = None,
        sensing: SensingConfig | str | None = None,
        dynamics: PointMassParams | dict | None = None,
        **unknown: Any,
    ) -> None:
        reject_unknown(unknown, POINTMASS_OPTIONS, "PointMassLanding-v0")
        super().__init__(*build_simulator(1, num_drones, platform, platform_speed, task, sensing, dynamics))


def pointmass_parallel_env(
    num_drones: int = 2,
    platform: str | PlatformConfig = "static-floor",
    platform_speed: float | tuple[float, float] | None = None,
    task: TaskConfig | dict | None = None,
    sensing: SensingConfig | str | None = None,
    dynamics: PointMassParams | dict | None = None,
    **unknown: Any,
) -> SwarmParallelEnv:
    """PettingZoo ``ParallelEnv`` of the point-mass swarm; options as :class:`PointMassLandingEnv`."""
    reject_unknown(unknown, POINTMASS_OPTIONS, "pointmass_parallel_env")
    return SwarmParallelEnv(*build_simulator(1, num_drones, platform, platform_speed, task, sensing, dynamics))


class PointMassVecEnv(LandingVecEnv):
    """Natively batched stable-baselines3 ``VecEnv`` of the point-mass swarm: ``num_envs`` swarms in one
    set of numpy arrays, no Python loop over environments. Same task, spaces and options as
    :class:`PointMassLandingEnv`; infos as :class:`~marlander_lite.envs.vec_env.LandingVecEnv`.
    """

    def __init__(
        self,
        num_envs: int = 1,
        num_drones: int = 2,
        platform: str | PlatformConfig = "static-floor",
        platform_speed: float | tuple[float, float] | None = None,
        task: TaskConfig | dict | None = None,
        sensing: SensingConfig | str | None = None,
        dynamics: PointMassParams | dict | None = None,
        seed: int | None = None,
        **unknown: Any,
    ) -> None:
        reject_unknown(unknown, (*POINTMASS_OPTIONS, "num_envs", "seed"), "PointMassVecEnv")
        simulator, sensing_config = build_simulator(
            num_envs, num_drones, platform, platform_speed, task, sensing, dynamics
        )
        super().__init__(simulator, sensing_config, seed)
