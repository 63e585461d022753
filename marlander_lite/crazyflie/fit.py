"""Fit the point-mass simulator to the PyBullet Crazyflie (issue 3, deliverable 6).

The point-mass drone (:class:`~marlander_lite.pointmass.simulator.PointMassSwarm`) follows a
velocity command through a simplified multirotor velocity loop (see
:class:`~marlander_lite.pointmass.simulator.PointMassParams`): velocity-loop time constants, an
attitude-loop time constant, a tilt limit and limits on the collective thrust.
:func:`crazyflie_response` records how the PyBullet Crazyflie under its cascaded PID answers
"go and brake" commands (a velocity held for 0.5 s, then zero), alone along each axis and
combined, up to the paper's 3 m/s; :func:`fit_point_mass` finds the six parameters that make the
point mass answer alike, by least squares on the velocity traces (Gauss-Newton with finite
differences, numpy only). Both simulators run through their
:class:`~marlander_lite.episodes.Simulator` interface, so the fit compares the real code paths.

Combined commands matter: a Crazyflie sinking at full speed has little thrust left to tilt with
and barely accelerates sideways. A model fitted on single-axis steps misses that, and a policy
trained on it dives at its pad and arrives with its sideways speed still unbraked.

Either tracker can be identified (``controller="pid"`` or ``"firmware"``, optionally with a
:class:`~marlander_lite.crazyflie.perturb.Perturbation`); :func:`identify_trackers` fits the point
mass to the variants in :data:`TRACKER_VARIANTS`, which bound the point mass's domain randomisation.
:func:`simulator_response` records any registered simulator the same way, so that the trackers of simulators
this project did not write (RotorPy, PyFlyt) can be placed against those bounds (docs/transfer.md, "PyFlyt"), and
:func:`position_hold` checks that a simulator's tracker holds a hover at all.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from marlander_lite.crazyflie.params import PhysicsConfig
from marlander_lite.crazyflie.perturb import Controller, Perturbation
from marlander_lite.platforms import PlatformConfig
from marlander_lite.pointmass.simulator import PointMassParams, PointMassSwarm
from marlander_lite.simulators import simulator_entry
from marlander_lite.task import TaskConfig

START = np.array([0.0, 0.0, 2.0])
"""Where every response starts, hovering (m): far from the floor, the plate and the walls."""


DIRECTIONS = np.array(
    [
        [1, 0, 0],
        [0, 1, 0],
        [0, 0, 1],
        [0, 0, -1],
        [1, 0, -1],
        [1, 0, 1],
        [1, 1, -1],
        [1, 0, -0.5],
        [0.5, 0, -1],
        [1, 1, 0],
    ]
)
"""Directions of the fit's commands (scaled so the largest component is the amplitude)."""


def fit_commands(hold: int = 12, brake: int = 12) -> np.ndarray:
    """Go-and-brake commands: ``hold`` steps at ``u``, then ``brake`` steps at 0; ``(K, hold + brake, 3)`` m/s.

    ``u`` runs over :data:`DIRECTIONS` (and their mirror images) at amplitudes 0.5, 1.5 and 3 m/s;
    0.5 s at 3 m/s moves the drone about 1 m, so every trace stays inside the arena from :data:`START`.
    """
    directions = np.concatenate([DIRECTIONS, -DIRECTIONS]).astype(float)
    directions /= np.abs(directions).max(axis=1, keepdims=True)
    commands = []
    for amplitude in (0.5, 1.5, 3.0):
        for d in directions:
            sequence = np.zeros((hold + brake, 3))
            sequence[:hold] = amplitude * d
            commands.append(sequence)
    return np.array(commands)


