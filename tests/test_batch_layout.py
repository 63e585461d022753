"""marlander_lite.batch_layout: the simulators' arrays, Fortran-ordered and spread over the cache's sets."""

import numpy as np

from marlander_lite.batch_layout import LINE_BYTES, PAGE_BYTES, batch_empty, batch_full, batch_zeros
from marlander_lite.platforms import PlatformConfig
from marlander_lite.pointmass import PointMassSwarm
from marlander_lite.task import TaskConfig


def page_offset(array: np.ndarray) -> int:
    return array.__array_interface__["data"][0] % PAGE_BYTES


def test_batch_arrays_are_fortran_ordered_numpy_arrays_of_the_asked_shape_and_values():
    zeros, full = batch_zeros(4096, 2, 3), batch_full((7, 3), np.nan)
    flags = batch_zeros(5, 16, dtype=bool)
    assert zeros.shape == (4096, 2, 3) and zeros.dtype == np.float64 and zeros.flags.f_contiguous
    assert zeros.flags.writeable and zeros.flags.aligned and not zeros.any()
    assert np.isnan(full).all() and flags.dtype == bool and not flags.any() and flags.flags.f_contiguous
    assert batch_empty((3, 1, 4), dtype=np.int8).shape == (3, 1, 4)
    zeros[:, 1, 2] = 1.0  # one contiguous plane, as the kernels read it
    assert np.shares_memory(zeros, zeros[:, 1, 2]) and zeros[:, 1, 2].flags.c_contiguous


def test_successive_arrays_start_at_different_cache_lines_of_their_pages():
    offsets = [page_offset(batch_zeros(4096, 2, 3)) for _ in range(PAGE_BYTES // LINE_BYTES)]
    assert all(offset % LINE_BYTES == 0 for offset in offsets)
    assert len(set(offsets)) == len(offsets)  # a whole page of distinct lines before one repeats


def test_a_point_mass_swarm_spreads_its_state_over_the_page():
    swarm = PointMassSwarm(TaskConfig(num_drones=2), PlatformConfig(), num_envs=4096)
    arrays = [swarm.pos, swarm.vel, swarm.ang_vel, swarm.quat, swarm._thrust_dir, swarm._pads, swarm._pad_vel]
    assert all(a.flags.f_contiguous for a in arrays)
    assert len({page_offset(a) for a in arrays}) == len(arrays)
