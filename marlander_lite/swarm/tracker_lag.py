"""The velocity tracker's time constant, identified in flight, for the safety filter's latency compensation.

Not in the paper. :class:`~marlander_lite.swarm.safety_filter.SafetyFilterConfig`'s ``latency_compensation`` ``L``
lets the policy and the guards act on each drone's state predicted ``L`` ahead. The best ``L`` depends on the tracker
that flies the commands: about half its horizontal time constant (docs/transfer.md measured 0.4 s best for PyFlyt's
0.76 s tracker, where 0.12 s left 49 of 400 drones leaving the arena), while a fast tracker loses landing accuracy with
so large an ``L``. A lab seldom knows its tracker's time constant; this module measures it from the flight itself, so
that ``identified_lag_share`` can set ``L`` to a share of it.

**The model.** A first-order velocity tracker that holds the command ``u_k`` for one policy period ``dt`` moves the
velocity from ``v_k`` to

    ``v_{k+1} - u_k = a (v_k - u_k)``,   ``a = exp(-dt / T)``,

``T`` its time constant. Each horizontal axis of each flying drone gives one sample of that line through the origin;
the least-squares slope over every sample of the flight (an ARX fit, in its recursive form [Ljung1999],
docs/references.md) is

    ``a = (w0 a0 + sum (v_{k+1} - u_k)(v_k - u_k)) / (w0 + sum (v_k - u_k)^2)``,

started from a prior ``a0`` (the time constant ``T0`` that ``latency_compensation / identified_lag_share`` implies)
worth ``w0`` (m/s)^2 of samples: with no data it gives ``T0``, and every sample in which the command and the velocity
differ moves it towards the tracker at hand. A tracker with a command delay, a tilt limit or a slow attitude loop
is not first order; the fitted ``T`` then is the first-order lag that best matches it, larger than its velocity-loop
time constant, which is what ``L`` should cover. Samples near the goal height (touchdown stops a drone whatever it
was told) and across a new episode (a jump in position that its velocity does not explain) are left out.
"""

from __future__ import annotations

import numpy as np

PRIOR_WEIGHT = 1.0
"""``w0`` ((m/s)^2): the prior's weight, that of a drone 1 m/s off its command on one axis for one policy period."""
MIN_HEIGHT = 0.05
"""A drone's samples count only while it is this far (m) above its goal, off the ground or pad it lands on."""
RESET_JUMP = 0.25
"""m: a drone whose position moved this much more than its velocity explains has started a new episode."""
TIME_CONSTANT_RANGE = (0.02, 2.0)
"""The identified time constant is kept within these bounds (s): no Crazyflie tracker is faster or slower."""