def crazyflie_response(
    commands: np.ndarray,
    task: TaskConfig,
    physics: PhysicsConfig | None = None,
    controller: Controller = "pid",
    perturbation: Perturbation | Mapping[str, Any] | None = None,
) -> np.ndarray:
    """Velocities of a PyBullet Crazyflie after each policy step, ``(K, T, 3)`` m/s, for commands ``(K, T, 3)``.

    Each of the K sequences starts from hover at :data:`START`, on a ``static-floor`` platform,
    flown by ``controller`` with ``perturbation`` (see :class:`~marlander_lite.crazyflie.simulator.CrazyflieSwarm`).
    """
    return simulator_response(
        commands, task, "crazyflie", physics=physics, controller=controller, perturbation=perturbation
    )


def simulator_response(commands: np.ndarray, task: TaskConfig, simulator: str, **options: Any) -> np.ndarray:
    """Velocities of one drone of ``simulator`` after each policy step, ``(K, T, 3)`` m/s, for commands ``(K, T, 3)``.

    ``simulator`` is any registered name whose swarm can ``place`` a drone (``"crazyflie"``, ``"rotorpy"``,
    ``"pyflyt"``, ...); ``options`` go to its swarm class (e.g. ``controller="firmware"``). Each of the K sequences
    starts from hover at :data:`START` on a ``static-floor`` platform, so that any simulator's velocity tracker can be
    identified as the PyBullet ones are (``fit_point_mass(commands, simulator_response(...))``).
    """
    sim = simulator_entry(simulator).swarm_class()(task.replace(num_drones=1), PlatformConfig(), 1, **options)
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


def position_hold(
    task: TaskConfig, simulator: str, seconds: float, gain: float = 1.0, seed: int = 0, **options: Any
) -> np.ndarray:
    """Position errors (m) of one drone of ``simulator`` held at :data:`START` by ``v = -gain (p - START)``, ``(T, 3)``.

    One row per policy step over ``seconds``. A velocity tracker that follows its commands holds a hover this way to
    millimetres; one that wanders shows it here, before any policy is blamed (PyFlyt 0.21.0's step order: its ``cf2x``
    wanders along y and not along x, ``pyflyt_sim.simulator.aviary_class``). ``options`` go to the swarm class.
    """
    sim = simulator_entry(simulator).swarm_class()(task.replace(num_drones=1), PlatformConfig(), 1, **options)
    errors = np.zeros((round(seconds * task.policy_hz), 3))
    try:
        sim.reset(np.arange(1), np.random.default_rng(seed))
        sim.place(0, START[None])
        for t in range(len(errors)):
            sim.step((-gain * (sim.pos[0, 0] - START))[None, None])
            errors[t] = sim.pos[0, 0] - START
    finally:
        sim.close()
    return errors


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


FITTED = (
    "velocity_time_constant",
    "vertical_time_constant",
    "attitude_time_constant",
    "max_tilt_deg",
    "max_climb_acceleration",
    "max_sink_acceleration",
)
"""The :class:`PointMassParams` fields the fit sets."""


@dataclass(frozen=True)
class PointMassFit:
    """Result of :func:`fit_point_mass`."""

    params: PointMassParams
    """The fitted time constants (s), tilt limit (degrees) and thrust limits (m/s^2)."""
    rms_error: float
    """Root mean square difference of the velocity traces after the fit (m/s)."""
    iterations: int
    """Gauss-Newton iterations run."""


def _to_theta(params: PointMassParams) -> np.ndarray:
    values = [getattr(params, name) for name in FITTED]
    values[3] = np.tan(np.radians(values[3]))  # fit the tilt's tangent, like every other value, in logs
    return np.log(values)


def _from_theta(theta: np.ndarray) -> PointMassParams:
    values = np.exp(theta)
    values[3] = np.degrees(np.arctan(values[3]))
    values[5] = min(values[5], 0.99 * 9.81)
    return PointMassParams(**{name: float(v) for name, v in zip(FITTED, values, strict=True)})


