"""How fast a policy's drones touch down: the whole distribution, not only the touchdowns that fail.

A touchdown on the own pad counts as a landing only below ``TaskConfig.touchdown_speed_max`` (0.5 m/s), and an
evaluation table counts the failures only. :func:`touchdown_speeds` flies lone drones of a shared policy (N = 1,
the paper's random starts, Vicon sensing) on the point mass with any :class:`DynamicsFamily` and records the speed of
every first touchdown, however fast or slow, so that one sees how close to the limit the policy flies and which
property of the tracker pushes it over (docs/scaling.md, "Why the touchdowns are not soft";
``benchmarks/touchdown_speeds.py`` prints a table of them).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from marlander_lite.envs.options import policy_input
from marlander_lite.platforms import PlatformConfig
from marlander_lite.pointmass.family import DynamicsFamily
from marlander_lite.pointmass.simulator import PointMassParams
from marlander_lite.policy_file import read_contract
from marlander_lite.swarm.evaluation import actor_factory, make_episodes


def touchdown_speeds(
    policy_path: str | Path,
    family: DynamicsFamily,
    episodes: int = 200,
    seed: int = 0,
    filter_settings: dict[str, float] | None = None,
) -> np.ndarray:
    """Speed (m/s, relative to the world) of the first touchdown of each of ``episodes`` lone drones, ``(episodes,)``.

    Args:
        policy_path: a shared policy file.
        family: the point mass's dynamics; each drone draws its own from it (``DynamicsFamily.fixed(...)``: one
            member).
        episodes: lone drones, flown at once, one per env.
        seed: seed of the starts, the dynamics draws and the sensing noise.
        filter_settings: fly through the safety filter with these changes to its defaults (``{}``: its defaults);
            None: the policy alone.

    A drone that never touched anything within the episode (30 s), or left the arena first, gets NaN.
    """
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}.")
    # Under a limit of 1 mm/s every touchdown counts as a crash, and the simulator reports its speed at the contact.
    changes = {"touchdown_speed_max": 1e-3, **read_contract(policy_path).interface_options()}
    swarm = make_episodes(1, episodes, seed, params=PointMassParams(family=family), task_changes=changes)
    controller = "shared" if filter_settings is None else "shared-filter"
    act = actor_factory(
        controller, swarm.task, PlatformConfig(), episodes, policy_path=policy_path, filter_settings=filter_settings
    )(None)
    obs = policy_input(swarm.reset())
    speeds, flying = np.full(episodes, np.nan), np.ones(episodes, dtype=bool)
    for _ in range(round(swarm.task.episode_seconds * swarm.task.policy_hz) + 1):
        outcome = swarm.step(act(obs))
        obs = policy_input(outcome.obs)
        crashed = flying & outcome.crashed[:, 0]
        speeds[crashed] = np.linalg.norm(swarm.sim.state().vel[crashed, 0], axis=-1)
        speeds[flying & outcome.landed_now[:, 0]] = 0.0  # slower than 1 mm/s: a landing even under that limit
        flying &= ~(outcome.terminated | outcome.truncated)
        if not flying.any():
            break
    return speeds
