"""Compiled kernels of the point-mass step (numba): bit for bit the numpy reference, and faster.

:class:`~marlander_lite.pointmass.simulator.PointMassSwarm` is written in plain numpy: every line of
its ``_thrust``, ``_set_attitude`` and ``_resolve_contacts`` is a whole-batch array operation that can
be checked against the model it implements. That version stays the reference. At training sizes
(4096 envs x 2 drones, 1024 x 16) those few dozen operations each make a pass over memory, and the
pair loop of :func:`marlander_lite.task.min_separation` makes ``N (N - 1) / 2`` of them; a compiled
loop that takes one drone (or one pair) at a time through the same formulas does the work in one pass.

What the kernels promise, and how:

* **The same bits.** Each kernel repeats the reference's floating-point operations in the same order
  and on the same operands (no ``fastmath``, so no reassociation and no fused multiply-add); the
  clip/maximum helpers below copy numpy's choice of operand, signed zeros included. The step's one angle is
  :func:`marlander_lite.rotations.turn_angle`, written with square roots, divisions and products only, so that
  both engines compute it alike (numpy's ``arctan2`` and libm's differ in the last bit on AVX-512 machines, and
  neither vectorises in a compiled loop). The step is split in two kernels only because the plates move between
  them. ``tests/test_pointmass_kernels.py``
  checks bit equality over seeded rollouts with resets, touchdowns, collisions, moving plates, stopped
  motors and dynamics-family draws.
* **Vectorised.** The loops over environments run several drones at once in the vector registers (four
  doubles with AVX2): square roots and divisions are correctly rounded there too, so the bits stay the same. For
  LLVM to do that, a loop's body must be straight-line code (the dynamics family's terms live in their own copy of
  the loop, the command delay in its own kernel) and LLVM may check at run time that a dozen arrays do not overlap
  (the option set below).
* **Numba is optional.** Without it (or with ``MARLANDER_LITE_ENGINE=numpy`` in the environment), nothing
  here is compiled and the simulator runs the reference. :func:`resolve_engine` decides.
* **Little compile cost.** ``cache=True`` keeps the machine code on disk (next to this file, or in numba's
  user cache when that is read-only), so only the first process on a machine pays the compile (a few seconds,
  see ``benchmarks/bench_pointmass.py``).

Arrays follow the simulator's layout: ``(num_envs, N, 3)`` in Fortran order, so the inner loops run over
the environment index, which is contiguous.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from typing import Any, Literal

import numpy as np

from marlander_lite.rotations import arctan_series

try:  # numba is optional: without it the simulator runs the numpy reference
    import llvmlite.binding
    import numba
except ImportError:  # pragma: no cover - depends on the installation
    numba = None
else:
    # The kernels below read and write a dozen arrays per loop. LLVM vectorises such a loop only after runtime checks
    # that the arrays do not overlap, and by default gives up beyond 8 of them: the physics loop then runs one drone
    # at a time, about twice as slow (benchmarks/bench_pointmass.py). Raising the limits lets it check and vectorise.
    # The checks fall back to the scalar loop when arrays do overlap, so no result changes; numba itself sets LLVM
    # options this way. It applies to whatever this process compiles from now on.
    llvmlite.binding.set_option("marlander_lite", "-runtime-memory-check-threshold=256")
    llvmlite.binding.set_option("marlander_lite", "-vectorize-memory-check-threshold=1024")

Engine = Literal["auto", "numpy", "numba"]
ENGINES: tuple[str, ...] = ("auto", "numpy", "numba")
ENGINE_VARIABLE = "MARLANDER_LITE_ENGINE"
"""Environment variable that picks the engine wherever ``engine="auto"`` (the default): ``numpy`` or ``numba``."""

GRAVITY = 9.81
CONTACT_NONE, CONTACT_OWN_PAD, CONTACT_OTHER = 0, 1, 2  # as marlander_lite.task (no import: no cycle)


def numba_available() -> bool:
    """Whether numba could be imported."""
    return numba is not None


def resolve_engine(engine: str = "auto") -> Literal["numpy", "numba"]:
    """``"numpy"`` or ``"numba"`` for a requested engine.

    ``"auto"`` reads :data:`ENGINE_VARIABLE` and otherwise takes numba when it is installed. Asking for
    ``"numba"`` without numba installed raises, rather than silently running the slow path.
    """
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}.")
    if engine == "auto":
        engine = os.environ.get(ENGINE_VARIABLE, "").strip().lower() or "auto"
        if engine not in ENGINES:
            raise ValueError(f"{ENGINE_VARIABLE} must be one of {ENGINES} (or unset), got {engine!r}.")
        if engine == "auto":
            return "numba" if numba is not None else "numpy"
    if engine == "numba" and numba is None:
        raise ValueError('engine="numba" needs numba: pip install numba (or use engine="numpy").')
    return engine  # type: ignore[return-value]


def jit_kernel(function: Callable[..., Any]) -> Callable[..., Any]:
    """``function`` compiled as every kernel of the engine is (cached on disk, no GIL), or as it is without numba."""
    # No fastmath: it would license reassociation and fused multiply-adds, and the bits would differ.
    return numba.njit(cache=True, nogil=True, error_model="numpy")(function) if numba is not None else function


def jit_inline(function: Callable[..., Any]) -> Callable[..., Any]:
    """:func:`jit_kernel` for small helpers, inlined into the kernels that call them (numba IR inlining), so that
    LLVM sees their constant arguments and straight-line code in the kernels' loops, which it can vectorise."""
    if numba is None:
        return function
    return numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")(function)


