"""Artificial potential field (APF) planner of the baseline (paper Sec. IV-D) and of MorphoLander.

The planner turns the paper's centralised observation (eq. 2, ``13 N`` numbers) into a velocity
command per drone (m/s, world frame): the negative gradient of an attractive potential pulling
each drone to its own pad plus a repulsive potential pushing the drones apart. Its velocity goes
through the same tracking loop as the policy's action (eq. 3): the point-mass lag or the
Crazyflie's cascaded PID.

**Attraction.** Drone ``i`` sees ``p_i`` = its position minus its goal (the pad centre raised by
``landed_height``) and ``v_i`` = its velocity relative to the platform. It is pulled towards a
point on a *descent cone* above its pad,

    ``e_i = p_i - (0, 0, z*)``,  ``z* = min(cone_slope max(|p_i,xy| - r_tip, 0), approach_height) - aim_below``,

so that it comes down only once it is nearly above the pad (descending at a shallow angle would
touch the plate, or the other pad, first: a crash). Within ``cone_tip_radius`` the cone is flat
and its tip lies ``aim_below`` under the goal, so the final descent is brisk (a slow creep onto a
moving pad is what gets caught by the pad's reversals). The command is a PID on ``e_i`` plus a
feed-forward of the platform velocity:

    ``u_att = ff * v_pad_hat - k_p e_i - k_i I_i - k_d v_i``,  ``I_i = integral of e_i,xy dt``

The observation holds only velocities relative to the platform, so ``v_pad_hat`` comes from an
observer (:func:`observe_platform_velocity`): the drone's own velocity is predicted from its
last command through the tracking lag, and ``v_pad_hat = v_hat - v_i``. Without it a P or PI
loop lags a 0.5 m/s pad by ``v / k_p`` (30 cm) and never lands on it. The feed-forward and the
integral act only within ``near_zone`` of the pad and are capped at ``platform_speed_limit``:
far from the pad the commands are large, the tracking is acceleration-limited and the
observer's linear model overestimates the drone's speed, which fed back through ``ff`` would
run away (it did on the PyBullet Crazyflie before the cap). ``|u_att|`` is capped at
``max_speed`` and the descent at ``max_descent_speed`` so that touchdowns stay under the task's
``touchdown_speed_max`` (0.5 m/s).

**Repulsion** (Khatib's potential ``U = eta / 2 (1/d - 1/d0)^2`` for ``d < d0``):

    ``u_rep,i = sum_j eta (1/d_ij - 1/d0) / d_ij^2 * (x_i - x_j) / d_ij``

The drones' relative positions ``x_i - x_j`` are not in the observation directly, but follow
from it and the plate geometry: ``x_i - x_j = p_i - p_j + o_i - o_j`` with ``o`` the known pad
offsets of :meth:`~marlander_lite.platforms.PlateGeometry.pad_offsets` (the plate never yaws).
With ``d0`` larger than the pad spacing (0.25 m), two drones on neighbouring pads would push each
other off them (the classic APF weakness of goals inside an obstacle's influence), so the
repulsion on drone ``i`` is scaled by ``min(1, |p_i| / goal_fade_distance)^2``: it vanishes as the
drone reaches its own goal, which stays the potential's minimum (after Ge and Cui, 2000).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

from marlander_lite.platforms import PlateGeometry
from marlander_lite.task import EQ2_POSITION, EQ2_VELOCITY, OBS_PER_DRONE


@dataclass(frozen=True)
class APFConfig:
    """Gains of the PID + APF baseline, tuned by hand on the point-mass simulator (docs/reproduction.md).

    Tuning, measured on 16-30 seeded trials per condition: ``k_i`` = 1.2 biased static landings by
    about 1 cm (integral windup on the approach) and could not keep up with the 0.5 m/s stroke's
    reversals, so the feed-forward took its job and ``k_i`` is 0; ``aim_below`` = 0.04 m made the
    final creep so slow that a pad reversal caught most drones at 0.5 m/s (19 % success, 73 % with
    0.15 m); ``d0`` = 0.22 m let crossing drones collide on static pads (1 in 16).
    """

    k_p: float = 1.6
    """Proportional gain on the position error ``e`` (1/s): m/s of command per metre of error."""
    k_i: float = 0.0
    """Integral gain on the horizontal error (1/s^2): lets the drone match a moving pad's velocity."""
    k_d: float = 0.15
    """Damping on the velocity relative to the platform (dimensionless: m/s of command per m/s)."""
    platform_speed_limit: float = 0.7
    """Cap on ``|k_i I|`` and on the feed-forward (m/s), just above the fastest platform (0.5 m/s): anti-windup."""
    near_zone: float = 0.6
    """The integral and the feed-forward act only within this horizontal distance of the pad (m): far away,
    the observer's model of the tracking loop is least accurate (large, acceleration-limited commands)."""
    max_speed: float = 1.0
    """Cap on the attractive command's speed (m/s); the task allows 3 m/s."""
    max_descent_speed: float = 0.35
    """Cap on the downward command relative to the pad (m/s), below ``touchdown_speed_max`` = 0.5 m/s."""
    cone_slope: float = 1.5
    """Height kept above the pad per metre of horizontal distance from it (m/m)."""
    approach_height: float = 1.0
    """Largest height of the descent cone above the pad (m)."""
    aim_below: float = 0.15
    """The cone's tip lies this far under the goal (m): the drone touches down at about ``k_p aim_below`` m/s."""
    cone_tip_radius: float = 0.02
    """Within this horizontal distance of the pad centre (m) the cone is flat: the drone descends all the way
    (a fifth of the 0.1 m pad radius, so a touchdown there still lands)."""
    feedforward_gain: float = 1.0
    """Fraction of the estimated platform velocity added to the command (0 turns the feed-forward off)."""
    tracking_time_constant: float = 0.15
    """Time constant the observer assumes for the drone's velocity tracking (s): the point-mass lag. Kept for
    the Crazyflie, whose cascaded PID reaches 63 % of a 0.5 m/s step in the same 0.17 s (4 policy steps)."""
    feedforward_filter: float = 0.1
    """Time constant of the low-pass filter on the platform-velocity estimate (s)."""
    eta: float = 0.01
    """Repulsion gain (m^3/s): the repulsive speed is ``eta (1/d - 1/d0) / d^2``."""
    influence_distance: float = 0.5
    """``d0``: drones closer than this repel each other (m); above the 0.25 m pad spacing (``goal_fade_distance``)."""
    max_repulsion_speed: float = 1.5
    """Cap on each drone's repulsive command (m/s)."""
    goal_fade_distance: float = 0.5
    """Repulsion on a drone is scaled by ``min(1, |p_i| / this)^2`` (m): it fades out near the drone's own goal,
    which keeps the goal the potential's minimum (after Ge and Cui's goal-aware repulsion)."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"APFConfig.{f.name} must be a finite number >= 0, got {value!r}.")
        for name in ("max_speed", "max_descent_speed", "influence_distance"):
            if getattr(self, name) <= 0:
                raise ValueError(f"APFConfig.{name} must be > 0, got {getattr(self, name)!r}.")

    @classmethod
    def textbook(cls) -> APFConfig:
        """The paper's kind of baseline: attraction straight at the pad, repulsion between drones, a PD on
        the error; no descent cone (``cone_slope`` 0) and no platform-velocity observer (``feedforward_gain`` 0).
        The speed caps stay: a landing PID would not dive onto its pad either."""
        return cls(cone_slope=0.0, approach_height=0.0, feedforward_gain=0.0)

    def as_dict(self) -> dict[str, float]:
        """The gains by name, for tables and run records."""
        return asdict(self)


def split_observation(obs: np.ndarray, num_drones: int) -> tuple[np.ndarray, np.ndarray]:
    """``p`` and ``v`` of every drone from a centralised observation ``(13 N,)``: each ``(N, 3)``.

    ``p`` is the position relative to the drone's goal (m), ``v`` the velocity relative to the
    platform (m/s), as laid out by eq. 2. A ``(16 N,)``, ``(19 N,)`` or ``(22 N,)`` observation (with the platform
    velocity, the previous command or the platform acceleration, ``task.OBSERVATION_OPTIONS``) is read the same
    way.
    """
    o = np.asarray(obs, dtype=np.float64)
    sizes = tuple((OBS_PER_DRONE + extra) * num_drones for extra in (0, 3, 6, 9))
    if o.ndim != 1 or o.shape[0] not in sizes:
        raise ValueError(f"Observation has shape {o.shape}; expected one of {sizes} entries for {num_drones} drone(s).")
    per_drone = o.reshape(num_drones, -1)
    return per_drone[:, EQ2_POSITION], per_drone[:, EQ2_VELOCITY]


def relative_positions(p: np.ndarray, pad_offsets: np.ndarray) -> np.ndarray:
    """``x_i - x_j`` for every pair, ``(N, N, 3)`` m, from goal-relative positions and pad offsets.

    The goals of all drones share one lift above their pads, so ``x_i - x_j = p_i - p_j + o_i - o_j``.
    """
    world = p + pad_offsets  # positions relative to the plate (plus a common lift)
    return world[:, None, :] - world[None, :, :]


def repulsion_velocity(p: np.ndarray, pad_offsets: np.ndarray, config: APFConfig) -> np.ndarray:
    """Khatib repulsion of every drone from the others, ``(N, 3)`` m/s (zero for one drone)."""
    diff = relative_positions(p, pad_offsets)
    d = np.sqrt((diff * diff).sum(axis=-1))
    np.fill_diagonal(d, np.inf)
    d0 = config.influence_distance
    near = d < d0
    safe_d = np.where(near, np.maximum(d, 1e-3), 1.0)
    magnitude = np.where(near, config.eta * (1.0 / safe_d - 1.0 / d0) / safe_d**2, 0.0)
    u = ((magnitude / safe_d)[..., None] * diff).sum(axis=1)
    if config.goal_fade_distance > 0:
        to_goal = np.sqrt((p * p).sum(axis=-1, keepdims=True))
        u *= np.minimum(1.0, to_goal / config.goal_fade_distance) ** 2
    return _cap(u, config.max_repulsion_speed)


def cone_error(p: np.ndarray, config: APFConfig) -> np.ndarray:
    """``e = p - (0, 0, z*)``: position error to the descent cone's point above the pad, ``(N, 3)`` m."""
    horizontal = np.sqrt(p[:, 0] ** 2 + p[:, 1] ** 2)
    lift = config.cone_slope * np.maximum(horizontal - config.cone_tip_radius, 0.0)
    z_star = np.minimum(lift, config.approach_height) - config.aim_below
    e = p.copy()
    e[:, 2] -= z_star
    return e


