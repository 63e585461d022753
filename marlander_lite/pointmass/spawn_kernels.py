"""Compiled starting positions: :func:`marlander_lite.task.sample_spawn_positions`' rejection loop, the same draws.

The reference redraws whole swarms until every pair of drones is ``spawn_separation`` apart: at 16 drones that is
about a dozen rounds per reset, each a dozen small numpy calls: a quarter of a 16-drone VecEnv step with random
actions (profiled; ``benchmarks/bench_pointmass.py`` setting) before these kernels.
These kernels run the rounds in one call and draw from the caller's ``np.random.Generator`` itself (numba shares
its bit generator), in the reference's order, so the positions and the generator's state afterwards are the same
to the last bit (``tests/test_pointmass_kernels.py``). Only the cosines and sines of near-pad starts (a training
aid) stay in numpy, whose SIMD versions may differ from libm's in the last bit. :mod:`marlander_lite.task` calls
:func:`sample_spawn_positions` when the compiled engine is on (``kernels.resolve_engine``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from marlander_lite.pointmass.kernels import jit_kernel, min_separation

if TYPE_CHECKING:
    from marlander_lite.task import TaskConfig


@jit_kernel
def spawn_rounds(
    rng: np.random.Generator,
    pos: np.ndarray,
    ids: np.ndarray,
    z_lo: np.ndarray,
    z_hi: float,
    half_width: float,
    near_pad: np.ndarray,
    separation: float,
    rounds: int,
    near_draws: np.ndarray,
    near_low: float,
) -> tuple[np.ndarray, int, int]:
    """Up to ``rounds`` rounds of the reference's ``draw(ids)`` and separation check, in one call.

    A round draws uniform positions for the swarms ``ids`` of ``pos`` ``(m, N, 3)``, then, for those of them that
    start near their pads, every angle, every radius and every height offset (in that order, heights from
    ``near_low`` to 1 m) into ``near_draws`` ``(3, m N)``, and then keeps the swarms whose pairs are too close
    (:func:`swarms_too_close`). A round that drew near-pad starts stops the loop before its check: their cosines and
    sines are numpy's to compute. Returns ``(ids, near-pad swarms of the last round, rounds done)``.
    """
    n = pos.shape[1]
    span = 2.0 * half_width
    for done in range(rounds):
        for a in range(ids.size):
            k = ids[a]
            for i in range(n):
                x, y, z = rng.random(), rng.random(), rng.random()
                pos[k, i, 0] = span * x - half_width
                pos[k, i, 1] = span * y - half_width
                pos[k, i, 2] = z_lo[k] + (z_hi - z_lo[k]) * z
        count = 0
        for a in range(ids.size):
            count += near_pad[ids[a]]
        if count:
            size = count * n
            for j in range(size):
                near_draws[0, j] = rng.uniform(0.0, 2.0 * np.pi)
            for j in range(size):
                near_draws[1, j] = 0.3 * math.sqrt(rng.random())
            for j in range(size):
                near_draws[2, j] = rng.uniform(near_low, 1.0)
            return ids, count, done + 1
        ids = swarms_too_close(pos, ids, separation)
        if ids.size == 0:
            return ids, 0, done + 1
    return ids, 0, rounds


@jit_kernel
def place_near_pads(
    pos: np.ndarray,
    ids: np.ndarray,
    near_pad: np.ndarray,
    pads: np.ndarray,
    near_draws: np.ndarray,
    cos: np.ndarray,
    sin: np.ndarray,
) -> None:
    """The rest of ``draw(ids)``: the near-pad swarms start at ``pad + (r cos a, r sin a, h)`` (``cos``, ``sin``
    computed by numpy from ``near_draws[0]``, as the reference does)."""
    n = pos.shape[1]
    j = 0
    for a in range(ids.size):
        k = ids[a]
        if not near_pad[k]:
            continue
        for i in range(n):
            radius = near_draws[1, j]
            pos[k, i, 0] = pads[k, i, 0] + radius * cos[j]
            pos[k, i, 1] = pads[k, i, 1] + radius * sin[j]
            pos[k, i, 2] = pads[k, i, 2] + near_draws[2, j]
            j += 1


@jit_kernel
def swarms_too_close(pos: np.ndarray, ids: np.ndarray, separation: float) -> np.ndarray:
    """The swarms among ``ids`` whose closest pair is less than ``separation`` (m) apart, as :func:`min_separation`
    measures it (a NaN distance passes, as ``NaN < separation`` is False in the reference)."""
    return ids[min_separation(pos[ids]) < separation]


@jit_kernel
def place_plates(
    env_ids: np.ndarray,
    plate_pos: np.ndarray,
    plate_vel: np.ndarray,
    pad_offsets: np.ndarray,
    plates: np.ndarray,
    pads: np.ndarray,
    pad_vel: np.ndarray,
) -> None:
    """The plates of the episodes ``env_ids`` at their start: the ``r``-th one's position ``plate_pos[r]`` and velocity
    ``plate_vel[r]`` (``(k, 3)``, m and m/s) into ``plates``, its pads ``plate + pad_offsets`` ``(N, 3)`` into ``pads``
    and their velocity into ``pad_vel`` (``(num_envs, N, 3)``): ``PointMassSwarm._update_platform``'s three numpy
    lines, which scatter slowly into the simulator's Fortran-ordered arrays."""
    n = pad_offsets.shape[0]
    for r in range(len(env_ids)):
        k = env_ids[r]
        for c in range(3):
            plates[k, c] = plate_pos[r, c]
            for i in range(n):
                pads[k, i, c] = plate_pos[r, c] + pad_offsets[i, c]
                pad_vel[k, i, c] = plate_vel[r, c]


def sample_spawn_positions(
    rng: np.random.Generator,
    z_lo: np.ndarray,
    z_hi: float,
    near_pad: np.ndarray,
    pads: np.ndarray | None,
    config: TaskConfig,
    max_tries: int,
) -> np.ndarray | None:
    """:func:`marlander_lite.task.sample_spawn_positions` after its argument checks, through the kernels above:
    the positions ``(len(z_lo), N, 3)`` m, or None when ``max_tries`` checks found no placement (the caller raises).

    Args:
        rng: the caller's generator; it advances exactly as the reference advances it.
        z_lo, z_hi: the lowest start height per swarm ``(m,)`` and the highest (m).
        near_pad: which swarms start near their pads ``(m,)`` bool, already drawn by the caller.
        pads: their pad centres ``(m, N, 3)`` m (needed when ``near_pad`` has a True).
    """
    m, n = len(z_lo), config.num_drones
    pos = np.empty((m, n, 3))
    near_draws = np.empty((3, m * n))
    pads = np.zeros((1, 1, 3)) if pads is None else np.ascontiguousarray(pads, dtype=float)
    z_lo = np.ascontiguousarray(z_lo, dtype=float)
    ids, rounds = np.arange(m), max_tries  # a check after each draw, as many as the reference makes
    while rounds:
        args = (rng, pos, ids, z_lo, z_hi, config.arena_half_width, near_pad, config.spawn_separation)
        ids, near, done = spawn_rounds(*args, rounds, near_draws, config.spawn_near_pad_height_min)
        rounds -= done
        if near:  # the round stopped before its check: place the near-pad starts, then check
            angle = near_draws[0, : near * n]
            place_near_pads(pos, ids, near_pad, pads, near_draws, np.cos(angle), np.sin(angle))
            ids = swarms_too_close(pos, ids, config.spawn_separation)
        if len(ids) == 0:
            return pos
    return None
