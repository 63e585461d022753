"""One control tick of a PyBullet swarm: tracker -> rotor speeds -> one force and one torque per flying drone.

:class:`~marlander_lite.crazyflie.simulator.CrazyflieSwarm` calls :meth:`ControlTick.run` at every control
tick (48 Hz with the PID, 240 Hz with the firmware tracker) with the drones' PyBullet state::

    rpm    = tracker(state, target, u)                        # control.py or firmware.py, per drone
    rpm    = MotorLag(rpm)                                    # physics.py, when motor_time_constant > 0
    wrench = motors (+ ground effect) + drag + downwash       # physics.py, body frame

drone by drone on Python floats (see :mod:`~marlander_lite.crazyflie.physics` for why not numpy arrays). That is
the reference. :class:`CompiledTick` runs the same tick for all drones in one call of a compiled kernel
(:mod:`~marlander_lite.crazyflie.tick_kernels`, numba), with the same results bit for bit; :func:`make_control_tick`
picks one of the two by engine (``"numpy"``: the reference, ``"numba"``, ``"auto"``).
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import chain

import numpy as np

from marlander_lite.crazyflie import tick_kernels as kernels
from marlander_lite.crazyflie.control import CascadedPID
from marlander_lite.crazyflie.firmware import FirmwareTracker
from marlander_lite.crazyflie.params import CF2XParams, PhysicsConfig
from marlander_lite.crazyflie.physics import (
    MotorLag,
    downwash_push,
    drag_force,
    ground_effect_gains,
    motor_wrench,
)
from marlander_lite.crazyflie.tracker_kernels import firmware_constants, pid_constants
from marlander_lite.pointmass.kernels import Engine, resolve_engine
from marlander_lite.rotations import quat_to_matrix_rows, world_to_body

_NO_GAIN = (1.0, 1.0, 1.0, 1.0)


class ControlTick:
    """The tracker and the forces of one control tick, for every flying drone.

    Args:
        physics: which aerodynamic effects act.
        params: the drone the forces are computed for.
        controller: the tracker; its ``update(i, ...)`` runs once per flying drone and tick.
        motor_lag: the rotors' lag over one tick.
        plate_half: the plate's half extents ``(x, y)`` (m), for the ground effect over the plate.
    """

    def __init__(
        self,
        physics: PhysicsConfig,
        params: CF2XParams,
        controller: CascadedPID | FirmwareTracker,
        motor_lag: MotorLag,
        plate_half: tuple[float, float],
    ) -> None:
        self.physics, self.params, self.controller, self.motor_lag = physics, params, controller, motor_lag
        self._half_x, self._half_y = plate_half
        self._rotors = tuple(tuple(rotor) for rotor in params.rotor_positions.tolist())
        self._kinematics_of: tuple[list, list, np.ndarray] | None = None

    takes_arrays = False
    """Whether :meth:`run` also takes ``targets`` and ``commands`` as ``(N, 3)`` arrays (lists of 3 floats always)."""

    def kinematics(self, poses: list, vels: list) -> np.ndarray:
        """Every drone's ``(pos, quat, vel, ang_vel)`` from PyBullet's tuples as one ``(N, 13)`` array (m, x y z w,
        m/s, rad/s), world frame.

        The simulator reads new lists at every tick and never changes one it has read, so the last pair's array is
        kept and handed out again when the same pair comes back (the compiled tick and the published state share
        one conversion). Do not write into it.
        """
        held = self._kinematics_of
        if held is None or held[0] is not poses or held[1] is not vels:
            n = len(poses)
            rows = (a + b + c + d for (a, b), (c, d) in zip(poses, vels, strict=True))
            kin = np.fromiter(chain.from_iterable(rows), float, 13 * n).reshape(n, 13)
            held = self._kinematics_of = (poses, vels, kin)
        return held[2]

    def rotor_speeds(self, value: float) -> list[list[float]]:
        """Rotor speeds of every drone, all ``value`` (RPM), in the form :meth:`run` takes: a list of lists."""
        return [[value] * 4 for _ in range(self.controller.num_drones)]

    def run(
        self,
        poses: list,
        vels: list,
        active: list[int],
        targets: list,
        commands: list,
        plate_pos: Sequence[float],
        rpm: list,
        rpm_command: list,
        forces: list,
        torques: list,
    ) -> None:
        """Run the tracker and evaluate the forces that act during the next tick.

        Args:
            poses, vels: PyBullet's ``(pos, quat)`` and ``(vel, ang_vel)`` of every drone.
            active: the drones whose motors push.
            targets, commands: target position (m) and velocity (m/s) of every drone, lists of 3 floats.
            plate_pos: the plate's top-face centre (m).
            rpm, rpm_command, forces, torques: per-drone lists, set at the indices of ``active``: rotor speeds
                now and as commanded (RPM), force and torque for PyBullet (body frame, N and N m).
        """
        cfg, params, update, lag = self.physics, self.params, self.controller.update, self.motor_lag
        rots = {}
        effective = rpm
        if lag.active:
            effective = [list(w) for w in rpm]
        for i in active:
            (pos, quat), (vel, ang_vel) = poses[i], vels[i]
            rots[i] = rot = quat_to_matrix_rows(quat)
            rpm_command[i] = command = list(update(i, pos, rot, vel, ang_vel, targets[i], commands[i]))
            if lag.active:  # first-order rotor lag, see MotorLag
                effective[i], rpm[i] = lag.step(command, rpm[i])
            else:
                rpm[i] = command
        if cfg.downwash:
            # k_f sum_i w_i^2, summed left to right (Python 3.12's sum() of floats compensates rounding).
            kf = params.kf
            thrusts = [kf * ((((0.0 + a * a) + b * b) + c * c) + d * d) for a, b, c, d in effective]
        for i in active:
            rot, pos = rots[i], poses[i][0]
            fx = fy = fz = 0.0
            if cfg.drag:
                a, b, c, d = effective[i]
                fx, fy, fz = drag_force((((0.0 + a) + b) + c) + d, world_to_body(rot, vels[i][0]), params)
            if cfg.downwash:
                push = self._downwash(pos, poses, thrusts)
                # World (0, 0, push) in body axes is push times the third row of R.
                fx, fy, fz = fx + rot[6] * push, fy + rot[7] * push, fz + rot[8] * push
            gain = self._ground_effect(pos, rot, plate_pos) if cfg.ground_effect else _NO_GAIN
            fz_motor, tx, ty, tz = motor_wrench(effective[i], params, gain)
            forces[i] = (fx, fy, fz + fz_motor)
            torques[i] = (tx, ty, tz)

    def _downwash(self, pos: Sequence[float], poses: list, thrusts: list[float]) -> float:
        """The summed :func:`~marlander_lite.crazyflie.physics.downwash_push` on the drone at ``pos`` (N)."""
        params, (x, y, z) = self.params, pos
        push = 0.0
        for j, other in enumerate(poses):
            q = other[0]
            dz = q[2] - z
            if dz <= 0.0:  # not above (or the drone itself): downwash_push is 0.0, which leaves the sum as it is
                continue
            push += downwash_push(dz, (q[0] - x) ** 2 + (q[1] - y) ** 2, thrusts[j], params)
        return push

    def _ground_effect(self, pos: Sequence[float], rot: tuple, plate_pos: Sequence[float]) -> tuple[float, ...]:
        """Each rotor's thrust gain from its height above the floor, or above the plate when the drone is over it."""
        px, py, pz = plate_pos
        over_plate = abs(pos[0] - px) <= self._half_x and abs(pos[1] - py) <= self._half_y and pos[2] >= pz
        base = pos[2] - (pz if over_plate else 0.0)
        r20, r21, r22 = rot[6], rot[7], rot[8]
        (x0, y0, z0), (x1, y1, z1), (x2, y2, z2), (x3, y3, z3) = self._rotors
        heights = (
            base + r20 * x0 + r21 * y0 + r22 * z0,
            base + r20 * x1 + r21 * y1 + r22 * z1,
            base + r20 * x2 + r21 * y2 + r22 * z2,
            base + r20 * x3 + r21 * y3 + r22 * z3,
        )
        return ground_effect_gains(heights, self.params)


