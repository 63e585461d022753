"""Figures of the experiments: Fig. 7 (3D landing trajectories) and success / error versus platform speed.

Fig. 7 of the paper shows, for one trial each, the drones' and their pads' paths landing (a) on
the floor, (b) on the UR10 held still and (c) on the UR10 moving linearly at constant speed. Its
colours are kept: drone 1 light blue, drone 2 orange, pad 1 red, pad 2 blue; the moving pads
magenta and cyan.
"""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from marlander_lite.experiments.controllers import CONTROLLER_LABELS
from marlander_lite.experiments.metrics import TrialMetrics
from marlander_lite.experiments.protocol import CONDITION_NAMES, Trajectory, condition
from marlander_lite.experiments.tables import SummaryRow

DRONE_COLOURS = ("#5bc0eb", "#f28e2b")
"""Drone 1 light blue, drone 2 orange (Fig. 7)."""
PAD_COLOURS = ("#d62728", "#1f3fbf")
"""Static pads: pad 1 red, pad 2 blue (Fig. 7)."""
MOVING_PAD_COLOURS = ("#e377c2", "#17becf")
"""Moving pads: pad 1 magenta, pad 2 cyan (Fig. 7c)."""
PANEL_TITLES = {"a": "(a) floor", "b": "(b) on the UR10", "c": "(c) UR10 moving linearly"}


def fig7_conditions(available: Sequence[str]) -> dict[str, str]:
    """Panel letter -> condition for Fig. 7, from the conditions a run flew.

    (a) ``static-floor``, (b) ``static-elevated``, (c) the slowest ``moving-linear-S`` flown (the
    paper's panel shows one constant-velocity linear motion); panels whose condition was not flown are left out.
    """
    panels = {}
    if "static-floor" in available:
        panels["a"] = "static-floor"
    if "static-elevated" in available:
        panels["b"] = "static-elevated"
    linear = [c for c in CONDITION_NAMES if c.startswith("moving-linear") and c in available]
    if linear:
        panels["c"] = linear[0]
    return panels


def plot_trajectories(trajectories: Mapping[str, Trajectory], title: str = "") -> Figure:
    """Fig. 7: one 3D panel per entry of ``trajectories`` (key = panel letter), drones and pads over time."""
    fig = plt.figure(figsize=(4.2 * max(len(trajectories), 1), 4.4))
    for k, (panel, traj) in enumerate(trajectories.items()):
        ax = fig.add_subplot(1, len(trajectories), k + 1, projection="3d")
        moving = np.ptp(traj.pad_pos[:, 0, :2], axis=0).max() > 1e-6
        pad_colours = MOVING_PAD_COLOURS if moving else PAD_COLOURS
        for i in range(traj.drone_pos.shape[1]):
            d, p = traj.drone_pos[:, i], traj.pad_pos[:, i]
            ax.plot(d[:, 0], d[:, 1], d[:, 2], color=DRONE_COLOURS[i % 2], lw=1.6, label=f"drone {i + 1}")
            ax.scatter(*d[0], color=DRONE_COLOURS[i % 2], marker="o", s=18)
            if moving:
                ax.plot(p[:, 0], p[:, 1], p[:, 2], color=pad_colours[i % 2], lw=1.2, ls="--", label=f"pad {i + 1} path")
            ax.scatter(*p[-1], color=PAD_COLOURS[i % 2], marker="s", s=30, label=f"pad {i + 1}")
        outcome = _outcome_text(traj.metrics)
        ax.set_title(f"{PANEL_TITLES.get(panel, panel)}\n{outcome}", fontsize=9)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_zlabel("z (m)")
        if k == 0:
            ax.legend(fontsize=7, loc="upper left")
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return fig


def _outcome_text(m: TrialMetrics) -> str:
    if m.success:
        errors = ", ".join(f"{e:.1f}" for e in m.landing_error_cm)
        return f"landed in {m.landing_time_s:.1f} s, errors {errors} cm"
    return f"failed: {m.outcome} after {m.duration_s:.1f} s"


def plot_speed(rows: Sequence[SummaryRow], title: str = "") -> Figure:
    """Success rate (Wilson 95 % CI) and mean landing error (bootstrap 95 % CI) against platform speed.

    One line per controller and motion (arc solid, linear dashed); the static UR10 condition is
    drawn at speed 0 when present.
    """
    fig, (ax_s, ax_e) = plt.subplots(1, 2, figsize=(10, 4))
    controllers = list(dict.fromkeys(r.controller for r in rows))
    colours = dict(zip(controllers, plt.rcParams["axes.prop_cycle"].by_key()["color"], strict=False))
    for name in controllers:
        for kind, style in (("moving-arc", "-"), ("moving-linear", "--")):
            cells = [
                r for r in rows if r.controller == name and (r.cell.startswith(kind) or r.cell == "static-elevated")
            ]
            if not any(r.cell.startswith(kind) for r in cells):
                continue
            cells.sort(key=lambda r: condition(r.cell).speed)
            speed = np.array([condition(r.cell).speed for r in cells])
            s = [r.summary for r in cells]
            rate = np.array([x.success_rate for x in s]) * 100
            # Clipped at 0: at 0 or 100 % success the Wilson bound lands a rounding error beyond the rate.
            rate_err = np.array([[x.success_rate - x.success_low, x.success_high - x.success_rate] for x in s]).T * 100
            rate_err = np.clip(rate_err, 0.0, None)
            err = np.array([x.error_mean_cm for x in s])
            err_ci = np.array([[x.error_mean_cm - x.error_mean_low, x.error_mean_high - x.error_mean_cm] for x in s]).T
            err_ci = np.clip(np.nan_to_num(err_ci), 0.0, None)
            label = f"{CONTROLLER_LABELS[name]}, {kind.split('-')[1]}"
            offset = 0.004 * (controllers.index(name) - (len(controllers) - 1) / 2) + (0.002 if style == "--" else 0)
            ax_s.errorbar(
                speed + offset, rate, yerr=rate_err, ls=style, marker="o", color=colours[name], capsize=3, label=label
            )
            ax_e.errorbar(
                speed + offset, err, yerr=err_ci, ls=style, marker="o", color=colours[name], capsize=3, label=label
            )
    ax_s.set_xlabel("platform tool speed (m/s); 0 = UR10 static")
    ax_s.set_ylabel("success rate (%)")
    ax_s.set_ylim(-5, 105)
    ax_e.set_xlabel("platform tool speed (m/s); 0 = UR10 static")
    ax_e.set_ylabel("mean landing error (cm)")
    ax_e.set_ylim(bottom=0)
    ax_s.legend(fontsize=7)
    for ax in (ax_s, ax_e):
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return fig


def write_trajectories_csv(trajectories: Mapping[str, Trajectory], path: Path) -> Path:
    """Long CSV (one row per panel, step and drone): time, drone and pad positions in metres (mm rounding)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(["panel", "step", "time_s", "drone", "x", "y", "z", "pad_x", "pad_y", "pad_z"])
        for panel, t in trajectories.items():
            for k in range(len(t.time_s)):
                for i in range(t.drone_pos.shape[1]):
                    d, p = t.drone_pos[k, i], t.pad_pos[k, i]
                    writer.writerow([panel, k, f"{t.time_s[k]:.4f}", i, *(f"{x:.4f}" for x in (*d, *p))])
    return path


def save(fig: Figure, path: Path, dpi: int = 110) -> Path:
    """Write ``fig`` as a PNG (kept small: < 1 MB) and close it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
