"""The PyBullet Crazyflie 2.x swarm simulator and its env faces (paper Sec. III-F, Fig. 4)."""

from marlander_lite.crazyflie.control import CascadedPID, PIDGains
from marlander_lite.crazyflie.firmware import FirmwareGains, FirmwareTracker
from marlander_lite.crazyflie.params import PHYSICS_PRESETS, CF2XParams, PhysicsConfig
from marlander_lite.crazyflie.perturb import CONTROLLERS, Perturbation
from marlander_lite.crazyflie.simulator import CrazyflieSwarm

__all__ = [
    "CONTROLLERS",
    "PHYSICS_PRESETS",
    "CF2XParams",
    "CascadedPID",
    "CrazyflieSwarm",
    "FirmwareGains",
    "FirmwareTracker",
    "PIDGains",
    "Perturbation",
    "PhysicsConfig",
]
