"""Training-curve figures like the paper's Fig. 5 (episode reward mean) and Fig. 6 (episode length mean).

Curves are read from the ``logs/progress.csv`` that stable-baselines3 writes for every run.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

CURVES = {
    "reward": ("rollout/ep_rew_mean", "Episode reward mean", "Fig. 5"),
    "length": ("rollout/ep_len_mean", "Episode length mean (steps)", "Fig. 6"),
    "success": ("rollout/success_rate", "Success rate", ""),
    "error": ("rollout/landing_error_cm", "Landing error (cm)", ""),
}
"""Curve name -> (CSV column, axis label, paper figure)."""


STEPS_COLUMN = "time/total_timesteps"
"""The column every SB3 training log has: environment steps so far (the x axis)."""


def progress_path(run: str | Path) -> Path:
    """The training log of ``run``: the CSV itself, or ``logs/progress.csv`` inside a run directory."""
    path = Path(run)
    return path / "logs" / "progress.csv" if path.is_dir() else path


def read_progress(path: str | Path) -> dict[str, np.ndarray]:
    """Columns of an SB3 ``progress.csv`` as float arrays (empty cells become NaN).

    ``path`` may be the CSV itself or a run directory containing ``logs/progress.csv``. A file
    that is not such a log (no ``time/total_timesteps`` column, text cells, binary data) raises
    ``ValueError`` saying so.
    """
    path = progress_path(path)
    if not path.is_file():
        raise FileNotFoundError(f"No training log at {path}; pass a run directory or its logs/progress.csv.")
    not_a_log = f"{path} is not a training log (a logs/progress.csv written by 'marlander train')"
    try:
        with path.open(newline="") as handle:
            rows = list(csv.DictReader(handle))
    except (UnicodeDecodeError, csv.Error) as error:
        raise ValueError(f"{not_a_log}: {error}.") from None
    if not rows:
        raise ValueError(f"{path} holds no logged rollouts yet.")
    if STEPS_COLUMN not in rows[0]:
        raise ValueError(f"{not_a_log}: it has no {STEPS_COLUMN} column.")
    try:
        return {
            key: np.array([float(r[key]) if r.get(key) not in ("", None) else np.nan for r in rows]) for key in rows[0]
        }
    except (TypeError, ValueError) as error:
        raise ValueError(f"{not_a_log}: {error}.") from None


def plot_training_curves(
    runs: Sequence[str | Path],
    labels: Sequence[str] | None = None,
    curves: Sequence[str] = ("reward", "length"),
    out: str | Path | None = None,
) -> plt.Figure:
    """One panel per curve (default: the paper's Fig. 5 and Fig. 6), one line per run.

    A sweep folder (``marlander sweep``) counts as one run: its line is the IQM over its seeds (the mean
    with fewer than four) with a 95 % bootstrap band (:func:`marlander_lite.experiments.seed_stats.seed_curves`).
    The x axis is environment steps in millions.
    """
    unknown = [c for c in curves if c not in CURVES]
    if unknown:
        raise ValueError(f"Unknown curve(s) {unknown}; available: {', '.join(CURVES)}.")
    labels = list(labels) if labels is not None else [Path(r).name for r in runs]
    if len(labels) != len(runs):
        raise ValueError(f"Got {len(labels)} labels for {len(runs)} runs.")
    from marlander_lite.training.sweep import sweep_runs

    seeds = [sweep_runs(run) for run in runs]  # a sweep's finished seeds; None for a single run
    # every log is checked before a figure is opened
    logs = [read_progress(run) if group is None else {} for run, group in zip(runs, seeds, strict=True)]
    cols = min(2, len(curves))
    rows = -(-len(curves) // cols)
    fig, grid = plt.subplots(rows, cols, figsize=(5.5 * cols, 3.6 * rows), squeeze=False)
    for spare in grid.ravel()[len(curves) :]:
        spare.set_visible(False)
    axes = grid.ravel()[: len(curves)]
    for data, group, label in zip(logs, seeds, labels, strict=True):
        for ax, name in zip(axes, curves, strict=True):
            if group is not None:
                _plot_over_seeds(ax, group, name, label)
            elif CURVES[name][0] in data:
                ax.plot(data[STEPS_COLUMN] / 1e6, data[CURVES[name][0]], label=label)
    for ax, name in zip(axes, curves, strict=True):
        _, ylabel, figure = CURVES[name]
        ax.set_xlabel("Environment steps (millions)")
        ax.set_ylabel(ylabel)
        ax.set_title(f"{ylabel} during training" + (f" (paper {figure})" if figure else ""))
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=120)
    return fig


def _plot_over_seeds(ax: plt.Axes, runs: Sequence[Path], curve: str, label: str) -> None:
    from marlander_lite.experiments.seed_stats import seed_curves

    summary = seed_curves(runs, curve)
    centre = "IQM" if len(runs) >= 4 else "mean"
    (line,) = ax.plot(summary.steps / 1e6, summary.centre, label=f"{label} ({centre} of {len(runs)} seeds)")
    ax.fill_between(summary.steps / 1e6, summary.low, summary.high, color=line.get_color(), alpha=0.25, lw=0)


def plot_performance_profiles(
    sweeps: Sequence[str | Path],
    labels: Sequence[str] | None = None,
    conditions: str = "protocol",
    out: str | Path | None = None,
) -> plt.Figure:
    """Success-rate performance profiles of sweeps (Agarwal et al., NeurIPS 2021), one line per sweep.

    A point ``(tau, y)`` says: a fraction ``y`` of all (seed, condition) runs landed in more than ``tau`` of
    their episodes; the conditions are those of ``conditions`` (default: the ten platform set-ups of the
    paper's Tables I and II). The shaded band is a 95 % stratified bootstrap over seeds. A line that stays
    high to the right is a method that lands reliably everywhere, on every seed.
    """
    from marlander_lite.experiments.seed_stats import sweep_profile

    labels = list(labels) if labels is not None else [Path(s).name for s in sweeps]
    if len(labels) != len(sweeps):
        raise ValueError(f"Got {len(labels)} labels for {len(sweeps)} sweeps.")
    profiles = [sweep_profile(s, conditions) for s in sweeps]  # all read before a figure opens
    fig, ax = plt.subplots(figsize=(6.0, 4.0))
    for profile, label in zip(profiles, labels, strict=True):
        text = f"{label} ({profile.seeds} seeds x {len(profile.conditions)} conditions)"
        (line,) = ax.step(100 * profile.taus, profile.fraction, where="post", label=text)
        ax.fill_between(
            100 * profile.taus, profile.low, profile.high, step="post", color=line.get_color(), alpha=0.2, lw=0
        )
    ax.set_xlabel("Success rate threshold tau (%)")
    ax.set_ylabel("Fraction of runs with success > tau")
    ax.set_title(f"Performance profile over the {conditions!r} conditions")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=120)
    return fig