# ---------------------------------------------------------------- numpy's elementwise choices, as scalars
@jit_inline
def _clip(x: float, low: float, high: float) -> float:
    """``np.clip``: keeps ``x`` when it is inside, signed zero and NaN included."""
    return low if x < low else (high if x > high else x)


@jit_inline
def _maximum(a: float, b: float) -> float:
    """``np.maximum(a, b)``: NaN wins; on a tie (``-0.0, 0.0``) numpy returns ``b``."""
    return a if (a > b or a != a) else b


@jit_inline
def _minimum(a: float, b: float) -> float:
    """``np.minimum(a, b)``: NaN wins; on a tie numpy returns ``b``."""
    return a if (a < b or a != a) else b


_arctan_series = jit_inline(arctan_series)
"""``rotations.arctan_series``, inlined into :func:`_turn_angle`."""


@jit_inline
def _turn_angle(sin: float, cos: float) -> float:
    """:func:`marlander_lite.rotations.turn_angle` for one angle: the same operations in the same order."""
    r = math.sqrt(sin * sin + cos * cos)
    denominator = r + abs(cos)
    t = sin / (denominator if denominator > 0.0 else 1.0)
    t = t / (1.0 + math.sqrt(1.0 + t * t))
    angle = 4.0 * (t * _arctan_series(t * t))
    return math.pi - angle if cos < 0.0 else angle


# ---------------------------------------------------------------- eq. 6: closest pair
@jit_kernel
def min_separation(pos: np.ndarray) -> np.ndarray:
    """:func:`marlander_lite.task.min_separation` compiled: the smallest distance between two drones per env.

    ``pos`` ``(num_envs, N, 3)`` m, any layout; returns ``(num_envs,)`` (inf for one drone, NaN if a
    distance is NaN). The minimum is taken over squared distances and rooted once: the square root is
    correctly rounded and monotone, so that is the minimum of the distances to the last bit.
    """
    e, n = pos.shape[0], pos.shape[1]
    best = np.full(e, np.inf)
    nan = np.zeros(e, dtype=np.bool_)
    for a in range(n - 1):
        for b in range(a + 1, n):
            for k in range(e):  # innermost over envs: contiguous in the simulator's layout, and vectorised
                dx = pos[k, b, 0] - pos[k, a, 0]
                dy = pos[k, b, 1] - pos[k, a, 1]
                dz = pos[k, b, 2] - pos[k, a, 2]
                sq = dx * dx + dy * dy + dz * dz
                best[k] = sq if sq < best[k] else best[k]
                nan[k] |= sq != sq
    out = np.sqrt(best)
    for k in range(e):
        if nan[k]:
            out[k] = np.nan
    return out


