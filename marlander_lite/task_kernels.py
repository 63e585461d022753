"""Compiled kernels of one MDP step (numba): :mod:`marlander_lite.task`'s formulas, one drone at a time, the same bits.

:class:`~marlander_lite.episodes.LandingEpisodes` evaluates the MDP after each physics step: eq. 2's observation, the
distances and speeds it needs, the touchdown test, eq. 5's per-drone reward and the arena test. In
:mod:`marlander_lite.task` each is a whole-batch numpy expression that can be read against the paper, and they stay
the reference. At training sizes (4096 envs x 2 drones, 1024 x 16) those few dozen expressions each make a pass over
memory; :func:`evaluate_step` makes one pass, :func:`observe_envs` does the same for the environments a reset starts,
and :func:`velocity_commands` is eq. 3's clip and scale. Like :mod:`marlander_lite.pointmass.kernels` they repeat the
reference's floating-point operations in the same order (no ``fastmath``), and ``tests/test_pointmass_kernels.py``
checks every output of seeded rollouts bit for bit against the numpy path. They apply on level plates; an inclined
plate's pad-frame test stays in numpy.

Arrays are ``(num_envs, N, ...)`` in any layout, though each layout compiles once more (seconds), so
:class:`~marlander_lite.episodes.LandingEpisodes` passes one (``episodes.fortran_state``); the outputs are allocated
by the caller.
"""

from __future__ import annotations

import math

import numpy as np

from marlander_lite.pointmass.kernels import CONTACT_NONE, CONTACT_OWN_PAD, _clip, jit_inline, jit_kernel


@jit_kernel
def velocity_commands(action: np.ndarray, max_speed: float, velocity: np.ndarray) -> bool:
    """:func:`marlander_lite.task.action_to_velocity` compiled: ``action`` ``(num_envs, N, 3)`` (any float dtype and
    layout) clipped to ``[-1, 1]`` and scaled by ``max_speed`` into ``velocity`` (float64, its own layout). Returns
    False, leaving ``velocity`` partly written, when an entry is NaN or infinite (the caller raises)."""
    e, n = action.shape[0], action.shape[1]
    finite = True
    for c in range(3):
        for i in range(n):
            for k in range(e):
                x = np.float64(action[k, i, c])
                finite &= x - x == 0.0  # False for NaN and +-inf
                velocity[k, i, c] = _clip(x, -1.0, 1.0) * max_speed
    return finite


@jit_kernel
def _observe_drone(
    k: int,
    i: int,
    row: int,
    pos: np.ndarray,
    quat: np.ndarray,
    vel: np.ndarray,
    ang_vel: np.ndarray,
    pad_pos: np.ndarray,
    pad_vel: np.ndarray,
    goal_lift: np.ndarray,
    limits: np.ndarray,
    obs: np.ndarray,
) -> tuple[float, float, float, float, float, float]:
    """``LandingEpisodes._measure`` for drone ``i`` of env ``k``: eq. 2's 13 numbers, each part clipped to ``limits``
    = ``(p_max, v_max, w_max)``, written to ``obs[row, i, :13]``. Returns ``p`` and ``v`` (position and velocity
    relative to the goal and the pad) unclipped. Straight-line code: a loop or a branch here would keep LLVM from
    vectorising the kernels' loops (:func:`_observe_extras` writes the rest)."""
    p_max, v_max, w_max = limits[0], limits[1], limits[2]
    p0 = pos[k, i, 0] - (pad_pos[k, i, 0] + goal_lift[0])
    p1 = pos[k, i, 1] - (pad_pos[k, i, 1] + goal_lift[1])
    p2 = pos[k, i, 2] - (pad_pos[k, i, 2] + goal_lift[2])
    v0, v1, v2 = vel[k, i, 0] - pad_vel[k, i, 0], vel[k, i, 1] - pad_vel[k, i, 1], vel[k, i, 2] - pad_vel[k, i, 2]
    obs[row, i, 0] = _clip(p0, -p_max, p_max)
    obs[row, i, 1] = _clip(p1, -p_max, p_max)
    obs[row, i, 2] = _clip(p2, -p_max, p_max)
    obs[row, i, 3] = quat[k, i, 0]
    obs[row, i, 4] = quat[k, i, 1]
    obs[row, i, 5] = quat[k, i, 2]
    obs[row, i, 6] = quat[k, i, 3]
    obs[row, i, 7] = _clip(v0, -v_max, v_max)
    obs[row, i, 8] = _clip(v1, -v_max, v_max)
    obs[row, i, 9] = _clip(v2, -v_max, v_max)
    obs[row, i, 10] = _clip(ang_vel[k, i, 0], -w_max, w_max)
    obs[row, i, 11] = _clip(ang_vel[k, i, 1], -w_max, w_max)
    obs[row, i, 12] = _clip(ang_vel[k, i, 2], -w_max, w_max)
    return p0, p1, p2, v0, v1, v2


