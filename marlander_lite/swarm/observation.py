"""What one drone of a swarm feeds the shared policy: its own eq. 2 observation plus its neighbours.

The paper's centralised policy reads every drone's 13 numbers at once (``13 N`` inputs), so it
flies one swarm size only. A *shared* policy reads, for drone ``i``,

    ``x_i = [O_t^i, n_i1, ..., n_ik]``,  ``n_ij = [x_j - x_i, v_j - v_i, 1]``  (7 numbers each)

where ``O_t^i`` is eq. 2 (13 numbers, relative to drone ``i``'s own pad) and ``j`` runs over the
``k`` drones nearest to ``i``, nearest first: their position and velocity relative to drone ``i``
(m, m/s, world frame) and a flag 1. A swarm with fewer than ``k + 1`` drones fills the missing
neighbours with zeros, flag 0. The input has ``13 + 7 k`` numbers whatever N is.

Nothing beyond the centralised observation is needed: the pads sit at fixed offsets ``o_i`` on
a plate that never yaws (:mod:`marlander_lite.platforms`), so ``x_j - x_i = (p_j + o_j) - (p_i +
o_i)`` and, since every pad moves with the plate, ``v_j - v_i`` is the difference of the two
drones' eq. 2 velocities. A motion-capture system senses the same numbers; with sensing noise the
neighbour features carry it too.

Sorting by distance makes the input independent of the drones' numbering: permuting the drones
permutes the inputs (and so the shared policy's actions) and changes nothing else
(``tests/test_swarm.py``).
"""

from __future__ import annotations

import numpy as np

from marlander_lite.task import EQ2_POSITION, EQ2_VELOCITY, OBS_PER_DRONE

NEIGHBOUR_FEATURES = 7
"""Numbers per neighbour: relative position (3, m), relative velocity (3, m/s), present flag (1)."""


def shared_obs_size(neighbours: int, obs_per_drone: int = OBS_PER_DRONE) -> int:
    """Length of one drone's shared-policy input: ``obs_per_drone + 7 k``."""
    return obs_per_drone + NEIGHBOUR_FEATURES * neighbours


def pairwise_offsets(pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offsets and squared distances between the drones of each swarm.

    ``pos`` ``(..., N, 3)`` m; returns ``rel[..., i, j] = x_j - x_i`` ``(..., N, N, 3)`` and its squared norm
    ``(..., N, N)`` with ``inf`` on the diagonal: a drone is not its own neighbour.
    """
    rel = pos[..., None, :, :] - pos[..., :, None, :]
    dist_sq = np.einsum("...k,...k->...", rel, rel)
    n = pos.shape[-2]
    dist_sq[..., np.arange(n), np.arange(n)] = np.inf
    return rel, dist_sq


def neighbour_features(
    obs: np.ndarray, pad_offsets: np.ndarray, neighbours: int, radius: float | None = None
) -> np.ndarray:
    """The k nearest neighbours of every drone, ``(..., N, 7 k)``.

    Args:
        obs: eq. 2 observations ``(..., N, 13)`` (or 16 with the platform velocity).
        pad_offsets: each drone's pad centre relative to the plate, ``(N, 3)`` m
            (:meth:`~marlander_lite.platforms.PlateGeometry.pad_offsets`).
        neighbours: ``k >= 1``.
        radius: sensing range (m): neighbours farther away are left out like missing ones (zeros, flag 0);
            ``None`` senses the k nearest at any distance.

    Returns, for drone ``i`` and its ``m``-th nearest other drone ``j``: ``[x_j - x_i, v_j - v_i, 1]``
    in entries ``7 m .. 7 m + 6``; zeros where the swarm has no ``m``-th neighbour.
    """
    obs = np.asarray(obs, dtype=np.float64)
    n = obs.shape[-2]
    offsets = np.asarray(pad_offsets, dtype=np.float64)
    if offsets.shape != (n, 3):
        raise ValueError(f"pad_offsets must be ({n}, 3) for {n} drones, got shape {offsets.shape}.")
    if isinstance(neighbours, bool) or not isinstance(neighbours, int | np.integer) or neighbours < 1:
        raise ValueError(f"neighbours must be an integer >= 1, got {neighbours!r}.")
    if radius is not None and not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"radius must be None or a finite distance > 0 m, got {radius!r}.")
    lead = obs.shape[:-2]
    out = np.zeros((*lead, n, neighbours, NEIGHBOUR_FEATURES))
    if n > 1:
        pos = obs[..., EQ2_POSITION] + offsets  # plate-relative positions (plus the common goal lift)
        rel_pos, dist = pairwise_offsets(pos)
        rel_vel = obs[..., None, :, EQ2_VELOCITY] - obs[..., :, None, EQ2_VELOCITY]
        # A stable sort, so that equal distances keep the drones' order (ties have measure zero in flight).
        order = np.argsort(dist, axis=-1, kind="stable")[..., : min(neighbours, n - 1)]
        m = order.shape[-1]
        out[..., :m, 0:3] = np.take_along_axis(rel_pos, order[..., None], axis=-2)
        out[..., :m, 3:6] = np.take_along_axis(rel_vel, order[..., None], axis=-2)
        out[..., :m, 6] = 1.0
        if radius is not None:  # nearest first, so the sensed neighbours stay in front of the left-out ones
            out[..., :m, :] *= (np.take_along_axis(dist, order, axis=-1) <= radius * radius)[..., None]
    return out.reshape(*lead, n, neighbours * NEIGHBOUR_FEATURES)


def shared_observations(
    obs: np.ndarray, pad_offsets: np.ndarray, neighbours: int, radius: float | None = None
) -> np.ndarray:
    """Every drone's shared-policy input ``(..., N, 13 + 7 k)``: its own ``obs`` then :func:`neighbour_features`."""
    obs = np.asarray(obs)
    features = neighbour_features(obs, pad_offsets, neighbours, radius)
    return np.concatenate([obs.astype(np.float64), features], axis=-1)
