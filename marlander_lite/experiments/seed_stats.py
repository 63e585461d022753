"""Results over training seeds, with interval estimates (Agarwal et al., NeurIPS 2021).

A handful of seeds is too few for a normal-theory interval, and one run can be an outlier either way.
Following "Deep RL at the edge of the statistical precipice" (docs/references.md) we report

- the **interquartile mean** (IQM: the mean of the middle 50 % of runs, ``scipy.stats.trim_mean(x, 0.25)``),
  which ignores one lucky or broken seed yet uses more runs than the median;
- **percentile bootstrap intervals** (``scipy.stats.bootstrap``) of the IQM and of the mean over seeds;
- a **stratified bootstrap** when several conditions are pooled (the runs of each condition are resampled
  within that condition: ``scipy.stats.bootstrap`` with one sample per condition does exactly this);
- **performance profiles**: the fraction of (seed, condition) runs whose score exceeds each threshold tau;
- training **curves** as the IQM over seeds at each step with a bootstrap band (the paper's Fig. 5 and 6).

With fewer than two seeds there is no interval: the bounds are NaN and the tables say "n = 1".
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from marlander_lite.plotting import CURVES, STEPS_COLUMN, read_progress

CONFIDENCE = 0.95
RESAMPLES = 2000


def iqm(values: Any, axis: int | None = None) -> Any:
    """Interquartile mean: the mean of the middle 50 % of ``values`` (along ``axis``)."""
    return stats.trim_mean(np.asarray(values, dtype=float), 0.25, axis=axis)


@dataclass(frozen=True)
class Estimate:
    """A point estimate over seeds with its bootstrap interval."""

    value: float
    low: float
    high: float
    n: int
    """Runs the estimate pools (seeds, or seeds x conditions)."""

    def __str__(self) -> str:
        if self.n < 2 or not np.isfinite(self.low):
            return f"{self.value:.3g} (n = {self.n})"
        return f"{self.value:.3g} [{self.low:.3g}, {self.high:.3g}]"

    def percent(self) -> str:
        """The estimate of a rate as percentages."""
        if self.n < 2 or not np.isfinite(self.low):
            return f"{100 * self.value:.1f} % (n = {self.n})"
        return f"{100 * self.value:.1f} % [{100 * self.low:.1f}, {100 * self.high:.1f}]"


def estimate(samples: Sequence[Any], statistic: Callable[[np.ndarray], float] = iqm, seed: int = 0) -> Estimate:
    """``statistic`` of the pooled ``samples`` with a stratified percentile bootstrap interval.

    Args:
        samples: one array of per-seed scores per stratum (condition); one array for a single condition.
            NaN scores (e.g. the landing error of a seed that never landed) are dropped.
        statistic: a function of the pooled 1-D scores (default :func:`iqm`; ``np.mean`` for the mean).
        seed: seeds the resampling, so the same scores always give the same interval.
    """
    strata = [np.asarray(s, dtype=float) for s in samples]
    strata = [s[np.isfinite(s)] for s in strata]
    strata = [s for s in strata if s.size]
    if not strata:
        return Estimate(float("nan"), float("nan"), float("nan"), 0)
    pooled = np.concatenate(strata)
    value = float(statistic(pooled))
    if any(s.size < 2 for s in strata) or np.ptp(pooled) == 0:
        # scipy cannot resample a single run; identical scores have a zero-width interval.
        width = 0.0 if pooled.size >= 2 and np.ptp(pooled) == 0 else float("nan")
        return Estimate(value, value - width, value + width, int(pooled.size))
    vectorized = _takes_axis(statistic)
    result = stats.bootstrap(
        strata,
        # With an axis, scipy hands all resamples at once (one call instead of one per resample, the same resamples
        # and the same numbers): a training-curve band is 60 of these intervals per curve.
        (lambda *parts, axis: statistic(np.concatenate(parts, axis=axis), axis=axis))
        if vectorized
        else (lambda *parts: statistic(np.concatenate(parts))),
        vectorized=vectorized,
        paired=False,
        n_resamples=RESAMPLES,
        confidence_level=CONFIDENCE,
        method="percentile",
        rng=np.random.default_rng(seed),
    )
    interval = result.confidence_interval
    return Estimate(value, float(interval.low), float(interval.high), int(pooled.size))


def _takes_axis(statistic: Callable[..., Any]) -> bool:
    """Whether ``statistic`` takes an ``axis`` keyword, as :func:`iqm` and ``np.mean`` do."""
    try:
        return "axis" in inspect.signature(statistic).parameters
    except (TypeError, ValueError):  # no signature to read (some builtins)
        return False


def performance_profile(scores: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """Fraction of runs (all seeds and conditions, ``scores`` of any shape) scoring above each tau."""
    flat = np.asarray(scores, dtype=float).ravel()
    return (flat[None, :] > np.asarray(taus, dtype=float)[:, None]).mean(axis=1)


@dataclass(frozen=True)
class Profile:
    """A performance profile over (seed, condition) runs with its stratified bootstrap band."""

    taus: np.ndarray
    """``(k,)`` score thresholds."""
    fraction: np.ndarray
    """``(k,)`` fraction of runs scoring above each tau."""
    low: np.ndarray
    high: np.ndarray
    seeds: int
    conditions: tuple[str, ...]


def profile_with_band(
    scores: np.ndarray, taus: np.ndarray, conditions: Sequence[str] = (), seed: int = 0, resamples: int = RESAMPLES
) -> Profile:
    """:func:`performance_profile` of ``scores`` ``(seeds, conditions)`` with a 95 % stratified bootstrap band.

    Each resample draws the seeds again, with replacement, separately within every condition (the strata of
    Agarwal et al.), and recomputes the profile; the band is the 2.5 and 97.5 percentiles at each tau.
    """
    scores = np.asarray(scores, dtype=float)
    if scores.ndim != 2 or not scores.size:
        raise ValueError(f"scores must be a non-empty (seeds, conditions) array, got shape {scores.shape}.")
    taus = np.asarray(taus, dtype=float)
    fraction = performance_profile(scores, taus)
    n_seeds, n_cond = scores.shape
    picks = np.random.default_rng(seed).integers(0, n_seeds, size=(resamples, n_seeds, n_cond))
    resampled = scores[picks, np.arange(n_cond)]  # (resamples, seeds, conditions)
    profiles = (resampled[..., None] > taus).mean(axis=(1, 2))  # (resamples, k)
    low, high = np.percentile(profiles, [2.5, 97.5], axis=0) if n_seeds > 1 else (fraction * np.nan,) * 2
    names = tuple(conditions) or tuple(str(i) for i in range(n_cond))
    return Profile(taus, fraction, low, high, n_seeds, names)


def sweep_scores(
    out: str | Path, conditions: str = "protocol", metric: str = "success_rate"
) -> tuple[list[int], list[str], np.ndarray]:
    """``(seeds, condition names, scores (seeds, conditions))`` from a sweep's ``evaluation.csv``.

    ``conditions`` names a set of :data:`marlander_lite.training.sweep.SWEEP_CONDITIONS`; only seeds that were
    flown on every one of them count. ``metric`` is a column of the CSV (default ``success_rate``).
    """
    from marlander_lite.training.sweep import EVALUATION_FIELDS, EVALUATION_FILE, SWEEP_CONDITIONS, read_evaluation

    if conditions not in SWEEP_CONDITIONS:
        raise ValueError(f"Unknown evaluation set {conditions!r}; allowed: {', '.join(SWEEP_CONDITIONS)}.")
    if metric not in EVALUATION_FIELDS[3:]:
        raise ValueError(f"Unknown metric {metric!r}; allowed: {', '.join(EVALUATION_FIELDS[3:])}.")
    path = Path(out) / EVALUATION_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{out} has no {EVALUATION_FILE}; run 'marlander sweep --evaluate {conditions}'.")
    names = [c.name for c in SWEEP_CONDITIONS[conditions]]
    table = {(r["seed"], r["condition"]): r[metric] for r in read_evaluation(path)}
    seeds = sorted({seed for seed, _ in table if all((seed, n) in table for n in names)})
    if not seeds:
        raise ValueError(
            f"No seed of {out} was flown on every condition of {conditions!r}; run "
            f"'marlander sweep --preset P --seeds S --out {out} --evaluate {conditions}' (it resumes)."
        )
    return seeds, names, np.array([[table[seed, n] for n in names] for seed in seeds])


def sweep_profile(out: str | Path, conditions: str = "protocol", points: int = 101, seed: int = 0) -> Profile:
    """The success-rate performance profile of a sweep over ``conditions`` (default: the paper's Tables I, II)."""
    _, names, scores = sweep_scores(out, conditions)
    return profile_with_band(scores, np.linspace(0.0, 1.0, points), names, seed)


@dataclass(frozen=True)
class SeedCurves:
    """One training curve over seeds, on a common step grid."""

    steps: np.ndarray
    """``(points,)`` environment steps."""
    per_seed: np.ndarray
    """``(seeds, points)`` each seed's curve, interpolated onto ``steps``."""
    centre: np.ndarray
    """``(points,)`` the IQM over seeds (the mean when there are fewer than four)."""
    low: np.ndarray
    high: np.ndarray


def seed_curves(runs: Sequence[str | Path], curve: str = "success", points: int = 60, seed: int = 0) -> SeedCurves:
    """The ``curve`` (a key of :data:`marlander_lite.plotting.CURVES`) of several runs, summarised over seeds.

    Each run's log is interpolated onto ``points`` steps spanning the range every run reached; the band is a
    percentile bootstrap of the centre over seeds at each step.
    """
    if curve not in CURVES:
        raise ValueError(f"Unknown curve {curve!r}; allowed: {', '.join(CURVES)}.")
    logs = [read_progress(run) for run in runs]
    column = CURVES[curve][0]
    last = min(float(np.nanmax(log[STEPS_COLUMN])) for log in logs)
    first = max(float(np.nanmin(log[STEPS_COLUMN])) for log in logs)
    steps = np.linspace(first, last, points)
    per_seed = np.stack([np.interp(steps, log[STEPS_COLUMN], _filled(log[column])) for log in logs])
    statistic = iqm if len(runs) >= 4 else np.mean
    centre = np.array([statistic(per_seed[:, j]) for j in range(points)])
    bounds = np.array([_bounds(per_seed[:, j], statistic, seed) for j in range(points)])
    return SeedCurves(steps, per_seed, centre, bounds[:, 0], bounds[:, 1])


def _filled(values: np.ndarray) -> np.ndarray:
    """Carry the last logged value over empty cells (e.g. no landing yet in that rollout); NaN before the first."""
    out = values.copy()
    for i in range(1, out.size):
        if not np.isfinite(out[i]):
            out[i] = out[i - 1]
    return out


def _bounds(values: np.ndarray, statistic: Callable[[np.ndarray], float], seed: int) -> tuple[float, float]:
    result = estimate([values], statistic, seed)
    return result.low, result.high


def summary_rows(rows: Sequence[dict[str, Any]], seed: int = 0) -> list[dict[str, Any]]:
    """One row per condition of a sweep's evaluation (``sweep.read_evaluation``), plus the pooled row.

    Success: IQM over seeds with its interval; landing error and time: mean over seeds with its interval.
    The pooled row is the stratified-bootstrap IQM over all seeds and conditions.
    """
    conditions = list(dict.fromkeys(r["condition"] for r in rows))
    table: list[dict[str, Any]] = []
    by_condition = {c: [r for r in rows if r["condition"] == c] for c in conditions}
    for name, chosen in by_condition.items():
        table.append(
            {
                "condition": name,
                "seeds": len(chosen),
                "success_iqm": estimate([[r["success_rate"] for r in chosen]], iqm, seed),
                "success_mean": estimate([[r["success_rate"] for r in chosen]], np.mean, seed),
                "worst_seed_success": min(r["success_rate"] for r in chosen),
                "landing_error_cm": estimate([[r["landing_error_mean_cm"] for r in chosen]], np.mean, seed),
                "landing_time_s": estimate([[r["landing_time_mean_s"] for r in chosen]], np.mean, seed),
                "collision_rate": float(np.mean([r["collision_rate"] for r in chosen])),
            }
        )
    pooled = [[r["success_rate"] for r in chosen] for chosen in by_condition.values()]
    table.append({"condition": "all (stratified)", "seeds": len(rows), "success_iqm": estimate(pooled, iqm, seed)})
    return table


def markdown_table(table: Sequence[dict[str, Any]]) -> str:
    """:func:`summary_rows` as a Markdown table (rates in %, 95 % bootstrap intervals in brackets)."""
    lines = [
        "| condition | seeds | success IQM | success mean | worst seed | landing error (cm) | landing time (s) |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in table:
        cells = [row["condition"], str(row["seeds"]), row["success_iqm"].percent()]
        if "success_mean" in row:
            cells += [
                row["success_mean"].percent(),
                f"{100 * row['worst_seed_success']:.1f} %",
                str(row["landing_error_cm"]),
                str(row["landing_time_s"]),
            ]
        else:
            cells += ["", "", "", ""]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def summarise_sweep(out: str | Path, conditions: str | None = None) -> str:
    """The Markdown summary of a sweep folder's ``evaluation.csv``: every row, or only those of the evaluation set
    ``conditions`` (a key of :data:`marlander_lite.training.sweep.SWEEP_CONDITIONS`), in that set's order."""
    from marlander_lite.training.sweep import EVALUATION_FILE, SWEEP_CONDITIONS, read_evaluation

    path = Path(out) / EVALUATION_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{out} has no {EVALUATION_FILE}; run 'marlander sweep' with --evaluate first.")
    rows = read_evaluation(path)
    if conditions is not None:
        if conditions not in SWEEP_CONDITIONS:
            raise ValueError(f"Unknown evaluation set {conditions!r}; allowed: {', '.join(SWEEP_CONDITIONS)}.")
        order = {c.name: i for i, c in enumerate(SWEEP_CONDITIONS[conditions])}
        rows = sorted((r for r in rows if r["condition"] in order), key=lambda r: (order[r["condition"]], r["seed"]))
    return markdown_table(summary_rows(rows))
