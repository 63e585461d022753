"""Batched landing episodes over any swarm simulator.

A *simulator* only moves drones: it is reset, told velocity commands, and reports a
:class:`SwarmState`. :class:`LandingEpisodes` turns that into the MDP of :mod:`marlander_lite.task`
(observation, reward, landing, collision, episode end) and applies the motion-capture model of
:mod:`marlander_lite.sensing`. The gymnasium, stable-baselines3 and PettingZoo faces of both
simulators are thin layers over this one class.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from marlander_lite import task, training_aids
from marlander_lite.batch_layout import batch_full, batch_zeros
from marlander_lite.observation_history import ObservationHistory
from marlander_lite.pad_frame_lead import flight_leads, lead_tracker
from marlander_lite.platforms import PlatformConfig
from marlander_lite.rotations import vector_norm
from marlander_lite.sensing import ObservationChannel, SensingConfig
from marlander_lite.swarm.pad_acceleration import acceleration_step
from marlander_lite.swarm.vertical_bias import VerticalBias
from marlander_lite.task import PLATFORM_VELOCITY, TaskConfig


@dataclass
class SwarmState:
    """Physical state of ``num_envs`` swarms of ``N`` drones, world frame, SI units."""

    pos: np.ndarray
    """Drone positions, ``(num_envs, N, 3)`` m."""
    quat: np.ndarray
    """Drone attitudes ``(x, y, z, w)``, ``(num_envs, N, 4)``."""
    vel: np.ndarray
    """Drone velocities, ``(num_envs, N, 3)`` m/s."""
    ang_vel: np.ndarray
    """Drone angular velocities, ``(num_envs, N, 3)`` rad/s."""
    pad_pos: np.ndarray
    """Top-face centre of each drone's own pad, ``(num_envs, N, 3)`` m."""
    pad_vel: np.ndarray
    """Velocity of each drone's own pad, ``(num_envs, N, 3)`` m/s."""
    contact: np.ndarray
    """Contact code per drone (``task.CONTACT_*``) during the last step, ``(num_envs, N)`` int."""

    def take(self, env_ids: np.ndarray) -> SwarmState:
        """The state of some environments only (copies)."""
        return SwarmState(**{name: value[env_ids] for name, value in vars(self).items()})


class Simulator(Protocol):
    """What :class:`LandingEpisodes` needs from a physics back end."""

    task: TaskConfig
    platform: PlatformConfig
    num_envs: int

    def reset(self, env_ids: np.ndarray, rng: np.random.Generator) -> None:
        """Place platform and drones of ``env_ids`` at random (``task.sample_spawn_positions``), at rest."""

    def step(self, velocity: np.ndarray) -> None:
        """Advance every env by one policy period ``task.dt`` tracking ``velocity`` ``(num_envs, N, 3)`` m/s.

        Landed drones ignore their command and stay on their pads.
        """

    def state(self) -> SwarmState:
        """Current state of every env."""

    def land(self, landed: np.ndarray) -> None:
        """Fix the drones where ``landed`` ``(num_envs, N)`` is True to their pads from now on."""

    def close(self) -> None:
        """Release resources."""


@dataclass
class StepOutcome:
    """Everything one batched step produced. Arrays are ``(num_envs,)`` or ``(num_envs, N)``."""

    obs: np.ndarray
    """Observation as the policy sees it (noise and latency applied), ``(num_envs, N, 13)``."""
    reward: np.ndarray
    """Team reward ``R_t`` of eq. 4."""
    drone_rewards: np.ndarray
    """Per drone ``r_t^i`` of eq. 5."""
    terminated: np.ndarray
    """All landed, or a crash, a collision or a drone out of the arena."""
    truncated: np.ndarray
    """Time limit reached without termination."""
    landed: np.ndarray
    """Drones on their own pads so far."""
    landed_now: np.ndarray
    """Drones that landed at this step."""
    crashed: np.ndarray
    """Drones that touched anything but a valid landing spot at this step."""
    collided: np.ndarray
    """Two drones closer than ``collision_distance`` at this step."""
    out_of_arena: np.ndarray
    """Drones outside the arena at this step."""
    success: np.ndarray
    """Every drone landed (meaningful once the episode has ended)."""
    landing_error: np.ndarray
    """Horizontal distance from the pad centre at touchdown (m); NaN until a drone lands."""
    landing_time: np.ndarray
    """Time of each drone's touchdown since the episode start (s); NaN until it lands."""
    min_separation: np.ndarray
    """Smallest distance between any two drones so far in the episode (m); inf for one drone."""
    rel_speed: np.ndarray
    """Each drone's speed relative to its pad at this step (m/s), as the touchdown test saw it: for a drone
    touching down now, its impact speed."""
    episode_return: np.ndarray
    """Sum of ``R_t`` so far in the episode."""
    episode_length: np.ndarray
    """Steps so far in the episode."""

    @property
    def agent_rewards(self) -> np.ndarray:
        """Per drone ``r_t^i + r^c + K``: each drone's own term plus the shared ones, for per-agent learners."""
        shared = self.reward - self.drone_rewards.sum(axis=-1)
        return self.drone_rewards + shared[:, None]

    @property
    def done(self) -> np.ndarray:
        """Terminated or truncated."""
        return self.terminated | self.truncated


