"""The MARLander MDP (paper Sec. III-B/C), written once and shared by every simulator.

Everything here is plain, batched numpy, written to be checked against the paper line by line:
arrays are ``(num_envs, num_drones, ...)`` in any memory layout. Both simulators
(:mod:`marlander_lite.pointmass`, :mod:`marlander_lite.crazyflie`) and the deployment loop
(:mod:`marlander_lite.deploy`) call these functions, so an observation or a reward means the same
thing everywhere. A simulator that computes in a layout of its own (the point mass: Fortran order)
converts at its own boundary; ``tests/test_task.py`` checks that its observations equal these
formulas to the last bit.

Paper symbol -> code:

=====================  ===============================================================
eq. 2  ``O_t^i``       :func:`observe` -> ``(..., 13)``: ``[p, q, v, omega]``
eq. 3  ``A_t^i``       :func:`action_to_velocity`, :func:`command_velocity`, :func:`next_target_position`
eq. 4  ``R_t``         :func:`team_reward`
eq. 5  ``r_t^i``       :func:`drone_rewards` (``alpha``, ``beta``, ``c``)
eq. 6  ``r^c``         :func:`collision_penalty` (``alpha_c``), :func:`min_separation`
``K``                  :func:`team_reward` when every drone has landed
landing                :func:`touchdown_outcome`
=====================  ===============================================================
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from marlander_lite.pad_assignment import PAD_ASSIGNMENTS, PadAssignment, assign_starts_to_pads
from marlander_lite.rotations import vector_norm

OBS_PER_DRONE = 13
"""Length of one drone's observation (eq. 2): position 3, quaternion 4, velocity 3, angular velocity 3."""
EQ2_POSITION, EQ2_VELOCITY = slice(0, 3), slice(7, 10)
"""Where ``p`` (position minus goal, m) and ``v`` (velocity relative to the platform, m/s) sit in each drone's
eq. 2 observation (:func:`observe`: ``[p, q, v, omega]``)."""
PLATFORM_VELOCITY = slice(13, 16)
"""Where a drone's observation holds its pad's velocity (m/s), with ``TaskConfig.observe_platform_velocity``."""
ACT_PER_DRONE = 3
"""Length of one drone's action (eq. 3): a velocity command along x, y, z."""

OBS_LIMITS = (20.0, 1.0, 50.0, 200.0)
"""Bounds of |p| (m), |q|, |v| (m/s), |omega| (rad/s) per component: observations are clipped to
them. Only a crash or a drone far outside the arena reaches them."""


CommandFrame = Literal["world", "pad"]
COMMAND_FRAMES: tuple[str, ...] = ("world", "pad")
"""The frames eq. 3's velocity command may be read in (``TaskConfig.command_frame``): the paper's world frame, or
relative to the drone's pad."""

MAX_PAD_FRAME_LEAD = 2.0
"""The longest ``TaskConfig.pad_frame_lead`` (s) a task, a policy file, the transfer matrix or a lab config takes."""

MAX_LEAD_SHARE = 2.0
"""The largest ``TaskConfig.pad_frame_lead_share``: a lead of twice the identified tracker lag."""

MAX_OBSERVATION_HISTORY = 8
"""The most frames ``TaskConfig.observation_history`` may stack."""

OBSERVATION_OPTIONS = ("observe_platform_velocity", "observe_previous_command", "observe_platform_acceleration")
"""The ``TaskConfig`` switches that append to eq. 2's observation (3 numbers each, in this order): a policy
file's choice, which every simulator and the deployment loop follow."""


def observation_limits(frame_per_drone: int, history: int = 1) -> np.ndarray:
    """Half-widths of one drone's observation ``(frame_per_drone * history,)``: eq. 2's four parts bounded by
    :data:`OBS_LIMITS`, then the extras (platform velocity, previous command, platform acceleration), each bounded
    like a velocity (the acceleration estimate never exceeds 3 m/s^2); repeated for each of the ``history`` frames
    (``TaskConfig.observation_history``)."""
    p, q, v, w = OBS_LIMITS
    return np.tile(np.repeat(np.array([p, q, v, w, v]), [3, 4, 3, 3, 9])[:frame_per_drone], history)


CONTACT_NONE, CONTACT_OWN_PAD, CONTACT_OTHER = 0, 1, 2
"""Contact codes a simulator reports per drone: touching nothing, its own pad, or anything else."""


