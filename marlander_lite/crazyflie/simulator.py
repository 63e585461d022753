"""``CrazyflieSwarm``: N Crazyflies in PyBullet behind the :class:`~marlander_lite.episodes.Simulator` protocol.

One env step (one policy period ``task.dt``, 1/24 s by default) runs as::

    target = p + u dt                        # eq. 3, task.next_target_position, once per action
    repeat control_hz / policy_hz times:     # PID ticks (2 by default)
        rpm    = CascadedPID(state, target, u)                   # control.py   } ticks.ControlTick,
        wrench = motors (+ ground effect) + drag + downwash      # physics.py   } body frame
        move a moving platform, and the drones latched to it, to where it is at the tick's end
        one applyExternalForce + one applyExternalTorque per flying drone
        stepSimulation: PyBullet runs physics_hz / control_hz steps (5 by default) itself
        one getContactPoints for the whole world; read the drones' state (2 calls per drone)

PyBullet keeps an external force for all the sub-steps of one ``stepSimulation`` call (set
with ``setPhysicsEngineParameter(fixedTimeStep=1 / control_hz, numSubSteps=...)``), so one
call per PID tick does the same physics as ``physics_hz / control_hz`` calls at ``1 /
physics_hz``, with 5 times fewer round trips from Python. Two consequences, both small at
48 Hz: a force given in the body frame is turned into the world frame once per tick (the drone
turns by at most a few degrees in 1/48 s), and contacts are read once per tick.

Landing: contact points name the body and link a drone touches, which gives the contact code
of :mod:`marlander_lite.task` (own pad, anything else); :class:`~marlander_lite.episodes.LandingEpisodes`
then applies :func:`task.touchdown_outcome`, the same test as for the point-mass simulator.
PyBullet's solver stops a drone at the contact within the same physics step, so at the end of
the env step a drone that hit its pad at 3 m/s sits still on it. So that the landing test sees
the *impact*, the velocity reported for a drone whose contact began during the step is its
velocity at the control tick before the touch (at most ``1 / control_hz`` earlier).
A landed drone is latched to its pad: it loses its mass (PyBullet then never moves it), its
motors stop, and it rides with the pad.

Tracking offset: both PID ticks of an action aim at the same target ``p + u dt``, which stays
about ``u dt`` ahead of a drone that flies at ``u``; the position term then adds to the velocity
term, and a constant command settles 6 to 8 % above ``u`` (``K_p / K_d * 0.75 dt``). This is the
paper's action semantics; a policy trained in closed loop absorbs it.

``controller="firmware"`` swaps the PID for the Crazyflie firmware's own velocity tracker
(:mod:`marlander_lite.crazyflie.firmware`), which needs its attitude and rate loops at the fast
rate: the control tick is then one physics step (``physics.control_hz`` is set to ``physics_hz``,
10 ticks per action at 240 / 24 Hz) and it tracks ``u`` alone. A
:class:`~marlander_lite.crazyflie.perturb.Perturbation` makes the drone heavier than its tracker
believes, delays the commands, or scales the tracker's outer gains.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pybullet as p

from marlander_lite import task
from marlander_lite.crazyflie.control import CascadedPID, PIDGains
from marlander_lite.crazyflie.firmware import FirmwareGains, FirmwareTracker
from marlander_lite.crazyflie.params import CF2XParams, PhysicsConfig, build_physics, ratio_to_count
from marlander_lite.crazyflie.perturb import (
    Controller,
    Perturbation,
    build_perturbation,
    build_tracker,
    check_controller,
)
from marlander_lite.crazyflie.physics import MotorLag
from marlander_lite.crazyflie.ticks import make_control_tick
from marlander_lite.crazyflie.world import World, connect
from marlander_lite.episodes import SwarmState
from marlander_lite.platforms import PlatformConfig, PlatformMotion
from marlander_lite.pointmass.kernels import Engine, resolve_engine
from marlander_lite.task import TaskConfig

CONTACT_TOLERANCE = 1e-3
"""Contact points closer than this (m) count as touching; PyBullet also reports points up to its
collision margin apart."""
_ORIGIN = (0.0, 0.0, 0.0)
_ZERO = (0.0, 0.0, 0.0)


class CrazyflieSwarm:
    """One swarm of ``N`` Crazyflies over a platform, in its own PyBullet client.

    Implements :class:`marlander_lite.episodes.Simulator` with ``num_envs = 1`` (batch it with
    subprocesses, see :func:`marlander_lite.crazyflie.envs.make_crazyflie_vec_env`). Arrays of
    :meth:`state` are ``(1, N, ...)``, world frame, SI units.

    Args:
        task_config: the MDP constants (N, policy rate, arena).
        platform: plate motion.
        num_envs: must be 1.
        physics: rates and aerodynamic effects: a :class:`PhysicsConfig`, a preset name (``"aero"``, the default, or
            ``"bare"``) or a mapping of its fields (:func:`~marlander_lite.crazyflie.params.build_physics`).
        drone: the quadrotor's constants.
        gains: the cascaded PID's gains (``controller="pid"``).
        gui: open a PyBullet window instead of running headless.
        controller: the velocity tracker, ``"pid"`` (:class:`CascadedPID`, ``physics.control_hz``) or
            ``"firmware"`` (:class:`~marlander_lite.crazyflie.firmware.FirmwareTracker`, every physics step).
        perturbation: a :class:`~marlander_lite.crazyflie.perturb.Perturbation` or a mapping of its
            fields (``{"mass_scale": 1.15}``); ``None`` for none.
        firmware_gains: the firmware tracker's gains (default: the CF2 firmware's).
        engine: who runs the control ticks: ``"numpy"``, the reference (Python floats, drone by drone,
            :class:`~marlander_lite.crazyflie.ticks.ControlTick`), ``"numba"``, compiled kernels with the same
            results bit for bit (:mod:`~marlander_lite.crazyflie.tick_kernels`), or ``"auto"`` (numba when
            installed, unless ``MARLANDER_LITE_ENGINE=numpy``). The engine that runs is :attr:`engine`.
    """

    def __init__(
        self,
        task_config: TaskConfig,
        platform: PlatformConfig,
        num_envs: int = 1,
        physics: PhysicsConfig | Mapping[str, Any] | str | None = None,
        drone: CF2XParams | None = None,
        gains: PIDGains | None = None,
        gui: bool = False,
        controller: Controller = "pid",
        perturbation: Perturbation | Mapping[str, Any] | None = None,
        firmware_gains: FirmwareGains | None = None,
        engine: Engine = "auto",
    ) -> None:
        self.controller_kind: Controller = check_controller(controller)
        self.engine = resolve_engine(engine)
        """The engine of the control ticks: ``"numpy"`` (the reference) or ``"numba"``."""
        self.perturbation = build_perturbation(perturbation)
        if num_envs != 1:
            raise ValueError(
                f"CrazyflieSwarm simulates one swarm (num_envs=1), got num_envs={num_envs}; "
                "use make_vec_env('crazyflie', num_envs=...) for several, one per subprocess."
            )
        self.task, self.platform, self.num_envs = task_config, platform, 1
        self.physics = build_physics(physics)  # a PhysicsConfig, a preset name or a mapping of changes; None: "aero"
        self.params = drone or CF2XParams()
        self.gains = gains or PIDGains()
        n = self.num_drones = task_config.num_drones
        tracker = build_tracker(controller, self.perturbation, self.params, self.gains, self.physics, n, firmware_gains)
        self.physics, self.body_params, self._delay = tracker.physics, tracker.body, tracker.delay
        self._ticks_per_action = ratio_to_count(
            self.physics.control_hz, task_config.policy_hz, "control_hz", "policy_hz"
        )
        self.control_dt = 1.0 / self.physics.control_hz
        """One PID tick (s); PyBullet runs ``physics.steps_per_tick`` physics steps in it."""
        self.client = connect(gui)
        self._closed = False
        self.world = World(self.client, n, platform, self.body_params, self.physics, task_config.arena_half_width)
        self.motion = PlatformMotion(platform, 1, n, task_config.arena_half_width)
        self._motor_lag = MotorLag(self.physics.motor_time_constant, self.control_dt)
        self.controller: CascadedPID | FirmwareTracker = tracker.controller
        """The tracker (``controller_kind`` names it); it believes in ``params``, PyBullet flies ``body_params``."""
        half = platform.geometry.half_extents(n)
        self._tick = make_control_tick(self.engine, self.physics, self.params, self.controller, self._motor_lag, half)
        self.time = 0.0
        # Published state, (1, N, ...) as the Simulator protocol wants; views of one buffer that
        # is filled with one assignment per env step.
        self._kinematics = np.zeros((1, n, 13))
        self.pos, self.quat = self._kinematics[..., 0:3], self._kinematics[..., 3:7]
        self.vel, self.ang_vel = self._kinematics[..., 7:10], self._kinematics[..., 10:13]
        self.pad_pos, self.pad_vel = np.zeros((1, n, 3)), np.zeros((1, n, 3))
        self._pad_radius_sq = self.platform.geometry.pad_radius**2
        inclined = self.platform.geometry.inclination_deg != 0
        self._pad_normal = tuple(self.platform.geometry.normal().tolist()) if inclined else None
        self.contact = np.zeros((1, n), dtype=np.int8)
        self.landed = np.zeros((1, n), dtype=bool)
        self.motors_stopped = np.zeros((1, n), dtype=bool)
        self._reported_vel = np.zeros((1, n, 3))
        # Working state: PyBullet's tuples, read at every control tick.
        self._poses: list = []
        self._vels: list = []
        self.rpm = self._tick.rotor_speeds(0.0)
        """Rotor speeds per drone at the last tick (RPM); they lag the command when ``motor_time_constant > 0``.
        ``rpm[i]`` holds drone ``i``'s four (a list with the ``"numpy"`` engine, an ``(N, 4)`` array with numba)."""
        self.rpm_command = self._tick.rotor_speeds(0.0)
        """Rotor speeds the PID asked for at its last tick, per drone (RPM), in the form of :attr:`rpm`."""
        self._forces: list = [_ZERO] * n
        self._torques: list = [_ZERO] * n
        self._active: list[int] = []
        self._touching = [False] * n
        self._touched_now = [False] * n
        self._touch_vel: list = [_ZERO] * n
        self._latched_offset = np.zeros((n, 3))
        self._plate_pos = [0.0, 0.0, 0.0]
        self._state = SwarmState(
            pos=self.pos,
            quat=self.quat,
            vel=self._reported_vel,
            ang_vel=self.ang_vel,
            pad_pos=self.pad_pos,
            pad_vel=self.pad_vel,
            contact=self.contact,
        )
        self._set_platform_time(0.0)
        self._place_all(self.pad_pos[0] + np.array([0.0, 0.0, 1.0]))

    # ------------------------------------------------------------------ Simulator API
    def reset(self, env_ids: np.ndarray, rng: np.random.Generator) -> None:
        ids = self._check_env_ids(env_ids)
        if len(ids) == 0:
            return
        self.motion.sample(rng, ids)
        self.time = 0.0
        self._set_platform_time(0.0)
        spawn = task.sample_spawn_positions(rng, np.array([self._plate_pos[2]]), self.task, self.pad_pos)[0]
        self._place_all(spawn)

    def step(self, velocity: np.ndarray) -> None:
        u = np.asarray(velocity, dtype=float)
        if u.shape != (1, self.num_drones, 3):
            raise ValueError(f"velocity must have shape (1, {self.num_drones}, 3) m/s, got {u.shape}.")
        targets, commands = task.next_target_position(self.pos[0], u[0], self.task.dt), u[0].copy()
        if not self._tick.takes_arrays:  # the reference tick works on Python floats
            targets, commands = targets.tolist(), commands.tolist()
        self.contact[:] = task.CONTACT_NONE
        self._touched_now = [False] * self.num_drones
        sent, delay, run = (targets, commands), self._delay, self._tick.run
        for _ in range(self._ticks_per_action):
            if delay is not None:  # what reaches the tracker now was sent latency_s ago
                targets, commands = delay.push(sent)
            state = self._poses, self._vels, self._active, targets, commands, self._plate_pos
            run(*state, self.rpm, self.rpm_command, self._forces, self._torques)
            self._advance_tick()
            self._read_state()
        self._publish()

    def state(self) -> SwarmState:
        """The current state; its arrays are updated in place by later calls (copy to keep them)."""
        return self._state

    def land(self, landed: np.ndarray) -> None:
        new = np.asarray(landed, dtype=bool).reshape(self.num_drones) & ~self.landed[0]
        for i in np.flatnonzero(new).tolist():
            dx, dy = (self.pos[0, i, :2] - self.pad_pos[0, i, :2]).tolist()
            self._latched_offset[i] = (dx, dy, self.task.landed_height)
            self.world.set_drone_mass(i, latched=True)
            self.world.place_drone(i, self.pad_pos[0, i] + self._latched_offset[i])
            self.landed[0, i] = True
        if new.any():
            self.controller.reset(np.flatnonzero(new).tolist())
            self._refresh_active()
            self._read_state()
            self._publish()

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            p.disconnect(physicsClientId=self.client)

    # ------------------------------------------------------------------ rehearsal extras
    def place(self, env_id: int, drone_pos: np.ndarray) -> None:
        """Put the drones at ``drone_pos`` ``(N, 3)`` m, at rest and level (z = ``landed_height`` sits on the floor).

        Clears landings and stopped motors; the PID starts afresh.
        """
        self._check_env_ids(np.array([env_id]))
        pos = np.asarray(drone_pos, dtype=float)
        if pos.shape != (self.num_drones, 3) or not np.isfinite(pos).all():
            raise ValueError(f"drone_pos must be a finite ({self.num_drones}, 3) array, got shape {pos.shape}.")
        self._place_all(pos)

    def stop_motors(self, stopped: np.ndarray) -> None:
        """Set the rotor speed of drones where ``stopped`` ``(1, N)`` is True to zero: they fall until they
        touch something, and ignore velocity commands until :meth:`place` or :meth:`reset`."""
        mask = np.asarray(stopped, dtype=bool).reshape(self.num_drones)
        self.motors_stopped[0] |= mask
        self.controller.reset(np.flatnonzero(mask).tolist())
        self._refresh_active()

    # ------------------------------------------------------------------ internals
    def _check_env_ids(self, env_ids: np.ndarray) -> np.ndarray:
        ids = np.atleast_1d(np.asarray(env_ids)).astype(int)
        if np.any(ids != 0):
            raise ValueError(f"CrazyflieSwarm holds one environment (id 0); got env ids {ids.tolist()}.")
        return ids

    def _set_platform_time(self, t: float, move_latched: bool = False) -> None:
        """Put the plate where it is at time ``t`` (s), and the drones latched to it with it."""
        plate, vel = self.motion.state(np.array([t]))
        self._plate_pos = plate[0].tolist()
        self.pad_pos[0] = plate[0] + self.motion.pad_offsets
        self.pad_vel[0] = vel[0]
        self.world.move_platform(self._plate_pos)
        if move_latched:
            for i in np.flatnonzero(self.landed[0]).tolist():
                self.world.place_drone(i, self.pad_pos[0, i] + self._latched_offset[i], keep_velocity=True)

    def _place_all(self, pos: np.ndarray) -> None:
        for i in range(self.num_drones):
            if self.landed[0, i]:
                self.world.set_drone_mass(i, latched=False)
            self.world.place_drone(i, pos[i])
        self.landed[:] = False
        self.motors_stopped[:] = False
        self.contact[:] = task.CONTACT_NONE
        self._touching = [False] * self.num_drones
        self._touched_now = [False] * self.num_drones
        self.controller.reset()
        if self._delay is not None:  # nothing in flight: "hold still here" is what arrives first
            self._delay.fill((pos.tolist(), [[0.0, 0.0, 0.0]] * self.num_drones))
        hover = self.params.hover_rpm
        self.rpm = self._tick.rotor_speeds(hover)
        self.rpm_command = self._tick.rotor_speeds(hover)
        self._refresh_active()
        self._read_state()
        self._publish()

    def _refresh_active(self) -> None:
        """Drones whose motors push: neither landed nor stopped. The others get no force at all."""
        idle = self.landed[0] | self.motors_stopped[0]
        self._active = np.flatnonzero(~idle).tolist()
        for i in np.flatnonzero(idle).tolist():
            self.rpm[i] = [0.0] * 4
            self.rpm_command[i] = [0.0] * 4

    def _advance_tick(self) -> None:
        """Apply the held forces and let PyBullet run one control period (``steps_per_tick`` physics steps)."""
        cid, bodies = self.client, self.world.drones
        if self.platform.is_moving:
            self._set_platform_time(self.time + self.control_dt, move_latched=True)
        apply_force, apply_torque, link_frame = p.applyExternalForce, p.applyExternalTorque, p.LINK_FRAME
        forces, torques = self._forces, self._torques
        # physicsClientId by position: PyBullet parses keywords more slowly, and these run per drone and tick.
        for i in self._active:
            body = bodies[i]
            apply_force(body, -1, forces[i], _ORIGIN, link_frame, cid)
            apply_torque(body, -1, torques[i], link_frame, cid)
        p.stepSimulation(cid)
        self.time += self.control_dt
        points = p.getContactPoints(physicsClientId=cid)
        if points:
            self._register_contacts(points)
        elif True in self._touching:
            self._touching = [False] * self.num_drones

    def _register_contacts(self, points: tuple) -> None:
        """Turn PyBullet contact points into contact codes and touchdown velocities.

        A drone touches its own pad when the contact is with its pad's link, or with the plate *under* its
        pad (within the pad radius of the pad centre): the pad is only 2.5 mm proud of the plate, and a drone
        that settles a few millimetres into the soft contact at touchdown meets the plate's collision box
        there too. That is still a touchdown on the pad, not on the plate beside it.
        """
        index, platform, pads = self.world.drone_index, self.world.platform, self.world.pad_links
        contact = self.contact[0]
        touching = [False] * self.num_drones
        for point in points:
            if point[8] > CONTACT_TOLERANCE:
                continue
            # (drone body, other body, other link, contact point on the other body)
            for me, other, other_link, at in (
                (point[1], point[2], point[4], point[6]),
                (point[2], point[1], point[3], point[5]),
            ):
                i = index.get(me)
                if i is None:
                    continue
                own = other == platform and (other_link == pads[i] or (other_link == -1 and self._under_own_pad(i, at)))
                code = task.CONTACT_OWN_PAD if own else task.CONTACT_OTHER
                if code > contact[i]:
                    contact[i] = code
                touching[i] = True
        for i, now in enumerate(touching):
            if now and not self._touching[i] and not self._touched_now[i]:
                self._touch_vel[i] = self._vels[i][0]  # velocity at the last control tick before the touch
                self._touched_now[i] = True
        self._touching = touching

    def _under_own_pad(self, drone: int, point: tuple[float, float, float]) -> bool:
        """Whether a contact point on the plate lies within the pad radius of drone ``drone``'s pad centre,
        measured within the pad plane (horizontally on a level plate)."""
        dx, dy = point[0] - self.pad_pos[0, drone, 0], point[1] - self.pad_pos[0, drone, 1]
        if self._pad_normal is None:
            return dx * dx + dy * dy <= self._pad_radius_sq
        dz = point[2] - self.pad_pos[0, drone, 2]
        nx, ny, nz = self._pad_normal
        along = dx * nx + dy * ny + dz * nz
        return dx * dx + dy * dy + dz * dz - along * along <= self._pad_radius_sq

    def _read_state(self) -> None:
        """Read every drone's pose and velocity from PyBullet (two calls per drone), as tuples."""
        cid, bodies = self.client, self.world.drones
        get_pose, get_vel = p.getBasePositionAndOrientation, p.getBaseVelocity
        self._poses = [get_pose(body, cid) for body in bodies]
        self._vels = [get_vel(body, cid) for body in bodies]

    def _publish(self) -> None:
        """Copy the working state into the arrays of :meth:`state` (one sign per attitude: w >= 0)."""
        kinematics = self._kinematics[0]
        kinematics[:] = self._tick.kinematics(self._poses, self._vels)
        flipped = kinematics[:, 6] < 0.0
        if flipped.any():
            kinematics[flipped, 3:7] = -kinematics[flipped, 3:7]
        if self.landed.any():
            mask = self.landed[0]
            self.vel[0, mask] = self.pad_vel[0, mask]
            self.ang_vel[0, mask] = 0.0
        self._reported_vel[:] = self.vel
        if True in self._touched_now:
            for i, touched in enumerate(self._touched_now):
                if touched:
                    self._reported_vel[0, i] = self._touch_vel[i]
