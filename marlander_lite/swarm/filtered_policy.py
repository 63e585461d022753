"""A simulated policy flown through the safety filter (:mod:`marlander_lite.swarm.safety_filter`), the way the
deployment loop flies a lab's drones: :func:`with_safety_filter` wraps a batch actor, :func:`with_safety_filter_on`
wraps one for a simulated swarm (:class:`~marlander_lite.episodes.LandingEpisodes`), reading from it what the loop
reads from motion capture (pad velocities, what a pad-frame command carries)."""

from __future__ import annotations

import itertools
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from marlander_lite.swarm.filter_config import SafetyFilterConfig
from marlander_lite.swarm.pad_acceleration import PadAcceleration
from marlander_lite.swarm.safety_filter import filter_actions, predict_observations
from marlander_lite.swarm.tracker_lag import TrackerLag
from marlander_lite.task import EQ2_POSITION, EQ2_VELOCITY, PLATFORM_VELOCITY

if TYPE_CHECKING:
    from marlander_lite.episodes import LandingEpisodes

BatchAct = Callable[[np.ndarray], np.ndarray]
"""Centralised observations of every env ``(E, 13 N)`` -> actions ``(E, 3 N)`` in [-1, 1]."""


def with_safety_filter(
    act: BatchAct,
    num_drones: int,
    pad_offsets: np.ndarray,
    max_speed: float,
    config: SafetyFilterConfig | None = None,
    policy_dt: float | None = None,
    observes_pad_velocity: bool = False,
    pads_move: bool = False,
    tracker_lag: TrackerLag | None = None,
    command_frame: str = "world",
    pad_velocity: Callable[[], np.ndarray] | None = None,
    carried_pad_velocity: Callable[[], np.ndarray] | None = None,
) -> BatchAct:
    """Wrap a batch actor (centralised observations ``(E, 13 N)`` -> actions ``(E, 3 N)`` in [-1, 1]) with
    :func:`filter_commands`: actions are read as commands of ``max_speed`` m/s per unit (eq. 3).

    Positions are eq. 2's goal-relative ``p`` plus each drone's pad offset ``(N, 3)`` m (the plate never yaws,
    so their differences are the drones' relative positions); velocities are eq. 2's ``v``.

    Some rules need each pad's velocity (m/s, world frame). The wrapper reads it from the observations when the policy
    observes it (``observes_pad_velocity``, the policy's ``TaskConfig.observe_platform_velocity``), or else from
    ``pad_velocity`` (no arguments -> ``(E, N, 3)``, read once per call): where the loop knows it otherwise, as the
    deployment loop does from motion capture whatever the policy (in a simulator, its state).
    With ``config.pad_lead`` > 0 the wrapper estimates each pad's acceleration (:class:`PadAcceleration`) from those
    pad velocities, which needs them and the time between two calls, ``policy_dt`` (s).
    With ``config.latency_compensation`` > 0 the policy reads the observations predicted that far ahead
    (:func:`predict_observations`), and so do the filter's guards (:func:`filter_actions`).
    With ``config.identified_lag_share`` > 0 the wrapper identifies the tracker with ``tracker_lag`` (pass one to read
    what it identified; None: a new :class:`TrackerLag` starting from ``latency_compensation / identified_lag_share``)
    and sets ``L`` per env from it.
    With ``config.low_velocity_step`` > 0 the velocity-step limit compares commands with each drone's velocity in the
    world frame: eq. 2's ``v`` plus the pad velocity, or ``v`` itself on pads at rest. On pads that move
    (``pads_move``) it therefore needs the pad velocities. With ``config.low_velocity_step_lag`` > 0 it identifies the
    tracker as above (starting from ``low_velocity_step_lag`` unless ``identified_lag_share`` is set) and scales the
    step per env (:meth:`SafetyFilterConfig.velocity_step`).
    With ``command_frame`` ``"pad"`` (``TaskConfig.command_frame``) an action is a velocity relative to the pad: the
    filter works on the world command, the action plus the pad velocity the command carries, and hands back the
    filtered command relative to the pad again. That velocity comes from ``carried_pad_velocity`` (no arguments ->
    ``(E, N, 3)`` m/s, read once per call: what the loop will add, lead included, as the deployment loop filters
    the command it sends; e.g. :meth:`~marlander_lite.episodes.LandingEpisodes.carried_pad_velocity`), or else is the
    pad velocity itself (without a lead). On moving pads it needs one of them.
    """
    config = config or SafetyFilterConfig()
    knows_pad_velocity = observes_pad_velocity or pad_velocity is not None
    how = (
        "pass pad_velocity (the loop's, e.g. the simulator's state), or fly a policy trained with "
        "observe_platform_velocity, as the moving preset is"
    )
    if command_frame == "pad" and pads_move and not knows_pad_velocity and carried_pad_velocity is None:
        raise ValueError(
            "A pad-frame policy (command_frame='pad') on moving pads needs the pad velocity its commands carry for "
            f"the safety filter to see the world command: pass carried_pad_velocity (the loop's, e.g. "
            f"LandingEpisodes.carried_pad_velocity), or {how}; or fly it without the filter, or on static pads."
        )
    if config.low_velocity_step > 0 and pads_move and not knows_pad_velocity:
        raise ValueError(
            "low_velocity_step > 0 on moving pads needs each pad's velocity: without it the limit would hold the drone "
            f"to its velocity relative to the pad. {how[0].upper()}{how[1:]}; or fly it on static pads, or set "
            "low_velocity_step=0."
        )
    lag = None
    if config.identified_lag_share > 0 or config.low_velocity_step_lag > 0:
        if not policy_dt or (pads_move and not knows_pad_velocity):
            raise ValueError(
                "identified_lag_share > 0 or low_velocity_step_lag > 0 needs the policy period (policy_dt) and, on "
                "moving pads, each pad's velocity (the tracker is identified from world-frame velocities): "
                f"{how}. Or set both to 0."
            )
        lag = tracker_lag or config.tracker_lag(policy_dt)
    lead = None
    if config.pad_lead > 0:
        if not (knows_pad_velocity and policy_dt):
            raise ValueError(
                f"pad_lead > 0 needs each pad's velocity ({how}) and the policy period (policy_dt); or set pad_lead=0."
            )
        lead, calls = PadAcceleration(), itertools.count()
    offsets = np.asarray(pad_offsets, dtype=float)
    if offsets.shape != (num_drones, 3):
        raise ValueError(f"pad_offsets must be ({num_drones}, 3), got shape {offsets.shape}.")

    def filtered(obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=float)
        per_drone = obs.reshape(len(obs), num_drones, -1)
        pad_vel = None
        if observes_pad_velocity:
            pad_vel = per_drone[..., PLATFORM_VELOCITY]
        elif pad_velocity is not None:
            pad_vel = np.asarray(pad_velocity(), dtype=float)
        latency: float | np.ndarray = config.latency_compensation
        step = None
        if lag is not None:
            lags = lag.observe(per_drone[..., EQ2_POSITION], per_drone[..., EQ2_VELOCITY], pad_vel)
            if config.identified_lag_share > 0:
                latency = np.minimum(config.identified_lag_share * lags, 0.5)[:, None, None]  # (E, 1, 1) s
            if config.low_velocity_step_lag > 0:
                step = np.asarray(config.velocity_step(lags))[:, None]  # (E, 1) m/s
        ahead = predict_observations(per_drone, latency).reshape(obs.shape)
        command = np.asarray(act(ahead), dtype=float).reshape(len(obs), num_drones, 3)
        accel = None if lead is None else lead.update(pad_vel, next(calls) * policy_dt)
        frame_offset = None
        if command_frame == "pad":
            frame_offset = pad_vel if carried_pad_velocity is None else np.asarray(carried_pad_velocity(), dtype=float)
        actions, _ = filter_actions(
            per_drone, command, offsets, max_speed, config, accel, pad_vel, latency, frame_offset, step
        )
        if lag is not None:
            lag.commanded(actions * max_speed + (0.0 if frame_offset is None else frame_offset))
        return actions.reshape(len(obs), 3 * num_drones)

    return filtered