@dataclass(frozen=True)
class TaskConfig:
    """Constants of the MARLander MDP.

    Values the paper publishes are the defaults (``max_speed``, the 4 x 4 x 4 m arena). The
    reward constants are not published: the defaults below are ours, chosen so that shaping
    (``alpha``) dominates while flying, a landing (``c``, ``K``) is worth a few metres of
    approach, and a collision (``alpha_c``) costs more than a landing earns.

    Source: the paper (Aschu et al., MARLander, Sec. III-B/C/E; docs/references.md) for eqs. 2-6,
    the arena and the speed limit.
    """

    num_drones: int = 2
    """Number of drones N (the paper flies 2)."""
    max_speed: float = 3.0
    """Largest commanded speed per axis (m/s); action 1.0 maps to it (paper: 3 m/s)."""
    policy_hz: float = 24.0
    """Rate at which the policy acts (Hz); dt = 1 / policy_hz. Chosen: two 48 Hz PID ticks per action."""
    episode_seconds: float = 10.0
    """Time limit of an episode (s); the episode is truncated after it."""
    arena_half_width: float = 2.0
    """The arena spans [-w, w] in x and y (m): the paper's 4 x 4 m footprint."""
    arena_height: float = 4.0
    """The arena spans [0, h] in z (m): the paper's 4 m height."""
    spawn_height_min: float = 0.5
    """Lowest starting height of a drone (m)."""
    spawn_clearance: float = 0.3
    """Drones start at least this high above the plate top (m)."""
    spawn_ceiling_margin: float = 0.3
    """Drones start at least this far below the arena ceiling (m)."""
    spawn_separation: float = 0.5
    """Smallest distance between two drones at the start (m)."""
    spawn_near_pad_fraction: float = 0.0
    """Training aid, not in the paper: this fraction of episodes starts with every drone within 0.3 m
    horizontally and ``spawn_near_pad_height_min``-1.0 m above its own pad, so landings are practised from the first
    update. 0 (the default, used for every evaluation) keeps the paper's uniform start."""
    pad_assignment: PadAssignment = "fixed"
    """Which drone lands on which pad: ``"fixed"`` (the paper) gives drone ``i`` pad ``i`` whatever its start;
    ``"shortest"`` (not in the paper) hands each episode's random starts out so that the sum of squared
    start-to-pad distances is least (CAPT's assignment, :mod:`marlander_lite.pad_assignment`), so that the
    drones' paths cross far less often. Near-pad starts (a training aid) and relaunched drones keep their draw."""
    spawn_near_pad_height_min: float = 0.15
    """Lowest start above the pad of a near-pad start (m): lower puts drones a few centimetres up beside a pad that may
    be moving away, where a policy must learn to wait before it descends."""
    alpha: float = 10.0
    """Position shaping factor of eq. 5 (reward per metre of approach)."""
    beta: float = -0.02
    """Speed factor of eq. 5 (reward per m/s of speed relative to the platform, per step); <= 0 penalises speed."""
    c: float = 10.0
    """Landing reward of eq. 5, paid to a drone once, at the step it lands on its own pad."""
    alpha_c: float = 20.0
    """Collision penalty of eq. 6, subtracted at the step two drones come closer than ``collision_distance``."""
    K: float = 20.0
    """Final reward of eq. 4, paid once when every drone has landed."""
    collision_distance: float = 0.15
    """Two drones collide when their centres are closer than this (m): CF2X radius 0.06 m, doubled, plus margin."""
    touchdown_speed_max: float = 0.5
    """A touchdown on the own pad counts as a landing only below this speed relative to the pad (m/s)."""
    landing_tolerance: float | None = None
    """Training aid, not in the paper: when set, a touchdown counts as a landing only within this horizontal
    distance of the pad centre (m), stricter than the pad radius; None (the default, used for every
    evaluation) accepts the whole pad."""
    training_touchdown_speed: float | None = None
    """Training aid, not in the paper: when set, a touchdown counts as a landing only below this speed (m/s),
    stricter than ``touchdown_speed_max``, so that policies touch down softly on trackers that brake later."""
    approach_cone_penalty: float = 0.0
    """Training aid, not in the paper: reward lost per step and per metre that a drone flies below its approach
    cone (height above its goal ``< min(approach_cone_slope * horizontal distance, approach_cone_height)``), so that
    drones descend over their pad instead of skimming the floor or plate towards it. 0 switches it off."""
    approach_cone_slope: float = 1.0
    """Height the approach cone asks for per metre of horizontal distance to the pad (m/m)."""
    approach_cone_height: float = 0.6
    """The approach cone asks for at most this height above the goal (m), however far the pad."""
    command_speed_penalty: float = 0.0
    """Training aid, not in the paper: reward lost per step and per m/s that a command exceeds the speed from which
    a drone can still stop at its goal, ``sqrt(final_approach_speed^2 + 2 braking_deceleration d)`` (relative to the
    pad; ``d`` the distance to the goal). 0 switches it off."""
    braking_deceleration: float = 2.0
    """Deceleration assumed by the command-speed aid (m/s^2); a Crazyflie at a 20 degree tilt limit makes 3.6."""
    final_approach_speed: float = 0.3
    """Speed the command-speed aid allows at the goal itself (m/s)."""
    command_error_penalty: float = 0.0
    """Training aid, not in the paper: reward lost per step and per m/s by which a command differs from the drone's
    velocity beyond ``command_error_free``: a command no tracker can follow at once saturates its tilt. 0: off."""
    command_error_free: float = 0.6
    """Velocity error a command may ask for without cost (m/s); the firmware's tilt saturates near 0.8 m/s."""
    action_change_penalty: float = 0.0
    """Training aid, not in the paper: reward lost per step and per m/s that a drone's command changes from the
    previous step's, ``|u_t - u_{t-1}|``. A fast tracker turns a jittery command into jittery flight. 0: off."""
    landing_precision_bonus: float = 0.0
    """Training aid, not in the paper: extra reward at the step a drone lands, ``landing_precision_bonus * (1 - e /
    r)`` with ``e`` its horizontal distance from the pad centre and ``r`` the landing radius (``landing_tolerance``
    or the pad radius). Eq. 5's ``c`` pays a landing 3 cm off centre as much as a centred one. 0 switches it off."""
    landed_height: float = 0.0125
    """Height of a drone's body origin above a surface it rests on (m): half the CF2X collision cylinder."""
    observe_platform_velocity: bool = False
    """Beyond the paper: append the platform's world velocity (3 numbers, m/s) to each drone's eq. 2 observation
    (16 numbers then). Eq. 2 only has velocities relative to the platform, from which a memoryless policy cannot
    tell how fast the pad moves; a motion-capture system measures it anyway. False keeps the paper's 13."""
    observe_previous_command: bool = False
    """Beyond the paper: append the drone's previous velocity command (3 numbers, m/s, zero after a reset) to its
    observation, after the platform velocity when both are on. With it a memoryless policy sees what it asked for
    next to how the drone moved, which tells a sluggish tracker from a brisk one (the last action in the input, as
    in [Hwangbo2019] and [Kaufmann2023], docs/references.md). It is known exactly: sensing noise and latency never
    touch it."""
    observe_platform_acceleration: bool = False
    """Beyond the paper: append the platform's acceleration (3 numbers, m/s^2) last, estimated as the deployment loop
    estimates it, from the platform velocities the policy observed (noise and latency included;
    :func:`~marlander_lite.swarm.pad_acceleration.acceleration_step`), so that a policy could lead a pad that brakes
    and turns instead of trailing it. Needs ``observe_platform_velocity``. Off in every shipped policy: the ``moving``
    preset trained with it landed less on moving pads, with motion capture's noise and without it
    (docs/transfer.md)."""
    command_frame: CommandFrame = "world"
    """Beyond the paper: the frame of eq. 3's velocity command. ``"world"`` (the paper): ``u = a v_max``. ``"pad"``:
    ``u = v_pad + a v_max``, each axis within ``+-v_max`` (:func:`command_velocity`): the policy commands its velocity
    relative to its pad, the frame eq. 2 already measures ``v`` in, and the loop carries the pad's own motion (a
    feed-forward of the pad velocity, as the PID + APF baseline has). Identical on pads at rest. In simulation
    ``v_pad`` is the pad's velocity; in the deployment loop the motion-capture estimate of it. A policy file keeps
    its frame; ``marlander transfer --command-frame`` flies one in the other (docs/transfer.md)."""
    pad_frame_lead: float = 0.0
    """Beyond the paper, with ``command_frame`` ``"pad"``: ``T_lead`` (s), how far ahead the pad velocity a command
    carries is taken, ``v_pad + T_lead a_pad``, ``a_pad`` each pad's acceleration estimated from its velocity at each
    command as the deployment loop estimates it (:mod:`marlander_lite.swarm.pad_acceleration`). A tracker that lags
    by about ``T_lead`` then keeps up with a pad that brakes, reverses or turns, as the safety filter's ``pad_lead``
    does for world-frame policies. 0 to 2 s; 0: no lead."""
    pad_frame_lead_share: float = 0.0
    """Beyond the paper, with ``command_frame`` ``"pad"``: ``s`` > 0 sets the lead in flight, ``s`` times the velocity
    tracker's time constant identified from the commands sent and the velocities that followed
    (:mod:`marlander_lite.pad_frame_lead`); ``pad_frame_lead`` leads for the first half second. 0 to 2; 0: the fixed
    ``pad_frame_lead``. A flight setting (``--pad-frame-lead auto``), or trained with and then carried by the policy
    file, which flies it unless told otherwise."""
    vertical_bias_compensation: bool = False
    """Beyond the paper, a flight setting (``marlander transfer --vertical-bias``, the lab config's
    ``limits.vertical_bias``): identify each drone's steady vertical velocity bias in flight, the climb or sink its
    tracker adds to every command (a drone lighter or heavier than a controller without integral action believes), and
    take it off the vertical commands sent (:mod:`marlander_lite.swarm.vertical_bias`). False: commands as the policy
    gives them."""
    observation_history: int = 1
    """Beyond the paper: ``H``, how many of a drone's latest observation frames its observation holds, newest first
    (``H`` times :attr:`frame_per_drone` numbers; 1 to 8). A memoryless policy sees one instant; a few frames show it
    how the drone answered its last commands (a sluggish tracker, a late one) and how the pad's velocity changes:
    the short state history of [Hwangbo2019], which [Kumar2021] reads to adapt to unknown dynamics
    (docs/references.md). After a reset every slot holds the first frame. 1 keeps the paper's single frame;
    ``data/policies/moving-history-24m.safetensors`` reads 3 frames with the previous command (docs/transfer.md)."""

    def __post_init__(self) -> None:
        checks: list[tuple[bool, str]] = [
            (
                isinstance(self.num_drones, int | np.integer) and self.num_drones >= 1,
                "num_drones must be an integer >= 1",
            ),
            (self.max_speed > 0, "max_speed must be > 0 m/s"),
            (self.policy_hz > 0, "policy_hz must be > 0 Hz"),
            (self.episode_seconds > 0, "episode_seconds must be > 0 s"),
            (isinstance(self.vertical_bias_compensation, bool | np.bool_), "vertical_bias_compensation must be a bool"),
            (self.arena_half_width > 0 and self.arena_height > 0, "the arena sizes must be > 0 m"),
            (self.beta <= 0, "beta must be <= 0 (it penalises speed, eq. 5)"),
            (
                self.alpha >= 0 and self.c >= 0 and self.K >= 0 and self.alpha_c >= 0,
                "alpha, c, K, alpha_c must be >= 0",
            ),
            (self.collision_distance >= 0, "collision_distance must be >= 0 m"),
            (self.touchdown_speed_max > 0, "touchdown_speed_max must be > 0 m/s"),
            (
                self.training_touchdown_speed is None or self.training_touchdown_speed > 0,
                "training_touchdown_speed must be None or > 0 m/s",
            ),
            (
                min(
                    self.approach_cone_penalty,
                    self.command_speed_penalty,
                    self.command_error_penalty,
                    self.action_change_penalty,
                    self.landing_precision_bonus,
                )
                >= 0,
                "the training-aid penalties and landing_precision_bonus must be >= 0",
            ),
            (
                self.approach_cone_slope >= 0 and self.approach_cone_height >= 0,
                "approach_cone_slope and approach_cone_height must be >= 0",
            ),
            (
                self.braking_deceleration > 0 and self.final_approach_speed >= 0 and self.command_error_free >= 0,
                "braking_deceleration must be > 0 m/s^2, final_approach_speed and command_error_free >= 0 m/s",
            ),
            (
                self.spawn_height_min + self.spawn_ceiling_margin < self.arena_height,
                "the spawn heights do not fit in the arena",
            ),
            (
                self.observe_platform_velocity or not self.observe_platform_acceleration,
                "observe_platform_acceleration is estimated from the observed platform velocity: it needs "
                "observe_platform_velocity=True",
            ),
            (
                isinstance(self.observation_history, int | np.integer)
                and not isinstance(self.observation_history, bool)
                and 1 <= self.observation_history <= MAX_OBSERVATION_HISTORY,
                f"observation_history must be an integer from 1 to {MAX_OBSERVATION_HISTORY} (frames)",
            ),
            (
                self.command_frame in COMMAND_FRAMES,
                f"command_frame must be one of {', '.join(COMMAND_FRAMES)}",
            ),
            (
                0.0 <= self.pad_frame_lead <= MAX_PAD_FRAME_LEAD
                and (self.pad_frame_lead == 0.0 or self.command_frame == "pad"),
                f"pad_frame_lead must be from 0 to {MAX_PAD_FRAME_LEAD:g} s, and above 0 only with command_frame='pad'",
            ),
            (
                0.0 <= self.pad_frame_lead_share <= MAX_LEAD_SHARE
                and (self.pad_frame_lead_share == 0.0 or self.command_frame == "pad"),
                f"pad_frame_lead_share must be from 0 to {MAX_LEAD_SHARE:g}, and above 0 only with command_frame='pad'",
            ),
            (
                self.pad_assignment in PAD_ASSIGNMENTS,
                f"pad_assignment must be one of {', '.join(PAD_ASSIGNMENTS)}",
            ),
            (
                0.0 < self.spawn_near_pad_height_min < 1.0,
                "spawn_near_pad_height_min must be above 0 m and below 1 m (the highest near-pad start)",
            ),
        ]
        for name in (f.name for f in dataclasses.fields(self)):
            value = getattr(self, name)
            if isinstance(value, float) and not np.isfinite(value):
                raise ValueError(f"TaskConfig.{name} must be finite, got {value!r}.")
        for ok, message in checks:
            if not ok:
                raise ValueError(f"Invalid TaskConfig: {message}; got {self!r}.")

    @property
    def dt(self) -> float:
        """Policy period (s)."""
        return 1.0 / self.policy_hz

    @property
    def max_steps(self) -> int:
        """Policy steps before the episode is truncated."""
        return round(self.episode_seconds * self.policy_hz)

    @property
    def frame_per_drone(self) -> int:
        """Length of one observation frame of one drone: 13 (eq. 2), plus 3 for each of
        ``observe_platform_velocity``, ``observe_previous_command`` and ``observe_platform_acceleration``."""
        return OBS_PER_DRONE + 3 * sum(bool(getattr(self, name)) for name in OBSERVATION_OPTIONS)

    @property
    def obs_per_drone(self) -> int:
        """Length of one drone's observation: :attr:`frame_per_drone` times ``observation_history``."""
        return self.frame_per_drone * int(self.observation_history)

    @property
    def obs_dim(self) -> int:
        """Length of the centralised observation: :attr:`obs_per_drone` N (13 N for the paper's eq. 2)."""
        return self.obs_per_drone * self.num_drones

    @property
    def act_dim(self) -> int:
        """Length of the centralised action: 3 N."""
        return ACT_PER_DRONE * self.num_drones

    def replace(self, **changes: Any) -> TaskConfig:
        """A copy with some fields changed; unknown names raise with the list of fields."""
        known = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise TypeError(f"Unknown TaskConfig field(s) {unknown}; allowed: {sorted(known)}.")
        return dataclasses.replace(self, **changes)


