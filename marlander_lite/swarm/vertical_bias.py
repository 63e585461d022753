"""A steady climb or sink the velocity tracker adds to every vertical command, identified in flight and cancelled.

Not in the paper. A velocity tracker without integral action leaves a steady error wherever its feed-forward is wrong:
RotorPy's ``cmd_vel`` loop asks for ``m0 (k_v (u - v) + g)`` with the mass ``m0`` it was built with, so a drone of
mass ``m`` settles at ``v = u + g (m0 - m) / (m k_v)``, climbing when lighter than its controller believes (0.15 m/s
at ``m = 0.87 m0``, ``k_v`` = 10 1/s). A policy that lands slowly asks for 0.1-0.2 m/s down over its pad; such a
drone then hovers there until the time limit (docs/transfer.md, "Random RotorPy Crazyflies"). The Crazyflie firmware's
velocity PID integrates the error away; a lab's other tracker may not.

**The model.** The vertical axis of each drone is a first-order tracker with a bias ``b`` that holds the command
``u_k`` for one policy period:

    ``v_{k+1} - u_k = a (v_k - u_k) + (1 - a) b``,   ``a = exp(-dt / T)``.

That is a line ``y = a x + c`` with ``x = v_k - u_k``, ``y = v_{k+1} - u_k`` and intercept ``c = (1 - a) b``; its
least-squares fit over the drone's airborne samples (an ARX fit with an offset [Ljung1999], docs/references.md),
the slope started from the prior ``a0`` worth :data:`PRIOR_WEIGHT` samples, gives ``b = c / (1 - a)``. The bias has
no prior: in steady flight ``y = x`` and the fit gives ``b = x`` whatever the slope. The fit is per
drone, because each drone carries its own battery, and only on the vertical axis, where gravity makes a wrong
feed-forward show. The compensated command is ``u - b`` on that axis (:meth:`VerticalBias.compensate`), ``b``
clamped to :data:`MAX_BIAS`; until :data:`WARMUP_SAMPLES` samples it is ``u`` unchanged.
``TaskConfig.vertical_bias_compensation`` turns it on in every loop (``marlander transfer --vertical-bias``, the lab
config's ``limits.vertical_bias``). A tracker with integral action (the firmware's) settles at ``b`` = 0 and is flown
as before, up to the transients a first-order fit reads as a bias.
"""

from __future__ import annotations

import numpy as np

PRIOR_WEIGHT = 5.0
"""How many samples of ``x`` = 1 m/s the prior time constant is worth."""
PRIOR_TIME_CONSTANT = 0.15
"""``T0`` (s): the vertical time constant the fit starts from (the firmware's fitted 0.12 s, PyBullet PID's 0.06 s and
RotorPy's 0.1 s lie near it)."""
MIN_HEIGHT = 0.05
"""A drone's samples count only while it is this far (m) above its goal: touchdown stops it whatever it was told."""
WARMUP_SAMPLES = 24
"""Samples (policy steps of one airborne drone, one second at 24 Hz) before the identified bias is flown."""
MAX_BIAS = 0.4
"""The largest bias (m/s) the compensation cancels: no Crazyflie tracker that still flies errs by more."""
SLOPE_RANGE = (0.05, 0.99)
"""``a`` is kept within these bounds so that ``b = c / (1 - a)`` stays finite."""


