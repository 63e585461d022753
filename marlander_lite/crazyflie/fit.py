"""Fit the point-mass simulator to the PyBullet Crazyflie (issue 3, deliverable 6).

The point-mass drone (:class:`~marlander_lite.pointmass.simulator.PointMassSwarm`) follows a
velocity command through a first-order lag of time constant ``tau`` whose change of velocity
is capped at ``a_max dt``. :func:`measure_responses` records how the PyBullet Crazyflie under its
cascaded PID answers the same kind of commands, and :func:`fit_point_mass` finds the
``(tau, a_max)`` that make the point mass answer alike, by least squares on the velocity traces
(Gauss-Newton with finite differences, numpy only). Both simulators run through their
:class:`~marlander_lite.episodes.Simulator` interface, so the fit compares the real code paths.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from marlander_lite.crazyflie.params import PhysicsConfig
from marlander_lite.crazyflie.simulator import CrazyflieSwarm
from marlander_lite.platforms import PlatformConfig
from marlander_lite.pointmass.simulator import PointMassParams, PointMassSwarm
from marlander_lite.task import TaskConfig

START = np.array([0.0, 0.0, 2.0])
"""Where every response starts, hovering (m): far from the floor, the plate and the walls."""


def step_commands(amplitudes: tuple[float, ...], axes: tuple[int, ...], steps: int) -> np.ndarray:
    """Constant velocity commands, one per (axis, amplitude) pair: ``(K, steps, 3)`` m/s."""
    pairs = [(axis, amp) for axis in axes for amp in amplitudes]
    commands = np.zeros((len(pairs), steps, 3))
    for k, (axis, amp) in enumerate(pairs):
        commands[k, :, axis] = amp
    return commands


def fit_commands(steps: int = 48) -> np.ndarray:
    """The step commands the point-mass defaults were fitted on: ``(26, steps, 3)`` m/s.

    Along x and y: 0.25, 0.5, 1, 2 and 3 m/s (the paper's speed limit); along z: 0.25, 0.5 and
    0.75 m/s, so that 2 s of climbing or sinking stays within 1.5 m of the 2 m start; each in
    both directions, held for ``steps`` policy steps (2 s at 24 Hz).
    """
    commands = np.concatenate(
        [step_commands((0.25, 0.5, 1.0, 2.0, 3.0), (0, 1), steps), step_commands((0.25, 0.5, 0.75), (2,), steps)]
    )
    return np.concatenate([commands, -commands])


def crazyflie_response(commands: np.ndarray, task: TaskConfig, physics: PhysicsConfig | None = None) -> np.ndarray:
    """Velocities of a PyBullet Crazyflie after each policy step, ``(K, T, 3)`` m/s, for commands ``(K, T, 3)``.

    Each of the K sequences starts from hover at :data:`START`, on a ``static-floor`` platform.
    """
    task = task.replace(num_drones=1)
    sim = CrazyflieSwarm(task, PlatformConfig(), physics=physics)
    out = np.zeros_like(commands)
    try:
        for k, sequence in enumerate(commands):
            sim.place(0, START[None])
            for t, u in enumerate(sequence):
                sim.step(u[None, None])
                out[k, t] = sim.vel[0, 0]
    finally:
        sim.close()
    return out


def point_mass_response(commands: np.ndarray, task: TaskConfig, params: PointMassParams) -> np.ndarray:
    """Velocities of point-mass drones after each policy step, ``(K, T, 3)`` m/s (all K at once, batched)."""
    k = len(commands)
    sim = PointMassSwarm(task.replace(num_drones=1), PlatformConfig(), num_envs=k, params=params)
    sim.reset(np.arange(k), np.random.default_rng(0))
    for e in range(k):
        sim.place(e, START[None])
    out = np.zeros_like(commands)
    for t in range(commands.shape[1]):
        sim.step(commands[:, t, None, :])
        out[:, t] = sim.vel[:, 0]
    return out


@dataclass(frozen=True)
class PointMassFit:
    """Result of :func:`fit_point_mass`."""

    params: PointMassParams
    """The fitted ``velocity_time_constant`` (s) and ``max_acceleration`` (m/s^2)."""
    rms_error: float
    """Root mean square difference of the velocity traces after the fit (m/s)."""
    iterations: int
    """Gauss-Newton iterations run."""


def fit_point_mass(
    commands: np.ndarray,
    target: np.ndarray,
    task: TaskConfig,
    start: PointMassParams | None = None,
    iterations: int = 12,
) -> PointMassFit:
    """Least-squares ``(tau, a_max)`` that make :func:`point_mass_response` match ``target`` ``(K, T, 3)``.

    Gauss-Newton on ``theta = (log tau, log a_max)`` (logs keep both positive): the Jacobian of
    the residual ``r(theta) = v_pm(theta) - target`` comes from central differences, and each
    step solves ``J d = -r`` with ``numpy.linalg.lstsq``, halved until the error falls.
    """
    start = start or PointMassParams()
    theta = np.log([start.velocity_time_constant, start.max_acceleration])
    a_cap = np.log(9.81 * 0.999)

    def residual(th: np.ndarray) -> np.ndarray:
        tau, acc = np.exp(th[0]), np.exp(min(th[1], a_cap))
        return (point_mass_response(commands, task, PointMassParams(tau, acc)) - target).ravel()

    r = residual(theta)
    done = 0
    while done < iterations:
        done += 1
        h = 1e-3
        jac = np.column_stack([(residual(theta + h * e) - residual(theta - h * e)) / (2 * h) for e in np.eye(2)])
        delta = np.linalg.lstsq(jac, -r, rcond=None)[0]
        step, improved = 1.0, False
        while step > 1e-3:
            candidate = residual(theta + step * delta)
            if candidate @ candidate < r @ r:
                theta, r, improved = theta + step * delta, candidate, True
                break
            step /= 2
        if not improved or np.abs(step * delta).max() < 1e-4:
            break
    params = PointMassParams(float(np.exp(theta[0])), float(np.exp(min(theta[1], a_cap))))
    return PointMassFit(params, float(np.sqrt(np.mean(r * r))), done)