class TrackerLag:
    """Each env's velocity-tracker time constant (s), from the commands sent and the velocities that followed.

    Args:
        prior: the time constant ``T0`` (s) assumed before any sample, within :data:`TIME_CONSTANT_RANGE`.
        dt: the policy period (s), the time between two :meth:`observe` calls.
        prior_weight: ``w0`` ((m/s)^2), how many squared m/s of command-velocity difference the prior is worth.
    """

    def __init__(self, prior: float, dt: float, prior_weight: float = PRIOR_WEIGHT) -> None:
        low, high = TIME_CONSTANT_RANGE
        if not (low <= prior <= high and dt > 0 and prior_weight > 0):
            raise ValueError(
                f"TrackerLag needs a prior time constant within [{low}, {high}] s, dt > 0 and prior_weight > 0; got "
                f"prior={prior!r}, dt={dt!r}, prior_weight={prior_weight!r}."
            )
        self.prior, self.dt, self.prior_weight = float(prior), float(dt), float(prior_weight)
        self._prior_slope = np.exp(-self.dt / self.prior)
        self._moment: np.ndarray | None = None  # (E,) sum (v_{k+1} - u_k)(v_k - u_k), prior included
        self._power: np.ndarray | None = None  # (E,) sum (v_k - u_k)^2, prior included
        self._samples: np.ndarray | None = None  # (E,) how many drone-steps gave a sample since the prior
        self._last: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # p, v relative, v world at step k
        self._command: np.ndarray | None = None  # the command sent at step k

    def reset(self, envs: np.ndarray | None = None) -> None:
        """Forget what ``envs`` ((E,) bool; None: all) have flown: their estimate is the prior again."""
        if self._moment is None or envs is None:
            self._moment = self._power = self._samples = None
            self._last = self._command = None
            return
        assert self._power is not None and self._samples is not None
        self._moment[envs] = self.prior_weight * self._prior_slope
        self._power[envs] = self.prior_weight
        self._samples[envs] = 0

    def restart(
        self, envs: np.ndarray, rel_goal: np.ndarray, rel_velocity: np.ndarray, pad_velocity: np.ndarray | None = None
    ) -> None:
        """Start the envs ``envs`` (indices) afresh, as new flights: their estimate is the prior again and their next
        sample starts from this state (``(k, N, 3)`` arrays, one row per env in ``envs``, as :meth:`observe` takes);
        the other envs keep what they identified. Before the first :meth:`observe`, ``envs`` must be every env."""
        envs = np.asarray(envs)
        rel_goal, rel_velocity = np.array(rel_goal, dtype=float), np.array(rel_velocity, dtype=float)
        velocity = rel_velocity if pad_velocity is None else rel_velocity + np.asarray(pad_velocity, dtype=float)
        if self._moment is None or self._last is None:
            if not np.array_equal(envs, np.arange(len(rel_goal))):
                raise ValueError(
                    "TrackerLag.restart() before the first observe() must restart every env (indices 0 to E - 1), "
                    f"to know how many there are; got {envs.tolist()}."
                )
            self.reset()
            self.observe(rel_goal, rel_velocity, pad_velocity)
            return
        mask = np.zeros(len(self._moment), dtype=bool)
        mask[envs] = True
        self.reset(mask)
        for last, now in zip(self._last, (rel_goal, rel_velocity, velocity), strict=True):
            last[envs] = now

    def skip(self) -> None:
        """Take no sample across the next step (the loop paused, or the time since the last :meth:`observe` was not
        ``dt``): the next :meth:`observe` only records its state. What was identified stays."""
        self._last = self._command = None

    def time_constant(self) -> np.ndarray:
        """The identified time constant of every env ``(E,)`` s (the prior before the first :meth:`observe`)."""
        if self._moment is None or self._power is None:
            return np.array([self.prior])
        low, high = TIME_CONSTANT_RANGE
        slope = np.clip(self._moment / self._power, np.exp(-self.dt / low), np.exp(-self.dt / high))
        return -self.dt / np.log(slope)

    def samples(self) -> np.ndarray:
        """How many samples (one per airborne drone and policy step) every env's estimate rests on ``(E,)`` (``(1,)``
        zero before the first :meth:`observe`): what a user of the estimate may wait for before trusting it."""
        return np.zeros(1, dtype=np.int64) if self._samples is None else self._samples.copy()

    def observe(
        self, rel_goal: np.ndarray, rel_velocity: np.ndarray, pad_velocity: np.ndarray | None = None
    ) -> np.ndarray:
        """Take this step's measured state; return every env's time constant ``(E,)`` s, for this step's command.

        The samples are the step from the previous call's state, under the command :meth:`commanded` recorded then.

        Args:
            rel_goal: eq. 2's ``p`` (position minus goal) of every drone ``(E, N, 3)`` m.
            rel_velocity: eq. 2's ``v`` (velocity relative to the pad) of every drone ``(E, N, 3)`` m/s.
            pad_velocity: every drone's pad velocity ``(E, N, 3)`` m/s, in the commands' frame; None: pads at rest.
        """
        rel_goal, rel_velocity = np.asarray(rel_goal, dtype=float), np.asarray(rel_velocity, dtype=float)
        velocity = rel_velocity if pad_velocity is None else rel_velocity + np.asarray(pad_velocity, dtype=float)
        if rel_goal.ndim != 3 or rel_goal.shape[-1] != 3 or velocity.shape != rel_goal.shape:
            raise ValueError(
                f"TrackerLag.observe() needs (E, N, 3) arrays of one shape, got {rel_goal.shape}, {rel_velocity.shape}"
                f" and {None if pad_velocity is None else np.shape(pad_velocity)}."
            )
        envs = len(rel_goal)
        if self._moment is None or self._power is None or len(self._moment) != envs:
            self._moment = np.full(envs, self.prior_weight * self._prior_slope)
            self._power = np.full(envs, self.prior_weight)
            self._samples = np.zeros(envs, dtype=np.int64)
            self._last = None
        if self._last is not None and self._command is not None:
            last_goal, last_rel_velocity, last_velocity = self._last
            # p follows the velocity relative to the pad; across a new episode it jumps
            explained = last_goal + 0.5 * (last_rel_velocity + rel_velocity) * self.dt
            jumped = (np.linalg.norm(rel_goal - explained, axis=-1) > RESET_JUMP).any(axis=-1)
            self.reset(jumped)
            before = (last_velocity - self._command)[..., :2]
            after = (velocity - self._command)[..., :2]
            airborne = (last_goal[..., 2] > MIN_HEIGHT) & (rel_goal[..., 2] > MIN_HEIGHT) & ~jumped[:, None]
            # a drone motion capture lost (NaN) gives no sample, and leaves no NaN in the sums
            usable = airborne & np.isfinite(before).all(axis=-1) & np.isfinite(after).all(axis=-1)
            before, after = np.where(usable[..., None], before, 0.0), np.where(usable[..., None], after, 0.0)
            self._moment += np.einsum("enk,enk,en->e", after, before, usable)
            self._power += np.einsum("enk,enk,en->e", before, before, usable)
            assert self._samples is not None
            self._samples += usable.sum(axis=-1)
        self._last, self._command = (rel_goal.copy(), rel_velocity.copy(), np.array(velocity)), None
        return self.time_constant()

    def commanded(self, command: np.ndarray) -> None:
        """Record the velocity command ``(E, N, 3)`` m/s sent after the last :meth:`observe` (the commands' frame)."""
        command = np.asarray(command, dtype=float)
        if self._last is None or command.shape != self._last[0].shape:
            raise ValueError(
                "TrackerLag.commanded() records the command for the state of the last observe() call, of its shape "
                f"{None if self._last is None else self._last[0].shape}; got {command.shape}."
            )
        self._command = command
