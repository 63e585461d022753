"""Another PyFlyt Crazyflie: its mass, command latency, loop gains, tilt clamp and body drag changed.

PyFlyt's ``cf2x`` as shipped is one drone under one tuning. A lab's drone, or the next simulator a policy meets, is
another: a heavier battery, a slower radio link, loops tuned harder or softer, another tilt clamp. :class:`PyFlytTuning`
gives :class:`~marlander_lite.pyflyt_sim.simulator.PyFlytSwarm` those differences, the way
:class:`~marlander_lite.crazyflie.perturb.Perturbation` gives them to our PyBullet swarm, so that random Crazyflies
(:mod:`marlander_lite.experiments.variants`) can be drawn in a simulator this project did not write. PyFlyt's own
controller stays what it is (its cascaded PID in ground-velocity mode, ``quadx.py``); only the numbers it is built with
change. The gain names are PyFlyt's ``cf2x.yaml`` blocks.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from marlander_lite.envs.options import build_config, check_bounded_fields
from marlander_lite.pointmass.hosted import TUNING_BOUNDS

PYFLYT_TILT_LIMIT_DEG = math.degrees(0.4)
"""PyFlyt's ``cf2x`` tilt clamp: its ``lin_vel`` loop's output (an attitude setpoint, rad) is clipped at 0.4 rad."""


@dataclass(frozen=True)
class PyFlytTuning:
    """How a PyFlyt Crazyflie differs from the ``cf2x`` PyFlyt ships. The defaults change nothing.

    The controller is not told about the mass: PyFlyt's vertical PID has no weight feed-forward, and its integrator
    starts warm for the true mass (an episode begins after take-off, as in the PyBullet swarm's firmware tracker).
    """

    mass_scale: float = 1.0
    """Factor on the mass and inertia of every link of the drone, in [0.5, 2]."""
    latency_s: float = 0.0
    """How late each velocity command reaches PyFlyt's controller (s), in [0, 0.5], rounded to whole control periods
    (1/120 s at PyFlyt's own rate). Before the first command arrives the controller holds the drone still."""
    outer_gain_scale: float = 1.0
    """Factor, in (0, 5], on the velocity loops' kp, ki and kd: ``lin_vel`` (horizontal) and ``z_vel`` (vertical)."""
    inner_gain_scale: float = 1.0
    """Factor, in (0, 5], on the roll and pitch gains of the attitude loops: ``ang_pos`` kp and ``ang_vel`` kp, ki
    and kd (yaw is left alone)."""
    tilt_limit_deg: float | None = None
    """The clamp on the attitude setpoint the velocity loop asks for (deg), in [5, 80]; None keeps PyFlyt's
    :data:`PYFLYT_TILT_LIMIT_DEG`."""
    body_drag: bool = True
    """False turns off PyFlyt's body drag (its ``drag_params``: linear and rotational), the rigid body alone."""

    def __post_init__(self) -> None:
        bounds = [*TUNING_BOUNDS, ("tilt_limit_deg", 5.0, 80.0, False)]
        check_bounded_fields(self, bounds, optional=("tilt_limit_deg",))  # None keeps PyFlyt's clamp
        if not isinstance(self.body_drag, bool):
            raise ValueError(f"PyFlytTuning.body_drag must be True or False, got {self.body_drag!r}.")

    def delay_periods(self, control_hz: float) -> int:
        """The latency in whole control periods of ``1 / control_hz`` s (nearest)."""
        return round(self.latency_s * control_hz)


def build_tuning(tuning: PyFlytTuning | Mapping[str, Any] | None) -> PyFlytTuning:
    """The option ``tuning`` as a :class:`PyFlytTuning`: one, a mapping of its fields, or None for none."""
    return build_config(PyFlytTuning, tuning, "PyFlyt tuning")


def apply_tuning(aviary: Any, quad: Any, tuning: PyFlytTuning) -> None:
    """Change PyFlyt drone ``quad`` in ``aviary`` (a PyBullet client) as ``tuning`` says, before its first flight.

    The gains are the drone's ``K*`` arrays, from which every ``set_mode`` builds its attitude and velocity PIDs, and
    its vertical PIDs' own gains (those PyFlyt builds once).
    """
    if tuning.mass_scale != 1.0:
        for link in range(-1, aviary.getNumJoints(quad.Id)):
            mass, _, inertia, *_ = aviary.getDynamicsInfo(quad.Id, link)
            aviary.changeDynamics(
                quad.Id,
                link,
                mass=mass * tuning.mass_scale,
                localInertiaDiagonal=[v * tuning.mass_scale for v in inertia],
            )
    outer, inner = tuning.outer_gain_scale, tuning.inner_gain_scale
    for name in ("Kp_lin_vel", "Ki_lin_vel", "Kd_lin_vel"):
        setattr(quad, name, np.asarray(getattr(quad, name), dtype=float) * outer)
    z_vel = quad.z_PIDs[0]
    z_vel.kp, z_vel.ki, z_vel.kd = z_vel.kp * outer, z_vel.ki * outer, z_vel.kd * outer
    roll_pitch = np.array([inner, inner, 1.0])
    for name in ("Kp_ang_pos", "Kp_ang_vel", "Ki_ang_vel", "Kd_ang_vel"):
        setattr(quad, name, np.asarray(getattr(quad, name), dtype=float) * roll_pitch)
    if tuning.tilt_limit_deg is not None:
        quad.lim_lin_vel = np.full_like(np.asarray(quad.lim_lin_vel, dtype=float), math.radians(tuning.tilt_limit_deg))
    if not tuning.body_drag:
        quad.body.drag_consts = np.zeros_like(quad.body.drag_consts)
        quad.drag_coef_pqr = 0.0
