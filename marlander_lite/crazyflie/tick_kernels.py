"""Compiled control ticks of the PyBullet swarm (numba): :class:`~marlander_lite.crazyflie.ticks.ControlTick`
for every flying drone of a swarm in one call, bit for bit.

:meth:`ControlTick.run <marlander_lite.crazyflie.ticks.ControlTick.run>` is the reference: per flying drone, the
tracker (:meth:`CascadedPID.update <marlander_lite.crazyflie.control.CascadedPID.update>` or
:meth:`FirmwareTracker.update <marlander_lite.crazyflie.firmware.FirmwareTracker.update>`), the
:class:`~marlander_lite.crazyflie.physics.MotorLag`, then drag, downwash, ground effect and
:func:`~marlander_lite.crazyflie.physics.motor_wrench`, on Python floats (7-11 us per drone and tick). The two
kernels here, :func:`pid_tick` and :func:`firmware_tick`, take the same steps in the same order for all drones
at once (the trackers' parts are in :mod:`~marlander_lite.crazyflie.tracker_kernels`), and keep the same bits, as
the point-mass kernels do (:mod:`marlander_lite.pointmass.kernels`):

* every expression keeps the reference's operand order (Python evaluates ``a + b + c`` as ``(a + b) + c``, and so
  does the kernel); no ``fastmath``, so no reassociation and no fused multiply-add;
* ``sqrt`` is IEEE's; ``sin``, ``cos``, ``asin``, ``atan2`` and ``exp`` are the C library's, the functions Python's
  ``math`` module calls;
* the trackers' memory lives in their own numpy arrays (``CascadedPID.state``, ``FirmwareTracker.pid_memory``,
  ``.phase``, ``.setpoint``), which the reference and the kernels update in place alike.

``tests/test_crazyflie_kernels.py`` flies both engines side by side and asserts equality. Constants travel as a
few float arrays whose layouts are named by index constants: ``AERO_*`` below, ``PID_*`` and ``FW_*`` in
:mod:`~marlander_lite.crazyflie.tracker_kernels`.
"""

from __future__ import annotations

import math

import numpy as np

from marlander_lite.crazyflie.params import CF2XParams, PhysicsConfig
from marlander_lite.crazyflie.physics import RPM_TO_RAD_S, MotorLag
from marlander_lite.crazyflie.tracker_kernels import firmware_drone, pid_drone, rotation
from marlander_lite.pointmass.kernels import jit_kernel

# Layout of the ``aero`` constants (physics.py's numbers for one drone type, the plate, the motor lag).
AERO_KF, AERO_KM, AERO_ROTOR_X, AERO_ROTOR_Y, AERO_ROTOR_Z, AERO_YAW_SIGN = 0, 1, 2, 6, 10, 11  # x, y, sign: 4 each
AERO_RADIUS, AERO_GE_COEFF, AERO_GE_FLOOR, AERO_DRAG_XY, AERO_DRAG_Z = 15, 16, 17, 18, 19
AERO_C1, AERO_C2, AERO_ARM, AERO_BODY_HEIGHT, AERO_HALF_X, AERO_HALF_Y = 20, 21, 22, 23, 24, 25
AERO_DECAY, AERO_M1, AERO_M2, AERO_RPM_TO_RAD_S, AERO_SQUARE, AERO_SIZE = 26, 27, 28, 29, 30, 31
# Layout of the ``switches`` (ints): which effects act.
ON_DRAG, ON_DOWNWASH, ON_GROUND_EFFECT, ON_LAG = 0, 1, 2, 3