# ---------------------------------------------------------------- the policy's input
@jit_kernel
def policy_rows(obs: np.ndarray, out: np.ndarray) -> None:
    """``envs.options.policy_input`` compiled: ``obs`` ``(num_envs, N, d)`` (any layout) into the float32
    ``out`` ``(num_envs, N d)``, one env per row, drone after drone.

    The cast rounds each number to the nearest float32 as numpy's does. The copy transposes the simulators'
    env-major arrays into rows, which numpy does element by element, three times slower than this loop.
    """
    e, n, d = obs.shape
    for i in range(n):
        for c in range(d):
            column = i * d + c
            for k in range(e):
                out[k, column] = obs[k, i, c]


# ---------------------------------------------------------------- a reset
@jit_kernel
def rest_envs(
    env_ids: np.ndarray,
    vel: np.ndarray,
    ang_vel: np.ndarray,
    quat: np.ndarray,
    thrust_dir: np.ndarray,
    landed: np.ndarray,
    motors_stopped: np.ndarray,
) -> None:
    """``PointMassSwarm._at_rest`` for whole envs ``env_ids``: at rest, level (thrust axis up), not landed, motors
    on."""
    for i in range(vel.shape[1]):
        for k in env_ids:
            for c in range(3):
                vel[k, i, c] = 0.0
                ang_vel[k, i, c] = 0.0
            quat[k, i, 0], quat[k, i, 1], quat[k, i, 2], quat[k, i, 3] = 0.0, 0.0, 0.0, 1.0
            thrust_dir[k, i, 0], thrust_dir[k, i, 1], thrust_dir[k, i, 2] = 0.0, 0.0, 1.0
            landed[k, i] = False
            motors_stopped[k, i] = False


# ---------------------------------------------------------------- the step, in two halves
@jit_inline
def _rest_height(
    x: float, y: float, plate_pos: np.ndarray, k: int, half_x: float, half_y: float, lift: float, floor: float
) -> float:
    """``PointMassSwarm._surface``'s rest height on a level plate: the plate top over the plate, else the floor."""
    over_plate = abs(x - plate_pos[k, 0]) <= half_x and abs(y - plate_pos[k, 1]) <= half_y
    return plate_pos[k, 2] + lift if over_plate else floor


@jit_kernel
def delayed_commands(
    velocity: np.ndarray, cmd_gain: np.ndarray, latency: np.ndarray, commands: np.ndarray, acting: np.ndarray
) -> None:
    """The command a drone drawn from a dynamics family acts on (``PointMassSwarm._family_thrust``'s first lines).

    ``velocity`` ``(num_envs, N, 3)`` m/s is scaled by the drone's gain error and arrives ``latency`` policy periods
    late: ``acting`` gets the blend of it with the two previous commands, which ``commands`` ``(2, num_envs, N, 3)``
    holds and which move one slot on.
    """
    e, n = velocity.shape[0], velocity.shape[1]
    for i in range(n):
        for k in range(e):
            g = cmd_gain[k, i, 0]
            late = _clip(latency[k, i, 0], 0.0, 1.0)
            later = _clip(latency[k, i, 0] - 1.0, 0.0, 1.0)
            for c in range(3):
                now = velocity[k, i, c] * g
                older = (1.0 - later) * commands[0, k, i, c] + later * commands[1, k, i, c]
                acting[k, i, c] = (1.0 - late) * now + late * older
                commands[1, k, i, c] = commands[0, k, i, c]
                commands[0, k, i, c] = now


