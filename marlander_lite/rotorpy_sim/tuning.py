"""Another RotorPy Crazyflie: its mass (unknown to its controller), command latency and loop gains changed.

RotorPy's Crazyflie as published is one drone under one tuning (``rotorpy.vehicles.crazyflie_params``). A lab's drone,
or the next simulator a policy meets, is another. :class:`RotorPyTuning` gives
:class:`~marlander_lite.rotorpy_sim.simulator.RotorPySwarm` those differences, as
:class:`~marlander_lite.pyflyt_sim.tuning.PyFlytTuning` does for PyFlyt, so that random Crazyflies
(:mod:`marlander_lite.experiments.variants`) can be drawn in a third simulator. RotorPy's own ``cmd_vel`` controller
stays what it is (a world-frame velocity P loop asking for a thrust vector, an SE(3) attitude loop); only the numbers
it is built with change. It has no tilt clamp, so none is drawn here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from marlander_lite.envs.options import build_config, check_bounded_fields
from marlander_lite.pointmass.hosted import TUNING_BOUNDS

INERTIA_KEYS = ("Ixx", "Iyy", "Izz", "Ixy", "Iyz", "Ixz")
"""RotorPy's inertia parameters, scaled with the mass (a heavier drone of the same shape)."""


@dataclass(frozen=True)
class RotorPyTuning:
    """How a RotorPy Crazyflie differs from the one RotorPy publishes. The defaults change nothing.

    The controller is not told about the mass: RotorPy's ``cmd_vel`` loop asks for ``m (a_cmd + g)`` and the moment
    ``J (...)`` with the published ``m`` and ``J`` while the body has ``mass_scale`` times both, as a drone with a
    heavier battery flies the firmware it was tuned with.
    """

    mass_scale: float = 1.0
    """Factor on the mass and inertia of the drone, in [0.5, 2]; its controller keeps the published ones."""
    latency_s: float = 0.0
    """How late each velocity command reaches RotorPy's controller (s), in [0, 0.5], rounded to whole control periods
    (1/96 s by default). Before the first command arrives the controller holds the drone still."""
    outer_gain_scale: float = 1.0
    """Factor, in (0, 5], on the velocity loop's gain ``k_v`` (10 1/s as published)."""
    inner_gain_scale: float = 1.0
    """Factor, in (0, 5], on the attitude loop's gains ``kp_att`` and ``kd_att`` (310 and 57 as published)."""

    def __post_init__(self) -> None:
        check_bounded_fields(self, TUNING_BOUNDS)

    def delay_periods(self, control_hz: float) -> int:
        """The latency in whole control periods of ``1 / control_hz`` s (nearest)."""
        return round(self.latency_s * control_hz)

    def vehicle_params(self, params: Mapping[str, Any]) -> dict[str, Any]:
        """RotorPy parameters of the body as flown: ``params`` with the gains scaled and the mass and inertia too."""
        changed = dict(params)
        changed["k_v"] = params["k_v"] * self.outer_gain_scale
        changed["kp_att"] = params["kp_att"] * self.inner_gain_scale
        changed["kd_att"] = params["kd_att"] * self.inner_gain_scale
        changed["mass"] = params["mass"] * self.mass_scale
        for key in INERTIA_KEYS:
            changed[key] = params[key] * self.mass_scale
        return changed


def build_tuning(tuning: RotorPyTuning | Mapping[str, Any] | None) -> RotorPyTuning:
    """The option ``tuning`` as a :class:`RotorPyTuning`: one, a mapping of its fields, or None for none."""
    return build_config(RotorPyTuning, tuning, "RotorPy tuning")
