"""What a trial measured, and the statistics of a table cell (paper Sec. IV, Tables I and II).

Per trial (:class:`TrialMetrics`): each drone's landing error (horizontal distance from its pad
centre at touchdown, cm), success (every drone landed on its own pad, no collision, within the
time limit), landing time (s, when the last drone touched down) and the smallest distance between
two drones (m).

Per cell of trials (:func:`summarise`): success rate with a Wilson 95 % interval; mean and median
landing error with a seeded percentile-bootstrap 95 % interval that resamples *trials* (the two
drones of one trial share a platform and a start, so their errors are not independent); mean
landing time of the successful trials. Everything is numpy; scipy only checks it in the tests.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from statistics import NormalDist
from typing import Literal, get_args

import numpy as np

from marlander_lite.episodes import StepOutcome

Outcome = Literal["success", "collision", "crash", "out-of-arena", "timeout"]
OUTCOMES: tuple[str, ...] = get_args(Outcome)
Statistic = Literal["mean", "median"]


@dataclass(frozen=True)
class TrialMetrics:
    """The measurements of one finished trial (one episode of one swarm)."""

    outcome: Outcome
    """Why the episode ended: ``success``, or the first failure (collision, crash, out-of-arena, timeout)."""
    landed: tuple[bool, ...]
    """Per drone: it touched down on its own pad, within the pad radius, slowly enough."""
    landing_error_cm: tuple[float, ...]
    """Per drone: horizontal distance of its centre from its pad centre at touchdown (cm); NaN if it did not land."""
    landing_time_s: float
    """Time from the start until the last drone touched down (s); NaN unless every drone landed."""
    min_separation_m: float
    """Smallest distance between two drone centres during the trial (m); inf for one drone."""
    duration_s: float
    """Length of the episode (s)."""

    @property
    def success(self) -> bool:
        """All drones on their own pads, no collision, within the time limit."""
        return self.outcome == "success"

    @classmethod
    def from_outcome(cls, outcome: StepOutcome, dt: float, env: int = 0) -> TrialMetrics:
        """Read the metrics of environment ``env`` from the :class:`StepOutcome` of its episode's last step.

        Args:
            outcome: the outcome of the step at which the episode ended (``outcome.done[env]``).
            dt: policy period (s), to turn the episode length into seconds.
            env: which environment of the batch.
        """
        if not outcome.done[env]:
            raise ValueError("The episode has not ended yet: take the metrics from the step where done is True.")
        if outcome.success[env]:
            result: Outcome = "success"
        elif outcome.collided[env]:
            result = "collision"
        elif outcome.crashed[env].any():
            result = "crash"
        elif outcome.out_of_arena[env].any():
            result = "out-of-arena"
        else:
            result = "timeout"
        landed = outcome.landed[env]
        errors_cm = np.where(landed, outcome.landing_error[env] * 100.0, np.nan)
        landing_time = float(np.max(outcome.landing_time[env])) if landed.all() else math.nan
        return cls(
            outcome=result,
            landed=tuple(bool(x) for x in landed),
            landing_error_cm=tuple(float(x) for x in errors_cm),
            landing_time_s=landing_time,
            min_separation_m=float(outcome.min_separation[env]),
            duration_s=float(outcome.episode_length[env] * dt),
        )


def wilson_interval(successes: int, trials: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion ``k / n``.

    ``centre = (p + z^2 / 2n) / (1 + z^2 / n)``,
    ``half = z / (1 + z^2 / n) * sqrt(p (1 - p) / n + z^2 / 4n^2)``, with ``p = k / n`` and ``z``
    the ``(1 + confidence) / 2`` normal quantile (1.95996 for 95 %). Unlike ``p +- z se`` it stays
    in ``[0, 1]`` and is not empty at ``k = 0`` or ``k = n``. Returns ``(nan, nan)`` for ``n = 0``.
    Source: Wilson 1927 (docs/references.md).
    """
    if trials < 0 or not 0 <= successes <= max(trials, 0):
        raise ValueError(f"Need 0 <= successes <= trials, got successes={successes}, trials={trials}.")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}.")
    if trials == 0:
        return math.nan, math.nan
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    n, p = trials, successes / trials
    denominator = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denominator
    half = z / denominator * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def _statistic(values: np.ndarray, statistic: Statistic) -> np.ndarray:
    """Mean or median over every non-NaN entry of each resample: ``(B, n, ...)`` -> ``(B,)``."""
    flat = values.reshape(values.shape[0], -1)
    with _quiet_all_nan():
        return np.nanmean(flat, axis=1) if statistic == "mean" else np.nanmedian(flat, axis=1)