def with_safety_filter_on(
    act: BatchAct,
    episodes: LandingEpisodes,
    config: SafetyFilterConfig | None = None,
    tracker_lag: TrackerLag | None = None,
) -> BatchAct:
    """:func:`with_safety_filter` for an actor flying ``episodes``, the way the deployment loop filters its commands:
    the swarm size, speed, period, observations and command frame are the episodes' task's, the pad offsets and
    motion its plate's, and each pad's velocity comes from the simulator's state (motion capture's, in the lab), with
    what a pad-frame command carries (:meth:`~marlander_lite.episodes.LandingEpisodes.carried_pad_velocity`)."""
    task, sim = episodes.task, episodes.sim
    n = task.num_drones

    def pad_velocity() -> np.ndarray:
        return sim.state().pad_vel

    return with_safety_filter(
        act,
        n,
        sim.platform.geometry.pad_offsets(n),
        task.max_speed,
        config,
        policy_dt=task.dt,
        observes_pad_velocity=task.observe_platform_velocity,
        pads_move=sim.platform.is_moving,
        tracker_lag=tracker_lag,
        command_frame=task.command_frame,
        pad_velocity=pad_velocity,
        carried_pad_velocity=episodes.carried_pad_velocity if task.command_frame == "pad" else None,
    )