@jit_kernel
def thrust_and_integrate(
    velocity: np.ndarray,
    pos: np.ndarray,
    vel: np.ndarray,
    thrust_dir: np.ndarray,
    motors_stopped: np.ndarray,
    gain: np.ndarray,
    turn: np.ndarray,
    tan_tilt: np.ndarray,
    thrust_min: np.ndarray,
    thrust_max: np.ndarray,
    family: bool,
    inv_mass: np.ndarray,
    drag: np.ndarray,
    cushion: np.ndarray,
    use_cushion: bool,
    plate_pos: np.ndarray,
    surface: np.ndarray,
    dt: float,
    start: np.ndarray,
    cross: np.ndarray,
    sin: np.ndarray,
    cos: np.ndarray,
    quat: np.ndarray,
) -> None:
    """First half of ``PointMassSwarm.step`` for level plates: ``_thrust`` (or ``_family_thrust``, given the
    command :func:`delayed_commands` made act), stopped motors, the position and velocity update, and
    ``_set_attitude`` up to the angle of the axis's turn.

    Updates ``pos``, ``vel``, ``thrust_dir`` and ``quat`` in place and writes ``start`` (positions before the step),
    ``cross`` (``d_prev x d``), ``sin`` (its norm) and ``cos`` (``d_prev . d``) for
    :func:`attitude_rates_and_contacts`. Per-env parameters have a drone axis of length 1, per-drone ones (a family)
    of length N. ``surface`` is ``(half_x, half_y, lift, landed_height)``. The loop is written twice, with and without
    the family's terms, so that each has no branch LLVM cannot turn into a vector select.
    """
    e, n = pos.shape[0], pos.shape[1]
    per_drone = gain.shape[1] > 1
    if family:
        for i in range(n):
            for k in range(e):
                _drone_step(
                    k, i, i if per_drone else 0, True, velocity, pos, vel, thrust_dir, motors_stopped, gain, turn,
                    tan_tilt, thrust_min, thrust_max, inv_mass, drag, cushion, use_cushion, plate_pos, surface, dt,
                    start, cross, sin, cos, quat,
                )  # fmt: skip
    else:
        for i in range(n):
            for k in range(e):
                _drone_step(
                    k, i, i if per_drone else 0, False, velocity, pos, vel, thrust_dir, motors_stopped, gain, turn,
                    tan_tilt, thrust_min, thrust_max, inv_mass, drag, cushion, use_cushion, plate_pos, surface, dt,
                    start, cross, sin, cos, quat,
                )  # fmt: skip


