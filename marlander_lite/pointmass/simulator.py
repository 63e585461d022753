"""The lightweight simulator: each drone is a point mass that tracks its velocity command.

A Crazyflie under a cascaded velocity PID follows a velocity step roughly like a first-order
lag whose acceleration saturates when the attitude limit is reached. This module integrates
exactly that, for every drone of every environment at once, with no Python loop over
environments. Attitude and angular velocity are derived from the acceleration (a multirotor
tilts its thrust along ``a + g e_z``), so eq. 2's ``q`` and ``omega`` carry real information.

Speed note: every batched array is Fortran-ordered, so ``pos[..., 0]`` is one contiguous
plane and per-environment values broadcast over drones without short inner loops. Numpy keeps
that layout through arithmetic; see ``benchmarks/bench_pointmass.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from marlander_lite import task
from marlander_lite.episodes import SwarmState
from marlander_lite.platforms import PlatformConfig, PlatformMotion
from marlander_lite.rotations import IDENTITY_QUAT, vector_norm
from marlander_lite.task import TaskConfig

GRAVITY = 9.81


@dataclass(frozen=True)
class PointMassParams:
    """How a point-mass drone answers a velocity command."""

    velocity_time_constant: float = 0.051
    """Time constant tau of the first-order velocity lag (s): least-squares fit to the PyBullet Crazyflie's
    velocity step responses (``marlander_lite.crazyflie.fit``, notebook 02)."""
    max_acceleration: float = 4.07
    """Largest acceleration magnitude (m/s^2): fitted like ``velocity_time_constant`` (the PID's 30 deg tilt
    limit allows 5.7; the time the drone takes to tilt lowers the effective value)."""
    randomization: float = 0.0
    """Domain randomisation: each episode scales tau and a_max by independent factors drawn log-uniformly
    from [1/(1+r), 1+r]; 0 keeps them fixed. Policies trained with r > 0 cope with other dynamics (PyBullet)."""

    def __post_init__(self) -> None:
        if not (np.isfinite(self.velocity_time_constant) and self.velocity_time_constant > 0):
            raise ValueError(f"velocity_time_constant must be > 0 s, got {self.velocity_time_constant!r}.")
        if not (np.isfinite(self.max_acceleration) and 0 < self.max_acceleration < GRAVITY):
            raise ValueError(f"max_acceleration must be in (0, {GRAVITY}) m/s^2, got {self.max_acceleration!r}.")
        if not (np.isfinite(self.randomization) and 0 <= self.randomization <= 2):
            raise ValueError(f"randomization must be in [0, 2], got {self.randomization!r}.")
        if self.max_acceleration * (1 + self.randomization) >= GRAVITY:
            raise ValueError("max_acceleration * (1 + randomization) must stay below g; lower one of them.")


def batch_zeros(*shape: int) -> np.ndarray:
    """Zeros in the engine's layout: Fortran order, the environment index varying fastest."""
    return np.zeros(shape, order="F")