def aero_constants(params: CF2XParams, physics: PhysicsConfig, lag: MotorLag, plate_half: tuple[float, float]) -> tuple:
    """``(aero, switches)``: the constants of the forces of :class:`~marlander_lite.crazyflie.ticks.ControlTick`,
    ``(AERO_SIZE,)`` floats, and which effects act, ``(4,)`` ints (``ON_*``)."""
    aero = np.zeros(AERO_SIZE)
    aero[AERO_KF], aero[AERO_KM] = params.kf, params.km
    aero[AERO_ROTOR_X : AERO_ROTOR_X + 4] = [x for x, _ in params.rotor_xy]
    aero[AERO_ROTOR_Y : AERO_ROTOR_Y + 4] = [y for _, y in params.rotor_xy]
    aero[AERO_ROTOR_Z] = params.rotor_z
    aero[AERO_YAW_SIGN : AERO_YAW_SIGN + 4] = params.yaw_signs
    aero[AERO_RADIUS], aero[AERO_GE_COEFF] = params.prop_radius, params.ground_effect_coeff
    aero[AERO_GE_FLOOR] = params.collision_height / 2 + params.rotor_z  # as ground_effect_gains forms it
    aero[AERO_DRAG_XY], aero[AERO_DRAG_Z] = params.drag_coeff_xy, params.drag_coeff_z
    aero[AERO_C1], aero[AERO_C2] = params.downwash_coeffs[0], params.downwash_coeffs[1]
    aero[AERO_ARM], aero[AERO_BODY_HEIGHT] = params.arm, params.collision_height
    aero[AERO_HALF_X], aero[AERO_HALF_Y] = plate_half
    aero[AERO_DECAY], aero[AERO_M1], aero[AERO_M2] = lag.decay, lag.m1, lag.m2
    aero[AERO_RPM_TO_RAD_S] = RPM_TO_RAD_S
    # The downwash's distances are squared as ``d ** 2``, which calls the C library's pow (it differs from d * d in
    # the last bit for about 1 value in 1000). The kernel calls pow too, with this exponent read at run time so that
    # LLVM cannot turn pow(d, 2.0) into d * d.
    aero[AERO_SQUARE] = 2.0
    switches = np.array([physics.drag, physics.downwash, physics.ground_effect, lag.active], dtype=np.int64)
    return aero, switches


# ---------------------------------------------------------------- forces, all flying drones
@jit_kernel
def _lag(
    active: np.ndarray, rpm: np.ndarray, rpm_command: np.ndarray, effective: np.ndarray, aero: np.ndarray, lagging: bool
) -> np.ndarray:
    """Rotor speeds after the tracker wrote ``rpm_command``: :class:`~marlander_lite.crazyflie.physics.MotorLag`
    (``effective``: the tick's mean-thrust speeds, ``rpm``: at its end), or ``rpm = rpm_command`` without a lag.
    Returns the speeds the forces use (``effective`` or ``rpm``), every drone's (the idle ones' are 0)."""
    if not lagging:
        for a in range(active.size):
            i = active[a]
            for m in range(4):
                rpm[i, m] = rpm_command[i, m]
        return rpm
    decay, m1, m2 = aero[AERO_DECAY], aero[AERO_M1], aero[AERO_M2]
    effective[:] = rpm  # the idle drones' too, as the reference copies every drone's list
    for a in range(active.size):
        i = active[a]
        for m in range(4):
            c = rpm_command[i, m]
            gap = rpm[i, m] - c
            square = c * c + 2.0 * c * gap * m1 + gap * gap * m2
            effective[i, m] = math.sqrt(square if not square < 0.0 else 0.0)  # max(square, 0.0) as Python picks
            rpm[i, m] = c + gap * decay
    return effective