@jit_inline
def _drone_step(
    k: int,
    i: int,
    j: int,
    family: bool,
    velocity: np.ndarray,
    pos: np.ndarray,
    vel: np.ndarray,
    thrust_dir: np.ndarray,
    motors_stopped: np.ndarray,
    gain: np.ndarray,
    turn: np.ndarray,
    tan_tilt: np.ndarray,
    thrust_min: np.ndarray,
    thrust_max: np.ndarray,
    inv_mass: np.ndarray,
    drag: np.ndarray,
    cushion: np.ndarray,
    use_cushion: bool,
    plate_pos: np.ndarray,
    surface: np.ndarray,
    dt: float,
    start: np.ndarray,
    cross: np.ndarray,
    sin: np.ndarray,
    cos: np.ndarray,
    quat: np.ndarray,
) -> None:
    """:func:`thrust_and_integrate` for drone ``i`` of env ``k`` (``j``: its index into per-env or per-drone
    parameters). ``family`` is a constant of each call site, so each copy of the loop keeps only its own terms."""
    u0, u1, u2 = velocity[k, i, 0], velocity[k, i, 1], velocity[k, i, 2]
    v0, v1, v2 = vel[k, i, 0], vel[k, i, 1], vel[k, i, 2]
    p0, p1, p2 = thrust_dir[k, i, 0], thrust_dir[k, i, 1], thrust_dir[k, i, 2]
    t_min, t_max = thrust_min[k, j], thrust_max[k, j]
    # _thrust: the wanted acceleration, the thrust vector for it within the tilt and thrust limits ...
    w0 = (u0 - v0) * gain[k, j, 0]
    w1 = (u1 - v1) * gain[k, j, 1]
    w2 = (u2 - v2) * gain[k, j, 2] + GRAVITY
    fz = _clip(w2, t_min, t_max)
    horizontal = math.sqrt(w0 * w0 + w1 * w1)
    shrink = _minimum(1.0, fz * tan_tilt[k, j] / _maximum(horizontal, 1e-12))
    w0, w1, w2 = w0 * shrink, w1 * shrink, fz
    norm = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    # ... the axis turned part of the way towards it, and the thrust along that axis.
    a0 = p0 + (w0 / norm - p0) * turn[k, j, 0]
    a1 = p1 + (w1 / norm - p1) * turn[k, j, 0]
    a2 = p2 + (w2 / norm - p2) * turn[k, j, 0]
    norm = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    a0, a1, a2 = a0 / norm, a1 / norm, a2 / norm
    thrust = _clip(fz / _maximum(a2, 0.1), t_min, t_max)
    f0, f1, f2 = a0 * thrust, a1 * thrust, a2 * thrust - GRAVITY
    s0, s1, s2 = pos[k, i, 0], pos[k, i, 1], pos[k, i, 2]
    if family:  # the nominal mass's acceleration scaled to the true mass, drag, ground cushion
        m = inv_mass[k, i, 0]
        f0, f1, f2 = f0 * m, f1 * m, (f2 + GRAVITY) * m - GRAVITY
        d = drag[k, i, 0]
        f0, f1, f2 = f0 - d * v0, f1 - d * v1, f2 - d * v2
        # Computed for every drone and kept where the batch has a cushion: a select, not a branch (see above).
        height = _maximum(s2 - _rest_height(s0, s1, plate_pos, k, surface[0], surface[1], surface[2], surface[3]), 0.0)
        r = 0.04 / (0.04 + height)  # family.CUSHION_LENGTH
        with_cushion = f2 + cushion[k, i] * GRAVITY * (r * r)
        f2 = with_cushion if use_cushion else f2
    if motors_stopped[k, i]:  # gravity alone, and the attitude stays
        f0, f1, f2 = 0.0, 0.0, -GRAVITY
        a0, a1, a2 = p0, p1, p2
    half_dt = 0.5 * dt
    start[k, i, 0], start[k, i, 1], start[k, i, 2] = s0, s1, s2
    pos[k, i, 0] = s0 + (v0 + half_dt * f0) * dt
    pos[k, i, 1] = s1 + (v1 + half_dt * f1) * dt
    pos[k, i, 2] = s2 + (v2 + half_dt * f2) * dt
    vel[k, i, 0] = v0 + f0 * dt
    vel[k, i, 1] = v1 + f1 * dt
    vel[k, i, 2] = v2 + f2 * dt
    # _set_attitude, up to the angle of the axis's turn, which turn_rates computes in a loop of its own.
    x0, x1, x2 = p1 * a2 - p2 * a1, p2 * a0 - p0 * a2, p0 * a1 - p1 * a0
    cross[k, i, 0], cross[k, i, 1], cross[k, i, 2] = x0, x1, x2
    sin[k, i] = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    cos[k, i] = p0 * a0 + p1 * a1 + p2 * a2
    scale = 1.0 / math.sqrt(2.0 * (1.0 + a2))
    quat[k, i, 0], quat[k, i, 1], quat[k, i, 3] = -a1 * scale, a0 * scale, (1.0 + a2) * scale
    thrust_dir[k, i, 0], thrust_dir[k, i, 1], thrust_dir[k, i, 2] = a0, a1, a2