# ----------------------------------------------------------------------------- eq. 2


def observe(
    rel_pos: np.ndarray,
    quat: np.ndarray,
    rel_vel: np.ndarray,
    ang_vel: np.ndarray,
    pad_vel: np.ndarray | None = None,
    previous_command: np.ndarray | None = None,
    pad_acceleration: np.ndarray | None = None,
) -> np.ndarray:
    """Eq. 2: ``O_t^i = [p_t^i, q_t^i, v_t^i, omega_t^i]``, shape ``(..., 13)`` (16, 19 or 22 with the extras).

    Args:
        rel_pos: ``p``, drone position minus its goal point (own pad centre raised by
            ``landed_height``), ``(..., 3)`` m, world frame.
        quat: ``q``, attitude quaternion ``(x, y, z, w)``, ``(..., 4)``.
        rel_vel: ``v``, drone velocity minus the platform's, ``(..., 3)`` m/s.
        ang_vel: ``omega``, angular velocity, ``(..., 3)`` rad/s, world frame.
        pad_vel: only with ``TaskConfig.observe_platform_velocity`` (beyond the paper): the pad's
            world velocity ``(..., 3)`` m/s, appended as numbers 13-15.
        previous_command: only with ``TaskConfig.observe_previous_command`` (beyond the paper): the velocity command
            of the previous step ``(..., 3)`` m/s, appended next.
        pad_acceleration: only with ``TaskConfig.observe_platform_acceleration`` (beyond the paper): the estimate of
            the pad's acceleration ``(..., 3)`` m/s^2, appended last.

    Each part is clipped to :data:`OBS_LIMITS`; a unit quaternion is within ``[-1, 1]`` already.
    """
    p_max, _, v_max, w_max = OBS_LIMITS
    parts = [
        np.clip(rel_pos, -p_max, p_max),
        quat,
        np.clip(rel_vel, -v_max, v_max),
        np.clip(ang_vel, -w_max, w_max),
    ]
    if pad_vel is not None:
        parts.append(np.clip(pad_vel, -v_max, v_max))
    if previous_command is not None:
        parts.append(np.clip(previous_command, -v_max, v_max))
    if pad_acceleration is not None:
        parts.append(np.clip(pad_acceleration, -v_max, v_max))
    return np.concatenate(parts, axis=-1)


