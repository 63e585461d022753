"""Which drone lands on which pad: the paper's fixed pairs, or the pairing with the shortest paths.

The paper gives drone ``i`` pad ``i`` whatever their starts (Sec. III-E). With random starts in the 4 x 4 m arena
and pads 0.25 m apart, the straight paths of two drones then cross in many swarms of eight, and a shared policy
that senses its neighbours only within 0.2 m meets them there (docs/scaling.md).

Pairing starts ``a`` with pads ``p`` so that ``sum_i |a_i - p_i|^2`` is least is the assignment step of CAPT
[Turpin2014]. Swapping any two drones' pads cannot lower that sum, which says ``(a_i - a_j) . (p_i - p_j) >= 0``
for every pair; straight paths flown so that every drone arrives at the same time then keep any two drones at least
``min(|a_i - a_j|, |p_i - p_j|) / sqrt(2)`` apart. Our drones fly a learned policy, not those paths. Seen from above,
the straight lines from 8 random starts to their pads cross 0.75 times a swarm with this pairing and 6.5 times with
the paper's (1000 draws; notebook 09 counts them).

The drones of a swarm are alike, so the pairing is made by handing the starts out: drone ``i`` keeps pad ``i``,
and the MDP, the observations and every per-drone record stay indexed as before. :func:`assign_starts_to_pads`
solves the assignment with scipy's :func:`~scipy.optimize.linear_sum_assignment`; ``TaskConfig.pad_assignment``
switches it on at every reset of every simulator.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

PadAssignment = Literal["fixed", "shortest"]
"""``"fixed"``: drone ``i`` lands on pad ``i`` (the paper); ``"shortest"``: the pairing of least total squared
distance from the starts to the pads (CAPT's assignment, not in the paper)."""
PAD_ASSIGNMENTS: tuple[str, ...] = ("fixed", "shortest")


def shortest_pairing(starts: np.ndarray, pads: np.ndarray) -> np.ndarray:
    """For each pad, the start that flies to it: ``order`` ``(N,)`` with ``starts[order[i]]`` paired to pad ``i``.

    ``starts`` and ``pads`` are ``(N, 3)`` m (or ``(N, 2)``), in one frame. The pairing minimises
    ``sum_i |starts[order[i]] - pads[i]|^2``; ties are broken by scipy's solver, the same way for the same input.
    """
    starts, pads = np.asarray(starts, dtype=float), np.asarray(pads, dtype=float)
    if starts.ndim != 2 or starts.shape != pads.shape:
        raise ValueError(f"starts and pads must both be (N, 3) arrays, got shapes {starts.shape} and {pads.shape}.")
    if not (np.isfinite(starts).all() and np.isfinite(pads).all()):
        raise ValueError("starts and pads must be finite positions (m); got NaN or inf.")
    # Imported here, not at the top: scipy.optimize loads pybind11 extensions, and a Ctrl-C while they load during
    # the marlander command's start-up aborts the process instead of printing "Interrupted." (test_deploy_cli_startup).
    from scipy.optimize import linear_sum_assignment

    cost = ((pads[:, None, :] - starts[None, :, :]) ** 2).sum(axis=-1)  # cost[pad, start]
    _, order = linear_sum_assignment(cost)
    return order


def assign_starts_to_pads(starts: np.ndarray, pads: np.ndarray) -> np.ndarray:
    """The starts handed out so that drone ``i`` starts where the shortest pairing sends a drone to pad ``i``.

    ``starts`` and ``pads`` are ``(num_envs, N, 3)`` m; returns a new ``(num_envs, N, 3)`` array holding the same
    positions in each env, reordered by :func:`shortest_pairing`.
    """
    starts, pads = np.asarray(starts, dtype=float), np.asarray(pads, dtype=float)
    if starts.ndim != 3 or starts.shape != pads.shape:
        raise ValueError(
            f"starts and pads must both be (num_envs, N, 3) arrays, got shapes {starts.shape} and {pads.shape}."
        )
    out = np.empty_like(starts)
    for env in range(len(starts)):
        out[env] = starts[env, shortest_pairing(starts[env], pads[env])]
    return out


def path_crossings(starts: np.ndarray, pads: np.ndarray) -> int:
    """How many pairs of the straight paths ``starts[i] -> pads[i]`` cross, seen from above (x, y only).

    ``starts`` and ``pads`` are ``(N, 3)`` m. Two segments cross when each one's end points lie strictly on opposite
    sides of the other's line (touching or collinear segments do not count).
    """
    a, b = np.asarray(starts, dtype=float)[:, :2], np.asarray(pads, dtype=float)[:, :2]

    def side(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Sign of the turn p -> q -> r, for every pair (i, j): p, q from path i, r from path j."""
        d = q - p
        return np.sign(
            d[:, None, 0] * (r[None, :, 1] - p[:, None, 1]) - d[:, None, 1] * (r[None, :, 0] - p[:, None, 0])
        )

    split_j = side(a, b, a) * side(a, b, b)  # [i, j] < 0: path j's ends on opposite sides of path i's line
    crossing = (split_j < 0) & (split_j.T < 0)
    return int(np.triu(crossing, k=1).sum())