def attraction_velocity(e: np.ndarray, v: np.ndarray, integral: np.ndarray, config: APFConfig) -> np.ndarray:
    """PID on the cone error: ``-k_p e - k_i I - k_d v``, speed and descent capped, ``(N, 3)`` m/s.

    Args:
        e: cone error (:func:`cone_error`), ``(N, 3)`` m.
        v: velocity relative to the platform, ``(N, 3)`` m/s.
        integral: ``I``, integral of the horizontal error, ``(N, 2)`` m s.
    """
    u = -config.k_p * e - config.k_d * v
    u[:, :2] -= _cap(config.k_i * integral, config.platform_speed_limit)
    u = _cap(u, config.max_speed)
    u[:, 2] = np.maximum(u[:, 2], -config.max_descent_speed)
    return u


def update_integral(integral: np.ndarray, e: np.ndarray, dt: float, config: APFConfig) -> np.ndarray:
    """One step of ``I += e_xy dt`` for drones within ``near_zone``; others keep ``I`` (anti-windup clamp)."""
    horizontal = np.sqrt(e[:, 0] ** 2 + e[:, 1] ** 2)
    inside = (horizontal < config.near_zone)[:, None]
    new = np.where(inside, integral + e[:, :2] * dt, integral)
    if config.k_i > 0:
        new = _cap(new, config.platform_speed_limit / config.k_i)
    return new


