"""Plots of a flight log: the paper's Fig. 7 (3D trajectories of the drones and their pads) and a timeline.

Colours follow the paper's caption: first drone light blue, second orange; first drone's pad
red, second's blue (a moving pad's trajectory magenta and cyan). Further drones take the next
colours of matplotlib's cycle (which repeats after ten: in swarms, tell drones apart by the legend order).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from marlander_lite.deploy.flight_log import FlightLog
from marlander_lite.task import pad_frame_errors

DRONE_COLOURS = ("#56b4e9", "#ff7f0e")
PAD_COLOURS = ("red", "blue")
MOVING_PAD_COLOURS = ("magenta", "cyan")


def _colour(palette: tuple[str, ...], i: int) -> str:
    return palette[i] if i < len(palette) else f"C{i + 2}"


def plot_trajectories(log: FlightLog, ax: Any = None, title: str | None = None) -> Any:
    """Fig. 7: each drone's estimated 3D trajectory and its pad's, from a flight log.

    Drone paths start with a circle and end with a cross; touchdowns are marked with a star.
    Returns the matplotlib ``Axes3D``.
    """
    import matplotlib.pyplot as plt

    if ax is None:
        fig = plt.figure(figsize=(6.4, 5.2))
        ax = fig.add_subplot(projection="3d")
    pos, pads = log.estimates("pos"), log.estimates("pad_pos")
    touchdowns = {e["drone"]: e for e in log.events if e["kind"] == "touchdown"}
    times = log.times()
    for i, name in enumerate(log.drones):
        path = pos[:, i]
        ok = np.isfinite(path).all(axis=-1)
        colour = _colour(DRONE_COLOURS, i)
        ax.plot(*path[ok].T, color=colour, lw=1.6, label=f"{name}")
        if ok.any():
            first, last = path[ok][0], path[ok][-1]
            ax.scatter(*first, color=colour, marker="o", s=25)
            ax.scatter(*last, color=colour, marker="x", s=35)
        pad = pads[:, i][np.isfinite(pads[:, i]).all(axis=-1)]
        moving = len(pad) > 1 and np.ptp(pad, axis=0).max() > 0.02
        pad_colour = _colour(MOVING_PAD_COLOURS if moving else PAD_COLOURS, i)
        if moving:
            ax.plot(*pad.T, color=pad_colour, lw=1.2, ls="--", label=f"pad of {name}")
        elif len(pad):
            ax.scatter(*np.median(pad, axis=0), color=pad_colour, marker="s", s=40, label=f"pad of {name}")
        if i in touchdowns:
            k = int(np.searchsorted(times, touchdowns[i]["t"]))
            ax.scatter(*path[min(k, len(path) - 1)], color=colour, marker="*", s=120, edgecolor="k")
    finite = np.concatenate([pos.reshape(-1, 3), pads.reshape(-1, 3)])
    finite = finite[np.isfinite(finite).all(axis=1)]
    if len(finite):
        ax.set_box_aspect(np.maximum(np.ptp(finite, axis=0), 0.2))  # metres look the same on every axis
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_title(title or "Trajectories (paper Fig. 7)")
    many = len(log.drones) > 4  # a swarm: two columns of small entries keep the legend off the plot
    ax.legend(loc="upper left", fontsize=6 if many else 8, ncol=2 if many else 1)
    return ax


def plot_timeline(log: FlightLog, axes: Any = None) -> Any:
    """Height above the goal and distance from the pad centre per drone over time, with events, both in the pad's
    frame (along its normal, within its plane; on a level pad the height and the horizontal distance), as the loop
    judges touchdowns.

    Returns the two matplotlib ``Axes``.
    """
    import matplotlib.pyplot as plt

    if axes is None:
        _, axes = plt.subplots(2, 1, figsize=(7.0, 4.8), sharex=True)
    t = log.times()
    height, offset = pad_frame_errors(log.estimates("pos") - log.estimates("goal"), log.estimates("pad_normal"))
    for i, name in enumerate(log.drones):
        colour = _colour(DRONE_COLOURS, i)
        axes[0].plot(t, height[:, i], color=colour, label=name)
        axes[1].plot(t, offset[:, i], color=colour, label=name)
    for e in log.events:
        if e["kind"] in (
            "armed",
            "policy_start",
            "fault_injected",
            "stale_hover",
            "land",
            "stale_land",
            "touchdown",
            "geofence_breach",
            "link_lost",
            "interrupt",
            "recovered",
        ):
            for ax in axes:
                ax.axvline(e["t"], color="0.6", lw=0.8, ls=":")
            axes[0].annotate(e["kind"], (e["t"], axes[0].get_ylim()[1]), rotation=90, fontsize=7, va="top", ha="right")
    axes[0].set_ylabel("height above goal (m)")
    axes[1].set_ylabel("distance from pad centre (m)")
    axes[1].set_xlabel("time (s)")
    axes[0].legend(fontsize=8)
    return axes