@jit_kernel
def _wrenches(
    kin: np.ndarray,
    rot: np.ndarray,
    active: np.ndarray,
    speeds: np.ndarray,
    px: float,
    py: float,
    pz: float,
    aero: np.ndarray,
    switches: np.ndarray,
    thrusts: np.ndarray,
    forces: np.ndarray,
    torques: np.ndarray,
) -> None:
    """The second loop of ``ControlTick.run``: drag, downwash, ground effect and motor wrench of every drone in
    ``active`` into ``forces[i]`` and ``torques[i]`` (body frame, N and N m); ``speeds`` are the rotor speeds
    (RPM) they act with, ``thrusts`` ``(N,)`` scratch."""
    kf, km, n = aero[AERO_KF], aero[AERO_KM], kin.shape[0]
    drag, downwash, ground_effect = switches[ON_DRAG] != 0, switches[ON_DOWNWASH] != 0, switches[ON_GROUND_EFFECT] != 0
    if downwash:  # k_f sum_i w_i^2 of every drone, summed left to right
        for j in range(n):
            a, b, c, d = speeds[j, 0], speeds[j, 1], speeds[j, 2], speeds[j, 3]
            thrusts[j] = kf * ((((0.0 + a * a) + b * b) + c * c) + d * d)
    for a in range(active.size):
        i = active[a]
        x, y, z = kin[i, 0], kin[i, 1], kin[i, 2]
        r20, r21, r22 = rot[i, 6], rot[i, 7], rot[i, 8]
        fx = fy = fz = 0.0
        if drag:  # drag_force on the velocity in body axes
            spin = ((((0.0 + speeds[i, 0]) + speeds[i, 1]) + speeds[i, 2]) + speeds[i, 3]) * aero[AERO_RPM_TO_RAD_S]
            kxy, kz = aero[AERO_DRAG_XY] * spin, aero[AERO_DRAG_Z] * spin
            vx, vy, vz = kin[i, 7], kin[i, 8], kin[i, 9]
            fx = -kxy * (rot[i, 0] * vx + rot[i, 3] * vy + r20 * vz)
            fy = -kxy * (rot[i, 1] * vx + rot[i, 4] * vy + r21 * vz)
            fz = -kz * (rot[i, 2] * vx + rot[i, 5] * vy + r22 * vz)
        if downwash:  # downwash_push of every drone above, world z in body axes
            push = 0.0
            for j in range(n):
                dz = kin[j, 2] - z
                if dz <= 0.0:
                    continue
                horizontal_sq = math.pow(kin[j, 0] - x, aero[AERO_SQUARE]) + math.pow(kin[j, 1] - y, aero[AERO_SQUARE])
                push += _downwash_push(dz, horizontal_sq, thrusts[j], aero)
            fx, fy, fz = fx + r20 * push, fy + r21 * push, fz + r22 * push
        base = z
        if ground_effect:  # height above the plate when over it, else above the floor
            over_plate = abs(x - px) <= aero[AERO_HALF_X] and abs(y - py) <= aero[AERO_HALF_Y] and z >= pz
            base = z - (pz if over_plate else 0.0)
        # motor_wrench, rotor by rotor from M1 to M4, with each rotor's ground-effect gain
        total = tx = ty = tz = 0.0
        for m in range(4):
            gain = 1.0
            if ground_effect:
                rx, ry = aero[AERO_ROTOR_X + m], aero[AERO_ROTOR_Y + m]
                h = base + r20 * rx + r21 * ry + r22 * aero[AERO_ROTOR_Z]
                floor = aero[AERO_GE_FLOOR]
                ratio = aero[AERO_RADIUS] / (4.0 * (h if h > floor else floor))
                gain = 1.0 + aero[AERO_GE_COEFF] * ratio * ratio
            w = speeds[i, m]
            q = w * w
            t = kf * q * gain
            total += t
            tx += aero[AERO_ROTOR_Y + m] * t
            ty -= aero[AERO_ROTOR_X + m] * t
            tz += aero[AERO_YAW_SIGN + m] * km * q
        forces[i, 0], forces[i, 1], forces[i, 2] = fx, fy, fz + total
        torques[i, 0], torques[i, 1], torques[i, 2] = tx, ty, tz


@jit_kernel
def _downwash_push(dz: float, horizontal_sq: float, thrust_above: float, aero: np.ndarray) -> float:
    """:func:`~marlander_lite.crazyflie.physics.downwash_push` for ``dz > 0`` (N)."""
    radius = aero[AERO_RADIUS]
    ratio = radius / (4.0 * dz)
    peak = aero[AERO_C1] * ratio * ratio
    peak = thrust_above if thrust_above < peak else peak
    width = aero[AERO_C2] * dz + aero[AERO_ARM] + radius
    onset = dz / aero[AERO_BODY_HEIGHT]
    onset = onset if onset < 1.0 else 1.0
    return -peak * math.exp(-horizontal_sq / (2.0 * width * width)) * onset


