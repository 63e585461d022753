"""A safety filter: the smallest change to the drones' velocity commands that keeps them apart and lands them softly.

Not in the paper. The paper's policy and ours learn to avoid each other through eq. 6's collision penalty
alone, and with 8 or 16 drones converging on pads 0.25 m apart they often do not (docs/scaling.md). A lab
flying a swarm wants rules that hold whatever the policy does. This module holds them, written once for the
simulators' evaluation (:mod:`marlander_lite.swarm.evaluation`, controller ``shared-filter``) and for the
deployment loop (:mod:`marlander_lite.deploy.runner`). It sits between any controller and the velocity
tracker, like a safety filter in the control-barrier-function literature, and works for any N.

**Separation** (a velocity-level control barrier function, after Wang, Ames and Egerstedt's safety
barrier certificates [Wang2016], docs/references.md). For two drones ``i`` and ``j`` let ``r = x_i - x_j`` be
their relative position *predicted* ``tau`` seconds ahead (``x + v tau``: a new command takes about that long
to change the velocity, through the tracker's lag and the sensing latency), ``d = |r|`` and ``n = r / d``.
The pair stays apart if its commands ``u`` satisfy

    ``n . (u_i - u_j) >= -gamma (d - d_s)``

the closing speed along ``n`` may be at most ``gamma`` times the distance left to the safety distance
``d_s``; once closer than ``d_s`` the pair must separate. The duty is split *reciprocally*: drone ``i``
takes a share ``s_ij``, ``n . u_i >= -s_ij gamma (d - d_s)``, with ``s_ij + s_ji = 1``, so no drone needs
the other's command. Shares are weighted by how far each drone still is from its goal
(``yield_distance``): the drone about to land keeps its line and the one passing by goes round; a drone
settled on its pad will not move, so the flying one takes all of it. Each drone's command is moved onto
the intersection of its half-spaces by cyclic projection (``iterations`` sweeps over its neighbours, nearest
first, so that renumbering the drones only renumbers the commands), which changes nothing when no rule
is violated. A violated pair also turns each drone to its left
(``sidestep``), so two drones flying straight at each other pass rather than stall nose to nose (the
classic deadlock of barrier functions). The filter never pushes a drone *down*: the lower drone of a
stacked pair, pushed down, touched its pad faster than 0.5 m/s.

**Wake.** Two flying drones ``dz`` apart vertically keep ``wake_radius + wake_slope dz`` apart horizontally
(the same cyclic projection, on horizontal normals): a drone's downwash pushes the one under it down, in
PyBullet's wake model with up to its whole weight.

**Descent guard.** The downward command is capped at the speed ``v`` from which the drone brakes to
``v_td`` within its height ``h`` above the goal: ``v^2 = v_td^2 + 2 a h`` without a response delay (the training
aid ``command_speed_penalty`` asks the same of the policy; here it is enforced).

**Approach guard.** A drone may not descend below ``min(slope (r - r_0), h_max)`` above its goal, ``r`` its
horizontal distance from it: it comes down over its pad, not beside it (issue "Policies that transfer"
asks for >= 0.3 m of height 0.5 m from the pad; clutter, ground effect and other pads do not forgive a
low approach). Below that surface its descent is braked at rate ``gamma``; by default it is never pushed up, and with
``approach_climb`` ``c`` it climbs back at ``c gamma`` per metre below the surface (a drone trailing its pad low over
the plate, on a slow tracker). With ``r_0`` = 5 mm the surface is almost a cone whose tip is the goal: the drone
centres itself over its pad as it comes down.

**Pad lead** (``pad_lead``, off by default). On a moving pad every command first gains ``T_lead`` times the pad's
acceleration, estimated from the pad velocities the loop observes (:class:`PadAcceleration`): a velocity tracker
with time constant ``T`` trails a pad that brakes or turns, and the lead cancels that lag when ``T_lead = T``.

**Latency compensation** (``latency_compensation``, off by default). A command computed from a pose ``L`` seconds
old acts ``L`` seconds late. With ``L`` set, the policy and the guards (descent, approach, centring) read each drone's
observation predicted ``L`` ahead at its present velocity (eq. 2's ``p + v L``, :func:`predict_observations`), as a
Smith predictor acts on the output predicted past a known delay [Smith1957] (docs/references.md), here from the
measured velocity, not a model. The separation and wake rules keep the measured positions: they predict ``tau``
ahead on their own, and predicting from the predicted positions too added collisions (docs/transfer.md). With
``identified_lag_share`` ``s`` each flight identifies its velocity tracker's time constant ``T`` from the commands it
sent and the velocities that followed (:mod:`marlander_lite.swarm.tracker_lag`) and ``L`` becomes ``min(s T, 0.5 s)``,
so that one setting fits fast and slow trackers.

**Velocity-step limit** (``low_velocity_step``, off by default). A velocity tracker tilts a drone in proportion to the
difference between its command and its velocity. Below ``h_max`` above its goal, a drone's horizontal command is
moved towards its horizontal velocity until the two differ by at most ``max(Delta, |v_rel|)``, ``v_rel`` its velocity
relative to its pad: it may always brake to its pad's velocity, but a swing across the pad is not reversed harder than
``Delta``. Through a tracker without a tilt limit such reversals tilted drones past 50 degrees a few centimetres over
their pads, and they met the floor sideways (docs/transfer.md, "A held-out tracker").

**Centring.** Over its pad (within the pad radius) and below ``h_max``, a drone's horizontal command gains
``-k_c`` times its horizontal offset from the goal. A policy that hovers a few centimetres off its pad centre
would otherwise wait at the approach guard until the flight time ran out; with the rule it is drawn to the
centre and lands there. It acts after the separation rule, at most ``k_c`` times the 0.1 m pad radius
(0.2 m/s with the default), and a drone a neighbour's separation rule holds off its pad centre is drawn back
towards it. Together with the approach guard it is what brings the shared policy's landing error
under the paper's 2.26 cm: the learned policy alone lands 3.4 cm from the centre (docs/scaling.md).

Measured with the shared policy, 200 trials, seed 0 (docs/scaling.md, where the tuning is described): at
N = 8 on the point mass it lands 36 % of swarms alone (57.5 % end in a collision) and 98.0 % through this
filter, without a collision, 1.27 cm from the pad centres; at N = 16, 7.5 % and 95.5 %; in PyBullet through
the firmware's velocity tracker at N = 8 (100 trials), 22 % and 98 %. Only relative positions and velocities
enter the separation and wake rules, so any common frame will do.

Where things are: the settings in :mod:`marlander_lite.swarm.filter_config` (re-exported here), the rules in this
module (:func:`filter_commands`, and :func:`filter_actions` on eq. 3 actions), and the wrappers that put the filter
between a simulated policy and its simulator in :mod:`marlander_lite.swarm.filtered_policy`.
"""