class CompiledTick(ControlTick):
    """:class:`ControlTick` for all drones of the swarm in one call of a compiled kernel: the same arguments,
    results and tracker state, bit for bit (:mod:`~marlander_lite.crazyflie.tick_kernels`).

    The tracker's memory stays in its own arrays, which the kernel updates in place, so its ``reset`` and
    attributes work as with the reference. Differences in form only: :meth:`rotor_speeds` are ``(N, 4)`` arrays,
    and :meth:`run` writes lists into ``forces`` and ``torques``.
    """

    def __init__(
        self,
        physics: PhysicsConfig,
        params: CF2XParams,
        controller: CascadedPID | FirmwareTracker,
        motor_lag: MotorLag,
        plate_half: tuple[float, float],
    ) -> None:
        super().__init__(physics, params, controller, motor_lag, plate_half)
        n = self._num_drones = controller.num_drones
        self._firmware = isinstance(controller, FirmwareTracker)
        if self._firmware:
            limits, mix = firmware_constants(controller)
            memory = (controller.pid_memory, controller.phase, controller.setpoint)
            self._tracker = (controller.pid_constants, limits, mix, controller.velocity_every, *memory)
        else:
            self._tracker = (*pid_constants(controller), controller.state)
        self._aero = kernels.aero_constants(params, physics, motor_lag, plate_half)
        self._effective, self._thrusts, self._rot = np.zeros((n, 4)), np.zeros(n), np.zeros((n, 9))
        self._forces, self._torques = np.zeros((n, 3)), np.zeros((n, 3))
        # Each input list as an array, converted once per list object: the simulator hands the same lists to
        # every tick of an action (and through its command delay), and never changes one it has handed over.
        self._inputs: dict[str, tuple[object, np.ndarray]] = {}

    def rotor_speeds(self, value: float) -> np.ndarray:
        """Rotor speeds of every drone, all ``value`` (RPM), in the form :meth:`run` takes: ``(N, 4)``."""
        return np.full((self._num_drones, 4), float(value))

    takes_arrays = True

    def _array(self, role: str, values: list | np.ndarray, dtype: type) -> np.ndarray:
        if isinstance(values, np.ndarray):
            return values
        held = self._inputs.get(role)
        if held is None or held[0] is not values:
            held = self._inputs[role] = (values, np.array(values, dtype=dtype))
        return held[1]

    def run(
        self,
        poses: list,
        vels: list,
        active: list[int],
        targets: list,
        commands: list,
        plate_pos: Sequence[float],
        rpm: np.ndarray,
        rpm_command: np.ndarray,
        forces: list,
        torques: list,
    ) -> None:
        """:meth:`ControlTick.run`, with ``rpm`` and ``rpm_command`` the ``(N, 4)`` arrays of :meth:`rotor_speeds`;
        ``targets`` and ``commands`` may also be ``(N, 3)`` float arrays, which are read as they are (not copied)."""
        kin = self.kinematics(poses, vels)
        ids = self._array("active", active, np.int64)
        px, py, pz = plate_pos
        work = (*self._aero, rpm, rpm_command, self._effective, self._thrusts, self._rot, self._forces, self._torques)
        command = self._array("commands", commands, float)
        if self._firmware:
            kernels.firmware_tick(kin, ids, command, px, py, pz, *self._tracker, work)
        else:
            kernels.pid_tick(
                kin, ids, self._array("targets", targets, float), command, px, py, pz, *self._tracker, work
            )
        forces[:] = self._forces.tolist()
        torques[:] = self._torques.tolist()


def make_control_tick(
    engine: Engine,
    physics: PhysicsConfig,
    params: CF2XParams,
    controller: CascadedPID | FirmwareTracker,
    motor_lag: MotorLag,
    plate_half: tuple[float, float],
) -> ControlTick | CompiledTick:
    """The control tick of ``engine`` (``"auto"``, ``"numpy"`` or ``"numba"``, see
    :func:`~marlander_lite.pointmass.kernels.resolve_engine`): the reference :class:`ControlTick` or
    :class:`CompiledTick`."""
    if resolve_engine(engine) == "numba":
        return CompiledTick(physics, params, controller, motor_lag, plate_half)
    return ControlTick(physics, params, controller, motor_lag, plate_half)