@jit_kernel
def _observe_extras(
    env_ids: np.ndarray,
    pad_vel: np.ndarray,
    command: np.ndarray,
    v_max: float,
    observe_pad_vel: bool,
    observe_command: bool,
    obs: np.ndarray,
) -> None:
    """The numbers after eq. 2's 13 that the task asks for, clipped to ``v_max``: the pad velocity (read at
    ``env_ids[row]``), then the previous command (read at ``row``), into ``obs[row]``."""
    column = 13
    if observe_pad_vel:
        for c in range(3):
            for i in range(obs.shape[1]):
                for row in range(len(env_ids)):
                    obs[row, i, column + c] = _clip(pad_vel[env_ids[row], i, c], -v_max, v_max)
        column += 3
    if observe_command:
        for c in range(3):
            for i in range(obs.shape[1]):
                for row in range(len(env_ids)):
                    obs[row, i, column + c] = _clip(command[row, i, c], -v_max, v_max)


@jit_kernel
def evaluate_step(
    pos: np.ndarray,
    quat: np.ndarray,
    vel: np.ndarray,
    ang_vel: np.ndarray,
    pad_pos: np.ndarray,
    pad_vel: np.ndarray,
    contact: np.ndarray,
    goal_lift: np.ndarray,
    command: np.ndarray,
    landed: np.ndarray,
    prev_dist: np.ndarray,
    limits: np.ndarray,
    observe_pad_vel: bool,
    observe_command: bool,
    constants: np.ndarray,
    obs: np.ndarray,
    rel_pos: np.ndarray,
    dist: np.ndarray,
    speed: np.ndarray,
    horizontal: np.ndarray,
    landed_now: np.ndarray,
    crashed: np.ndarray,
    r_drones: np.ndarray,
    outside: np.ndarray,
) -> None:
    """The per-drone part of ``LandingEpisodes.step`` after the physics, on level plates.

    Writes eq. 2's ``obs`` and ``rel_pos`` (``p``), ``dist = |p|``, ``speed = |v|``, ``horizontal`` (the distance
    from the pad centre in the plane), :func:`~marlander_lite.task.touchdown_outcome`'s ``landed_now`` and ``crashed``,
    eq. 5's ``r_drones`` (:func:`~marlander_lite.task.drone_rewards`) and ``outside`` (out of the arena, and not
    landed before). ``constants`` is ``(pad radius, touchdown speed limit, alpha, beta, c, arena half width, arena
    height)`` as :func:`~marlander_lite.task.touchdown_limits` and the task give them.
    """
    e, n = pos.shape[0], pos.shape[1]
    radius, speed_max, alpha, beta, c = constants[0], constants[1], constants[2], constants[3], constants[4]
    half_width, height = constants[5], constants[6]
    for i in range(n):
        for k in range(e):
            p0, p1, p2, v0, v1, v2 = _observe_drone(
                k, i, k, pos, quat, vel, ang_vel, pad_pos, pad_vel, goal_lift, limits, obs
            )
            rel_pos[k, i, 0], rel_pos[k, i, 1], rel_pos[k, i, 2] = p0, p1, p2
            d = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
            s = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
            h = math.sqrt(p0 * p0 + p1 * p1)
            dist[k, i], speed[k, i], horizontal[k, i] = d, s, h
            active = not landed[k, i]
            touching = contact[k, i] != CONTACT_NONE and active
            lands = touching and contact[k, i] == CONTACT_OWN_PAD and h <= radius and s <= speed_max
            landed_now[k, i], crashed[k, i] = lands, touching and not lands
            r = alpha * (prev_dist[k, i] - d) + beta * s + c * (1.0 if lands else 0.0)
            r_drones[k, i] = r if active else 0.0
            x, y, z = pos[k, i, 0], pos[k, i, 1], pos[k, i, 2]
            outside[k, i] = (abs(x) > half_width or abs(y) > half_width or z > height or z < 0) and active
    if observe_pad_vel or observe_command:
        _observe_extras(np.arange(e), pad_vel, command, limits[1], observe_pad_vel, observe_command, obs)


