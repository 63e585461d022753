"""The pads' acceleration, estimated from the pad velocities a control loop observes, for the safety filter's pad lead.

Not in the paper. :class:`~marlander_lite.swarm.safety_filter.SafetyFilterConfig`'s ``pad_lead`` adds ``T_lead``
times each pad's acceleration to every command, so that a drone whose velocity tracker lags keeps up with a pad
that brakes, reverses or turns. Neither motion capture nor the policy's observation gives that acceleration; it is
differenced from the pad velocities the loop already has, which carry noise. The simulators' filter
(``with_safety_filter``) and the deployment runner each keep one :class:`PadAcceleration`.
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-9


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

    def __init__(self, limit: float = 3.0, smoothing: float = 0.3, max_gap: float = 0.5) -> None:
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
            difference = (velocity - self._velocity) / gap
            size = np.linalg.norm(difference, axis=-1, keepdims=True)
            difference *= np.minimum(1.0, self.limit / np.maximum(size, _EPS))
            estimate = self._estimate + self.smoothing * (difference - self._estimate)
            self._estimate = np.where(size > 2.0 * self.limit, 0.0, estimate)
        self._velocity, self._time = velocity, time
        return self._estimate
