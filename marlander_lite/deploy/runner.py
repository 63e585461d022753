"""The policy runner: estimate -> eq. 2 observation -> exported policy -> clamped velocity setpoints.

The observation is built by :func:`marlander_lite.task.observe`, the function both simulators
use, from the estimated state: position relative to the goal point (pad centre raised by
``landed_height``), attitude, velocity relative to the pad, angular velocity. It is then fed to
one of two kinds of policy file (:mod:`marlander_lite.policy_file`):

* a **centralised** policy (the paper's) gets every drone's observation flattened
  (:func:`marlander_lite.task.flatten_observations`, ``(1, 13 N)``) and returns one normalised
  action per drone, ``(1, 3 N)``; it flies the swarm size it was trained for only;
* a **shared** policy (beyond the paper, :mod:`marlander_lite.swarm`) gets, for every drone, its
  own eq. 2 observation plus its ``k`` nearest neighbours within the sensing range, built by
  :func:`marlander_lite.swarm.observation.shared_observations`, the very function the simulators
  train it with, and runs as one batch: one forward pass over ``(N, 13 + 7 k)`` inputs gives the
  ``(N, 3)`` actions, for any N.

Either way :func:`marlander_lite.task.action_to_velocity` turns the actions into m/s, and the lab
speed limit then scales each velocity down to at most ``max_speed`` (its direction kept): the
firmware does not clamp velocity setpoints.

Not in the paper: :meth:`PolicyRunner.filter_velocity` then passes the velocities through the safety
filter of :mod:`marlander_lite.swarm.safety_filter` (config section ``safety_filter``), the one the
simulators' ``shared-filter`` controller uses: each command changes as little as needed for every pair
of drones to keep ``n . (u_i - u_j) >= -gamma (d - d_s)`` (they stay ``d_s`` apart), for no drone to be
pushed down, and for each to descend no faster than it can brake to ``v_td`` and not below a cone
beside its pad; the result is speed-clamped again. With the filter's ``latency_compensation`` ``L`` the policy and
the filter's guards read the estimate predicted ``L`` ahead (:meth:`PolicyRunner.ahead`), where each drone and pad
will be when the command acts; the separation rules and the mission's safety rules keep the estimate as measured.
With the filter's ``identified_lag_share`` ``s`` the runner identifies the drones' velocity tracker in flight
(:class:`~marlander_lite.swarm.tracker_lag.TrackerLag`, from the setpoints sent and the velocities that followed) and
``L`` becomes ``s`` times its time constant.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Protocol

import numpy as np

from marlander_lite import task
from marlander_lite.deploy.estimation import SwarmEstimate
from marlander_lite.observation_history import ObservationHistory
from marlander_lite.pad_frame_lead import flight_leads, lead_tracker
from marlander_lite.swarm.observation import shared_observations
from marlander_lite.swarm.pad_acceleration import PadAcceleration
from marlander_lite.swarm.safety_filter import SafetyFilterConfig, filter_commands
from marlander_lite.swarm.vertical_bias import VerticalBias
from marlander_lite.task import TaskConfig


class Policy(Protocol):
    """Anything that maps observations to actions in [-1, 1] (e.g. ``MLPPolicy``).

    A centralised policy maps ``(1, 13 N)`` to ``(1, 3 N)``; a shared one (its ``contract.neighbours``
    set) maps ``(N, 13 + 7 k)`` to ``(N, 3)``.
    """

    def act(self, obs: np.ndarray) -> np.ndarray: ...


class InvalidAction(ValueError):
    """The policy returned something that is not a finite action in [-1, 1]."""


def clamp_speed(velocity: np.ndarray, max_speed: float) -> np.ndarray:
    """Scale each row of ``velocity`` ``(N, 3)`` (m/s) down to a norm of at most ``max_speed``, direction kept."""
    speed = np.linalg.norm(velocity, axis=-1, keepdims=True)
    return velocity * np.minimum(1.0, max_speed / np.maximum(speed, 1e-12))


class PolicyRunner:
    """Runs a policy on estimates.

    Args:
        policy: the exported policy (``marlander_lite.deploy.config.load_lab_policy``): centralised,
            or shared when its ``contract.neighbours`` is set.
        task_config: the MDP constants the policy was trained with (``num_drones``, ``max_speed``).
        max_speed: lab speed limit (m/s).
        safety_filter: settings of the safety filter (``LabConfig.safety_filter``); None: no filter,
            :meth:`filter_velocity` returns the velocities as they are.
    """

    def __init__(
        self,
        policy: Policy,
        task_config: TaskConfig,
        max_speed: float,
        safety_filter: SafetyFilterConfig | None = None,
    ) -> None:
        self.policy, self.task, self.max_speed = policy, task_config, max_speed
        self.safety_filter = safety_filter
        self.pad_acceleration = PadAcceleration() if safety_filter is not None and safety_filter.pad_lead > 0 else None
        """The pads' acceleration for the filter's pad lead, from the estimates' pad velocities; None without a lead."""
        contract = getattr(policy, "contract", None)
        self.neighbours: int | None = None if contract is None else contract.neighbours
        """``k`` of a shared policy (its input holds the k nearest neighbours); None for a centralised one."""
        self.radius: float | None = None if contract is None else contract.neighbour_radius
        """Sensing range of a shared policy (m); None: the k nearest at any distance."""
        self.previous_command = np.zeros((task_config.num_drones, 3))
        """The velocity setpoint last sent to each drone under the policy ``(N, 3)`` m/s (zero for a hover), which a
        policy with ``TaskConfig.observe_previous_command`` reads; the mission keeps it up to date."""
        self.observed_acceleration = PadAcceleration() if task_config.observe_platform_acceleration else None
        """The pads' acceleration a policy with ``TaskConfig.observe_platform_acceleration`` reads, estimated from the
        estimates' pad velocities as the simulators estimate it from observed ones; None for other policies."""
        self._acceleration_at: tuple[float, np.ndarray] | None = None
        leads = task_config.pad_frame_lead > 0 or task_config.pad_frame_lead_share > 0
        self.carried_acceleration = PadAcceleration() if leads else None
        """The pads' acceleration that leads the pad velocity a pad-frame command carries
        (``TaskConfig.pad_frame_lead``), estimated as the simulators estimate it; None without a lead."""
        self._carried_at: tuple[float, np.ndarray] | None = None
        self.history = ObservationHistory(
            task_config.observation_history, (task_config.num_drones,), task_config.frame_per_drone
        )
        """The latest frames a policy with ``TaskConfig.observation_history`` reads: one frame per policy step (each
        new estimate time), the first frame in every slot at the first step, as after a reset in the simulators."""
        self._history_at: float | None = None
        self._identified_latency: float | None = None
        self._identified_step: float | None = None
        filter_lag = None if safety_filter is None else safety_filter.tracker_lag(task_config.dt)
        self.tracker_lag = filter_lag or lead_tracker(task_config)
        """The velocity tracker's time constant, identified from the setpoints sent (:attr:`previous_command`) and the
        velocities that followed, once per policy step; None unless the filter's ``identified_lag_share`` or
        ``low_velocity_step_lag``, or the task's ``pad_frame_lead_share`` (``limits.pad_frame_lead: auto``), is set."""
        self._lag_at: float | None = None
        self.vertical_bias = VerticalBias(task_config.dt) if task_config.vertical_bias_compensation else None
        """Each drone's steady vertical velocity bias, identified from the setpoints sent and the velocities that
        followed, once per policy step, and taken off the policy's vertical setpoints (:meth:`cancel_vertical_bias`);
        None unless ``TaskConfig.vertical_bias_compensation`` (``limits.vertical_bias``) is set."""
        self._bias_at: float | None = None

    @property
    def shared(self) -> bool:
        """Whether the policy is shared (one network per drone, any N) rather than centralised."""
        return self.neighbours is not None

    @property
    def latency_compensation(self) -> float:
        """``L`` (s) of the filter's latency compensation; 0 without a filter. With ``identified_lag_share`` ``s``,
        ``min(s T, 0.5)`` for the time constant ``T`` identified so far (:meth:`identify_lag`)."""
        if self.safety_filter is None:
            return 0.0
        if self._identified_latency is not None:
            return self._identified_latency
        return self.safety_filter.latency_compensation

    def identify_lag(self, est: SwarmEstimate) -> None:
        """Update the identified tracker time constant from the estimate of a new policy step (once per estimate
        time ``est.t``): the step from the last one, under the setpoints sent since (:attr:`previous_command`), is a
        sample when it lasted one policy period (within half of one); otherwise none is taken."""
        if self.tracker_lag is None or self._lag_at == est.t:
            return
        lag = self.tracker_lag
        if self._lag_at is not None:
            lag.commanded(self.previous_command[None])
            if abs(est.t - self._lag_at - self.task.dt) > 0.5 * self.task.dt:
                lag.skip()
        self._lag_at = est.t
        rel_goal, rel_vel = (est.pos - est.goal)[None], (est.vel - est.pad_vel)[None]
        time_constant = float(lag.observe(rel_goal, rel_vel, est.pad_vel[None])[0])
        if self.safety_filter is None:
            return
        if self.safety_filter.identified_lag_share > 0:
            self._identified_latency = min(self.safety_filter.identified_lag_share * time_constant, 0.5)
        if self.safety_filter.low_velocity_step_lag > 0:
            self._identified_step = float(self.safety_filter.velocity_step(time_constant))

    def identify_vertical_bias(self, est: SwarmEstimate) -> None:
        """Update each drone's identified vertical bias from the estimate of a new policy step (once per estimate time
        ``est.t``), under the setpoints sent since (:attr:`previous_command`); a step that did not last one policy
        period (within half of one) gives no sample."""
        if self.vertical_bias is None or self._bias_at == est.t:
            return
        if self._bias_at is not None:
            self.vertical_bias.commanded(self.previous_command[None])
            if abs(est.t - self._bias_at - self.task.dt) > 0.5 * self.task.dt:
                self.vertical_bias.skip()
        self._bias_at = est.t
        self.vertical_bias.observe((est.pos - est.goal)[None], est.vel[None])

    def cancel_vertical_bias(self, velocity: np.ndarray) -> np.ndarray:
        """The setpoints ``velocity`` ``(N, 3)`` m/s with each drone's identified vertical bias taken off, clamped to
        the policy's top speed; ``velocity`` itself without ``TaskConfig.vertical_bias_compensation``."""
        if self.vertical_bias is None:
            return velocity
        return clamp_speed(self.vertical_bias.compensate(velocity[None])[0], self.max_speed)

    @property
    def velocity_step(self) -> float:
        """The step (m/s) of the filter's velocity-step limit; 0 without a filter. With ``low_velocity_step_lag``,
        scaled by the time constant identified so far (:meth:`SafetyFilterConfig.velocity_step`)."""
        if self.safety_filter is None:
            return 0.0
        if self._identified_step is not None:
            return self._identified_step
        return self.safety_filter.low_velocity_step

    def ahead(self, est: SwarmEstimate) -> SwarmEstimate:
        """The estimate predicted :attr:`latency_compensation` ahead at constant velocity: every drone at
        ``pos + vel L``, every pad (and goal) at ``pad_pos + pad_vel L``; ``est`` itself without compensation.
        Eq. 2's ``p`` then moves by ``(vel - pad_vel) L``, as :func:`~marlander_lite.swarm.safety_filter.
        predict_observations` moves it in the simulators."""
        lead = self.latency_compensation
        if not lead:
            return est
        return replace(
            est,
            t=est.t + lead,
            pos=est.pos + lead * est.vel,
            pad_pos=est.pad_pos + lead * est.pad_vel,
            goal=est.goal + lead * est.pad_vel,
        )

    def observe(self, est: SwarmEstimate) -> np.ndarray:
        """Eq. 2 for every drone, ``(N, 13)``, with the extras the policy asks for (up to ``(N, 22)``: the platform
        velocity, the previous command, the platform acceleration), from the estimate predicted
        :attr:`latency_compensation` ahead; with ``TaskConfig.observation_history`` ``H`` such frames, newest first
        (``(N, 22 H)``), the history advanced once per estimate time ``est.t``."""
        acceleration = self.pad_acceleration_estimate(est)
        self.identify_lag(est)
        self.identify_vertical_bias(est)
        t, est = est.t, self.ahead(est)
        pad_vel = est.pad_vel if self.task.observe_platform_velocity else None
        command = self.previous_command if self.task.observe_previous_command else None
        frame = task.observe(
            est.pos - est.goal, est.quat, est.vel - est.pad_vel, est.ang_vel, pad_vel, command, acceleration
        )
        if self.history.history == 1:
            return frame
        if self._history_at is None:
            stacked = self.history.reset(frame)
        elif self._history_at != t:
            stacked = self.history.push(frame)
        else:  # the same instant observed again: this frame replaces the newest, the older ones stay
            stacked = self.history.replace_newest(frame)
        self._history_at = t
        return stacked

    def pad_acceleration_estimate(self, est: SwarmEstimate) -> np.ndarray | None:
        """Each pad's acceleration ``(N, 3)`` m/s^2 for the observation, updated once per estimate time ``est.t``
        (observing the same estimate twice does not count as a zero-second step); None unless the policy reads it."""
        if self.observed_acceleration is None:
            return None
        if self._acceleration_at is None or self._acceleration_at[0] != est.t:
            self._acceleration_at = (est.t, self.observed_acceleration.update(est.pad_vel, est.t))
        return self._acceleration_at[1]

    def carried_pad_velocity(self, est: SwarmEstimate) -> np.ndarray:
        """The pad velocity a pad-frame command carries ``(N, 3)`` m/s (pass it to :meth:`act`): ``est.pad_vel``, led
        by ``TaskConfig.pad_frame_lead`` times the pads' acceleration estimated from their velocities, updated once per
        estimate time ``est.t``. Raises :class:`InvalidAction` on a pad velocity that is not finite: the loop hovers."""
        if self.carried_acceleration is None:
            return est.pad_vel
        if self._carried_at is None or self._carried_at[0] != est.t:
            try:
                self._carried_at = (est.t, self.carried_acceleration.update(est.pad_vel, est.t))
            except ValueError as error:
                raise InvalidAction(str(error)) from None
        return est.pad_vel + self.pad_frame_lead * self._carried_at[1]

    @property
    def pad_frame_lead(self) -> float:
        """The lead (s) of the next pad-frame command: ``TaskConfig.pad_frame_lead``, or with ``pad_frame_lead_share``
        that share of the tracker lag identified so far (:meth:`identify_lag`; :mod:`marlander_lite.pad_frame_lead`)."""
        tracker = self.tracker_lag if self.task.pad_frame_lead_share > 0 else None
        return float(flight_leads(self.task, tracker)[0])

    def policy_input(self, obs: np.ndarray, goals: np.ndarray | None = None) -> np.ndarray:
        """What the network reads: ``(1, 13 N)`` for a centralised policy, ``(N, 13 + 7 k)`` for a shared one.

        Args:
            obs: eq. 2 for every drone ``(N, 13)`` (:meth:`observe`).
            goals: every drone's goal point ``(N, 3)`` m (``SwarmEstimate.goal``); a shared policy needs it to
                place its neighbours (``x_j - x_i = (p_j + g_j) - (p_i + g_i)``), a centralised one ignores it.
        """
        if not self.shared:
            return task.flatten_observations(obs[None])
        if goals is None:
            raise ValueError("A shared policy needs the drones' goal points to sense its neighbours; pass goals.")
        # shared_observations takes pad offsets relative to the plate and uses only their differences: the goals
        # relative to their mean are those offsets (plus the common lift) for pads on one plate, and any layout.
        goals = np.asarray(goals, dtype=np.float64)
        return shared_observations(obs, goals - goals.mean(axis=0), int(self.neighbours), self.radius)  # type: ignore[arg-type]

    def act(
        self, obs: np.ndarray, goals: np.ndarray | None = None, pad_vel: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(action (3N,) in [-1, 1], clamped velocity (N, 3) m/s)``; raises :class:`InvalidAction`.

        ``goals`` ``(N, 3)`` is needed by a shared policy (see :meth:`policy_input`), and each pad's estimated
        velocity ``pad_vel`` ``(N, 3)`` m/s by a policy whose commands are relative to its pad
        (``TaskConfig.command_frame`` ``"pad"``; the velocity then carries the pad's). Whatever the policy, the
        action is checked the same way: ``3 N`` numbers, finite, within [-1, 1].
        """
        if self.task.command_frame == "pad" and pad_vel is None:
            raise ValueError("This policy commands velocities relative to its pad: pass the pads' velocities, pad_vel.")
        x = self.policy_input(obs, goals)
        try:
            action = np.asarray(self.policy.act(x), dtype=float).reshape(-1)  # one call: the whole swarm at once
        except (ValueError, FloatingPointError) as error:
            raise InvalidAction(f"the policy failed: {error}") from None
        n3 = self.task.act_dim
        if action.shape != (n3,):
            raise InvalidAction(f"the policy returned {action.size} numbers; {n3} expected")
        if not np.isfinite(action).all() or np.abs(action).max() > 1.0 + 1e-6:
            raise InvalidAction(f"the action {np.round(action, 3).tolist()} is not finite and within [-1, 1]")
        velocity = task.action_to_velocity(action, self.task.num_drones, self.task.max_speed)
        if pad_vel is not None:  # a pad-frame policy's command carries its pad (task.in_command_frame)
            try:
                velocity = task.in_command_frame(velocity, self.task, np.asarray(pad_vel, dtype=float)[None])
            except ValueError as error:  # a pad velocity that is not finite: no command can be formed, so hover
                raise InvalidAction(str(error)) from None
        velocity = velocity[0]
        return action, clamp_speed(velocity, self.max_speed)

    def filter_velocity(
        self, velocity: np.ndarray, est: SwarmEstimate, settled: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The velocity setpoints ``(N, 3)`` m/s through the safety filter, and ``(N,)`` bool: which it changed.

        Args:
            velocity: the policy's clamped velocities (:meth:`act`), world frame (m/s).
            est: this tick's estimate, as measured: the filter reads the drones' positions ``est.pos`` and
                velocities ``est.vel`` (world frame; only their differences keep drones apart) and eq. 2's
                ``p = pos - goal``, predicted :attr:`latency_compensation` ahead (:meth:`ahead`; for the guards, and to
                let the drone nearer its pad keep its line).
            settled: ``(N,)`` bool, drones that will not move (landed, landing, down): the filter leaves their
                setpoints alone and their neighbours keep clear of them alone.

        Without a filter (``safety_filter`` None) ``velocity`` itself comes back, none changed. A filter that
        cannot work on the estimate (not finite) raises :class:`InvalidAction`: the loop hovers.
        """
        if self.safety_filter is None:
            return velocity, np.zeros(len(velocity), dtype=bool)
        ahead = self.ahead(est)
        try:
            lead = None if self.pad_acceleration is None else self.pad_acceleration.update(est.pad_vel, est.t)
            return filter_commands(
                est.pos,
                est.vel,
                velocity,
                self.safety_filter,
                settled=settled,
                rel_goal=ahead.pos - ahead.goal,
                max_speed=self.max_speed,
                pad_acceleration=lead,
                pad_velocity=est.pad_vel,
                velocity_step=self.velocity_step,
            )
        except ValueError as error:
            raise InvalidAction(f"the safety filter failed: {error}") from None


def describe_filtering(names: list[str], i: int, est: SwarmEstimate, before: np.ndarray, after: np.ndarray) -> str:
    """What the safety filter did to drone ``i``'s setpoint (``before`` -> ``after``, m/s), for the flight log:
    with its nearest neighbour's distance (m) and its height above its goal (m)."""
    gap = np.linalg.norm(est.pos - est.pos[i], axis=-1)
    gap[i] = np.inf
    j = int(np.argmin(gap))
    near = f", nearest drone {names[j]} {gap[j]:.2f} m away" if len(names) > 1 else ""
    return (
        f"{names[i]}: the safety filter changes its command {np.round(before, 2).tolist()} -> "
        f"{np.round(after, 2).tolist()} m/s{near}, {est.pos[i, 2] - est.goal[i, 2]:.2f} m above its goal"
    )