@contextmanager
def _quiet_all_nan() -> Iterator[None]:
    """Silence numpy's 'Mean of empty slice' warnings: an all-NaN resample gives NaN on purpose."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        yield


def point_estimate(sample: np.ndarray, statistic: Statistic) -> float:
    """``statistic`` over every non-NaN entry of ``sample``; NaN if there is none."""
    return float(_statistic(np.asarray(sample, dtype=float)[None], statistic)[0])


def bootstrap_ci(
    sample: np.ndarray,
    statistic: Statistic = "mean",
    confidence: float = 0.95,
    n_resamples: int = 4000,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile-bootstrap interval of the mean or median of ``sample``, resampling its rows.

    Args:
        sample: ``(n,)`` values, or ``(n, k)`` with one row per trial (e.g. the landing errors of
            its ``k`` drones, NaN where a drone did not land). Rows are drawn with replacement, so
            values of one trial stay together (a cluster bootstrap).
        statistic: ``"mean"`` or ``"median"`` over all non-NaN values of a resample.
        confidence: coverage of the interval.
        n_resamples: bootstrap resamples ``B``.
        seed: seed of the resampling (the same seed gives the same interval).

    Returns ``(low, high)``: the ``(1 - confidence) / 2`` and ``(1 + confidence) / 2`` quantiles of
    the ``B`` resampled statistics; ``(nan, nan)`` if the sample holds no value.
    """
    if statistic not in get_args(Statistic):
        raise ValueError(f"Unknown statistic {statistic!r}; allowed: {', '.join(get_args(Statistic))}.")
    values = np.asarray(sample, dtype=float)
    if values.ndim not in (1, 2):
        raise ValueError(f"sample must be (n,) or (n, k), got shape {values.shape}.")
    if values.size == 0 or np.isnan(values).all():
        return math.nan, math.nan
    rng = np.random.default_rng(seed)
    n = values.shape[0]
    stats = np.empty(n_resamples)
    chunk = max(1, 2_000_000 // max(values.size, 1))
    for start in range(0, n_resamples, chunk):
        stop = min(start + chunk, n_resamples)
        idx = rng.integers(0, n, size=(stop - start, n))
        stats[start:stop] = _statistic(values[idx], statistic)
    stats = stats[~np.isnan(stats)]
    tail = (1 - confidence) / 2
    low, high = np.percentile(stats, [100 * tail, 100 * (1 - tail)])
    return float(low), float(high)


@dataclass(frozen=True)
class CellSummary:
    """Statistics of one table cell: the trials of one controller on one condition (or group)."""

    trials: int
    """Number of trials n."""
    successes: int
    """Trials where every drone landed on its own pad without a collision, within the time limit."""
    success_rate: float
    """``successes / trials`` (fraction)."""
    success_low: float
    """Wilson 95 % interval of the success rate: lower end."""
    success_high: float
    """Wilson 95 % interval: upper end."""
    landed_drones: int
    """Drones (over all trials) that landed on their own pad: the landing errors averaged below."""
    error_mean_cm: float
    """Mean landing error over every landed drone (cm)."""
    error_mean_low: float
    """Bootstrap 95 % interval of the mean error: lower end (cm)."""
    error_mean_high: float
    """Upper end (cm)."""
    error_median_cm: float
    """Median landing error over every landed drone (cm)."""
    error_median_low: float
    """Bootstrap 95 % interval of the median: lower end (cm)."""
    error_median_high: float
    """Upper end (cm)."""
    error_per_drone_cm: tuple[float, ...]
    """Mean landing error of each drone index (cm); the paper reports 2.67 / 3.26 cm (static)."""
    time_mean_s: float
    """Mean landing time of the successful trials (s); NaN if none succeeded."""
    time_median_s: float
    """Median landing time of the successful trials (s)."""
    min_separation_m: float
    """Smallest inter-drone distance seen in any trial (m)."""
    outcome_counts: dict[str, int]
    """Trials per outcome (``OUTCOMES``)."""


def summarise(trials: Sequence[TrialMetrics], seed: int = 0, n_resamples: int = 4000) -> CellSummary:
    """Statistics of a cell of trials (see the module doc). ``seed`` seeds the bootstrap."""
    n = len(trials)
    if n == 0:
        raise ValueError("Cannot summarise an empty cell: it has no trials.")
    successes = sum(t.success for t in trials)
    low, high = wilson_interval(successes, n)
    errors = np.array([t.landing_error_cm for t in trials], dtype=float)  # (n, N), NaN = not landed
    mean_ci = bootstrap_ci(errors, "mean", seed=seed, n_resamples=n_resamples)
    median_ci = bootstrap_ci(errors, "median", seed=seed, n_resamples=n_resamples)
    times = np.array([t.landing_time_s for t in trials if t.success], dtype=float)
    with _quiet_all_nan():
        per_drone = tuple(float(x) for x in np.nanmean(errors, axis=0))
    counts = {name: sum(t.outcome == name for t in trials) for name in OUTCOMES}
    return CellSummary(
        trials=n,
        successes=successes,
        success_rate=successes / n,
        success_low=low,
        success_high=high,
        landed_drones=int((~np.isnan(errors)).sum()),
        error_mean_cm=point_estimate(errors, "mean"),
        error_mean_low=mean_ci[0],
        error_mean_high=mean_ci[1],
        error_median_cm=point_estimate(errors, "median"),
        error_median_low=median_ci[0],
        error_median_high=median_ci[1],
        error_per_drone_cm=per_drone,
        time_mean_s=float(times.mean()) if len(times) else math.nan,
        time_median_s=float(np.median(times)) if len(times) else math.nan,
        min_separation_m=float(min(t.min_separation_m for t in trials)),
        outcome_counts=counts,
    )