def fit_point_mass(
    commands: np.ndarray,
    target: np.ndarray | None = None,
    task: TaskConfig | None = None,
    start: PointMassParams | None = None,
    iterations: int = 15,
    *,
    controller: Controller = "pid",
    perturbation: Perturbation | Mapping[str, Any] | None = None,
    physics: PhysicsConfig | None = None,
) -> PointMassFit:
    """Least-squares point-mass parameters (:data:`FITTED`) matching ``target`` ``(K, T, 3)`` m/s.

    ``target`` defaults to the PyBullet Crazyflie's answer to ``commands``, flown by ``controller``
    (``"pid"`` or ``"firmware"``) with ``perturbation`` and ``physics`` (:func:`crazyflie_response`);
    ``task`` defaults to one drone at the default policy rate.

    Gauss-Newton on the logarithms of the :data:`FITTED` values (the tilt as its tangent; logs
    keep them positive): the Jacobian of the residual ``r = v_pm(theta) - target`` comes from central
    differences, and each step solves ``J d = -r`` with ``numpy.linalg.lstsq``, halved until the
    error falls.
    """
    task = task or TaskConfig(num_drones=1)
    if target is None:
        target = crazyflie_response(commands, task, physics, controller, perturbation)
    theta = _to_theta(start or PointMassParams())

    def residual(th: np.ndarray) -> np.ndarray:
        return (point_mass_response(commands, task, _from_theta(th)) - target).ravel()

    r = residual(theta)
    done = 0
    while done < iterations:
        done += 1
        h = 1e-3
        basis = np.eye(len(theta))
        jac = np.column_stack([(residual(theta + h * e) - residual(theta - h * e)) / (2 * h) for e in basis])
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
    return PointMassFit(_from_theta(theta), float(np.sqrt(np.mean(r * r))), done)


TRACKER_VARIANTS: dict[str, tuple[Controller, Perturbation]] = {
    "pid": ("pid", Perturbation()),
    "firmware": ("firmware", Perturbation()),
    "firmware, gain 0.7": ("firmware", Perturbation(gain_scale=0.7)),
    "firmware, gain 1.3": ("firmware", Perturbation(gain_scale=1.3)),
    "firmware, mass 1.15": ("firmware", Perturbation(mass_scale=1.15)),
}
"""The trackers :func:`identify_trackers` fits by default: name -> (controller, perturbation)."""


def identify_trackers(
    variants: Mapping[str, tuple[Controller, Perturbation]] | None = None,
    commands: np.ndarray | None = None,
    task: TaskConfig | None = None,
    iterations: int = 15,
    start: PointMassParams | None = None,
) -> dict[str, PointMassFit]:
    """Fit the point mass to each tracker variant: name -> :class:`PointMassFit` (params and RMS error).

    Args:
        variants: name -> ``(controller, perturbation)``; default :data:`TRACKER_VARIANTS`.
        commands: the go-and-brake commands ``(K, T, 3)`` m/s; default :func:`fit_commands`.
        task: default one drone at the default policy rate.
        iterations: Gauss-Newton iterations per fit.
        start: first guess (default: the point-mass defaults, the ``"pid"`` fit).
    """
    variants = TRACKER_VARIANTS if variants is None else variants
    commands = fit_commands() if commands is None else commands
    task = task or TaskConfig(num_drones=1)
    return {
        name: fit_point_mass(commands, None, task, start, iterations, controller=controller, perturbation=perturbation)
        for name, (controller, perturbation) in variants.items()
    }


def fits_table(fits: Mapping[str, PointMassFit]) -> str:
    """A Markdown table of :func:`identify_trackers`' result: one row per variant, the :data:`FITTED` values and RMS."""
    header = ["tracker", *FITTED, "RMS (m/s)"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for name, fit in fits.items():
        values = [f"{getattr(fit.params, field):.4g}" for field in FITTED]
        lines.append(f"| {name} | " + " | ".join(values) + f" | {fit.rms_error:.3f} |")
    return "\n".join(lines)