from __future__ import annotations

import numpy as np

from marlander_lite.platforms import PlateGeometry
from marlander_lite.swarm.filter_config import (
    MOVING_PAD_SETTINGS,
    NAMED_SETTINGS,
    PAD_FRAME_SETTINGS,
    SafetyFilterConfig,
    parse_settings,
)
from marlander_lite.task import EQ2_POSITION, EQ2_VELOCITY

__all__ = [
    "MOVING_PAD_SETTINGS",
    "NAMED_SETTINGS",
    "PAD_FRAME_SETTINGS",
    "PAD_RADIUS",
    "SafetyFilterConfig",
    "filter_actions",
    "filter_commands",
    "parse_settings",
    "predict_observations",
    "settled_drones",
]

_EPS = 1e-9
PAD_RADIUS = PlateGeometry().pad_radius
"""m: a drone within this horizontal distance of its goal, low and slow, counts as settled (the plate's pad radius)."""


def predict_observations(obs: np.ndarray, seconds: float | np.ndarray) -> np.ndarray:
    """Eq. 2 observations ``(..., N, >= 13)`` predicted ``seconds`` ahead at constant velocity: ``p + v seconds``.

    ``p`` is the drone's position minus its goal and ``v`` its velocity relative to the pad, so ``dp/dt = v``
    whether the pad moves or not; attitude, velocities and the extras are kept. ``seconds`` is a number or an array
    that broadcasts against ``(..., N, 1)`` (one per env: ``(E, 1, 1)``). With ``seconds`` > 0 a new array; with 0
    (compensation off, the default) ``obs`` itself as floats, so that every filtered step does not copy it."""
    if np.ndim(seconds) == 0 and not seconds:
        return np.asarray(obs, dtype=float)
    predicted = np.array(obs, dtype=float)
    predicted[..., EQ2_POSITION] += seconds * predicted[..., EQ2_VELOCITY]
    return predicted