def observe_platform_velocity(
    drone_vel: np.ndarray,
    platform_vel: np.ndarray,
    command: np.ndarray,
    rel_vel: np.ndarray,
    dt: float,
    config: APFConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """One step of the platform-velocity observer behind the feed-forward, each array ``(N, 3)`` m/s.

    The observation holds only velocities *relative to the platform* (eq. 2). The drone's own
    velocity is predicted from the last command through the tracking lag,
    ``v_hat += (u_prev - v_hat) (1 - exp(-dt / tau))``, and the platform's is ``v_hat - v_rel``,
    low-pass filtered. Returns the new ``(v_hat, platform velocity estimate)``.
    """
    drone_vel = drone_vel + (command - drone_vel) * (1.0 - np.exp(-dt / config.tracking_time_constant))
    blend = 1.0 - np.exp(-dt / config.feedforward_filter) if config.feedforward_filter > 0 else 1.0
    platform_vel = platform_vel + (drone_vel - rel_vel - platform_vel) * blend
    return drone_vel, platform_vel


def feedforward_velocity(platform_vel: np.ndarray, e: np.ndarray, config: APFConfig) -> np.ndarray:
    """The feed-forward share of the command, ``(N, 3)`` m/s: ``ff * v_pad_hat`` (horizontal), capped
    at ``platform_speed_limit``, for drones within ``near_zone`` of their pad; zero for the others."""
    horizontal = np.sqrt(e[:, 0] ** 2 + e[:, 1] ** 2)
    u = np.zeros_like(platform_vel)
    u[:, :2] = _cap(config.feedforward_gain * platform_vel[:, :2], config.platform_speed_limit)
    return np.where((horizontal < config.near_zone)[:, None], u, 0.0)


def plate_offsets(num_drones: int, geometry: PlateGeometry | None = None) -> np.ndarray:
    """Pad offsets ``o_i`` relative to the plate, ``(N, 3)`` m; the default plate unless given."""
    return (geometry or PlateGeometry()).pad_offsets(num_drones)


def _cap(u: np.ndarray, limit: float) -> np.ndarray:
    """Scale each row of ``u`` down to at most ``limit`` in norm."""
    norm = np.sqrt((u * u).sum(axis=-1, keepdims=True))
    return u * np.minimum(1.0, limit / np.maximum(norm, 1e-12))