def _task_kernels() -> Any:
    # Imported here, not at the top: marlander_lite.pointmass, whose kernels these build on, imports this module.
    from marlander_lite import task_kernels

    return task_kernels


def fortran_state(s: SwarmState) -> SwarmState:
    """``s`` with every array in the point-mass layout (environment index fastest; ``contact`` as int8): the point
    mass's own arrays, not copied, and copies of other simulators' (one env each). The compiled MDP step then runs
    one machine-code version for every simulator; each other layout would be another compile of seconds."""
    return SwarmState(
        **{
            name: np.asfortranarray(value, dtype=np.int8 if name == "contact" else None)
            for name, value in vars(s).items()
        }
    )


def uses_compiled_mdp(simulator: Simulator) -> bool:
    """Whether :class:`LandingEpisodes` steps ``simulator``'s MDP through :mod:`marlander_lite.task_kernels`: numba
    runs (``MARLANDER_LITE_ENGINE`` is not ``numpy``), the simulator does not run its numpy reference, and the plate
    is level (an inclined plate's pad-frame test stays in numpy)."""
    if simulator.platform.geometry.inclination_deg or getattr(simulator, "engine", None) == "numpy":
        return False
    return task.compiled_kernels() is not None


class LandingEpisodes:
    """The MARLander MDP over ``simulator.num_envs`` environments stepped together.

    Args:
        simulator: any :class:`Simulator`.
        sensing: noise and latency applied to observations.
        seed: seed of the one random generator that drives resets and noise.
    """

    def __init__(self, simulator: Simulator, sensing: SensingConfig | None = None, seed: int | None = None) -> None:
        self.sim = simulator
        self.task = simulator.task
        self.sensing = sensing or SensingConfig()
        geometry = simulator.platform.geometry
        self.pad_radius = geometry.pad_radius
        self.pad_normal = geometry.normal()
        """Unit normal of every pad ``(3,)``: ``+z``, or tilted on an inclined plate (beyond the paper)."""
        self._inclined = geometry.inclination_deg != 0
        e, n = simulator.num_envs, self.task.num_drones
        self.num_envs, self.num_drones = e, n
        self.rng = np.random.default_rng(seed)
        exact = 3 if self.task.observe_previous_command else 0
        # The pad acceleration is appended after the channel: it is estimated from what the channel let through.
        self._observes_acceleration = self.task.observe_platform_acceleration
        channel_width = self.task.frame_per_drone - 3 * self._observes_acceleration
        self.channel = ObservationChannel(self.sensing, e, n, self.task.dt, channel_width, exact)
        # A landed drone's centre rests landed_height above its pad along the pad normal: that is eq. 2's goal.
        self._goal_lift = self.task.landed_height * self.pad_normal
        self.steps = np.zeros(e, dtype=np.int64)
        # The simulators' layout (marlander_lite.batch_layout): Fortran order, each array at its own place in a page.
        self.landed = batch_zeros(e, n, dtype=bool)
        self.prev_dist = batch_zeros(e, n)
        self.landing_error = batch_full((e, n), np.nan)
        self.landing_time = batch_full((e, n), np.nan)
        self.min_separation = np.full(e, np.inf)
        self.episode_return = np.zeros(e)
        self.previous_command = batch_zeros(e, n, 3)
        """Last velocity commands ``(num_envs, N, 3)`` m/s, zero after a reset: observed with
        ``TaskConfig.observe_previous_command`` and compared by the smoothness training aid."""
        self.pad_acceleration = np.zeros((e, n, 3))
        """Each pad's acceleration ``(num_envs, N, 3)`` m/s^2 as estimated from the observed pad velocities, zero after
        a reset: observed last with ``TaskConfig.observe_platform_acceleration``, as the deployment loop does."""
        self._seen_pad_vel = np.zeros((e, n, 3))
        self.carried_acceleration = np.zeros((e, n, 3))
        """Each pad's acceleration ``(num_envs, N, 3)`` m/s^2 estimated from its velocity at each command, zero after a
        reset: the lead of a pad-frame command (``TaskConfig.pad_frame_lead``)."""
        self._carried_pad_vel = np.zeros((e, n, 3))
        self._carried: np.ndarray | None = None  # this step's carried pad velocity, once formed
        self.lead_tracker = lead_tracker(self.task)
        """With ``TaskConfig.pad_frame_lead_share``: each env's velocity tracker, identified from the commands flown
        and the observed velocities that followed (as the deployment loop identifies it from motion capture), which
        sets the lead; a new episode starts from the prior. None for a fixed lead."""
        self.vertical_bias = VerticalBias(self.task.dt) if self.task.vertical_bias_compensation else None
        """With ``TaskConfig.vertical_bias_compensation``: each drone's steady vertical velocity bias, identified from
        the commands sent and the observed velocities that followed, and taken off its vertical commands; a new
        episode starts with none. None without."""
        # The frames are stacked last, from what the policy would see now (TaskConfig.observation_history).
        self.history = ObservationHistory(self.task.observation_history, (e, n), self.task.frame_per_drone)
        self._channel_width = channel_width
        self.compiled = uses_compiled_mdp(simulator)
        """Whether each step's MDP runs as :mod:`marlander_lite.task_kernels` (the same bits as the numpy reference):
        when numba runs (``MARLANDER_LITE_ENGINE``, or the simulator's ``engine``) and the plate is level."""
        if self.compiled:
            p_max, _, v_max, w_max = task.OBS_LIMITS
            self._limits = np.array([p_max, v_max, w_max], dtype=float)
            radius, speed_max = task.touchdown_limits(self.pad_radius, self.task)
            cfg = self.task
            self._constants = np.array(
                [radius, speed_max, cfg.alpha, cfg.beta, cfg.c, cfg.arena_half_width, cfg.arena_height], dtype=float
            )

    def seed(self, seed: int | None) -> None:
        """Restart the random generator: the same seed gives the same resets and noise."""
        self.rng = np.random.default_rng(seed)

    def true_observations(self) -> np.ndarray:
        """Eq. 2 observations of the current state without noise or latency, ``(num_envs, N, 13)`` (and the extras
        the task asks for; the pad acceleration is the current estimate, which exists only from observations). One
        frame: with ``TaskConfig.observation_history`` the older frames are those the policy saw."""
        return self._with_acceleration(self._measure(self.sim.state(), self.previous_command)[2])

    def _with_acceleration(self, obs: np.ndarray, env_ids: np.ndarray | slice = slice(None)) -> np.ndarray:
        if not self._observes_acceleration:
            return obs
        return np.concatenate([obs, self.pad_acceleration[env_ids]], axis=-1)

    def _estimate_acceleration(self, seen: np.ndarray) -> np.ndarray:
        """Update the pad-acceleration estimate from the observations the policy gets now, and append it."""
        if not self._observes_acceleration:
            return seen
        pad_vel = seen[..., PLATFORM_VELOCITY]
        self.pad_acceleration = acceleration_step(self.pad_acceleration, self._seen_pad_vel, pad_vel, self.task.dt)
        self._seen_pad_vel = pad_vel.copy()
        return self._with_acceleration(seen)

    def carried_pad_velocity(self) -> np.ndarray:
        """The pad velocity the next pad-frame command carries, ``(num_envs, N, 3)`` m/s: each pad's velocity now, led
        by ``TaskConfig.pad_frame_lead`` times its acceleration estimated from its velocity at each command
        (:func:`acceleration_step`, the deployment loop's estimate).

        Formed once per step, so reading it before :meth:`step` (a safety filter that works on the world command, as
        the deployment loop's does) changes nothing: :meth:`step` adds the same array.
        """
        pad_vel = self.sim.state().pad_vel
        if not self.leads_commands:
            return pad_vel
        if self._carried is None:
            self.carried_acceleration = acceleration_step(
                self.carried_acceleration, self._carried_pad_vel, pad_vel, self.task.dt
            )
            self._carried_pad_vel = np.array(pad_vel)
            leads = flight_leads(self.task, self.lead_tracker)
            self._carried = pad_vel + leads[:, None, None] * self.carried_acceleration
        return self._carried

    @property
    def leads_commands(self) -> bool:
        """Whether a pad-frame command's pad velocity is led (a fixed ``pad_frame_lead`` or one set in flight)."""
        return bool(self.task.pad_frame_lead or self.lead_tracker is not None)

    def pad_frame_leads(self) -> np.ndarray:
        """The lead (s) of every env's next pad-frame command ``(num_envs,)``: ``TaskConfig.pad_frame_lead``, or with
        ``pad_frame_lead_share`` that share of each env's tracker lag identified so far."""
        return np.broadcast_to(flight_leads(self.task, self.lead_tracker), (self.num_envs,)).copy()

    def _identify_tracker(self, seen: np.ndarray, env_ids: np.ndarray | None = None) -> None:
        """Feed the lead's tracker identification and the vertical bias's the observed ``p`` and ``v`` of eq. 2
        (``seen``, one frame per env in ``env_ids``; None: every env after a step) and the pads' velocities."""
        if self.vertical_bias is None and self.lead_tracker is None:
            return  # the training path: nothing to identify, no state to read
        pad_vel = self.sim.state().pad_vel
        if self.vertical_bias is not None:
            if env_ids is None:
                velocity = seen[..., task.EQ2_VELOCITY] + pad_vel
                self.vertical_bias.observe(seen[..., task.EQ2_POSITION], velocity)
            else:  # a new episode: nothing identified, and no sample across the reset
                self.vertical_bias.reset(env_ids)
        if self.lead_tracker is None:
            return
        if env_ids is None:
            self.lead_tracker.observe(seen[..., task.EQ2_POSITION], seen[..., task.EQ2_VELOCITY], pad_vel)
        else:
            self.lead_tracker.restart(
                env_ids, seen[..., task.EQ2_POSITION], seen[..., task.EQ2_VELOCITY], pad_vel[env_ids]
            )

    def _measure(self, s: SwarmState, command: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rel_pos = s.pos - (s.pad_pos + self._goal_lift)
        rel_vel = s.vel - s.pad_vel
        pad_vel = s.pad_vel if self.task.observe_platform_velocity else None
        command = command if self.task.observe_previous_command else None
        return rel_pos, rel_vel, task.observe(rel_pos, s.quat, rel_vel, s.ang_vel, pad_vel, command)

    def _evaluate(self, s: SwarmState, command: np.ndarray) -> tuple[np.ndarray, ...]:
        """:func:`marlander_lite.task_kernels.evaluate_step` on fresh arrays: ``(obs, rel_pos, dist, speed,
        horizontal, landed_now, crashed, r_drones, out)``, as the numpy lines of :meth:`step` compute them."""
        e, n = self.num_envs, self.num_drones
        obs = np.empty((e, n, self._channel_width), order="F")
        rel_pos = np.empty((e, n, 3), order="F")
        dist, speed, horizontal, r_drones = (np.empty((e, n), order="F") for _ in range(4))
        landed_now, crashed, out = (np.empty((e, n), dtype=bool, order="F") for _ in range(3))
        s = fortran_state(s)
        _task_kernels().evaluate_step(
            s.pos, s.quat, s.vel, s.ang_vel, s.pad_pos, s.pad_vel, s.contact, self._goal_lift,
            np.asfortranarray(command, dtype=float), self.landed, self.prev_dist, self._limits,
            self.task.observe_platform_velocity, self.task.observe_previous_command, self._constants, obs, rel_pos,
            dist, speed, horizontal, landed_now, crashed, r_drones, out,
        )  # fmt: skip
        return obs, rel_pos, dist, speed, horizontal, landed_now, crashed, r_drones, out

    def pad_offset(self, rel_pos: np.ndarray) -> np.ndarray:
        """Distance of each drone from its pad centre within the pad plane, ``(num_envs, N)`` m.

        This is what touchdown compares with the pad radius and what a landing records as its error. On a
        level pad it is the horizontal distance; on an inclined plate it is measured in the pad frame
        (:func:`marlander_lite.task.pad_frame_errors`), so a drone that sinks straight down onto a pad tilted by
        ``theta`` lands ``landed_height * tan(theta)`` off its centre.
        """
        if not self._inclined:
            return np.sqrt(rel_pos[..., 0] ** 2 + rel_pos[..., 1] ** 2)
        return task.pad_frame_errors(rel_pos, self.pad_normal)[1]

    def reset(self, env_ids: np.ndarray | None = None) -> np.ndarray:
        """Start new episodes in ``env_ids`` (all by default); returns their observations ``(k, N, 13)``."""
        ids = np.arange(self.num_envs) if env_ids is None else np.asarray(env_ids)
        if ids.dtype == bool:
            ids = np.flatnonzero(ids)
        self.sim.reset(ids, self.rng)
        if self.compiled:
            s = fortran_state(self.sim.state())
            obs = np.empty((len(ids), self.num_drones, self._channel_width), order="F")
            dist = np.empty((len(ids), self.num_drones), order="F")
            _task_kernels().observe_envs(
                ids.astype(np.int64, copy=False), s.pos, s.quat, s.vel, s.ang_vel, s.pad_pos, s.pad_vel,
                self._goal_lift, self._limits, self.task.observe_platform_velocity, self.task.observe_previous_command,
                obs, dist,
            )  # fmt: skip
            _task_kernels().start_episodes(
                ids.astype(np.int64, copy=False), s.pos, dist, self.steps, self.landed, self.prev_dist,
                self.landing_error, self.landing_time, self.episode_return, self.previous_command, self.min_separation,
            )  # fmt: skip
        else:
            s = self.sim.state().take(ids)
            rel_pos, _, obs = self._measure(s, np.zeros_like(s.vel))
            self.steps[ids] = 0
            self.landed[ids] = False
            self.prev_dist[ids] = vector_norm(rel_pos)
            self.landing_error[ids] = np.nan
            self.landing_time[ids] = np.nan
            self.episode_return[ids] = 0.0
            self.previous_command[ids] = 0.0
            self.min_separation[ids] = task.min_separation(s.pos)
        seen = self.channel.reset(ids, obs, self.rng)
        if self._observes_acceleration:
            self.pad_acceleration[ids] = 0.0
            self._seen_pad_vel[ids] = seen[..., PLATFORM_VELOCITY]
        self._identify_tracker(seen, ids)
        if self.leads_commands:
            self.carried_acceleration[ids] = 0.0
            self._carried_pad_vel[ids] = self.sim.state().pad_vel[ids]
            if self._carried is not None:  # formed this step: a new episode's first command carries its pad as it is
                self._carried[ids] = self._carried_pad_vel[ids]
        return self.history.reset(self._with_acceleration(seen, ids), ids)

    def relaunch(self, drones: np.ndarray) -> np.ndarray:
        """Start the drones where ``drones`` ``(num_envs, N)`` is True afresh, mid-episode, from new random starts (the
        simulator's ``relaunch``) while the others fly on; returns their first observations as the policy sees them,
        ``(k, 13)`` (or the task's stacked size) for the ``k`` drones in ``drones`` (row-major order). Not part of the
        paper's MDP: the per-drone episode ends of :class:`~marlander_lite.swarm.vec_env.SharedSwarmVecEnv`, a training
        aid, use it.
        """
        relaunch = getattr(self.sim, "relaunch", None)
        if relaunch is None:
            raise TypeError(f"{type(self.sim).__name__} cannot relaunch single drones; the point-mass swarm can.")
        if self._observes_acceleration:
            raise ValueError("Relaunching single drones needs observe_platform_acceleration=False.")
        drones = np.asarray(drones, dtype=bool)
        relaunch(drones, self.rng)
        rel_pos, _, obs = self._measure(self.sim.state(), np.zeros_like(self.previous_command))
        self.landed[drones] = False
        self.prev_dist[drones] = vector_norm(rel_pos)[drones]
        self.landing_error[drones] = np.nan
        self.landing_time[drones] = np.nan
        self.previous_command[drones] = 0.0
        return self.history.reset(self.channel.restart(drones, obs, self.rng), drones)

    def step(self, action: np.ndarray) -> StepOutcome:
        """Apply normalised actions (eq. 3) in every env and evaluate the MDP.

        ``action`` is ``(num_envs, 3N)`` or ``(num_envs, N, 3)`` in ``[-1, 1]``. Environments
        that end are *not* reset here: call :meth:`reset` with their ids.
        """
        cfg = self.task
        velocity = task.action_to_velocity(action, self.num_drones, cfg.max_speed)
        if velocity.shape[0] != self.num_envs:
            raise ValueError(f"Action batch has {velocity.shape[0]} environments; expected {self.num_envs}.")
        if cfg.command_frame != "world":
            velocity = task.in_command_frame(velocity, cfg, self.carried_pad_velocity())
        if self.vertical_bias is not None:  # a flight setting: the bias identified so far taken off, and recorded
            velocity = self.vertical_bias.compensate(velocity)
            self.vertical_bias.commanded(velocity)
        if self.lead_tracker is not None:
            self.lead_tracker.commanded(velocity)
        self.sim.step(velocity)
        self._carried = None
        s = self.sim.state()
        active = ~self.landed
        if self.compiled:  # the same formulas as below, in one compiled pass
            obs, rel_pos, dist, speed, horizontal, landed_now, crashed, r_drones, out = self._evaluate(s, velocity)
        else:
            rel_pos, rel_vel, obs = self._measure(s, velocity)
            dist = vector_norm(rel_pos)
            speed = vector_norm(rel_vel)
            horizontal = self.pad_offset(rel_pos)
            landed_now, crashed = task.touchdown_outcome(
                s.contact, horizontal, speed, self.landed, self.pad_radius, cfg
            )
            r_drones = task.drone_rewards(self.prev_dist, dist, speed, landed_now, active, cfg)
            out = task.outside_arena(s.pos, cfg) & active
        if cfg.landing_precision_bonus:
            r_drones += training_aids.landing_precision_reward(horizontal, landed_now, self.pad_radius, cfg)
        if training_aids.uses_training_penalties(cfg):
            penalty = training_aids.training_aid_penalty(
                velocity, rel_pos, s.vel, s.pad_vel, cfg, self.previous_command
            )
            r_drones -= penalty * active
        self.previous_command[...] = velocity
        separation = task.min_separation(s.pos)
        collided = separation < cfg.collision_distance
        np.minimum(self.min_separation, separation, out=self.min_separation)
        self.landed |= landed_now
        all_landed = self.landed.all(axis=-1)
        reward = task.team_reward(r_drones, collided, all_landed & landed_now.any(axis=-1), cfg)
        self.steps += 1
        terminated = all_landed | crashed.any(axis=-1) | collided | out.any(axis=-1)
        truncated = (self.steps >= cfg.max_steps) & ~terminated
        if landed_now.any():
            self.landing_error[landed_now] = horizontal[landed_now]
            self.landing_time[landed_now] = np.broadcast_to(self.steps[:, None] * cfg.dt, landed_now.shape)[landed_now]
            self.sim.land(landed_now)
        self.prev_dist = dist
        self.episode_return += reward
        seen = self.channel.observe(obs, self.rng)
        self._identify_tracker(seen)
        return StepOutcome(
            obs=self.history.push(self._estimate_acceleration(seen)),
            reward=reward,
            drone_rewards=r_drones,
            terminated=terminated,
            truncated=truncated,
            landed=self.landed.copy(),
            landed_now=landed_now,
            crashed=crashed,
            collided=collided,
            out_of_arena=out,
            success=all_landed,
            landing_error=self.landing_error.copy(),
            landing_time=self.landing_time.copy(),
            min_separation=self.min_separation.copy(),
            rel_speed=speed,
            episode_return=self.episode_return.copy(),
            episode_length=self.steps.copy(),
        )
