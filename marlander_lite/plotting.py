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


def read_progress(path: str | Path) -> dict[str, np.ndarray]:
    """Columns of an SB3 ``progress.csv`` as float arrays (empty cells become NaN).

    ``path`` may be the CSV itself or a run directory containing ``logs/progress.csv``.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "logs" / "progress.csv"
    if not path.is_file():
        raise FileNotFoundError(f"No training log at {path}; pass a run directory or its logs/progress.csv.")
    with path.open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    if not rows:
        raise ValueError(f"{path} holds no logged rollouts yet.")
    return {key: np.array([float(r[key]) if r.get(key) not in ("", None) else np.nan for r in rows]) for key in rows[0]}


def plot_training_curves(
    runs: Sequence[str | Path],
    labels: Sequence[str] | None = None,
    curves: Sequence[str] = ("reward", "length"),
    out: str | Path | None = None,
) -> plt.Figure:
    """One panel per curve (default: the paper's Fig. 5 and Fig. 6), one line per run.

    The x axis is environment steps in millions.
    """
    unknown = [c for c in curves if c not in CURVES]
    if unknown:
        raise ValueError(f"Unknown curve(s) {unknown}; available: {', '.join(CURVES)}.")
    labels = list(labels) if labels is not None else [Path(r).name for r in runs]
    if len(labels) != len(runs):
        raise ValueError(f"Got {len(labels)} labels for {len(runs)} runs.")
    cols = min(2, len(curves))
    rows = -(-len(curves) // cols)
    fig, grid = plt.subplots(rows, cols, figsize=(5.5 * cols, 3.6 * rows), squeeze=False)
    for spare in grid.ravel()[len(curves) :]:
        spare.set_visible(False)
    axes = grid.ravel()[: len(curves)]
    for run, label in zip(runs, labels, strict=True):
        data = read_progress(run)
        steps = data["time/total_timesteps"] / 1e6
        for ax, name in zip(axes, curves, strict=True):
            column = CURVES[name][0]
            if column in data:
                ax.plot(steps, data[column], label=label)
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
