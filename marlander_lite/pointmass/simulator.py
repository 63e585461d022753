"""The lightweight simulator: each drone is a point mass that tracks its velocity command.

A Crazyflie under a cascaded velocity PID answers a velocity command through two loops: the
velocity loop asks for an acceleration, the attitude loop tilts the thrust axis towards it, and
the collective thrust is set for the vertical part. This module integrates a simplified version
of exactly that (:class:`PointMassParams`), for every drone of every environment at once, with
no Python loop over environments. The attitude is the thrust axis, so eq. 2's ``q`` and
``omega`` carry real information.

Speed note: every batched array is Fortran-ordered, so ``pos[..., 0]`` is one contiguous
plane and per-environment values broadcast over drones without short inner loops. Numpy keeps
that layout through arithmetic; the row-major commands of :func:`marlander_lite.task.action_to_velocity`
are copied into it once per step. The layout is a speed choice only: ``tests/test_task.py`` checks
that it changes no bit of a flight or of an observation. The arrays are made by :mod:`marlander_lite.batch_layout`,
which also staggers where they start in memory. See ``benchmarks/bench_pointmass.py``.

Engines: this numpy code is the reference. When numba is installed, :mod:`marlander_lite.pointmass.kernels`
runs the same step as compiled loops over the drones, bit for bit the same (``engine="numba"``, the
default through ``"auto"``; inclined plates always use the reference).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from marlander_lite import task
from marlander_lite.batch_layout import batch_empty, batch_full, batch_zeros
from marlander_lite.episodes import SwarmState
from marlander_lite.platforms import PlatformConfig, PlatformMotion
from marlander_lite.pointmass import kernels, spawn_kernels
from marlander_lite.pointmass.family import (
    CUSHION_LENGTH,
    Corners,
    DynamicsFamily,
    draw_with_corners,
    family_corners,
)
from marlander_lite.rotations import IDENTITY_QUAT, turn_angle, vector_norm
from marlander_lite.task import TaskConfig

GRAVITY = 9.81
INTEGRAL_ACTION_LIMIT = 0.5
"""Largest speed (m/s, per horizontal axis) the integral action of ``DynamicsFamily.velocity_integral_gain`` may add
to a command. It clamps the integrator's output, not the integral itself: a drone held back for long (pinned by a
wall) keeps its boost at this bound, and the integral starts from zero again at every reset and relaunch."""


@dataclass(frozen=True)
class PointMassParams:
    """How a point-mass drone answers a velocity command: a multirotor's velocity loop, simplified.

    Each step the velocity loop asks for the acceleration ``(u - v) / tau`` (with its own ``tau`` for
    the vertical axis, where the thrust acts directly); the thrust vector that
    would give it is ``f = a + g e_z``, tilted at most ``max_tilt`` from vertical. The thrust *axis*
    turns towards that direction with time constant ``attitude_time_constant`` (the attitude loop),
    and the thrust *magnitude* is set for the asked-for vertical acceleration along the current
    axis, within ``[g - max_sink_acceleration, g + max_climb_acceleration]``. The drone then
    accelerates by ``T d - g e_z``. This reproduces what a Crazyflie under a cascaded PID does: a
    short delay before it moves sideways (it must tilt first), and little sideways authority while
    it sinks fast (little thrust to tilt with). The defaults are a least-squares fit to the PyBullet
    Crazyflie (``marlander_lite.crazyflie.fit``, notebook 02).
    """

    velocity_time_constant: float = 0.142
    """tau of the horizontal velocity loop (s): the acceleration asked for per m/s of velocity error is 1/tau."""
    vertical_time_constant: float = 0.0556
    """tau of the vertical velocity loop (s)."""
    attitude_time_constant: float = 0.135
    """Time constant with which the thrust axis turns to the asked-for direction (s)."""
    max_tilt_deg: float = 34.0
    """Largest tilt of the thrust axis from vertical (degrees)."""
    max_climb_acceleration: float = 10.3
    """Thrust headroom above hover (m/s^2): the thrust is at most g + this."""
    max_sink_acceleration: float = 5.39
    """The thrust is at least g - this (m/s^2); below g, the motors never stop."""
    randomization: float = 0.0
    """Domain randomisation: each episode scales the time constants (the two velocity ones together), and
    (together) the tilt's tangent and the
    thrust limits, by independent factors drawn log-uniformly from [1/(1+r), 1+r]; 0 keeps them fixed. Policies
    trained with r > 0 cope with other dynamics, the PyBullet Crazyflie's among them."""
    family: DynamicsFamily | None = None
    """Robust training (issue "policies that transfer"): each drone draws its own dynamics from this family at every
    reset, replacing the constants above (and ``randomization``), with latency, mass mismatch, drag, a ground
    cushion and a tracking-gain error on top. ``None`` (the default) keeps the fixed model above, bit for bit."""
    corner: DynamicsFamily | tuple[DynamicsFamily, ...] | None = None
    """Corners of ``family`` that :attr:`corner_fraction` of the drones draw from instead (a training aid): a uniform
    draw almost never combines a stiff velocity loop with a slow attitude and late commands (about 0.1 % of drones),
    where the policies' last-centimetre corrections ring (docs/transfer.md, "The stiff, late loop"). One corner or a
    list of them; as a mapping, a corner's ranges replace the family's and every other range is the family's; a
    curriculum that opens the family (``TrainConfig.family_opening``) leaves the corners whole. ``None``: every drone
    draws from ``family``, with the draws of the runs before it."""
    corner_fraction: float | tuple[float, ...] = 0.0
    """Share of the drones, in (0, 1], drawn from :attr:`corner` at each reset (each drone on its own); with several
    corners one share each, summing to at most 1."""

    @property
    def corners(self) -> Corners:
        """``((corner, share), ...)``: every corner with its share of the drones; empty without corners."""
        return family_corners(self.family, self.corner, self.corner_fraction)

    def __post_init__(self) -> None:
        if isinstance(self.family, dict):
            object.__setattr__(self, "family", DynamicsFamily.from_mapping(self.family))
        if self.family is not None and not isinstance(self.family, DynamicsFamily):
            raise TypeError(
                f"PointMassParams.family must be a DynamicsFamily or a dict of its ranges, got {self.family!r}."
            )
        corners = family_corners(self.family, self.corner, self.corner_fraction)
        if corners and isinstance(self.corner, dict | DynamicsFamily):
            object.__setattr__(self, "corner", corners[0][0])
        elif corners:
            object.__setattr__(self, "corner", tuple(each for each, _ in corners))
        if self.family is not None and self.randomization:
            raise ValueError("PointMassParams: give either randomization or family, not both (family replaces it).")
        for name, value in vars(self).items():
            if name in ("family", "corner", "corner_fraction"):
                continue
            if not np.isfinite(value):
                raise ValueError(f"PointMassParams.{name} must be finite, got {value!r}.")
        checks = [
            (self.velocity_time_constant > 0, "velocity_time_constant must be > 0 s"),
            (self.vertical_time_constant > 0, "vertical_time_constant must be > 0 s"),
            (self.attitude_time_constant > 0, "attitude_time_constant must be > 0 s"),
            (0 < self.max_tilt_deg < 90, "max_tilt_deg must be in (0, 90) degrees"),
            (self.max_climb_acceleration > 0, "max_climb_acceleration must be > 0 m/s^2"),
            (self.max_sink_acceleration > 0, "max_sink_acceleration must be > 0 m/s^2"),
            (0 <= self.randomization <= 2, "randomization must be in [0, 2]"),
            (
                self.max_sink_acceleration * (1 + self.randomization) < GRAVITY,
                "max_sink_acceleration * (1 + randomization) must stay below g (the motors never stop)",
            ),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(f"Invalid PointMassParams: {message}; got {self!r}.")


class PointMassSwarm:
    """``num_envs`` swarms of point-mass drones over moving or static platforms.

    Implements :class:`marlander_lite.episodes.Simulator`; world frame, metres, m/s. ``engine`` picks the
    numpy reference (``"numpy"``) or the compiled kernels (``"numba"``, the same bits, faster);
    ``"auto"`` takes numba when it is installed, unless ``MARLANDER_LITE_ENGINE=numpy`` is set. The engine
    that runs is :attr:`engine`.
    """

    def __init__(
        self,
        task_config: TaskConfig,
        platform: PlatformConfig,
        num_envs: int = 1,
        params: PointMassParams | None = None,
        engine: kernels.Engine = "auto",
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
        # Beyond the paper: an inclined plate (platforms.PlateGeometry.inclination_deg); level plates keep the
        # horizontal test of _surface bit for bit.
        self._rotation = geometry.rotation() if geometry.inclination_deg else None
        self._dt = task_config.dt
        # Per-env response (arrays so that domain randomisation can vary them per episode).
        prm = self.params
        self._gain = batch_empty((e, 1, 3))
        self._gain[...] = 1.0 / np.array([prm.velocity_time_constant] * 2 + [prm.vertical_time_constant])
        self._turn = batch_full((e, 1, 1), 1.0 - np.exp(-self._dt / prm.attitude_time_constant))
        self._tan_tilt = batch_full((e, 1), np.tan(np.radians(prm.max_tilt_deg)))
        self._thrust_max = batch_full((e, 1), GRAVITY + prm.max_climb_acceleration)
        self._thrust_min = batch_full((e, 1), GRAVITY - prm.max_sink_acceleration)
        self.family = prm.family
        self._corners = prm.corners  # checked once here, not at every reset
        if self.family is not None:
            self._init_family(e, n)
        self.time = np.zeros(e)
        self.pos, self.vel, self.ang_vel = batch_zeros(e, n, 3), batch_zeros(e, n, 3), batch_zeros(e, n, 3)
        self.quat = batch_zeros(e, n, 4)
        self.quat[..., 3] = 1.0
        self._thrust_dir = batch_zeros(e, n, 3)
        self._thrust_dir[..., 2] = 1.0
        self.contact = batch_zeros(e, n, dtype=np.int8)
        self.landed = batch_zeros(e, n, dtype=bool)
        self.motors_stopped = batch_zeros(e, n, dtype=bool)
        self._landed_offset = batch_zeros(e, n, 3)
        self._plate_pos, self._pads, self._pad_vel = batch_zeros(e, 3), batch_zeros(e, n, 3), batch_zeros(e, n, 3)
        self._update_platform()
        # The kernels judge contacts on level plates only; an inclined plate keeps the reference.
        self.engine = kernels.resolve_engine(engine) if self._rotation is None else "numpy"
        """The engine that steps this simulator: ``"numpy"`` (the reference) or ``"numba"``."""
        if self.engine == "numba":
            self._init_kernels(e, n)

    # ------------------------------------------------------------------ Simulator API
    def reset(self, env_ids: np.ndarray, rng: np.random.Generator) -> None:
        self.motion.sample(rng, env_ids)
        prm = self.params
        if prm.randomization:
            log_range = np.log1p(prm.randomization)
            slow, slow_turn, authority = np.exp(rng.uniform(-log_range, log_range, size=(3, len(env_ids))))
            taus = np.array([prm.velocity_time_constant] * 2 + [prm.vertical_time_constant])
            self._gain[env_ids, 0, :] = 1.0 / (slow[:, None] * taus)
            self._turn[env_ids, 0, 0] = 1.0 - np.exp(-self._dt / (prm.attitude_time_constant * slow_turn))
            self._tan_tilt[env_ids, 0] = np.tan(np.radians(prm.max_tilt_deg)) * authority
            self._thrust_max[env_ids, 0] = GRAVITY + prm.max_climb_acceleration * authority
            self._thrust_min[env_ids, 0] = GRAVITY - prm.max_sink_acceleration * authority
        if self.family is not None:
            self._draw_family(env_ids, rng)
        self.time[env_ids] = 0.0
        self._update_platform(env_ids)
        self.pos[env_ids] = task.sample_spawn_positions(
            rng, self._plate_pos[env_ids, 2], self.task, self._pads[env_ids]
        )
        if self.engine == "numba":
            ids = np.asarray(env_ids, dtype=np.int64)
            kernels.rest_envs(
                ids, self.vel, self.ang_vel, self.quat, self._thrust_dir, self.landed, self.motors_stopped
            )
        else:
            self._at_rest(env_ids)
        self.contact[env_ids] = task.CONTACT_NONE

    def step(self, velocity: np.ndarray) -> None:
        if self.engine == "numba":
            self._compiled_step(velocity)
            return
        # One copy of the (row-major) commands into the engine's layout keeps every operation below on
        # contiguous planes; mixing layouts costs more than the copy.
        velocity = np.asfortranarray(velocity)
        if self.family is None:
            accel, axis = self._thrust(velocity)
        else:
            accel, axis = self._family_thrust(velocity)
        if self.motors_stopped.any():  # no thrust: gravity alone, and the attitude stays
            stopped = self.motors_stopped[..., None]
            np.copyto(accel, (0.0, 0.0, -GRAVITY), where=stopped)
            np.copyto(axis, self._thrust_dir, where=stopped)
        start = self.pos.copy()
        dt = self._dt
        self.pos += (self.vel + (0.5 * dt) * accel) * dt
        self.vel += accel * dt
        self._set_attitude(axis)
        self.time += dt
        if self.platform.is_moving:
            self._update_platform()
        self._resolve_contacts(start)
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
        self._at_rest(env_id)
        if self.family is not None:
            self._error_integral[env_id] = 0.0

    def relaunch(self, drones: np.ndarray, rng: np.random.Generator, tries: int = 20) -> None:
        """Put the drones where ``drones`` ``(num_envs, N)`` is True at new random starting positions, at rest and
        level, while the others fly on (a training aid: per-drone episode ends; see :meth:`LandingEpisodes.relaunch`).

        Starts are drawn as at a reset (:func:`~marlander_lite.task.sample_spawn_positions`) and kept once every
        relaunched drone is ``spawn_separation`` from every other drone of its swarm; after ``tries`` draws the last
        is kept. A relaunched drone keeps its dynamics (the same airframe taking off again).
        """
        drones = np.asarray(drones, dtype=bool)
        if drones.shape != self.landed.shape:
            raise ValueError(f"drones must be a {self.landed.shape} bool array, got shape {drones.shape}.")
        from marlander_lite.swarm.observation import pairwise_offsets  # here: the swarm package builds on this one

        pending = np.flatnonzero(drones.any(axis=-1))
        for attempt in range(tries):
            if not pending.size:
                break
            draw = task.sample_spawn_positions(
                rng, self._plate_pos[pending, 2], self.task, self._pads[pending], pair_with_pads=False
            )
            mask = drones[pending]
            candidate = np.where(mask[..., None], draw, self.pos[pending])
            nearest_sq = np.where(mask, pairwise_offsets(candidate)[1].min(axis=-1), np.inf).min(axis=-1)
            keep = (nearest_sq >= self.task.spawn_separation**2) | (attempt == tries - 1)
            self.pos[pending[keep]] = candidate[keep]
            pending = pending[~keep]
        self._at_rest(drones)
        self.contact[drones] = task.CONTACT_NONE
        if self.family is not None:  # commands in flight to the old flight are dropped, and the integrator's memory
            self._commands[:, drones] = 0.0
            self._error_integral[drones] = 0.0

    def stop_motors(self, stopped: np.ndarray) -> None:
        """Cut the motors of drones where ``stopped`` ``(num_envs, N)`` is True: they fall freely until they
        touch something, and ignore velocity commands until :meth:`place` or :meth:`reset`."""
        self.motors_stopped |= np.asarray(stopped, dtype=bool)

    # ------------------------------------------------------------------ internals
    def _at_rest(self, index: np.ndarray | int) -> None:
        """The drones ``index`` selects (whole envs, or single drones by a ``(num_envs, N)`` mask): at rest, level
        (thrust axis up), not landed, motors on. Where they are is the caller's."""
        self.vel[index] = 0.0
        self.ang_vel[index] = 0.0
        self.quat[index] = IDENTITY_QUAT
        self._thrust_dir[index] = (0.0, 0.0, 1.0)
        self.landed[index] = False
        self.motors_stopped[index] = False

    def _thrust(self, velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Acceleration over the next step and the thrust axis it is produced along (see PointMassParams)."""
        wanted = (velocity - self.vel) * self._gain
        wanted[..., 2] += GRAVITY  # the thrust (per unit mass) that would give the wanted acceleration
        fz = np.clip(wanted[..., 2], self._thrust_min, self._thrust_max)
        horizontal = np.sqrt(wanted[..., 0] ** 2 + wanted[..., 1] ** 2)
        wanted[..., :2] *= np.minimum(1.0, fz * self._tan_tilt / np.maximum(horizontal, 1e-12))[..., None]
        wanted[..., 2] = fz
        target = wanted / vector_norm(wanted)[..., None]
        # The attitude loop turns the thrust axis part of the way to the wanted direction ...
        axis = self._thrust_dir + (target - self._thrust_dir) * self._turn
        axis /= vector_norm(axis)[..., None]
        # ... and the collective thrust gives the wanted vertical acceleration along that axis.
        thrust = np.clip(fz / np.maximum(axis[..., 2], 0.1), self._thrust_min, self._thrust_max)
        accel = axis * thrust[..., None]
        accel[..., 2] -= GRAVITY
        return accel, axis

    # ------------------------------------------------------------------ compiled engine (kernels)
    def _init_kernels(self, e: int, n: int) -> None:
        """Scratch arrays the kernels hand each other, and stand-ins for the family's arrays without one."""
        self._start, self._cross = batch_zeros(e, n, 3), batch_zeros(e, n, 3)
        self._sin, self._cos = batch_zeros(e, n), batch_zeros(e, n)
        self._surface_params = np.array([self._half_x, self._half_y, self._lift, self.task.landed_height], dtype=float)
        if self.family is None:  # never read: the kernel's family branch is off
            self._inv_mass = self._drag = batch_zeros(1, 1, 1)
            self._cushion = batch_zeros(1, 1)
        else:
            self._acting = batch_zeros(e, n, 3)

    def _compiled_step(self, velocity: np.ndarray) -> None:
        """:meth:`step` through :mod:`~marlander_lite.pointmass.kernels`: the same operations, drone by drone."""
        # One memory layout for every caller: each layout is one more compile of the kernels (seconds each).
        velocity = np.asfortranarray(velocity, dtype=float)
        if velocity.shape != self.pos.shape:  # the kernels do not check bounds
            raise ValueError(f"velocity must have shape {self.pos.shape} (num_envs, N, 3), got {velocity.shape}.")
        family = self.family is not None
        if family:  # the command each drone acts on, late and scaled
            kernels.delayed_commands(velocity, self._cmd_gain, self._latency, self._commands, self._acting)
            velocity = self._integral_action(self._acting)
        kernels.thrust_and_integrate(
            velocity, self.pos, self.vel, self._thrust_dir, self.motors_stopped, self._gain, self._turn,
            self._tan_tilt, self._thrust_min, self._thrust_max, family, self._inv_mass, self._drag, self._cushion,
            family and bool(self._cushion.any()), self._plate_pos, self._surface_params, self._dt, self._start,
            self._cross, self._sin, self._cos, self.quat,
        )  # fmt: skip
        kernels.turn_rates(self._cross, self._sin, self._cos, self._dt, self.ang_vel)
        self.time += self._dt
        if self.platform.is_moving:
            self._update_platform()
        kernels.contacts_and_landed(
            self._start, self.pos, self.vel, self.ang_vel, self.quat, self.contact, self.landed, self.motors_stopped,
            self._plate_pos, self._pads, self._pad_vel, self._landed_offset, self._surface_params, self._pad_radius_sq,
        )  # fmt: skip

    # ------------------------------------------------------------------ robust training (DynamicsFamily)
    def _init_family(self, e: int, n: int) -> None:
        """Per-drone dynamics arrays ``(num_envs, N, ...)``, set to the family's lower-middle until the first draw.

        Refuses a latency range reaching beyond two policy periods here, before any draw, so that a training run with
        it fails while it starts (and leaves nothing behind) rather than at its first reset.
        """
        highest_latency = max([self.family.latency_s[1]] + [c.latency_s[1] for c, _ in self._corners])
        if highest_latency > 2.0 * self._dt:
            raise ValueError(
                f"latency_s up to {highest_latency:.3f} s is more than two policy periods ({2 * self._dt:.3f} s), "
                "which the point mass does not model; lower the latency range or policy_hz."
            )
        self._gain = batch_empty((e, n, 3))
        self._turn = batch_empty((e, n, 1))
        self._tan_tilt, self._thrust_max, self._thrust_min = (batch_empty((e, n)) for _ in range(3))
        self._inv_mass, self._drag, self._cmd_gain = (batch_full((e, n, 1), 1.0) for _ in range(3))
        self._cushion = batch_zeros(e, n)
        self._latency = batch_zeros(e, n, 1)
        """Latency in policy periods, in [0, 2]: the command history below holds two periods."""
        self._commands = np.zeros((2, e, n, 3))
        """The two previous velocity commands (after the gain error), newest first."""
        self._integral_gain = batch_zeros(e, n, 1)
        self._error_integral = batch_zeros(e, n, 3)
        """Integral of each drone's horizontal velocity error ``(u - v)`` since its reset (m; z stays 0)."""
        self._integral_on = False
        """Whether any drone has drawn integral action (``velocity_integral_gain``): until then none is computed."""
        middle = {f.name: 0.5 * sum(getattr(self.family, f.name)) for f in dataclasses.fields(self.family)}
        self._set_family(np.arange(e), {name: np.full((e, n), value) for name, value in middle.items()})

    def set_family(self, family: DynamicsFamily) -> None:
        """Draw the next resets' dynamics from ``family`` (a curriculum opens it; drones in flight keep theirs).

        Only for a simulator built with a family, and only within the latency its command history holds.
        """
        if self.family is None:
            raise ValueError("set_family needs a simulator built with PointMassParams(family=...); this one has none.")
        if family.latency_s[1] > self._commands.shape[0] * self._dt:
            raise ValueError(
                f"latency_s up to {family.latency_s[1]:.3f} s is more than the {self._commands.shape[0]} policy "
                "periods this simulator's command history holds."
            )
        self.family = family

    def _draw_family(self, env_ids: np.ndarray, rng: np.random.Generator) -> None:
        shape = (len(env_ids), self.task.num_drones)
        self._set_family(env_ids, draw_with_corners(self.family, self._corners, rng, shape))
        self._commands[:, env_ids] = 0.0
        self._error_integral[env_ids] = 0.0

    def _set_family(self, env_ids: np.ndarray, draw: dict[str, np.ndarray]) -> None:
        dt = self._dt
        latency = draw["latency_s"] / dt
        self._gain[env_ids, :, 0] = self._gain[env_ids, :, 1] = 1.0 / draw["velocity_time_constant"]
        self._gain[env_ids, :, 2] = 1.0 / draw["vertical_time_constant"]
        self._turn[env_ids, :, 0] = 1.0 - np.exp(-dt / draw["attitude_time_constant"])
        self._tan_tilt[env_ids] = np.tan(np.radians(draw["max_tilt_deg"]))
        self._thrust_max[env_ids] = GRAVITY + draw["max_climb_acceleration"]
        self._thrust_min[env_ids] = GRAVITY - draw["max_sink_acceleration"]
        self._inv_mass[env_ids, :, 0] = 1.0 / draw["mass_scale"]
        self._drag[env_ids, :, 0] = draw["drag"]
        self._cushion[env_ids] = draw["ground_cushion"]
        self._cmd_gain[env_ids, :, 0] = draw["command_gain"]
        self._latency[env_ids, :, 0] = latency
        self._integral_gain[env_ids, :, 0] = draw["velocity_integral_gain"]
        self._integral_on = self._integral_on or bool(draw["velocity_integral_gain"].any())

    def _integral_action(self, acting: np.ndarray) -> np.ndarray:
        """``acting`` ``(num_envs, N, 3)`` m/s with the integral action of a PI velocity loop added, in place:
        ``u + k_i * integral(u - v) dt`` horizontally, the added speed clamped at :data:`INTEGRAL_ACTION_LIMIT` per
        axis, then this step's error integrated. Nothing without ``velocity_integral_gain``.
        """
        if not self._integral_on:
            return acting
        boost = np.clip(self._integral_gain * self._error_integral, -INTEGRAL_ACTION_LIMIT, INTEGRAL_ACTION_LIMIT)
        self._error_integral[..., :2] += (acting[..., :2] - self.vel[..., :2]) * self._dt
        acting += boost
        return acting

    def _family_thrust(self, velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_thrust` for a drone drawn from the family: the command arrives late and scaled, the
        tracker's thrust is meant for the nominal mass, drag slows the drone and the ground cushions it."""
        command = velocity * self._cmd_gain
        # Latency L (in periods) as the share of the period during which the older command still acts:
        # L = 0.5 flies half a period on the previous command; L = 1.5 half on each of the two before.
        late = np.clip(self._latency, 0.0, 1.0)
        later = np.clip(self._latency - 1.0, 0.0, 1.0)
        older = (1.0 - later) * self._commands[0] + later * self._commands[1]
        acting = (1.0 - late) * command + late * older
        self._commands[1] = self._commands[0]
        self._commands[0] = command
        accel, axis = self._thrust(self._integral_action(acting))
        # _thrust's acceleration is that of the nominal mass: the same force moves a heavier drone less.
        accel[..., 2] += GRAVITY
        accel *= self._inv_mass
        accel[..., 2] -= GRAVITY
        accel -= self._drag * self.vel
        if self._cushion.any():
            rest_height, _ = self._surface()
            height = np.maximum(self.pos[..., 2] - rest_height, 0.0)
            accel[..., 2] += self._cushion * GRAVITY * (CUSHION_LENGTH / (CUSHION_LENGTH + height)) ** 2
        return accel, axis

    def _set_attitude(self, axis: np.ndarray) -> None:
        """Attitude (zero yaw) with body z along the thrust axis, and the angular velocity of its turn.

        The quaternion taking ``e_z`` to a unit vector ``d`` is ``(-d_y, d_x, 0, 1 + d_z)`` divided
        by ``sqrt(2 (1 + d_z))``. Over one step the axis turns from ``d_prev`` to ``d`` about
        ``d_prev x d`` by ``atan2(|d_prev x d|, d_prev . d)`` (:func:`~marlander_lite.rotations.turn_angle`): that
        angle over ``dt`` is the angular velocity.
        """
        dx, dy, dz = axis[..., 0], axis[..., 1], axis[..., 2]
        px, py, pz = self._thrust_dir[..., 0], self._thrust_dir[..., 1], self._thrust_dir[..., 2]
        cx, cy, cz = py * dz - pz * dy, pz * dx - px * dz, px * dy - py * dx
        sin = np.sqrt(cx * cx + cy * cy + cz * cz)
        rate = turn_angle(sin, px * dx + py * dy + pz * dz) / (np.maximum(sin, 1e-12) * self._dt)
        self.ang_vel[..., 0] = cx * rate
        self.ang_vel[..., 1] = cy * rate
        self.ang_vel[..., 2] = cz * rate
        scale = 1.0 / np.sqrt(2.0 * (1.0 + dz))
        self.quat[..., 0] = -dy * scale
        self.quat[..., 1] = dx * scale
        self.quat[..., 3] = (1.0 + dz) * scale
        self._thrust_dir = axis

    def _update_platform(self, env_ids: np.ndarray | None = None) -> None:
        """Move the plates to ``self.time`` (only ``env_ids``' when given)."""
        sel = slice(None) if env_ids is None else env_ids
        plate_pos, plate_vel = self.motion.state(self.time[sel], env_ids)
        if env_ids is not None and self.engine == "numba":  # a reset's few envs: the same numbers, scattered faster
            ids = np.asarray(env_ids, dtype=np.int64)
            spawn_kernels.place_plates(
                ids, plate_pos, plate_vel, self.motion.pad_offsets, self._plate_pos, self._pads, self._pad_vel
            )
            return
        self._plate_pos[sel] = plate_pos
        self._pads[sel] = plate_pos[:, None, :] + self.motion.pad_offsets
        self._pad_vel[sel] = plate_vel[:, None, :]

    def _surface(self) -> tuple[np.ndarray, np.ndarray]:
        """Height a drone at its current x, y rests at (floor or plate), and whether it is over its own pad."""
        if self._rotation is not None:
            return self._inclined_surface()
        rx = self.pos[..., 0] - self._plate_pos[:, 0:1]
        ry = self.pos[..., 1] - self._plate_pos[:, 1:2]
        over_plate = (np.abs(rx) <= self._half_x) & (np.abs(ry) <= self._half_y)
        ex, ey = self.pos[..., 0] - self._pads[..., 0], self.pos[..., 1] - self._pads[..., 1]
        on_own_pad = ex * ex + ey * ey <= self._pad_radius_sq
        # The pads are 2.5 mm thick: anywhere over the plate counts as pad height, a conservative bound.
        rest_height = np.where(over_plate, self._plate_pos[:, 2:3] + self._lift, self.task.landed_height)
        return rest_height, on_own_pad

    def _inclined_surface(self) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_surface` on a tilted plate, judged in the plate frame.

        A drone is over the plate when its plate-frame ``x, y`` (``R^T (p - plate)``) lie within the half
        extents, and over its own pad when its offset from the pad centre *within the pad plane* is at most
        the pad radius. It rests where its centre is ``pad_thickness + landed_height`` above the plate along
        the normal ``n``: at ``z = plate_z - (n_x dx + n_y dy) / n_z + lift / n_z``.
        """
        rot = self._rotation
        assert rot is not None
        n = rot[:, 2]
        d = self.pos - self._plate_pos[:, None, :]
        local = d @ rot  # plate-frame coordinates, R^T d for every drone
        over_plate = (np.abs(local[..., 0]) <= self._half_x) & (np.abs(local[..., 1]) <= self._half_y)
        e = self.pos - self._pads
        along = e @ n
        on_own_pad = np.einsum("...k,...k->...", e, e) - along * along <= self._pad_radius_sq
        plane = self._plate_pos[:, 2:3] - (n[0] * d[..., 0] + n[1] * d[..., 1] - self._lift) / n[2]
        return np.where(over_plate, plane, self.task.landed_height), on_own_pad

    def _resolve_contacts(self, start: np.ndarray) -> None:
        """Stop drones at the floor or the plate and report what they touch.

        A drone that reaches a surface during the step stops where its path crossed it (the
        surface holds it), not where the free flight would have ended.
        """
        rest_height, on_own_pad = self._surface()
        touching = (self.pos[..., 2] <= rest_height) & ~self.landed
        if not touching.any():
            self.contact = np.zeros_like(self.contact)
            return
        first = touching & (self.contact == task.CONTACT_NONE)
        if first.any():
            z0, z1 = start[..., 2], self.pos[..., 2]
            fraction = np.clip((z0 - rest_height) / np.maximum(z0 - z1, 1e-12), 0.0, 1.0)
            crossing = start + fraction[..., None] * (self.pos - start)
            np.copyto(self.pos, crossing, where=first[..., None])
            rest_height, on_own_pad = self._surface()
        # A drone already resting on a surface stops pushing into it. At the first contact the
        # impact velocity is kept: the touchdown test needs it.
        resting = touching & ~first
        if resting.any():
            np.copyto(self.vel[..., 2], np.maximum(self.vel[..., 2], 0.0), where=resting)
            # Without thrust, friction holds a resting drone where it is.
            np.copyto(self.vel, 0.0, where=(resting & self.motors_stopped)[..., None])
        self.contact = np.where(
            touching, np.where(on_own_pad, task.CONTACT_OWN_PAD, task.CONTACT_OTHER), task.CONTACT_NONE
        ).astype(np.int8)
        np.copyto(self.pos[..., 2], rest_height, where=touching)

    def _hold_landed(self) -> None:
        mask = self.landed[..., None]
        np.copyto(self.pos, self._pads + self._landed_offset, where=mask)
        np.copyto(self.vel, self._pad_vel, where=mask)
        np.copyto(self.quat, IDENTITY_QUAT, where=mask)
        np.copyto(self.ang_vel, 0.0, where=mask)