def flatten_observations(obs: np.ndarray) -> np.ndarray:
    """Centralised input of the paper's policy: ``(num_envs, N, 13)`` -> ``(num_envs, 13 N)``, drone by drone."""
    return obs.reshape(obs.shape[0], -1)


# ----------------------------------------------------------------------------- eq. 3


def action_to_velocity(action: Any, num_drones: int, max_speed: float) -> np.ndarray:
    """Eq. 3: normalised actions -> velocity commands ``u`` in m/s, shape ``(num_envs, N, 3)``.

    ``action`` may be ``(3N,)``, ``(N, 3)``, ``(num_envs, 3N)`` or ``(num_envs, N, 3)``, each
    entry in ``[-1, 1]``; action 1.0 is ``max_speed``. Entries outside are clipped (policies with
    Gaussian heads sample beyond the box); NaN or infinite entries raise, since no safe velocity
    can be read from them.
    """
    a = np.asarray(action)
    if a.dtype not in (np.float32, np.float64):  # a policy's float32 stays as it is: the kernel reads it exactly
        a = a.astype(np.float64)
    n3 = ACT_PER_DRONE * num_drones
    if a.shape in ((n3,), (num_drones, ACT_PER_DRONE)):
        a = a.reshape(1, num_drones, ACT_PER_DRONE)
    elif a.ndim == 2 and a.shape[1] == n3:
        a = a.reshape(a.shape[0], num_drones, ACT_PER_DRONE)
    elif not (a.ndim == 3 and a.shape[1:] == (num_drones, ACT_PER_DRONE)):
        raise ValueError(
            f"Action has shape {a.shape}; for {num_drones} drone(s) expected ({n3},), ({num_drones}, 3), "
            f"(num_envs, {n3}) or (num_envs, {num_drones}, 3)."
        )
    if compiled_kernels() is not None:  # the same numbers in one pass, in the simulators' layout (env index fastest)
        from marlander_lite.task_kernels import velocity_commands  # here: it imports marlander_lite.pointmass

        velocity = np.empty(a.shape, order="F")
        if velocity_commands(a, float(max_speed), velocity):
            return velocity
    elif np.isfinite(a).all():
        return np.clip(a.astype(np.float64, copy=False), -1.0, 1.0) * max_speed
    raise ValueError(f"Action contains NaN or infinite values: {np.asarray(action)!r}. Every entry must be finite.")


