"""What a PyBullet swarm's step is timed against: a bare ``stepSimulation`` loop over the same bodies.

Issue 13 asks that a 16-drone :class:`~marlander_lite.crazyflie.CrazyflieSwarm` step cost at most twice the physics
it runs. :func:`bare_step_loop` is that physics alone: the same client, bodies and number of ``stepSimulation`` calls
per policy step (one per control tick), with gravity off so that the drones float as if hovering and nothing touches.
``benchmarks/bench_crazyflie.py`` and notebook 09 time a hovering swarm (:func:`hover_grid`) against it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pybullet as p

from marlander_lite.crazyflie.params import GRAVITY
from marlander_lite.crazyflie.simulator import CrazyflieSwarm


def hover_grid(num_drones: int) -> np.ndarray:
    """Hover positions ``(num_drones, 3)`` (m): level at 1.5 m on a 0.5 m grid, 4 drones a row."""
    return np.array([(0.5 * (i % 4) - 0.75, 0.5 * (i // 4) - 0.25, 1.5) for i in range(num_drones)])


def with_gravity_off(sim: CrazyflieSwarm, fn: Callable[[], None]) -> Callable[[], None]:
    """``fn`` run with ``sim``'s gravity switched off, and back on after it (also when ``fn`` raises)."""

    def run() -> None:
        p.setGravity(0.0, 0.0, 0.0, physicsClientId=sim.client)
        try:
            fn()
        finally:
            p.setGravity(0.0, 0.0, -GRAVITY, physicsClientId=sim.client)

    return run


def bare_physics(sim: CrazyflieSwarm) -> Callable[[], None]:
    """One policy step's physics of ``sim`` alone: ``stepSimulation`` once per control tick, nothing else (gravity
    as it is; wrap it in :func:`with_gravity_off`)."""
    ticks, cid = round(sim.physics.control_hz / sim.task.policy_hz), sim.client

    def run() -> None:
        for _ in range(ticks):
            p.stepSimulation(cid)  # the client id by position, as the simulator passes it

    return run


def bare_step_loop(sim: CrazyflieSwarm) -> Callable[[], None]:
    """:func:`bare_physics` with gravity off: the loop a step of ``sim`` is compared with."""
    return with_gravity_off(sim, bare_physics(sim))
