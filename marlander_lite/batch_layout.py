"""Batched arrays in the layout the compiled kernels run fastest on.

The batched simulators and :class:`~marlander_lite.episodes.LandingEpisodes` keep every per-drone quantity as one
``(num_envs, N, ...)`` array in Fortran order: the environment index varies fastest, so ``pos[:, i, c]`` is one
contiguous *plane* and the kernels' inner loops run down planes (``pointmass/kernels.py``).

Where each array starts matters too. A large array starts at the same place within a 4 KiB memory page as every other
large array, and with 4096 environments each plane is 32 KiB long, a whole number of pages. The 30 or so planes that
a kernel's loop reads and writes together then sit at the same offset within their pages, so that their elements at
one environment index fall into the same set of the L1 cache, which holds 8 lines per set (32 KiB, 8 ways on the
development VM's AMD EPYC, as on most x86 cores): most loads miss. The functions here start each new array 64 bytes
(one cache line) further into its page than the one before, cycling through the 64 lines of a page, which spreads the
planes of different arrays over the sets: the point mass's thrust kernel ran 1.5x faster at 4096 x 2 drones, the whole
VecEnv step 1.12-1.18x (``docs/scaling.md``). Values are never affected; only addresses.

This is for the arrays a simulator or an episode batch keeps for its lifetime: the C library hands out each large
block at the start of fresh pages, so without this they all line up. Arrays made anew at every step come from
wherever the allocator has room, which spreads them already, and making one here costs about 5 us more than
``np.empty``.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from numpy.typing import DTypeLike

PAGE_BYTES = 4096
"""The memory page, and the span of addresses that share the L1 cache's sets."""
LINE_BYTES = 64
"""One cache line: the step between the starts of successive arrays."""
_next_slot = itertools.count()


def batch_empty(shape: tuple[int, ...], dtype: DTypeLike = float) -> np.ndarray:
    """An uninitialised Fortran-ordered array of ``shape``, starting one cache line further into its page than the
    last array made here (modulo a page)."""
    dtype = np.dtype(dtype)
    nbytes = math.prod(shape) * dtype.itemsize
    slot = next(_next_slot) % (PAGE_BYTES // LINE_BYTES)
    buffer = np.empty(nbytes + 2 * PAGE_BYTES, dtype=np.uint8)
    start = -buffer.__array_interface__["data"][0] % PAGE_BYTES + slot * LINE_BYTES
    return buffer[start : start + nbytes].view(dtype).reshape(shape, order="F")


def batch_full(shape: tuple[int, ...], fill_value: float | bool, dtype: DTypeLike = float) -> np.ndarray:
    """:func:`batch_empty` filled with ``fill_value``."""
    array = batch_empty(shape, dtype)
    array[...] = fill_value
    return array


def batch_zeros(*shape: int, dtype: DTypeLike = float) -> np.ndarray:
    """:func:`batch_empty` filled with zeros."""
    return batch_full(shape, 0, dtype)