def command_velocity(action: Any, cfg: TaskConfig, pad_velocity: np.ndarray) -> np.ndarray:
    """Eq. 3 in the task's command frame: normalised actions -> velocity commands ``u`` ``(num_envs, N, 3)`` m/s
    (:func:`action_to_velocity`, then :func:`in_command_frame`)."""
    return in_command_frame(action_to_velocity(action, cfg.num_drones, cfg.max_speed), cfg, pad_velocity)


def in_command_frame(velocity: np.ndarray, cfg: TaskConfig, pad_velocity: np.ndarray) -> np.ndarray:
    """Eq. 3's ``a v_max`` ``(num_envs, N, 3)`` m/s as the command flown in ``cfg.command_frame``.

    ``"world"`` (the paper): ``velocity`` itself. ``"pad"``: ``velocity`` plus each drone's pad velocity
    ``pad_velocity`` (the same shape, or broadcast to it; m/s), written into ``velocity`` (its memory layout stays)
    and each axis clipped to ``+-max_speed`` as eq. 3 clips the action: a drone hovering relative to its pad (action
    0) follows the pad.
    """
    if cfg.command_frame == "world":
        return velocity
    pad_velocity = np.asarray(pad_velocity, dtype=np.float64)
    if not np.isfinite(pad_velocity).all():
        raise ValueError("The pad velocity is not finite: a pad-frame command cannot be formed from it.")
    np.add(velocity, pad_velocity, out=velocity)
    return np.clip(velocity, -cfg.max_speed, cfg.max_speed, out=velocity)