class PointMassSwarm:
    """``num_envs`` swarms of point-mass drones over moving or static platforms.

    Implements :class:`marlander_lite.episodes.Simulator`; world frame, metres, m/s.
    """

    def __init__(
        self,
        task_config: TaskConfig,
        platform: PlatformConfig,
        num_envs: int = 1,
        params: PointMassParams | None = None,
    ) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}.")
        self.task, self.platform, self.num_envs = task_config, platform, num_envs
        self.params = params or PointMassParams()
        e, n = num_envs, task_config.num_drones
        self.motion = PlatformMotion(platform, e, n, task_config.arena_half_width)
        geometry = platform.geometry
        self._half_x, self._half_y = geometry.half_extents(n)
        self._pad_radius_sq = geometry.pad_radius**2
        self._lift = geometry.pad_thickness + task_config.landed_height
        self._dt = task_config.dt
        # Per-env response: blend = 1 - exp(-dt / tau) and the largest velocity change a_max dt.
        self._blend = np.full((e, 1, 1), 1.0 - np.exp(-self._dt / self.params.velocity_time_constant))
        self._max_dv = np.full((e, 1), self.params.max_acceleration * self._dt)
        self.time = np.zeros(e)
        self.pos, self.vel, self.ang_vel = batch_zeros(e, n, 3), batch_zeros(e, n, 3), batch_zeros(e, n, 3)
        self.quat = batch_zeros(e, n, 4)
        self.quat[..., 3] = 1.0
        self._thrust_dir = batch_zeros(e, n, 3)
        self._thrust_dir[..., 2] = 1.0
        self.contact = batch_zeros(e, n).astype(np.int8, order="F")
        self.landed = batch_zeros(e, n).astype(bool, order="F")
        self.motors_stopped = batch_zeros(e, n).astype(bool, order="F")
        self._landed_offset = batch_zeros(e, n, 3)
        self._plate_pos, self._pads, self._pad_vel = batch_zeros(e, 3), batch_zeros(e, n, 3), batch_zeros(e, n, 3)
        self._update_platform()

    # ------------------------------------------------------------------ Simulator API
    def reset(self, env_ids: np.ndarray, rng: np.random.Generator) -> None:
        self.motion.sample(rng, env_ids)
        if self.params.randomization:
            log_range = np.log1p(self.params.randomization)
            tau_scale, acc_scale = np.exp(rng.uniform(-log_range, log_range, size=(2, len(env_ids))))
            tau = self.params.velocity_time_constant * tau_scale
            self._blend[env_ids, 0, 0] = 1.0 - np.exp(-self._dt / tau)
            self._max_dv[env_ids, 0] = self.params.max_acceleration * acc_scale * self._dt
        self.time[env_ids] = 0.0
        self._update_platform(env_ids)
        self.pos[env_ids] = task.sample_spawn_positions(
            rng, self._plate_pos[env_ids, 2], self.task, self._pads[env_ids]
        )
        for array in (self.vel, self.ang_vel, self.quat, self._thrust_dir):
            array[env_ids] = 0.0
        self.quat[env_ids, :, 3] = 1.0
        self._thrust_dir[env_ids, :, 2] = 1.0
        self.contact[env_ids] = task.CONTACT_NONE
        self.landed[env_ids] = False
        self.motors_stopped[env_ids] = False

    def step(self, velocity: np.ndarray) -> None:
        # First-order lag towards the command, with the change of velocity capped at a_max dt.
        dv = (velocity - self.vel) * self._blend
        dv *= np.minimum(1.0, self._max_dv / np.maximum(vector_norm(dv), 1e-12))[..., None]
        falling = self.motors_stopped.any()
        if falling:  # no thrust: gravity alone changes the velocity
            np.copyto(dv, (0.0, 0.0, -GRAVITY * self._dt), where=self.motors_stopped[..., None])
        self.pos += (self.vel + 0.5 * dv) * self._dt  # trapezoid: mean of old and new velocity
        self.vel += dv
        if falling:
            old = self.quat.copy(), self.ang_vel.copy(), self._thrust_dir.copy()
        self._update_attitude(dv)
        if falling:  # a falling drone keeps its attitude (the thrust direction is undefined)
            for array, before in zip((self.quat, self.ang_vel, self._thrust_dir), old, strict=True):
                np.copyto(array, before, where=self.motors_stopped[..., None])
        self.time += self._dt
        if self.platform.is_moving:
            self._update_platform()
        self._resolve_contacts()
        if self.landed.any():
            self._hold_landed()

    def state(self) -> SwarmState:
        return SwarmState(
            pos=self.pos,
            quat=self.quat,
            vel=self.vel,
            ang_vel=self.ang_vel,
            pad_pos=self._pads,
            pad_vel=self._pad_vel,
            contact=self.contact,
        )

    def land(self, landed: np.ndarray) -> None:
        self._landed_offset[landed] = (self.pos - self._pads)[landed]
        self.landed |= landed
        self._hold_landed()

    def close(self) -> None:
        pass

    # ------------------------------------------------------------------ rehearsal extras
    def place(self, env_id: int, drone_pos: np.ndarray) -> None:
        """Put the drones of ``env_id`` at ``drone_pos`` ``(N, 3)`` m, at rest and level (e.g. on the floor)."""
        pos = np.asarray(drone_pos, dtype=float)
        if pos.shape != (self.task.num_drones, 3) or not np.isfinite(pos).all():
            raise ValueError(f"drone_pos must be a finite ({self.task.num_drones}, 3) array, got shape {pos.shape}.")
        self.pos[env_id] = pos
        for array in (self.vel, self.ang_vel, self.quat, self._thrust_dir):
            array[env_id] = 0.0
        self.quat[env_id, :, 3] = 1.0
        self._thrust_dir[env_id, :, 2] = 1.0
        self.landed[env_id] = False
        self.motors_stopped[env_id] = False

    def stop_motors(self, stopped: np.ndarray) -> None:
        """Cut the motors of drones where ``stopped`` ``(num_envs, N)`` is True: they fall freely until they
        touch something, and ignore velocity commands until :meth:`place` or :meth:`reset`."""
        self.motors_stopped |= np.asarray(stopped, dtype=bool)

    # ------------------------------------------------------------------ internals
    def _update_attitude(self, dv: np.ndarray) -> None:
        """Tilt along ``a + g e_z`` with zero yaw; angular velocity from the tilt change.

        The quaternion taking ``e_z`` to a unit vector ``d`` is ``(-d_y, d_x, 0, 1 + d_z)``
        divided by ``sqrt(2 (1 + d_z))``. Over one step the thrust axis turns from ``d_prev`` to
        ``d`` about ``d_prev x d`` by ``atan2(|d_prev x d|, d_prev . d)``: that angle over ``dt``
        is the angular velocity (yaw never changes).
        """
        d = dv * (1.0 / self._dt)
        d[..., 2] += GRAVITY
        d /= np.maximum(vector_norm(d), 1e-12)[..., None]
        dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
        px, py, pz = self._thrust_dir[..., 0], self._thrust_dir[..., 1], self._thrust_dir[..., 2]
        cx, cy, cz = py * dz - pz * dy, pz * dx - px * dz, px * dy - py * dx
        sin = np.sqrt(cx * cx + cy * cy + cz * cz)
        rate = np.arctan2(sin, px * dx + py * dy + pz * dz) / (np.maximum(sin, 1e-12) * self._dt)
        self.ang_vel[..., 0] = cx * rate
        self.ang_vel[..., 1] = cy * rate
        self.ang_vel[..., 2] = cz * rate
        scale = 1.0 / np.sqrt(2.0 * (1.0 + dz))
        self.quat[..., 0] = -dy * scale
        self.quat[..., 1] = dx * scale
        self.quat[..., 3] = (1.0 + dz) * scale
        self._thrust_dir = d

    def _update_platform(self, env_ids: np.ndarray | None = None) -> None:
        """Move the plates to ``self.time`` (only ``env_ids``' when given)."""
        sel = slice(None) if env_ids is None else env_ids
        plate_pos, plate_vel = self.motion.state(self.time[sel], env_ids)
        self._plate_pos[sel] = plate_pos
        self._pads[sel] = plate_pos[:, None, :] + self.motion.pad_offsets
        self._pad_vel[sel] = plate_vel[:, None, :]

    def _resolve_contacts(self) -> None:
        """Stop drones at the floor or the plate and report what they touch."""
        rx = self.pos[..., 0] - self._plate_pos[:, 0:1]
        ry = self.pos[..., 1] - self._plate_pos[:, 1:2]
        over_plate = (np.abs(rx) <= self._half_x) & (np.abs(ry) <= self._half_y)
        ex, ey = self.pos[..., 0] - self._pads[..., 0], self.pos[..., 1] - self._pads[..., 1]
        on_own_pad = ex * ex + ey * ey <= self._pad_radius_sq
        # The pads are 2.5 mm thick: anywhere over the plate counts as pad height, a conservative bound.
        rest_height = np.where(over_plate, self._plate_pos[:, 2:3] + self._lift, self.task.landed_height)
        touching = (self.pos[..., 2] <= rest_height) & ~self.landed
        # A drone already resting on a surface stops pushing into it. At the first contact the
        # impact velocity is kept: the touchdown test needs it.
        resting = touching & (self.contact != task.CONTACT_NONE)
        if resting.any():
            np.copyto(self.vel[..., 2], np.maximum(self.vel[..., 2], 0.0), where=resting)
        self.contact = np.where(
            touching, np.where(on_own_pad, task.CONTACT_OWN_PAD, task.CONTACT_OTHER), task.CONTACT_NONE
        ).astype(np.int8)
        if touching.any():
            np.copyto(self.pos[..., 2], rest_height, where=touching)

    def _hold_landed(self) -> None:
        mask = self.landed[..., None]
        np.copyto(self.pos, self._pads + self._landed_offset, where=mask)
        np.copyto(self.vel, self._pad_vel, where=mask)
        np.copyto(self.quat, IDENTITY_QUAT, where=mask)
        np.copyto(self.ang_vel, 0.0, where=mask)