@jit_kernel
def turn_rates(cross: np.ndarray, sin: np.ndarray, cos: np.ndarray, dt: float, ang_vel: np.ndarray) -> None:
    """The rest of ``_set_attitude``: ``ang_vel`` ``(num_envs, N, 3)`` rad/s from the axis's turn over ``dt`` s
    (``cross = d_prev x d``, ``sin`` its norm, ``cos = d_prev . d``, from :func:`thrust_and_integrate`).

    A loop of its own: inside the long loop of :func:`thrust_and_integrate`, LLVM left :func:`_turn_angle` scalar,
    18 ns a drone against 6.7 ns here (``docs/scaling.md``).
    """
    for i in range(sin.shape[1]):
        for k in range(sin.shape[0]):
            rate = _turn_angle(sin[k, i], cos[k, i]) / (_maximum(sin[k, i], 1e-12) * dt)
            for c in range(3):
                ang_vel[k, i, c] = cross[k, i, c] * rate


@jit_kernel
def contacts_and_landed(
    start: np.ndarray,
    pos: np.ndarray,
    vel: np.ndarray,
    ang_vel: np.ndarray,
    quat: np.ndarray,
    contact: np.ndarray,
    landed: np.ndarray,
    motors_stopped: np.ndarray,
    plate_pos: np.ndarray,
    pads: np.ndarray,
    pad_vel: np.ndarray,
    landed_offset: np.ndarray,
    surface: np.ndarray,
    pad_radius_sq: float,
) -> None:
    """Second half of ``PointMassSwarm.step`` for level plates, after the plates have moved: ``_resolve_contacts``
    and ``_hold_landed``.

    Updates ``pos``, ``vel``, ``ang_vel``, ``quat`` and ``contact`` in place.
    """
    e, n = pos.shape[0], pos.shape[1]
    half_x, half_y, lift, floor = surface[0], surface[1], surface[2], surface[3]
    for i in range(n):
        for k in range(e):
            if landed[k, i]:  # _hold_landed: on the pad, moving with it, level; it touches nothing new
                for c in range(3):
                    pos[k, i, c] = pads[k, i, c] + landed_offset[k, i, c]
                    vel[k, i, c] = pad_vel[k, i, c]
                    ang_vel[k, i, c] = 0.0
                quat[k, i, 0], quat[k, i, 1], quat[k, i, 2], quat[k, i, 3] = 0.0, 0.0, 0.0, 1.0
                contact[k, i] = CONTACT_NONE
                continue
            x, y = pos[k, i, 0], pos[k, i, 1]
            rest = _rest_height(x, y, plate_pos, k, half_x, half_y, lift, floor)
            if not pos[k, i, 2] <= rest:
                contact[k, i] = CONTACT_NONE
                continue
            if contact[k, i] == CONTACT_NONE:  # first contact: stop where the path crossed the surface
                z0, z1 = start[k, i, 2], pos[k, i, 2]
                fraction = _clip((z0 - rest) / _maximum(z0 - z1, 1e-12), 0.0, 1.0)
                for c in range(3):
                    pos[k, i, c] = start[k, i, c] + fraction * (pos[k, i, c] - start[k, i, c])
                x, y = pos[k, i, 0], pos[k, i, 1]
                rest = _rest_height(x, y, plate_pos, k, half_x, half_y, lift, floor)
            else:  # resting: it stops pushing into the surface; without thrust, friction holds it
                vel[k, i, 2] = _maximum(vel[k, i, 2], 0.0)
                if motors_stopped[k, i]:
                    vel[k, i, 0], vel[k, i, 1], vel[k, i, 2] = 0.0, 0.0, 0.0
            ex, ey = x - pads[k, i, 0], y - pads[k, i, 1]
            contact[k, i] = CONTACT_OWN_PAD if ex * ex + ey * ey <= pad_radius_sq else CONTACT_OTHER
            pos[k, i, 2] = rest