def next_target_position(pos: np.ndarray, velocity: np.ndarray, dt: float) -> np.ndarray:
    """Eq. 3's use: the position the controller is sent to next, ``p + u dt`` (m)."""
    return pos + velocity * dt


# ----------------------------------------------------------------------------- eqs. 4-6


def drone_rewards(
    prev_dist: np.ndarray,
    dist: np.ndarray,
    rel_speed: np.ndarray,
    landed_now: np.ndarray,
    active: np.ndarray,
    config: TaskConfig,
) -> np.ndarray:
    """Eq. 5: ``r_t^i = alpha (|p_{t-1}| - |p_t|) + beta |v_t| + c`` per drone, ``(num_envs, N)``.

    ``c`` is paid only at the step drone ``i`` lands; drones that landed earlier (``active`` is
    False) earn nothing more.
    """
    r = config.alpha * (prev_dist - dist) + config.beta * rel_speed + config.c * landed_now
    return np.where(active, r, 0.0)


def collision_penalty(collided: np.ndarray, config: TaskConfig) -> np.ndarray:
    """Eq. 6: ``r^c = -alpha_c`` in environments where a collision happened this step, else 0."""
    return np.where(collided, -config.alpha_c, 0.0)


def team_reward(
    r_drones: np.ndarray, collided: np.ndarray, all_landed_now: np.ndarray, config: TaskConfig
) -> np.ndarray:
    """Eq. 4: ``R_t = sum_i r_t^i + r^c + K``, ``(num_envs,)``; ``K`` only at the step the last drone lands."""
    return r_drones.sum(axis=-1) + collision_penalty(collided, config) + config.K * all_landed_now