# ---------------------------------------------------------------- the entry points: one control tick of a swarm
WORK = ("aero", "switches", "rpm", "rpm_command", "effective", "thrusts", "rot", "forces", "torques")
"""The tuple ``work`` of :func:`pid_tick` and :func:`firmware_tick`, in this order."""
WORK_RPM_COMMAND, WORK_ROT = WORK.index("rpm_command"), WORK.index("rot")


@jit_kernel
def _forces(kin: np.ndarray, active: np.ndarray, px: float, py: float, pz: float, work: tuple) -> None:
    """After either tracker: the motor lag, then every active drone's force and torque (into ``work``)."""
    aero, switches, rpm, rpm_command, effective, thrusts, rot, forces, torques = work
    speeds = _lag(active, rpm, rpm_command, effective, aero, switches[ON_LAG] != 0)
    _wrenches(kin, rot, active, speeds, px, py, pz, aero, switches, thrusts, forces, torques)


@jit_kernel
def pid_tick(
    kin: np.ndarray,
    active: np.ndarray,
    target: np.ndarray,
    command: np.ndarray,
    px: float,
    py: float,
    pz: float,
    pos_gains: np.ndarray,
    att_gains: np.ndarray,
    limits: np.ndarray,
    mix: np.ndarray,
    state: np.ndarray,
    work: tuple,
) -> None:
    """``ControlTick.run`` with a :class:`CascadedPID`, for the drones ``active`` (indices, int64).

    Args:
        kin: every drone's ``(pos, quat, vel, ang_vel)`` ``(N, 13)`` (m, x y z w, m/s, rad/s), world frame.
        target, command: target position (m) and velocity (m/s) ``(N, 3)``.
        px, py, pz: the plate's top-face centre (m).
        pos_gains, att_gains, limits, mix: :func:`pid_constants`; ``state``: the tracker's ``state`` (updated).
        work: what both trackers' ticks share, :data:`WORK`: the :func:`aero_constants` ``aero`` and ``switches``;
            rotor speeds ``rpm`` and ``rpm_command`` ``(N, 4)`` (RPM), updated at the rows of ``active``; work space
            ``effective`` ``(N, 4)``, ``thrusts`` ``(N,)``, ``rot`` ``(N, 9)``; ``forces`` and ``torques`` ``(N, 3)``
            body frame (N, N m), written at the rows of ``active``.
    """
    rpm_command, rot = work[WORK_RPM_COMMAND], work[WORK_ROT]
    for a in range(active.size):
        i = active[a]
        rotation(kin, i, rot)
        pid_drone(i, kin, rot, target, command, pos_gains, att_gains, limits, mix, state, rpm_command)
    _forces(kin, active, px, py, pz, work)


@jit_kernel
def firmware_tick(
    kin: np.ndarray,
    active: np.ndarray,
    command: np.ndarray,
    px: float,
    py: float,
    pz: float,
    pids: np.ndarray,
    limits: np.ndarray,
    mix: np.ndarray,
    velocity_every: int,
    memory: np.ndarray,
    phase: np.ndarray,
    setpoint: np.ndarray,
    work: tuple,
) -> None:
    """``ControlTick.run`` with a :class:`FirmwareTracker` (which ignores target positions); arguments as
    :func:`pid_tick`, with the tracker's ``pid_constants`` (``pids``), :func:`firmware_constants`, its
    ``velocity_every``, and its ``pid_memory``, ``phase`` and ``setpoint`` (updated)."""
    rpm_command, rot = work[WORK_RPM_COMMAND], work[WORK_ROT]
    for a in range(active.size):
        i = active[a]
        rotation(kin, i, rot)
        firmware_drone(i, kin, rot, command, pids, limits, mix, velocity_every, memory, phase, setpoint, rpm_command)
    _forces(kin, active, px, py, pz, work)
