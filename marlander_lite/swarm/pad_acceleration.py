"""The pads' acceleration, estimated from the pad velocities a control loop observes, for the safety filter's pad lead.

Not in the paper. :class:`~marlander_lite.swarm.safety_filter.SafetyFilterConfig`'s ``pad_lead`` adds ``T_lead``
times each pad's acceleration to every command, so that a drone whose velocity tracker lags keeps up with a pad
that brakes, reverses or turns. Motion capture does not give that acceleration; it is differenced from the pad
velocities the loop already has, which carry noise. The simulators' filter (``with_safety_filter``) and the
deployment runner each keep one :class:`PadAcceleration`. A policy trained with
``TaskConfig.observe_platform_acceleration`` reads the same estimate: the simulators' episodes
(:class:`~marlander_lite.episodes.LandingEpisodes`) run :func:`acceleration_step` on the pad velocities the policy
observed, and the deployment runner a :class:`PadAcceleration` of its own.
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-9
DEFAULT_LIMIT, DEFAULT_SMOOTHING = 3.0, 0.3
"""The estimator's clip (m/s^2) and the share of each new difference in its average (see :class:`PadAcceleration`)."""


def acceleration_step(
    estimate: np.ndarray,
    previous_velocity: np.ndarray,
    velocity: np.ndarray,
    gap: float,
    limit: float = DEFAULT_LIMIT,
    smoothing: float = DEFAULT_SMOOTHING,
) -> np.ndarray:
    """One update of the estimate ``(..., 3)`` m/s^2 from two pad velocities ``(..., 3)`` m/s ``gap`` seconds apart.

    The difference quotient, its norm clipped to ``limit``, enters an exponential average with weight ``smoothing``;
    where the difference exceeds twice ``limit`` (a new episode or a glitch, no pad's motion) the estimate restarts
    at zero. Returns a new array.
    """
    difference = (velocity - previous_velocity) / gap
    size = np.linalg.norm(difference, axis=-1, keepdims=True)
    difference *= np.minimum(1.0, limit / np.maximum(size, _EPS))
    estimate = estimate + smoothing * (difference - estimate)
    return np.where(size > 2.0 * limit, 0.0, estimate)


class PadAcceleration:
    """Each pad's acceleration (m/s^2) from its velocity at successive commands, for the pad lead (``pad_lead``).

    The difference of two pad velocities over the time between them, its norm clipped to ``limit``, then an
    exponential average that takes ``smoothing`` of each new difference: motion capture's 0.02 m/s of velocity noise
    at 24 Hz gives differences spread by 0.7 m/s^2, which would otherwise reach the commands. A difference beyond
    twice ``limit`` is no motion a pad makes but a new episode or a glitch, and that pad's estimate restarts at
    zero; so does every pad's after a gap longer than ``max_gap`` seconds.

    Args:
        limit: largest acceleration credited to a pad (m/s^2); the UR10 scenes reverse at 1 m/s^2.
        smoothing: share of each new difference in the estimate, in (0, 1].
        max_gap: longest time between two updates (s) across which a difference is taken.
    """

    def __init__(
        self, limit: float = DEFAULT_LIMIT, smoothing: float = DEFAULT_SMOOTHING, max_gap: float = 0.5
    ) -> None:
        if not (limit > 0 and 0 < smoothing <= 1 and max_gap > 0):
            raise ValueError(
                f"PadAcceleration needs limit > 0, smoothing in (0, 1] and max_gap > 0; got {limit}, {smoothing}, "
                f"{max_gap}."
            )
        self.limit, self.smoothing, self.max_gap = limit, smoothing, max_gap
        self._velocity: np.ndarray | None = None
        self._time = -np.inf
        self._estimate: np.ndarray | None = None

    def update(self, pad_vel: np.ndarray, time: float) -> np.ndarray:
        """The estimate after the pads' velocities ``pad_vel`` ``(..., 3)`` m/s at ``time`` (s): ``(..., 3)`` m/s^2."""
        velocity = np.array(pad_vel, dtype=float)
        if not np.isfinite(velocity).all():
            raise ValueError("PadAcceleration got a NaN or infinite pad velocity; it needs finite ones.")
        gap = time - self._time
        if self._velocity is None or self._velocity.shape != velocity.shape or not 0 < gap <= self.max_gap:
            self._estimate = np.zeros_like(velocity)
        else:
            self._estimate = acceleration_step(
                self._estimate, self._velocity, velocity, gap, self.limit, self.smoothing
            )
        self._velocity, self._time = velocity, time
        return self._estimate