def min_separation(pos: np.ndarray) -> np.ndarray:
    """Smallest distance between two drone centres in each env, ``(num_envs,)`` m (inf for N = 1).

    ``pos`` is ``(num_envs, N, 3)``. :func:`min_separation_numpy` is the reference; when numba is installed
    (and ``MARLANDER_LITE_ENGINE`` is not ``numpy``) a compiled kernel with the same result to the last bit
    answers instead (:func:`marlander_lite.pointmass.kernels.min_separation`): with 16 drones this is the
    costliest line of a step, 120 pairs, and of every spawn draw.
    """
    kernels = compiled_kernels()
    if kernels is not None and pos.ndim == 3 and pos.shape[-1] == 3 and pos.dtype == np.float64:
        return kernels.min_separation(pos)
    return min_separation_numpy(pos)


def _paired(pos: np.ndarray, pads: np.ndarray, uniform: np.ndarray) -> np.ndarray:
    """``pos`` with the starts of the ``uniform`` envs handed out to their drones by the shortest pairing."""
    if uniform.any():
        pos[uniform] = assign_starts_to_pads(pos[uniform], pads[uniform])
    return pos


def compiled_kernels() -> Any:
    """The compiled kernels' module, or None when numba is missing or ``MARLANDER_LITE_ENGINE=numpy`` is set now."""
    global _KERNELS
    if _KERNELS is None:
        # Imported here, not at the top: marlander_lite.pointmass itself imports this module.
        from marlander_lite.pointmass import kernels

        _KERNELS = kernels
    return _KERNELS if _KERNELS.resolve_engine("auto") == "numba" else None


_KERNELS: Any = None


def min_separation_numpy(pos: np.ndarray) -> np.ndarray:
    """:func:`min_separation` in plain numpy, the reference.

    Pairs ``(i, i + s)`` are compared for each shift ``s``, so the cost grows with N, not N^2
    Python operations.
    """
    n = pos.shape[-2]
    best = np.full(pos.shape[:-2], np.inf)
    for shift in range(1, n):
        diff = pos[..., shift:, :] - pos[..., :-shift, :]
        np.minimum(best, vector_norm(diff).min(axis=-1), out=best)
    return best


# ----------------------------------------------------------------------------- landing


