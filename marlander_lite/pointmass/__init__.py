"""The lightweight, natively batched point-mass swarm simulator and its env faces."""

from marlander_lite.pointmass.envs import PointMassLandingEnv, PointMassVecEnv, pointmass_parallel_env
from marlander_lite.pointmass.simulator import PointMassParams, PointMassSwarm

__all__ = ["PointMassLandingEnv", "PointMassParams", "PointMassSwarm", "PointMassVecEnv", "pointmass_parallel_env"]
