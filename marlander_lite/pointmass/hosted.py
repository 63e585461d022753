"""The point-mass simulator's world hosting drones that another simulator flies (RotorPy, PyFlyt).

A simulator written elsewhere brings its own drone and velocity controller but not our world: plates and pads,
their motion, the paper's random starts, contacts with the floor and the plate, landed drones held on their pads.
:class:`HostedDroneSwarm` keeps all of that from :class:`~marlander_lite.pointmass.simulator.PointMassSwarm` and
replaces only how the drones fly during one policy step: ``control_periods`` periods of the other simulator's
controller, each advanced by :meth:`HostedDroneSwarm._fly_period`. A drone that reaches a surface during a period is
flown no further; the inherited contact step then stops it where its path crossed the surface and reports what it
touched, with its impact velocity, as in the point mass. ``marlander_lite.rotorpy_sim`` and
``marlander_lite.pyflyt_sim`` are the two subclasses.
"""

from __future__ import annotations

import numpy as np

from marlander_lite.pointmass.simulator import PointMassSwarm
from marlander_lite.task import CONTACT_NONE


def control_periods(control_hz: float, policy_hz: float) -> int:
    """Control periods of the hosted simulator per policy step, ``control_hz / policy_hz``.

    Raises:
        ValueError: ``control_hz`` is not a whole multiple (>= 1) of the policy rate.
    """
    periods = (
        control_hz / policy_hz if isinstance(control_hz, int | float) and not isinstance(control_hz, bool) else 0.0
    )
    if not (np.isfinite(periods) and periods >= 1 and abs(periods - round(periods)) < 1e-9):
        raise ValueError(
            f"control_hz must be a whole multiple of the policy rate ({policy_hz:g} Hz), got {control_hz!r}; "
            f"for example {4 * policy_hz:g}."
        )
    return round(periods)


TUNING_BOUNDS = (
    ("mass_scale", 0.5, 2.0, False),
    ("latency_s", 0.0, 0.5, False),
    ("outer_gain_scale", 0.0, 5.0, True),
    ("inner_gain_scale", 0.0, 5.0, True),
)
"""What every hosted simulator's tuning (PyFlyt's, RotorPy's) lets change, ``(field, low, high, open_low)``: a mass
the controller does not know about (x0.5-2), command latency (0-0.5 s), the outer and the inner loops' gains
(x0-5, 0 excluded); :func:`~marlander_lite.envs.options.check_bounded_fields` checks them."""


class HostedDroneSwarm(PointMassSwarm):
    """The point mass's world with drones flown by another simulator (see the module docstring).

    Subclasses set :attr:`control_periods` and implement :meth:`_fly_period`; they may override
    :meth:`_after_contacts` to hand our contact step's corrections back to their simulator.
    """

    control_periods: int
    """Control periods of the hosted simulator per policy step."""
    _in_flight: np.ndarray = np.zeros((0, 0, 0, 3))
    """Commands on their way to the controller, ``(delay periods, num_envs, N, 3)`` (see :meth:`_delay_commands`)."""
    _next_slot: int = 0

    def _delay_commands(self, periods: int) -> None:
        """Make every command reach the hosted controller ``periods`` control periods after it was given (a radio's
        latency); until the first one arrives the controller is told to hold still (a zero velocity)."""
        self._in_flight = np.zeros((periods, self.num_envs, self.task.num_drones, 3))
        self._next_slot = 0

    def _arriving(self, velocity: np.ndarray) -> np.ndarray:
        """The commands the controller gets this period: those given ``periods`` ago, ``velocity`` taking their slot;
        ``velocity`` itself without latency."""
        if not len(self._in_flight):
            return velocity
        slot = self._next_slot
        arriving = self._in_flight[slot].copy()
        self._in_flight[slot] = velocity
        self._next_slot = (slot + 1) % len(self._in_flight)
        return arriving

    def reset(self, env_ids: np.ndarray, rng: np.random.Generator) -> None:
        super().reset(env_ids, rng)
        if len(self._in_flight):  # nothing of the last episode is still on its way
            self._in_flight[:, np.atleast_1d(env_ids)] = 0.0

    def step(self, velocity: np.ndarray) -> None:
        velocity = np.asarray(velocity, dtype=float)
        if velocity.shape != self.pos.shape:
            raise ValueError(f"velocity must have shape {self.pos.shape} (num_envs, N, 3), got {velocity.shape}.")
        if not np.isfinite(velocity).all():
            raise ValueError("velocity must be finite (no NaN or inf).")
        self.time += self._dt
        if self.platform.is_moving:
            self._update_platform()
        start = self.pos.copy()
        flying = ~self.landed
        # A drone resting on a surface (before take-off) flies on; one that reaches a surface now is flown no further.
        resting = self.contact != CONTACT_NONE
        reached = np.zeros_like(flying)
        for _ in range(self.control_periods):
            self._fly_period(velocity, flying & ~reached)
            rest_height, _ = self._surface()
            reached |= flying & ~resting & (self.pos[..., 2] <= rest_height)
        self._resolve_contacts(start)
        if self.landed.any():
            self._hold_landed()
        self._after_contacts()

    def _fly_period(self, velocity: np.ndarray, active: np.ndarray) -> None:
        """Fly one control period of the commands ``velocity`` ``(num_envs, N, 3)`` m/s and copy the new states of
        the drones ``active`` ``(num_envs, N)`` selects into our arrays (the others are left as they are)."""
        raise NotImplementedError

    def _after_contacts(self) -> None:
        """Called at the end of every step, after the contact step and the landed drones' hold."""
