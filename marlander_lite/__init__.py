"""marlander_lite: the MARLander swarm-landing paper as a small, readable library.

Importing the package registers the gymnasium ids ``marlander_lite/PointMassLanding-v0`` and
``marlander_lite/CrazyflieLanding-v0``.
"""

from gymnasium.envs.registration import register, registry

from marlander_lite.make import ENV_IDS, SIMULATORS, make_parallel_env, make_vec_env
from marlander_lite.platforms import PLATFORM_KINDS, PlatformConfig
from marlander_lite.sensing import SensingConfig
from marlander_lite.task import TaskConfig

__version__ = "0.1.0"

_ENTRY_POINTS = {
    "pointmass": "marlander_lite.pointmass.envs:PointMassLandingEnv",
    "crazyflie": "marlander_lite.crazyflie.envs:CrazyflieLandingEnv",
}
for _name, _env_id in ENV_IDS.items():
    if _env_id not in registry:
        register(id=_env_id, entry_point=_ENTRY_POINTS[_name])

__all__ = [
    "ENV_IDS",
    "PLATFORM_KINDS",
    "SIMULATORS",
    "PlatformConfig",
    "SensingConfig",
    "TaskConfig",
    "__version__",
    "make_parallel_env",
    "make_vec_env",
]