def settled_drones(rel_goal: np.ndarray, vel: np.ndarray, config: SafetyFilterConfig) -> np.ndarray:
    """Drones resting on their pads, ``(..., N)`` bool, from eq. 2's ``p`` (position minus goal, m) and ``v``
    (velocity relative to the pad, m/s), both ``(..., N, 3)``."""
    rel_goal, vel = np.asarray(rel_goal, dtype=float), np.asarray(vel, dtype=float)
    low = np.abs(rel_goal[..., 2]) < config.settled_distance
    over_pad = np.hypot(rel_goal[..., 0], rel_goal[..., 1]) < PAD_RADIUS
    slow = np.linalg.norm(vel, axis=-1) < config.settled_speed
    return low & over_pad & slow


def filter_commands(
    positions: np.ndarray,
    velocities: np.ndarray,
    commands: np.ndarray,
    config: SafetyFilterConfig | None = None,
    settled: np.ndarray | None = None,
    rel_goal: np.ndarray | None = None,
    max_speed: float | None = None,
    pad_acceleration: np.ndarray | None = None,
    pad_velocity: np.ndarray | None = None,
    velocity_step: float | np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Velocity commands changed as little as the rules allow (module docstring).

    Args:
        positions: drone positions ``(..., N, 3)`` m, any common frame.
        velocities: drone velocities ``(..., N, 3)`` m/s.
        commands: the controller's velocity commands ``(..., N, 3)`` m/s.
        config: thresholds; :class:`SafetyFilterConfig` defaults when None.
        settled: ``(..., N)`` bool, drones resting on their pads (left alone; their partners take the whole
            duty); None: nobody settled.
        rel_goal: each drone's position minus its goal ``(..., N, 3)`` m (eq. 2's ``p``), for the split of the
            duty and the guards; None: equal split, no guards. With latency compensation the callers pass it
            predicted (``p + v L``) while ``positions`` stay as measured.
        max_speed: commands are scaled down to this speed (m/s) at the end; None: no cap.
        pad_acceleration: each drone's pad's acceleration ``(..., N, 3)`` m/s^2 (:class:`PadAcceleration`); with
            ``config.pad_lead`` > 0 every command first gains ``pad_lead`` times it (the pad lead); None: no lead.
        pad_velocity: each drone's pad's velocity ``(..., N, 3)`` m/s, in the frame of ``velocities``, for the
            velocity-step limit (which needs each drone's velocity in that frame and relative to its pad); None: the
            pads are at rest in that frame.
        velocity_step: the velocity-step limit's step (m/s), a number or ``(..., 1)`` (one per env, as
            :meth:`SafetyFilterConfig.velocity_step` scales it); None: ``config.low_velocity_step``. Only with
            ``config.low_velocity_step`` > 0.

    Returns:
        ``(filtered, acted)``: commands ``(..., N, 3)`` m/s and ``(..., N)`` bool, True where a drone's command
        was changed.
    """
    config = config or SafetyFilterConfig()
    pos, vel = np.asarray(positions, dtype=float), np.asarray(velocities, dtype=float)
    command = np.asarray(commands, dtype=float)
    if pos.shape != command.shape or vel.shape != command.shape or command.shape[-1:] != (3,):
        raise ValueError(
            f"positions, velocities and commands must share one (..., N, 3) shape; got {pos.shape}, {vel.shape} "
            f"and {command.shape}."
        )
    for name, array in (("positions", pos), ("velocities", vel), ("commands", command)):
        if not np.isfinite(array).all():
            raise ValueError(f"filter_commands() got a NaN or infinite value in {name}; the filter needs finite input.")
    n = command.shape[-2]
    settled = np.zeros(command.shape[:-1], bool) if settled is None else np.asarray(settled, dtype=bool)
    goal = None if rel_goal is None else np.asarray(rel_goal, dtype=float)
    requested = command
    if config.pad_lead > 0 and pad_acceleration is not None:
        lead = config.pad_lead * np.asarray(pad_acceleration, dtype=float)
        if lead.shape != command.shape or not np.isfinite(lead).all():
            raise ValueError(f"pad_acceleration must be a finite {command.shape} array, got shape {lead.shape}.")
        command = command + lead  # the policy's command with the feed-forward, which every rule below starts from
    if config.low_velocity_step > 0 and goal is not None:
        relative = vel
        if pad_velocity is not None:
            pad_vel = np.asarray(pad_velocity, dtype=float)
            if pad_vel.shape != command.shape or not np.isfinite(pad_vel).all():
                raise ValueError(f"pad_velocity must be a finite {command.shape} array, got shape {pad_vel.shape}.")
            relative = vel - pad_vel
        step = config.low_velocity_step if velocity_step is None else velocity_step
        command = _limit_velocity_step(command, vel, relative, goal, config, step)
    u = command.copy()
    if n >= 2:
        u = _separate(pos, vel, u, settled, goal, config)
        u[..., 2] = np.maximum(u[..., 2], command[..., 2])  # never pushed down
    if goal is not None:
        u[..., 2] = np.maximum(u[..., 2], _lowest_vertical_command(goal, config))
        if config.centring_gain > 0:
            offset = goal[..., :2]
            over_pad = (np.hypot(offset[..., 0], offset[..., 1]) < PAD_RADIUS) & (goal[..., 2] < config.cone_height)
            u[..., :2] -= config.centring_gain * offset * over_pad[..., None]
    if max_speed is not None:
        speed = np.linalg.norm(u, axis=-1, keepdims=True)
        u *= np.minimum(1.0, max_speed / np.maximum(speed, _EPS))
    u = np.where(settled[..., None], command, u)
    if config.settled_sink_limit > 0:
        u[..., 2] = np.where(settled, np.maximum(u[..., 2], -config.settled_sink_limit), u[..., 2])
    return u, np.linalg.norm(u - requested, axis=-1) > 1e-9


def _separate(
    pos: np.ndarray,
    vel: np.ndarray,
    u: np.ndarray,
    settled: np.ndarray,
    goal: np.ndarray | None,
    config: SafetyFilterConfig,
) -> np.ndarray:
    """The separation rule: ``u`` projected onto every drone's half-spaces ``n_ij . u_i >= b_ij``."""
    n = u.shape[-2]
    predicted = pos + config.reaction_time * vel
    r = predicted[..., :, None, :] - predicted[..., None, :, :]  # (..., N, N, 3): x_i - x_j
    dist = np.linalg.norm(r, axis=-1)
    normal = r / np.maximum(dist, _EPS)[..., None]
    if goal is None:
        weight = np.ones(u.shape[:-1])
    else:
        weight = np.clip(np.linalg.norm(goal, axis=-1) / config.yield_distance, config.min_yield, 1.0)
    weight = np.where(settled, 0.0, weight)
    share = weight[..., :, None] / np.maximum(weight[..., :, None] + weight[..., None, :], _EPS)
    safety = np.where(settled[..., None, :], config.settled_min_distance, config.min_distance)
    bound = -share * config.gain * (dist - safety)
    pair = (dist < config.activation_distance) & ~np.eye(n, dtype=bool) & ~settled[..., :, None]
    bound = np.where(pair, bound, -np.inf)
    wake = _wake_rule(r, share, settled, config) if config.wake_slope > 0 else None
    if config.sidestep:
        violation = np.maximum(bound - np.einsum("...ijk,...ik->...ij", normal, u), 0.0)
        # n points from j to i, against i's approach: n x z is the approaching drone's left-hand side
        left = np.stack([normal[..., 1], -normal[..., 0], np.zeros_like(dist)], axis=-1)
        left /= np.maximum(np.linalg.norm(left, axis=-1, keepdims=True), _EPS)
        u = u + config.sidestep * np.einsum("...ij,...ijk->...ik", violation, left)
    # every drone visits its neighbours nearest first, so numbering the drones differently changes nothing
    order = np.argsort(dist, axis=-1, kind="stable")[..., 1:]  # (..., N, N - 1); position 0 is the drone itself
    rules = [(normal, bound)] + ([] if wake is None else [wake])
    rules = [
        (np.take_along_axis(m, order[..., None], axis=-2), np.take_along_axis(b, order, axis=-1)) for m, b in rules
    ]
    rules = [(m, b) for m, b in rules if np.isfinite(b).any()]  # rules with no pair in reach change nothing
    for _ in range(config.iterations if rules else 0):
        moved = False
        for k in range(n - 1):
            for m, b in rules:
                mk = m[..., :, k, :]
                short = np.maximum(b[..., :, k] - np.einsum("...ik,...ik->...i", mk, u), 0.0)
                if short.any():
                    u = u + short[..., None] * mk
                    moved = True
        if not moved:  # a sweep that changed nothing: every later one would repeat it exactly
            break
    return u


