"""The Crazyflie firmware's PID velocity tracker: what really follows ``send_velocity_world_setpoint``.

On hardware the host sends a world-frame velocity setpoint; the drone's own firmware (controller
"PID", ``position_controller_pid.c`` + ``attitude_pid_controller.c``, gains from
``platform_defaults_cf2.h``, Crazyflie 2.x) tracks it in three cascaded PID loops, each
``out = kp e + ki int(e) + kd de/dt`` with the integral clipped to ``+-integral_limit`` and the
output to ``+-output_limit`` (``pid.c``):

1. **velocity, 100 Hz.** The world velocity error is rotated into the yaw-aligned body frame
   ``(e_x', e_y')``. Pitch and roll setpoints in DEGREES: ``pitch = PID_x(e_x')``,
   ``roll = -PID_y(e_y')`` (kp 25 deg per m/s, ki 1), each clipped to +-20 deg on its own (a
   diagonal command tilts the drone by up to 28 deg in all, as on hardware); the thrust in 16-bit
   PWM units ``T = 1000 PID_z(e_z) + 36000`` (kp 25, ki 15), at least 20000, at most 65535. The
   thrust does not follow the tilt, so ``g tan(20 deg)`` bounds the horizontal acceleration only
   in level flight; climbing at full thrust it reaches twice that. The position part of the
   setpoint is ignored (the host sends velocity only).
2. **attitude, 500 Hz.** Euler-angle errors (deg) -> body-rate setpoints (deg/s): roll and pitch
   kp 6, ki 3 (integral limit 20); yaw kp 6, ki 1, kd 0.35, holding yaw 0.
3. **rate, 500 Hz.** Body-rate errors (deg/s) -> roll, pitch, yaw commands in PWM units: roll and
   pitch kp 250, ki 500, kd 2.5 (integral limit 33.3); yaw kp 120, ki 16.7; each saturated to
   the int16 range. The power distribution gives motor ``i`` the PWM
   ``T +- roll/2 +- pitch/2 +- yaw`` (signs: :func:`~marlander_lite.crazyflie.control.mixer_matrix`),
   clipped to [0, 65535] like the firmware's ``limitThrust``, and the motor map of
   :class:`~marlander_lite.crazyflie.params.CF2XParams` turns PWM into RPM.

Signs: the firmware writes pitch positive nose-up; here every angle is right-handed about the
body axes (x forward, y left, z up), so a positive pitch is nose DOWN, tilts the thrust towards
+x and accelerates the drone along +x: a +x velocity error asks for a positive pitch.

Rates in the simulator. The attitude and rate loops run at every PyBullet step (240 Hz by
default; the firmware runs them at 500 Hz) and the velocity loop every
``round(tick_hz / 100)`` steps (every 2nd step, 120 Hz, at 240 Hz; 96 Hz at 480 Hz physics).
At 240 Hz the loops are inside their discrete stability limit (:func:`rate_loop_spectral_radius`
0.83 for roll and pitch, 0.67 for yaw; 0.91 at 480 Hz), so we keep PyBullet's 240 Hz and half the cost.

Three modelling choices, all ours:

* **Rate-loop D filter on.** The firmware ships its 30 Hz low-pass filter on the rate loop's D
  term switched off (``ATTITUDE_RATE_LPF_ENABLE false``) and relies on the rotors' own lag of a few
  tens of milliseconds. Our rotors follow their command at once (``PhysicsConfig.motor_time_constant
  = 0`` by default), and then the discrete D term changes the body rate by ``-b kd = -1.41`` times
  its last change at every tick: the loop diverges at ANY tick rate (spectral radius 1.78 at 240 Hz,
  1.58 at 500 Hz). We switch the firmware's own filter on (``rate_d_cutoff_hz = 30``). With a motor
  lag (``motor_time_constant`` 5-20 ms) switch it off again, as the firmware has it: filter and lag
  together are near the limit (0.995 at 240 Hz and 5 ms), the lag alone is not (0.77).
* **Hover thrust.** The firmware's thrust base 36000 is the PWM a real CF2 hovers near; our motor
  model hovers at ``(hover_rpm - offset) / scale`` = 38,725 PWM. The z velocity integrator absorbs
  the difference, as on a real drone (its battery, its propellers): from 36000 it takes up 2,725
  PWM after the drone has sunk 2725 / (1000 ki) = 18 cm. An episode starts after take-off, when
  that integrator is already warm, so :meth:`FirmwareTracker.reset` starts it at the thrust that
  holds the SIMULATED drone (``warm_start_pwm``; the simulator passes the perturbed mass): a drone
  placed in the air hovers at once. Nothing else knows the true mass: the thrust base, the
  gains and the limits are the nominal firmware's. Set ``warm_start_pwm`` to 36000 to see a cold
  start (the drone sinks, then the integrator catches up).
* **Perfect state.** The firmware reads its state estimator and a 80 Hz-filtered gyro; we give it
  PyBullet's true attitude, velocity and body rates.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from marlander_lite.crazyflie.control import check_gains, mix_to_rpm, mixer_matrix
from marlander_lite.crazyflie.params import CF2XParams
from marlander_lite.rotations import RotationRows, euler_zyx, world_to_body

Triple = tuple[float, float, float]
INT16_MAX = 32767.0
"""Largest magnitude of a rate-loop command (the firmware stores it as int16)."""
DEG = 180.0 / math.pi


@dataclass(frozen=True)
class FirmwareGains:
    """Gains and limits of the firmware PID (``platform_defaults_cf2.h``, ``position_controller_pid.c``).

    Source: bitcraze/crazyflie-firmware, ``position_controller_pid.c``, ``attitude_pid_controller.c``
    and ``platform_defaults_cf2.h`` (docs/references.md).

    Triples are per axis (x, y, z) for the velocity loop and (roll, pitch, yaw) for the others.
    """

    velocity_p: Triple = (25.0, 25.0, 25.0)
    """kp of the velocity loop: degrees of tilt per m/s (x, y); thrust / ``thrust_scale`` per m/s (z)."""
    velocity_i: Triple = (1.0, 1.0, 15.0)
    """ki of the velocity loop, per (m/s) s."""
    velocity_integral_limit: float = 5000.0
    """Bound of the velocity integrators (m; the firmware's default, in effect none)."""
    velocity_hz: float = 100.0
    """Rate of the velocity loop (Hz, the firmware's ``POSITION_RATE``)."""
    tilt_limit_deg: float = 20.0
    """Roll and pitch setpoints are clipped to +- this (deg, ``rpLimit``)."""
    tilt_output_overhead: float = 1.1
    """The x and y velocity PIDs' own output limit is ``tilt_limit_deg`` times this (``rpLimitOverhead``)."""
    thrust_scale: float = 1000.0
    """PWM units per unit of z velocity-PID output."""
    thrust_base: float = 36000.0
    """Thrust feed-forward (PWM), the firmware's ``thrustBase``."""
    thrust_min: float = 20000.0
    """Smallest thrust command (PWM), ``thrustMin``."""
    attitude_p: Triple = (6.0, 6.0, 6.0)
    """kp of the attitude loop (deg/s per deg)."""
    attitude_i: Triple = (3.0, 3.0, 1.0)
    """ki of the attitude loop (deg/s per deg s)."""
    attitude_d: Triple = (0.0, 0.0, 0.35)
    """kd of the attitude loop (deg/s per deg/s)."""
    attitude_integral_limit: Triple = (20.0, 20.0, 360.0)
    """Bound of the attitude integrators (deg s)."""
    rate_p: Triple = (250.0, 250.0, 120.0)
    """kp of the rate loop (PWM per deg/s)."""
    rate_i: Triple = (500.0, 500.0, 16.7)
    """ki of the rate loop (PWM per deg)."""
    rate_d: Triple = (2.5, 2.5, 0.0)
    """kd of the rate loop (PWM per deg/s^2)."""
    rate_integral_limit: Triple = (33.3, 33.3, 166.7)
    """Bound of the rate integrators (deg)."""
    rate_d_cutoff_hz: float = 30.0
    """Cut-off of the 2nd-order low-pass filter on the rate loop's D term (Hz); 0 switches it off
    (the firmware's default). See the module docstring for why it is on here."""

    def __post_init__(self) -> None:
        check_gains(self)
        if self.velocity_hz <= 0 or self.tilt_limit_deg <= 0 or self.tilt_limit_deg >= 90:
            raise ValueError("velocity_hz must be > 0 and tilt_limit_deg in (0, 90).")


PID_CONSTANTS = ("kp", "ki", "kd", "dt", "integral_limit", "output_limit", "b0", "a1", "a2", "filtered")
"""What :func:`pid_constants` holds about one PID, in this order (``filtered`` is 1.0 with a D filter, else 0.0)."""
PID_MEMORY = ("integral", "prev_error", "d1", "d2")
"""What one PID remembers between updates, in this order: the integral, the last error, the D filter's two delays."""


def pid_constants(
    kp: float,
    ki: float,
    kd: float,
    dt: float,
    integral_limit: float = 0.0,
    output_limit: float = 0.0,
    d_cutoff_hz: float = 0.0,
) -> tuple[float, ...]:
    """The constants of one firmware PID (``pid.c``), as :data:`PID_CONSTANTS`.

    Args:
        kp, ki, kd: gains.
        dt: time between updates (s).
        integral_limit: bound of the integrated error; ``output_limit``: of the output (0: none).
        d_cutoff_hz: cut-off of the 2nd-order Butterworth filter on the derivative (0: none), the
            firmware's ``lpf2p`` with its sample rate ``1 / dt``.
    """
    b0 = a1 = a2 = 0.0
    filtered = d_cutoff_hz > 0 and kd > 0
    if filtered:
        # lpf2pSetCutoffFreq: a Butterworth biquad from the bilinear transform.
        ohm = math.tan(math.pi * d_cutoff_hz * dt)
        c = 1.0 + 2.0 * math.cos(math.pi / 4.0) * ohm + ohm * ohm
        b0 = ohm * ohm / c
        a1 = 2.0 * (ohm * ohm - 1.0) / c
        a2 = (1.0 - 2.0 * math.cos(math.pi / 4.0) * ohm + ohm * ohm) / c
    return (kp, ki, kd, dt, integral_limit, output_limit, b0, a1, a2, 1.0 if filtered else 0.0)


def pid_update(c: Sequence[float], memory: list[float], at: int, error: float) -> float:
    """One step of a firmware PID (``pidUpdate``) with the error ``desired - measured``; returns the output.

    ``c`` are its :func:`pid_constants`; its memory (:data:`PID_MEMORY`) is ``memory[at:at + 4]``, updated in place.
    """
    kp, ki, kd, dt, integral_limit, output_limit, b0, a1, a2, filtered = c
    deriv = (error - memory[at + 1]) / dt
    if filtered:  # lpf2pApply, Direct Form II
        d1, d2 = memory[at + 2], memory[at + 3]
        d0 = deriv - d1 * a1 - d2 * a2
        deriv = b0 * (d0 + 2.0 * d1 + d2)
        memory[at + 2], memory[at + 3] = d0, d1
    integral = memory[at] + error * dt
    if integral_limit > 0.0:
        integral = (
            integral_limit if integral > integral_limit else -integral_limit if integral < -integral_limit else integral
        )
    memory[at], memory[at + 1] = integral, error
    out = kp * error + kd * deriv + ki * integral
    if output_limit > 0.0:
        out = output_limit if out > output_limit else -output_limit if out < -output_limit else out
    return out


class PID:
    """One firmware PID on its own: :func:`pid_update` with its :func:`pid_constants` (same arguments) and memory."""

    __slots__ = ("constants", "memory")

    def __init__(self, *args: float, **kwargs: float) -> None:
        self.constants = pid_constants(*args, **kwargs)
        self.memory = [0.0] * 4
        """:data:`PID_MEMORY`."""

    def reset(self, integral: float = 0.0) -> None:
        """Clear the memory (``pidReset``), optionally starting the integral at ``integral``."""
        self.memory = [integral, 0.0, 0.0, 0.0]

    def update(self, error: float) -> float:
        """One step with the error ``desired - measured``; returns the output."""
        return pid_update(self.constants, self.memory, 0, error)


class FirmwareTracker:
    """The firmware's cascaded PID for ``num_drones`` drones, ticked every ``dt`` seconds.

    Same calling convention as :class:`~marlander_lite.crazyflie.control.CascadedPID`: :meth:`update`
    once per tick per drone returns the four rotor speeds (RPM); :meth:`reset` clears a drone's memory.

    Args:
        params: the drone the firmware believes it flies (nominal mass: sets the warm start).
        gains: the firmware gains.
        num_drones: N.
        dt: the tick (s), at which the attitude and rate loops run.
        gain_scale: factor on the velocity loop's kp and ki (``Perturbation.gain_scale``).
        warm_start_pwm: the thrust (PWM) the z integrator holds after :meth:`reset`: where a hover
            before the episode left it (default: the nominal drone's hover, :attr:`hover_pwm`).
    """

    def __init__(
        self,
        params: CF2XParams,
        gains: FirmwareGains,
        num_drones: int,
        dt: float,
        gain_scale: float = 1.0,
        warm_start_pwm: float | None = None,
    ) -> None:
        self.params, self.gains, self.dt, self.num_drones = params, gains, dt, num_drones
        self.velocity_every = max(1, round(1.0 / (dt * gains.velocity_hz)))
        """Ticks between two runs of the velocity loop (2 at 240 Hz)."""
        self.velocity_dt = self.velocity_every * dt
        """Time between two runs of the velocity loop (s)."""
        g = gains
        kp = [k * gain_scale for k in g.velocity_p]
        ki = [k * gain_scale for k in g.velocity_i]
        self.hover_pwm = (params.hover_rpm - params.pwm_to_rpm_offset) / params.pwm_to_rpm_scale
        """PWM at which the nominal drone hovers (about 38,725)."""
        tilt_out = g.tilt_limit_deg * g.tilt_output_overhead
        z_out = 65535.0 / 2.0 / g.thrust_scale
        self.warm_start_pwm = self.hover_pwm if warm_start_pwm is None else warm_start_pwm
        """Thrust (PWM) the z integrator gives right after :meth:`reset`."""
        self._ki_z = ki[2]
        vdt, lim = self.velocity_dt, g.velocity_integral_limit
        velocity = [pid_constants(kp[k], ki[k], 0.0, vdt, lim, tilt_out if k < 2 else z_out) for k in range(3)]
        attitude = [
            pid_constants(g.attitude_p[k], g.attitude_i[k], g.attitude_d[k], dt, g.attitude_integral_limit[k])
            for k in range(3)
        ]
        rate = [
            pid_constants(
                g.rate_p[k], g.rate_i[k], g.rate_d[k], dt, g.rate_integral_limit[k], INT16_MAX, g.rate_d_cutoff_hz
            )
            for k in range(3)
        ]
        self.pid_constants = np.array(velocity + attitude + rate)
        """The nine PIDs' :func:`pid_constants` ``(9, 10)``: velocity x, y, z; attitude and rate roll, pitch, yaw.
        The same for every drone."""
        self._pids = tuple(velocity + attitude + rate)
        self.pid_memory = np.zeros((num_drones, 9, 4))
        """Every drone's nine PIDs' :data:`PID_MEMORY` ``(N, 9, 4)``, PIDs in the order of :attr:`pid_constants`."""
        self._memory_rows = self.pid_memory.reshape(num_drones, 36)  # a view: one row per drone
        self._mix = [tuple(row) for row in mixer_matrix(params).tolist()]
        self._motor_map = (params.pwm_max, params.pwm_to_rpm_scale, params.pwm_to_rpm_offset)
        self.phase = np.zeros(num_drones, dtype=np.int64)
        """Per drone, ticks since its velocity loop last ran, modulo :attr:`velocity_every` (0: it runs now)."""
        self.setpoint = np.zeros((num_drones, 3))
        """Per drone ``(N, 3)``, the velocity loop's last output: :attr:`attitude_setpoint`, :attr:`thrust_command`."""
        self.attitude_setpoint = self.setpoint[:, 0:2]
        """Last (roll, pitch) setpoint per drone ``(N, 2)`` (deg, right-handed), a view of :attr:`setpoint`."""
        self.thrust_command = self.setpoint[:, 2]
        """Last collective thrust command per drone ``(N,)`` (PWM), a view of :attr:`setpoint`."""
        self.reset()

    def reset(self, drones: Sequence[int] | None = None) -> None:
        """Clear the memory of ``drones`` (all by default); the z velocity integrator starts at the
        value that gives :attr:`warm_start_pwm` (see the module docstring)."""
        g = self.gains
        warm = (self.warm_start_pwm - g.thrust_base) / (g.thrust_scale * self._ki_z) if self._ki_z > 0 else 0.0
        rows = slice(None) if drones is None else list(drones)
        self.pid_memory[rows] = 0.0
        self.pid_memory[rows, 2, 0] = warm
        self.phase[rows] = 0
        self.setpoint[rows] = (0.0, 0.0, self.hover_pwm)

    def update(
        self,
        i: int,
        pos: Sequence[float],
        rot: RotationRows,
        vel: Sequence[float],
        ang_vel: Sequence[float],
        target_pos: Sequence[float],
        target_vel: Sequence[float],
    ) -> tuple[float, float, float, float]:
        """One tick of drone ``i``: its four rotor speeds (RPM).

        ``pos`` and ``target_pos`` are ignored (the firmware tracks the velocity setpoint only);
        ``rot`` is the body-to-world rotation (:func:`~marlander_lite.rotations.quat_to_matrix_rows`),
        ``vel`` (m/s) and ``ang_vel`` (rad/s) are world frame, ``target_vel`` the setpoint (m/s).
        """
        g, (vx, vy, vz, att_r, att_p, att_y, rate_r, rate_p, rate_y) = self.gains, self._pids
        memory = self._memory_rows[i].tolist()  # the nine PIDs' memory as floats, PID k at 4 k (written back below)
        roll, pitch, yaw = euler_zyx(rot)  # rad
        phase = int(self.phase[i])
        if phase == 0:
            # 1. velocity loop: world error in the yaw-aligned body frame -> tilt setpoints (deg), thrust (PWM).
            c, s = math.cos(yaw), math.sin(yaw)
            ex, ey = target_vel[0] - vel[0], target_vel[1] - vel[1]
            limit = g.tilt_limit_deg
            pitch_sp = pid_update(vx, memory, 0, c * ex + s * ey)
            roll_sp = -pid_update(vy, memory, 4, c * ey - s * ex)
            pitch_sp = limit if pitch_sp > limit else -limit if pitch_sp < -limit else pitch_sp
            roll_sp = limit if roll_sp > limit else -limit if roll_sp < -limit else roll_sp
            thrust = g.thrust_scale * pid_update(vz, memory, 8, target_vel[2] - vel[2]) + g.thrust_base
            thrust = g.thrust_min if thrust < g.thrust_min else 65535.0 if thrust > 65535.0 else thrust
            self.setpoint[i] = (roll_sp, pitch_sp, thrust)
        else:
            roll_sp, pitch_sp, thrust = self.setpoint[i].tolist()
        self.phase[i] = (phase + 1) % self.velocity_every
        # 2. attitude loop: ZYX Euler angles (deg) -> body-rate setpoints (deg/s); yaw held at 0.
        roll_rate = pid_update(att_r, memory, 12, roll_sp - roll * DEG)
        pitch_rate = pid_update(att_p, memory, 16, pitch_sp - pitch * DEG)
        yaw_rate = pid_update(att_y, memory, 20, -yaw * DEG)  # the yaw error is already within [-180, 180]
        # 3. rate loop on the body rates (deg/s) -> roll, pitch, yaw commands (PWM units), then the mixer
        wx, wy, wz = world_to_body(rot, ang_vel)
        tx = pid_update(rate_r, memory, 24, roll_rate - wx * DEG)
        ty = pid_update(rate_p, memory, 28, pitch_rate - wy * DEG)
        tz = pid_update(rate_y, memory, 32, yaw_rate - wz * DEG)
        self._memory_rows[i] = memory
        hi, scale, offset = self._motor_map
        return mix_to_rpm(thrust, tx, ty, tz, self._mix, scale, offset, 0.0, hi)


def rate_loop_spectral_radius(
    params: CF2XParams, gains: FirmwareGains, tick_hz: float, motor_time_constant: float = 0.0
) -> np.ndarray:
    """Spectral radius of the linearised, discrete rate loop per axis (roll, pitch, yaw), ``(3,)``.

    Around hover each axis is a pure inertia ``I w' = b u``, ``u`` the rate-loop command (PWM units,
    held for one tick ``T = 1 / tick_hz``) and ``b`` (N m per PWM) from the mixer and the motor map.
    The loop state over one tick is the body rate, the torque (which lags its command with
    ``motor_time_constant``, exactly as the simulator's rotors do, linearised), the previous error
    and the D filter's two delays; the rate setpoint is 0 and the slow integral is left out. Stable
    when the result is below 1.
    """
    w = params.hover_rpm
    d_thrust = 2.0 * params.kf * w * params.pwm_to_rpm_scale  # N per PWM count, one rotor
    d_torque_z = 2.0 * params.km * w * params.pwm_to_rpm_scale
    mix, xy = mixer_matrix(params), np.asarray(params.rotor_xy)
    b = np.array(
        [
            (xy[:, 1] * mix[:, 0]).sum() * d_thrust,
            (-xy[:, 0] * mix[:, 1]).sum() * d_thrust,
            (np.asarray(params.yaw_signs) * mix[:, 2]).sum() * d_torque_z,
        ]
    )
    t = 1.0 / tick_hz
    decay = math.exp(-t / motor_time_constant) if motor_time_constant > 0 else 0.0
    mean = motor_time_constant / t * (1.0 - decay) if motor_time_constant > 0 else 1.0
    out = np.empty(3)
    for axis in range(3):
        gain = b[axis] / params.inertia[axis] * DEG  # deg/s^2 per PWM

        def tick(x: np.ndarray, axis: int = axis, gain: float = gain) -> np.ndarray:
            omega, acc, prev, d1, d2 = x
            pid = PID(gains.rate_p[axis], 0.0, gains.rate_d[axis], t, d_cutoff_hz=gains.rate_d_cutoff_hz)
            filtered = pid.constants[9] > 0.0  # without a D filter its delays are no state
            pid.memory = [0.0, prev, d1, d2] if filtered else [0.0, prev, 0.0, 0.0]
            command = gain * pid.update(-omega)
            mean_acc = command + (acc - command) * mean if motor_time_constant > 0 else command
            new_acc = command + (acc - command) * decay if motor_time_constant > 0 else 0.0
            f = pid.memory
            return np.array([omega + mean_acc * t, new_acc, -omega, f[2], f[3]])

        matrix = np.column_stack([tick(e) for e in np.eye(5)])
        out[axis] = np.abs(np.linalg.eigvals(matrix)).max()
    return out