class VerticalBias:
    """Each drone's steady vertical velocity bias (m/s), from the commands sent and the velocities that followed.

    Args:
        dt: the policy period (s), the time between two :meth:`observe` calls.
        prior_time_constant: ``T0`` (s), the tracker time constant assumed before any sample.
        prior_weight: how many samples of a 1 m/s command-velocity difference the prior is worth.
    """

    def __init__(
        self, dt: float, prior_time_constant: float = PRIOR_TIME_CONSTANT, prior_weight: float = PRIOR_WEIGHT
    ) -> None:
        if not (dt > 0 and prior_time_constant > 0 and prior_weight > 0):
            raise ValueError(
                "VerticalBias needs dt > 0, prior_time_constant > 0 and prior_weight > 0; got "
                f"dt={dt!r}, prior_time_constant={prior_time_constant!r}, prior_weight={prior_weight!r}."
            )
        self.dt, self.prior_weight = float(dt), float(prior_weight)
        self.prior_slope = float(np.exp(-self.dt / prior_time_constant))
        self._sums: np.ndarray | None = None  # (E, N, 5): n, sum x, sum y, sum x^2, sum x y (prior excluded)
        self._last: tuple[np.ndarray, np.ndarray] | None = None  # height above goal, vertical velocity at step k
        self._command: np.ndarray | None = None  # the vertical command flown after step k

    def reset(self, envs: np.ndarray | None = None) -> None:
        """Forget what ``envs`` (indices or an ``(E,)`` mask; None: all) have flown: no bias again."""
        if self._sums is None or envs is None:
            self._sums, self._last, self._command = None, None, None
            return
        self._sums[envs] = 0.0
        if self._last is not None:
            self._last[0][envs] = np.nan  # no sample across a reset

    def observe(self, rel_goal: np.ndarray, velocity: np.ndarray) -> None:
        """Take this step's measured state: eq. 2's ``p`` ``(E, N, 3)`` m and the world velocity ``(E, N, 3)`` m/s.

        The sample is the step from the previous call's state under the command :meth:`commanded` recorded then."""
        rel_goal, velocity = np.asarray(rel_goal, dtype=float), np.asarray(velocity, dtype=float)
        if rel_goal.ndim != 3 or rel_goal.shape[-1] != 3 or velocity.shape != rel_goal.shape:
            raise ValueError(
                f"VerticalBias.observe() needs two (E, N, 3) arrays of one shape, got {rel_goal.shape} and "
                f"{velocity.shape}."
            )
        height, v_z = rel_goal[..., 2], velocity[..., 2]
        if self._sums is None or self._sums.shape[:2] != height.shape:
            self._sums = np.zeros((*height.shape, 5))
        elif self._last is not None and self._command is not None and self._command.shape == height.shape:
            last_height, last_v = self._last
            x, y = last_v - self._command, v_z - self._command
            usable = (last_height > MIN_HEIGHT) & (height > MIN_HEIGHT) & np.isfinite(x) & np.isfinite(y)
            x, y = np.where(usable, x, 0.0), np.where(usable, y, 0.0)
            self._sums += np.stack([usable.astype(float), x, y, x * x, x * y], axis=-1)
        self._last, self._command = (height.copy(), v_z.copy()), None

    def bias(self) -> np.ndarray:
        """Every drone's identified bias ``(E, N)`` m/s (``v - u`` in steady flight), zero before the warm-up."""
        if self._sums is None:
            return np.zeros((1, 1))
        n, sx, sy, sxx, sxy = np.moveaxis(self._sums, -1, 0)
        w, a0 = self.prior_weight, self.prior_slope
        # normal equations of min sum (y - a x - c)^2 + w (a - a0)^2; det >= w n > 0 once there are samples
        m11, m12, m22 = sxx + w, sx, n
        r1, r2 = sxy + w * a0, sy
        det = np.maximum(m11 * m22 - m12 * m12, 1e-12)
        slope = np.clip((r1 * m22 - m12 * r2) / det, *SLOPE_RANGE)
        intercept = (m11 * r2 - m12 * r1) / det
        identified = np.clip(intercept / (1.0 - slope), -MAX_BIAS, MAX_BIAS)
        return np.where(n >= WARMUP_SAMPLES, identified, 0.0)

    def compensate(self, command: np.ndarray) -> np.ndarray:
        """``command`` ``(E, N, 3)`` m/s with each drone's identified bias taken off its vertical part (a copy)."""
        flown = np.array(command, dtype=float)
        if self._sums is not None and self._sums.shape[:2] == flown.shape[:2]:
            flown[..., 2] -= self.bias()
        return flown

    def commanded(self, command: np.ndarray) -> None:
        """Record the command ``(E, N, 3)`` m/s sent after the last :meth:`observe`: the next sample's ``u``."""
        command = np.asarray(command, dtype=float)
        if command.ndim != 3 or command.shape[-1] != 3:
            raise ValueError(f"VerticalBias.commanded() needs an (E, N, 3) array, got {command.shape}.")
        self._command = command[..., 2].copy()

    def skip(self) -> None:
        """Take no sample across the next step (the loop paused, or the time since the last :meth:`observe` was not
        ``dt``): the next :meth:`observe` only records its state. What was identified stays."""
        self._last = self._command = None