def _wake_rule(
    r: np.ndarray, share: np.ndarray, settled: np.ndarray, config: SafetyFilterConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Half-spaces ``m_ij . u_i >= c_ij`` of the wake rule: horizontal normals ``(..., N, N, 3)`` and bounds."""
    n = r.shape[-2]
    horizontal = np.hypot(r[..., 0], r[..., 1])
    height = np.abs(r[..., 2])
    width = config.wake_radius + config.wake_slope * height
    # stacked exactly: part along x, by index, so the two drones choose opposite sides
    tie = np.where(np.arange(n)[:, None] > np.arange(n)[None, :], 1.0, -1.0)
    side = np.where(horizontal[..., None] > 1e-3, r / np.maximum(horizontal, _EPS)[..., None], 0.0)
    side[..., 0] = np.where(horizontal > 1e-3, side[..., 0], tie)
    side[..., 2] = 0.0
    flying = ~settled[..., :, None] & ~settled[..., None, :]
    active = flying & (height < config.wake_height) & (horizontal < width + 0.3) & ~np.eye(n, dtype=bool)
    bound = np.where(active, -share * config.gain * (horizontal - width), -np.inf)
    return side, bound


def _limit_velocity_step(
    command: np.ndarray,
    vel: np.ndarray,
    relative: np.ndarray,
    goal: np.ndarray,
    config: SafetyFilterConfig,
    allowed: float | np.ndarray,
) -> np.ndarray:
    """The velocity-step limit: below ``cone_height`` above its goal, the horizontal command moved towards the drone's
    horizontal velocity ``vel`` until the two differ by at most ``max(allowed, |relative|)`` (``allowed``: the step,
    m/s, a number or ``(..., 1)``; ``relative``: the velocity relative to the pad, so braking to the pad's velocity is
    always allowed); others unchanged."""
    step = command[..., :2] - vel[..., :2]
    size = np.hypot(step[..., 0], step[..., 1])
    bound = np.maximum(allowed, np.hypot(relative[..., 0], relative[..., 1]))
    low = goal[..., 2] < config.cone_height
    scale = np.where(low, np.minimum(1.0, bound / np.maximum(size, _EPS)), 1.0)
    limited = command.copy()
    limited[..., :2] = vel[..., :2] + step * scale[..., None]
    return limited


def _lowest_vertical_command(goal: np.ndarray, config: SafetyFilterConfig) -> np.ndarray:
    """The most negative vertical command the descent and approach guards allow, ``(..., N)`` m/s."""
    lowest = np.full(goal.shape[:-1], -np.inf)
    height = goal[..., 2]
    if config.touchdown_speed > 0:
        a, t_d = config.descent_deceleration, config.descent_delay
        reach = np.maximum(height, 0.0)
        # the speed v from which v t_d + (v^2 - v_td^2) / (2 a) = h: braking starts t_d late and ends at v_td
        brake = a * (-t_d + np.sqrt(t_d**2 + (config.touchdown_speed**2 + 2.0 * a * reach) / a**2))
        lowest = np.maximum(lowest, -np.maximum(brake, config.touchdown_speed))
    if config.cone_slope > 0:
        radius = np.hypot(goal[..., 0], goal[..., 1])
        surface = np.minimum(config.cone_slope * np.maximum(radius - config.cone_radius, 0.0), config.cone_height)
        # below the surface the drone's descent is braked; with approach_climb it is also pushed back up
        floor = config.gain * (surface - height)
        lowest = np.maximum(lowest, np.where(floor > 0, config.approach_climb * floor, floor))
    return lowest


def filter_actions(
    obs: np.ndarray,
    actions: np.ndarray,
    pad_offsets: np.ndarray,
    max_speed: float,
    config: SafetyFilterConfig,
    pad_acceleration: np.ndarray | None = None,
    pad_velocity: np.ndarray | None = None,
    latency: float | np.ndarray | None = None,
    command_offset: np.ndarray | None = None,
    velocity_step: float | np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`filter_commands` on eq. 3 actions, with positions and velocities read from eq. 2 observations.

    Args:
        obs: each drone's observation ``(..., N, >= 13)``, as measured (eq. 2's ``p`` and ``v`` are read from it; the
            guards read ``p`` predicted ``config.latency_compensation`` ahead, :func:`predict_observations`).
        actions: normalised actions ``(..., N, 3)``; entries beyond [-1, 1] are clipped first, as eq. 3 does.
        pad_offsets: each drone's pad offset on the plate ``(N, 3)`` m: ``p + offset`` places the drones in one frame.
        max_speed: eq. 3's speed of action 1 (m/s).
        config: the filter's settings.
        pad_acceleration: each drone's pad's acceleration ``(..., N, 3)`` m/s^2 for the pad lead (``config.pad_lead``);
            None: no lead.
        pad_velocity: each drone's pad's velocity ``(..., N, 3)`` m/s (from observations that hold it), for the
            velocity-step limit (``config.low_velocity_step``); None: the pads are taken to be at rest.
        latency: the latency compensation ``L`` (s) the guards predict ``p`` by: a number, or ``(..., 1, 1)`` (one
            per env, as ``config.identified_lag_share`` identifies it); None: ``config.latency_compensation``.
        command_offset: ``(..., N, 3)`` m/s added to ``actions * max_speed`` to make the world command, and taken off
            the filtered one: the pad velocities of a pad-frame policy (``TaskConfig.command_frame``); None: none.
        velocity_step: the velocity-step limit's step (m/s), a number or ``(..., 1)`` per env
            (:meth:`SafetyFilterConfig.velocity_step`); None: ``config.low_velocity_step``.

    Returns:
        ``(filtered, correction)``: actions ``(..., N, 3)`` in [-1, 1], and how far the filter moved each drone's
        command, ``(..., N)`` m/s.
    """
    rel_goal, vel = obs[..., EQ2_POSITION], obs[..., EQ2_VELOCITY]
    command = np.clip(actions, -1.0, 1.0) * max_speed
    if command_offset is not None:
        command = command + command_offset
    # Eq. 2's v is relative to the pad; the velocity-step limit compares commands (world frame) with world velocities.
    # Only the differences of velocities keep drones apart, so the other rules read the same either way; without the
    # limit the velocities stay as observed, so that filtered flights without it are what they were before it.
    world_frame = pad_velocity is not None and config.low_velocity_step > 0
    lead = config.latency_compensation if latency is None else latency
    u, _ = filter_commands(
        rel_goal + pad_offsets,
        vel + pad_velocity if world_frame else vel,
        command,
        config,
        settled=settled_drones(rel_goal, vel, config),
        rel_goal=rel_goal + lead * vel,  # where the guards act: p + v L
        max_speed=max_speed,
        pad_acceleration=pad_acceleration,
        pad_velocity=pad_velocity if world_frame else None,
        velocity_step=velocity_step,
    )
    correction = np.linalg.norm(u - command, axis=-1)
    if command_offset is not None:
        u = u - command_offset
    return np.clip(u / max_speed, -1.0, 1.0), correction