def touchdown_outcome(
    contact: np.ndarray,
    horizontal_error: np.ndarray,
    rel_speed: np.ndarray,
    landed_before: np.ndarray,
    pad_radius: float,
    config: TaskConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """Classify touchdowns: ``(landed_now, crashed)``, each ``(num_envs, N)`` bool.

    A drone lands when it touches its own pad with its centre within ``pad_radius`` of the pad
    centre (or the stricter ``landing_tolerance``, a training aid) and moves slower than
    ``touchdown_speed_max`` relative to the pad. Any other contact (floor, plate, another pad,
    too fast, off-centre) is a crash.
    """
    pad_radius, speed_max = touchdown_limits(pad_radius, config)
    touching = (contact != CONTACT_NONE) & ~landed_before
    landed_now = touching & (contact == CONTACT_OWN_PAD) & (horizontal_error <= pad_radius) & (rel_speed <= speed_max)
    return landed_now, touching & ~landed_now


def touchdown_limits(pad_radius: float, config: TaskConfig) -> tuple[float, float]:
    """The largest distance from the pad centre (m) and relative speed (m/s) at which :func:`touchdown_outcome`
    counts a touchdown as a landing: the pad radius and ``touchdown_speed_max``, or the stricter training aids."""
    if config.landing_tolerance is not None:
        pad_radius = min(pad_radius, config.landing_tolerance)
    speed_max = config.touchdown_speed_max
    if config.training_touchdown_speed is not None:
        speed_max = min(speed_max, config.training_touchdown_speed)
    return pad_radius, speed_max


def pad_frame_errors(rel_pos: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A drone's position relative to its pad, in the pad's frame: ``(height, offset)``, each ``(...)`` m.

    ``height = p . n`` is measured along the pad normal ``n`` (one ``(3,)`` for every row, or one per row,
    ``(..., 3)`` like ``rel_pos``) and ``offset = |p - (p . n) n|`` within the pad plane; on a level pad
    (``n = e_z``) they are ``p_z`` and the horizontal distance. For an inclined plate (beyond the paper,
    ``platforms.PlateGeometry.inclination_deg``) the offset is what :func:`touchdown_outcome` should compare
    with the pad radius as its ``horizontal_error``.
    """
    n = np.asarray(normal, dtype=float)
    height = np.einsum("...k,...k->...", rel_pos, n)  # one normal broadcasts over the rows
    offset_sq = np.einsum("...k,...k->...", rel_pos, rel_pos) - height * height
    return height, np.sqrt(np.maximum(offset_sq, 0.0))


def outside_arena(pos: np.ndarray, config: TaskConfig) -> np.ndarray:
    """True for drones outside the ``[-w, w]^2 x [0, h]`` arena, ``(num_envs, N)``."""
    w, z = config.arena_half_width, pos[..., 2]
    return (np.abs(pos[..., 0]) > w) | (np.abs(pos[..., 1]) > w) | (z > config.arena_height) | (z < 0)


def sample_spawn_positions(
    rng: np.random.Generator,
    plate_top: np.ndarray,
    config: TaskConfig,
    pads: np.ndarray | None = None,
    max_tries: int = 100,
    pair_with_pads: bool = True,
) -> np.ndarray:
    """Random starting positions in the arena, ``(len(plate_top), N, 3)`` m (paper Sec. III-E).

    x and y are uniform over the arena; z is uniform between ``spawn_height_min`` (and at least
    ``spawn_clearance`` above the plate top) and ``spawn_ceiling_margin`` below the ceiling.
    With ``spawn_near_pad_fraction`` > 0 (a training aid) that fraction of environments starts
    near the pads ``pads`` ``(k, N, 3)`` instead. Draws are repeated until every pair of drones
    is ``spawn_separation`` apart. With ``pad_assignment="shortest"`` (and ``pair_with_pads``) the uniform starts
    of each env are then handed out to its drones by :func:`~marlander_lite.pad_assignment.assign_starts_to_pads`
    (which needs ``pads``). With the compiled engine on, :mod:`marlander_lite.pointmass.spawn_kernels` runs
    this loop, drawing the same numbers from ``rng`` (a dozen rounds per reset at 16 drones).
    """
    n, w = len(plate_top), config.arena_half_width
    z_lo = np.maximum(config.spawn_height_min, plate_top + config.spawn_clearance)
    z_hi = config.arena_height - config.spawn_ceiling_margin
    if np.any(z_lo >= z_hi):
        raise ValueError(
            "The plate is too high for drones to start above it; lower elevated_height or raise the arena."
        )
    near_fraction = config.spawn_near_pad_fraction
    if near_fraction and pads is None:
        raise ValueError("spawn_near_pad_fraction > 0 needs the pad positions.")
    pairs = pair_with_pads and config.pad_assignment == "shortest"
    if pairs and pads is None:
        raise ValueError('pad_assignment="shortest" needs the pad positions (pads).')

    # Each env's kind of start is drawn once, so that redraws for separation keep the fraction.
    near_pad = rng.random(n) < near_fraction if near_fraction else np.zeros(n, dtype=bool)

    def draw(ids: np.ndarray) -> np.ndarray:
        u = rng.random((len(ids), config.num_drones, 3))
        u[..., :2] = (2.0 * w) * u[..., :2] - w
        u[..., 2] = z_lo[ids, None] + (z_hi - z_lo[ids, None]) * u[..., 2]
        near = near_pad[ids]
        if near.any():
            k = int(near.sum())
            angle = rng.uniform(0, 2 * np.pi, (k, config.num_drones))
            radius = 0.3 * np.sqrt(rng.random((k, config.num_drones)))
            height = rng.uniform(config.spawn_near_pad_height_min, 1.0, angle.shape)
            offset = np.stack((radius * np.cos(angle), radius * np.sin(angle), height), -1)
            u[near] = pads[ids[near]] + offset
        return u

    if compiled_kernels() is not None:
        from marlander_lite.pointmass import spawn_kernels  # here, not at the top: no import cycle

        pos = spawn_kernels.sample_spawn_positions(rng, z_lo, z_hi, near_pad, pads, config, max_tries)
        if pos is not None:
            return _paired(pos, pads, ~near_pad) if pairs else pos
    else:
        pos = draw(np.arange(n))
        for _ in range(max_tries):
            redo = np.flatnonzero(min_separation(pos) < config.spawn_separation)
            if len(redo) == 0:
                return _paired(pos, pads, ~near_pad) if pairs else pos
            pos[redo] = draw(redo)
    raise ValueError(
        f"Could not place {config.num_drones} drones {config.spawn_separation} m apart in the arena after "
        f"{max_tries} tries; lower spawn_separation or enlarge the arena."
    )