@jit_kernel
def observe_envs(
    env_ids: np.ndarray,
    pos: np.ndarray,
    quat: np.ndarray,
    vel: np.ndarray,
    ang_vel: np.ndarray,
    pad_pos: np.ndarray,
    pad_vel: np.ndarray,
    goal_lift: np.ndarray,
    limits: np.ndarray,
    observe_pad_vel: bool,
    observe_command: bool,
    obs: np.ndarray,
    dist: np.ndarray,
) -> None:
    """The per-drone part of ``LandingEpisodes.reset``: eq. 2 at the start of the episodes ``env_ids`` (no previous
    command), into ``obs[r]`` and ``dist[r] = |p|`` for the ``r``-th of them."""
    n = pos.shape[1]
    for i in range(n):
        for row in range(len(env_ids)):
            p0, p1, p2, _, _, _ = _observe_drone(
                env_ids[row], i, row, pos, quat, vel, ang_vel, pad_pos, pad_vel, goal_lift, limits, obs
            )
            dist[row, i] = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    if observe_pad_vel or observe_command:
        no_command = np.zeros((len(env_ids), n, 3))
        _observe_extras(env_ids, pad_vel, no_command, limits[1], observe_pad_vel, observe_command, obs)


@jit_kernel
def start_episodes(
    env_ids: np.ndarray,
    pos: np.ndarray,
    dist: np.ndarray,
    steps: np.ndarray,
    landed: np.ndarray,
    prev_dist: np.ndarray,
    landing_error: np.ndarray,
    landing_time: np.ndarray,
    episode_return: np.ndarray,
    previous_command: np.ndarray,
    min_separation: np.ndarray,
) -> None:
    """The rest of ``LandingEpisodes.reset`` for the episodes ``env_ids``, in one pass: no step taken, no drone landed,
    eq. 5's previous distance from ``dist[r]`` (:func:`observe_envs`'s), no landing recorded, no return, no previous
    command, and the closest pair of the new starts ``pos`` ``(num_envs, N, 3)`` m, as
    :func:`~marlander_lite.pointmass.kernels.min_separation` finds it (the minimum of the squared distances, rooted)."""
    n = pos.shape[1]
    for r in range(len(env_ids)):
        k = env_ids[r]
        steps[k] = 0
        episode_return[k] = 0.0
        best, nan = np.inf, False
        for i in range(n):
            landed[k, i] = False
            prev_dist[k, i] = dist[r, i]
            landing_error[k, i] = np.nan
            landing_time[k, i] = np.nan
            for c in range(3):
                previous_command[k, i, c] = 0.0
            for j in range(i + 1, n):
                dx = pos[k, j, 0] - pos[k, i, 0]
                dy = pos[k, j, 1] - pos[k, i, 1]
                dz = pos[k, j, 2] - pos[k, i, 2]
                sq = dx * dx + dy * dy + dz * dz
                best = sq if sq < best else best
                nan |= sq != sq
        min_separation[k] = np.nan if nan else math.sqrt(best)


@jit_kernel
def episode_summaries(
    env_ids: np.ndarray, landed: np.ndarray, landing_error: np.ndarray, landing_time: np.ndarray, out: np.ndarray
) -> None:
    """The record of the ended episodes ``env_ids`` (``LandingVecEnv``'s infos): ``out[r, 0]``, the mean landing error
    over the drones of env ``env_ids[r]`` that landed (m; NaN if none did), and ``out[r, 1]``, the time its last drone
    landed (s; NaN unless all did). The errors are added as numpy adds a row of up to 128 (:func:`_row_sum`)."""
    n = landed.shape[1]
    terms = np.empty(n)
    for r in range(len(env_ids)):
        k = env_ids[r]
        count, last = 0, -1.0
        for i in range(n):
            terms[i] = landing_error[k, i] if landed[k, i] else 0.0
            if landed[k, i]:
                count += 1
                last = max(last, landing_time[k, i])
        out[r, 0] = _row_sum(terms) / count if count else np.nan
        out[r, 1] = last if count == n else np.nan


@jit_inline
def _row_sum(a: np.ndarray) -> float:
    """``a.sum()`` for a contiguous float64 row of at most 128 entries, in numpy's order: one after another below 8,
    else eight running sums combined pairwise, then the rest (numpy's ``pairwise_sum``)."""
    n = len(a)
    if n < 8:
        total = 0.0
        for i in range(n):
            total += a[i]
        return total
    r = a[:8].copy()
    i = 8
    while i < n - n % 8:
        for j in range(8):
            r[j] += a[i + j]
        i += 8
    total = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        total += a[i]
        i += 1
    return total
