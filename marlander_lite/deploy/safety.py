"""Safety rules of the deployment: when in doubt, hover; when doubt lasts, land.

The rules (thresholds in :class:`marlander_lite.deploy.config.SafetyConfig`):

=============================  ===================================================================
before take-off                :meth:`SafetyMonitor.arming_problems`: every drone and pad seen and
                               fresh, valid, inside the soft fence (a pad 5 cm inside it, where the
                               fence guard lets a drone reach), still, level, apart; links up;
                               the take-off height 0.3 m above the pads.
fence guard                    every policy setpoint: a component towards a wall or the ceiling of
                               the soft box is slowed to the speed the drone can stop from in the
                               room left (:func:`keep_inside`), so that the policy, which does not
                               observe the walls (eq. 2), cannot fly a drone out of it.
geofence                       a flying drone outside the soft box, or one whose stopping
                               distance (:func:`stopping_distance`) reaches the hard box -> every
                               drone hovers for ``geofence_hover_s``, then lands. Not resumed.
stale or missing body          any drone or pad body older than ``stale_hover_s`` -> hover (the
                               policy is centralised: one bad input spoils every command);
                               older than ``stale_land_s`` -> land. Fresh again before: resume.
NaN / out-of-range pose        rejected by the estimator -> hover at once; the body then ages
                               like a missing one.
NaN / out-of-range action      hover; if it lasts ``stale_land_s`` -> land.
lost radio link                that drone gets nothing more (its firmware levels out after
                               0.5 s and stops its motors after 2 s); every other drone lands.
tumbled                        a flying drone tilted more than ``tumble_tilt_deg`` for
                               ``tumble_s`` (hit, flipped: no command can fly it) -> its motors
                               stop; during take-off or the policy every other drone lands.
Ctrl-C, emergency key          every drone lands; a second Ctrl-C stops every motor.
=============================  ===================================================================

Every decision comes with :class:`Event` s, which the loop logs.

**Braking.** A drone told to hover does not stop where it is. The command reaches it a latency
``t_lat`` later (mocap + radio, :data:`LINK_LATENCY_S`, plus one loop period); the firmware's
velocity tracker then needs :data:`TRACKER_RESPONSE_DELAY_S` before the drone decelerates, and
brakes at :data:`FIRMWARE_BRAKE_DECELERATION`, well below the ``g tan(20 deg)`` = 3.57 m/s^2 its
tilt limit would allow. From speed ``v`` it travels

    d(v) = SAFETY_FACTOR * (v (t_lat + t_resp) + v^2 / (2 a_fw))

before it stands still (:func:`stopping_distance`). Told to fly at ``limits.max_speed``, a drone
reaches :data:`SPEED_OVERSHOOT` times that speed, so the config loader demands
``geofence.margin >= d(SPEED_OVERSHOOT * limits.max_speed)`` (:func:`required_margin`). In flight
:class:`SafetyMonitor` brakes as soon as a drone's stopping point ``pos + d(|v|) v/|v|``, at its
*measured* speed (which already contains any overshoot), leaves the hard box. The three
constants were measured in the PyBullet Crazyflie with the firmware velocity tracker (see
``docs/lab_guide.md``, *Config validation and the geofence margin*).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from marlander_lite.rotations import tilt_deg

if TYPE_CHECKING:  # config imports this module's braking model: no import cycle at run time
    from marlander_lite.deploy.config import LabConfig
    from marlander_lite.deploy.estimation import SwarmEstimate

GRAVITY = 9.81
"""m/s^2."""
MAX_TILT_DEG = 20.0
"""Tilt limit of the stock Crazyflie firmware's velocity controller (degrees, ``rpLimit``)."""
TILT_LIMIT_DECELERATION = GRAVITY * math.tan(math.radians(MAX_TILT_DEG))
"""``g tan(20 deg)`` = 3.57 m/s^2: the deceleration the tilt limit would allow in level flight. The firmware
does not reach it (:data:`FIRMWARE_BRAKE_DECELERATION`); kept for reference, not used by the margin."""
SPEED_OVERSHOOT = 1.10
"""How much faster than a commanded speed the drone flies at worst (ratio). The firmware's velocity PID
(kp 25 deg per m/s, ki 1) overshoots a step: measured in the PyBullet Crazyflie with the firmware tracker,
the speed peaks at 1.089 x the command at 0.5-1 m/s (1.095 on a diagonal), 1.07 at 1.5 m/s, 1.05 at 2 m/s,
1.03 at 3 m/s, about 0.5 s after the step."""
FIRMWARE_BRAKE_DECELERATION = 2.4
"""Deceleration the firmware's velocity tracker achieves when its setpoint drops to 0 (m/s^2). Its kp of
25 deg per m/s saturates the 20 deg tilt only above 0.8 m/s of error, and the attitude loop needs time to
tilt back, so the drone brakes at far less than ``g tan(20 deg)``. Measured in the PyBullet Crazyflie (firmware
tracker, 240 Hz) by commanding ``v`` then 0 and fitting ``v(t)`` with a delay and a constant deceleration:
1.4 m/s^2 from 0.55 m/s, 2.6 from 1.1 m/s, 3.1 from 1.6 m/s, 3.4 from 2.1 m/s, 3.8 from 3.1 m/s. 2.4 m/s^2
is the largest value for which ``d(v)`` (without the safety factor, with :data:`TRACKER_RESPONSE_DELAY_S`)
covers every measured stop, 0.5-3 m/s commanded, stopped at any moment of the acceleration, within 1 %."""
TRACKER_RESPONSE_DELAY_S = 0.15
"""Time from a 0 setpoint reaching the firmware to the drone slowing down (s): the 100 Hz velocity loop, the
attitude loop tilting the drone back, and the velocity integrator unwinding. Fitted 0.06-0.11 s from a steady
speed; stopped in mid-acceleration, when the drone is still tilted forwards, it travels as if 0.15 s late."""
BRAKE_DECELERATION = FIRMWARE_BRAKE_DECELERATION
"""The deceleration the margin assumes (m/s^2): :data:`FIRMWARE_BRAKE_DECELERATION`."""
LINK_LATENCY_S = 0.030
"""Motion capture plus radio latency before a command acts (s); one loop period is added to it."""
SAFETY_FACTOR = 1.25
"""The stopping distance is stretched by this factor (estimation noise, wind, a weaker battery)."""
TAKEOFF_CLEARANCE = 0.3
"""The take-off height must be at least this far above the pads (and so above the floor) (m)."""


def brake_latency(loop_hz: float) -> float:
    """Time from a pose to a command acting on the drone: ``LINK_LATENCY_S`` plus one loop period (s)."""
    return LINK_LATENCY_S + 1.0 / loop_hz


def coast_time(loop_hz: float) -> float:
    """Time a drone keeps its speed after the pose that should stop it: ``brake_latency`` plus the tracker's
    :data:`TRACKER_RESPONSE_DELAY_S` (s)."""
    return brake_latency(loop_hz) + TRACKER_RESPONSE_DELAY_S


def stopping_distance(speed: Any, loop_hz: float) -> Any:
    """``SAFETY_FACTOR (v (t_lat + t_resp) + v^2 / (2 a_fw))``: how far a drone flying at ``speed`` (m/s, its
    actual speed, overshoot included) goes before it stops (m)."""
    v = np.abs(speed)
    return SAFETY_FACTOR * (v * coast_time(loop_hz) + v**2 / (2.0 * BRAKE_DECELERATION))


def required_margin(max_speed: float, loop_hz: float) -> float:
    """The gap between soft and hard fence that a drone commanded at the lab speed limit needs to stop in (m):
    the stopping distance from ``SPEED_OVERSHOOT * max_speed``."""
    return float(stopping_distance(SPEED_OVERSHOOT * max_speed, loop_hz))


def braking_margin_problem(max_speed: float, margin: float, loop_hz: float) -> str | None:
    """Why a soft-fence ``margin`` (m) is too narrow to stop in from ``max_speed`` (m/s), or None if it is not.

    The fixes it names are rounded so that they pass: the margin up, the speed down (to the centimetre).
    """
    needed = required_margin(max_speed, loop_hz)
    if margin >= needed - 1e-9:
        return None
    wider = math.ceil(needed * 100 - 1e-6) / 100
    slower = math.floor(fastest_speed_for(margin, loop_hz) * 100 + 1e-6) / 100
    return (
        f"geofence.margin {margin} m is too narrow to brake in at limits.max_speed {max_speed} m/s: a Crazyflie "
        f"needs {wider:.2f} m ({SAFETY_FACTOR} x (v t + v^2 / (2 a)) at v = {SPEED_OVERSHOOT} x max_speed "
        f"(the firmware overshoots), t = {coast_time(loop_hz) * 1e3:.0f} ms of latency and tracker delay, "
        f"a = {BRAKE_DECELERATION:.1f} m/s^2 the firmware brakes at). Either lower limits.max_speed to "
        f"{slower:.2f} m/s or less, or widen the gap: geofence.margin >= {wider:.2f} m "
        "(moving the hard fence out by as much)."
    )


def fastest_speed_for(margin: Any, loop_hz: float) -> Any:
    """The highest commanded speed (m/s; the highest ``limits.max_speed``) whose stopping distance, overshoot
    included, fits ``margin`` (m, a float or an array; inverse of :func:`required_margin`)."""
    a, t = BRAKE_DECELERATION, coast_time(loop_hz)
    return a * (np.sqrt(t * t + 2.0 * np.asarray(margin) / (SAFETY_FACTOR * a)) - t) / SPEED_OVERSHOOT


FENCE_GUARD_BUFFER = 0.05
"""The fence guard stops drones this far inside the soft fence (m): motion-capture noise and the tracker's drift at a
zero setpoint would carry a drone that stopped on the fence itself across it (measured in the rehearsal: 5 mm)."""


def keep_inside(
    velocity: np.ndarray,
    pos: np.ndarray,
    vel: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    loop_hz: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The fence guard: velocity setpoints ``(N, 3)`` m/s that a drone at ``pos`` ``(N, 3)`` m flying ``vel``
    ``(N, 3)`` m/s (as measured) can follow and still stop inside the box ``[low, high]`` (``(3,)`` m each;
    ``low[2] = -inf`` leaves the floor unguarded, for landing), and ``(N,)`` bool: which drones' setpoints changed.

    The room to a face is the distance to it less :data:`FENCE_GUARD_BUFFER`. A component pointing at a face is cut
    to :func:`fastest_speed_for` that room, and to 0 (brake) once the drone's own speed towards the face needs all of
    it (:func:`stopping_distance`: a tracker answers a lowered setpoint more softly than a stop); with no room left,
    to a push back inwards at the speed that room's overrun would allow. Components pointing inwards (unless pushed
    harder), and the other axes, are kept. The drone then slows down as it nears a wall and slides along it, instead
    of crossing it. A NaN position leaves the setpoint alone (the stale-data rules handle it).
    """

    def allowed(distance: np.ndarray, speed: np.ndarray) -> np.ndarray:
        room = distance - FENCE_GUARD_BUFFER
        limit = np.sign(room) * fastest_speed_for(np.abs(room), loop_hz)
        brake = stopping_distance(np.clip(speed, 0.0, None), loop_hz) >= room
        return np.where(np.isnan(room), np.inf, np.where(brake, np.minimum(limit, 0.0), limit))

    with np.errstate(invalid="ignore"):  # NaN rooms give NaN speeds, replaced by inf above
        up, down = allowed(high - pos, vel), allowed(pos - low, -vel)
    guarded = np.clip(velocity, -down, up)
    return guarded, (guarded != velocity).any(axis=-1)


EventKind = Literal[
    "armed",
    "arming_failed",
    "takeoff",
    "policy_start",
    "geofence_breach",
    "fence_guard",
    "stale_hover",
    "stale_land",
    "invalid_pose",
    "invalid_action",
    "recovered",
    "safety_filter",
    "tracker_lag",
    "link_lost",
    "touchdown",
    "handover",
    "hard_touchdown",
    "off_pad_contact",
    "land",
    "motors_off",
    "land_replanned",
    "land_timeout",
    "tumbled",
    "flight_timeout",
    "interrupt",
    "emergency",
    "loop_overrun",
    "fault_injected",
    "firmware",
    "error",
]
Action = Literal["fly", "hover", "land"]


@dataclass
class Event:
    """Something the loop noticed or did."""

    t: float
    """Time since the start of the mission (s)."""
    kind: EventKind
    message: str
    drone: int | None = None
    """Index of the drone concerned, or None for the swarm."""

    def __post_init__(self) -> None:
        self.t = float(self.t)
        self.drone = None if self.drone is None else int(self.drone)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class Verdict:
    """What the swarm must do this tick, and why."""

    action: Action
    events: list[Event]


class SafetyMonitor:
    """Applies the rules above tick by tick. Times are mission times (s)."""

    def __init__(self, lab: LabConfig) -> None:
        self.lab = lab
        self.names = lab.drone_names
        self.pad_bodies = [p.body for p in lab.drone_pads()]
        low, high = lab.geofence.bounds(soft=True)
        self._low, self._high = np.array(low), np.array(high)
        hard_low, hard_high = lab.geofence.bounds(soft=False)
        self._hard_low = np.array([hard_low[0], hard_low[1], -np.inf])  # descending to the floor is landing
        self._hard_high = np.array(hard_high)
        self.geofence_at: float | None = None
        """When the geofence was breached (the flight is then aborted)."""
        self._tilted_since = np.full(len(self.names), np.nan)
        """Since when each drone has been tilted beyond ``tumble_tilt_deg`` (s; NaN: it is not)."""
        self._degraded = False
        self._bad_action_since: float | None = None
        self._landing = False

    def inside_soft_fence(self, pos: np.ndarray) -> np.ndarray:
        """Per drone ``(N,)``: inside the soft box (NaN positions count as inside; staleness handles them)."""
        outside = (pos < self._low) | (pos > self._high)
        return ~outside.any(axis=-1)

    def keep_inside(self, velocity: np.ndarray, pos: np.ndarray, vel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The policy's setpoints ``(N, 3)`` m/s through the fence guard (:func:`keep_inside`) of the soft box, drones
        at ``pos`` ``(N, 3)`` m flying ``vel`` ``(N, 3)`` m/s; and ``(N,)`` bool, which changed. The floor is not
        guarded: landing goes down."""
        low = np.array([self._low[0], self._low[1], -np.inf])
        return keep_inside(velocity, pos, vel, low, self._high, self.lab.rates.loop_hz)

    def guard_lets_reach(self, point: np.ndarray) -> bool:
        """Whether the fence guard lets a drone reach ``point`` ``(3,)`` m: at least :data:`FENCE_GUARD_BUFFER` inside
        the soft box's side walls (the ceiling does not matter for a pad; NaN counts as reachable)."""
        xy = np.asarray(point, dtype=float)[:2]
        inside = (xy >= self._low[:2] + FENCE_GUARD_BUFFER) & (xy <= self._high[:2] - FENCE_GUARD_BUFFER)
        return bool((inside | np.isnan(xy)).all())

    def stopping_points(self, pos: np.ndarray, vel: np.ndarray) -> np.ndarray:
        """Where each drone ``(N, 3)`` would stand still if told to hover now (its braking path is straight)."""
        speed = np.linalg.norm(vel, axis=-1, keepdims=True)
        distance = stopping_distance(speed, self.lab.rates.loop_hz)
        return pos + np.divide(vel * distance, speed, out=np.zeros_like(vel), where=speed > 1e-9)

    def stops_inside_hard_fence(self, pos: np.ndarray, vel: np.ndarray) -> np.ndarray:
        """Per drone ``(N,)``: its stopping point is inside the hard box (the floor excepted; NaN counts as inside)."""
        stop = self.stopping_points(pos, vel)
        outside = (stop < self._hard_low) | (stop > self._hard_high)
        return ~outside.any(axis=-1)

    def arming_problems(self, est: SwarmEstimate, lost: list[str | None]) -> list[str]:
        """Everything that forbids take-off now (empty: cleared to take off)."""
        cfg, problems = self.lab.safety, []
        for i, name in enumerate(self.names):
            pad = self.pad_bodies[i]
            bodies = ((name, est.drone_age[i], est.drone_invalid[i]), (pad, est.pad_age[i], est.pad_invalid[i]))
            for body, age, invalid in bodies:
                if invalid:
                    problems.append(f"{body}: its latest pose was rejected")
                elif not age <= cfg.stale_hover_s:
                    problems.append(f"{body}: not seen by the motion-capture system for {age:.2f} s")
            if lost[i]:
                problems.append(f"{name}: radio link lost ({lost[i]})")
            pos = est.pos[i]
            if not np.isfinite(pos).all():
                continue
            if not self.lab.geofence.contains(pos, soft=True):
                problems.append(f"{name} at {np.round(pos, 2).tolist()} is outside the soft geofence")
            pad_at = np.round(est.pad_pos[i], 2).tolist()
            if not self.lab.geofence.contains(est.pad_pos[i], soft=False):
                problems.append(f"pad of {name} at {pad_at} is outside the geofence")
            elif not self.guard_lets_reach(est.pad_pos[i]):
                problems.append(
                    f"pad of {name} at {pad_at} is not {100 * FENCE_GUARD_BUFFER:.0f} cm inside the soft geofence: the "
                    f"fence guard holds drones that far inside it, so {name} could not reach its pad. Move the pad "
                    "inwards or widen the geofence."
                )
            pad_tilt = float(np.degrees(np.arccos(np.clip(est.pad_normal[i, 2], -1.0, 1.0))))
            if pad_tilt > cfg.max_pad_tilt_deg:  # NaN (pad unseen) is reported above
                problems.append(
                    f"pad of {name} is tilted {pad_tilt:.0f} degrees (limit {cfg.max_pad_tilt_deg}): its normal is the "
                    f"z axis of body {pad!r}. If the plate is not tilted that far, define the body with its z axis "
                    "perpendicular to the pads; otherwise raise safety.max_pad_tilt_deg"
                )
            speed = float(np.linalg.norm(est.vel[i]))
            if speed > cfg.arming_max_speed:
                problems.append(f"{name} moves at {speed:.2f} m/s (limit {cfg.arming_max_speed})")
            tilt = float(tilt_deg(est.quat[i]))
            if tilt > cfg.arming_max_tilt_deg:
                problems.append(f"{name} is tilted {tilt:.0f} degrees (limit {cfg.arming_max_tilt_deg})")
            if pos[2] > self.lab.limits.takeoff_height - 0.2:
                problems.append(f"{name} is at z={pos[2]:.2f} m, not below the take-off height")
        pad_top = np.nanmax(est.pad_pos[:, 2]) if np.isfinite(est.pad_pos[:, 2]).any() else np.nan
        height = self.lab.limits.takeoff_height
        if pad_top + TAKEOFF_CLEARANCE > height:
            problems.append(
                f"the take-off height {height} m is not {TAKEOFF_CLEARANCE} m above the pads (z={pad_top:.2f} m)"
            )
        for i in range(len(self.names)):
            for j in range(i + 1, len(self.names)):
                gap = float(np.linalg.norm(est.pos[i] - est.pos[j]))
                if gap < cfg.arming_min_separation:
                    problems.append(f"{self.names[i]} and {self.names[j]} are {gap:.2f} m apart")
        return problems

    def tumbled(self, now: float, est: SwarmEstimate, flying: np.ndarray) -> list[int]:
        """Drones of ``flying`` ``(N,)`` whose fresh, valid pose has been tilted more than ``tumble_tilt_deg`` for at
        least ``tumble_s``: hit or flipped, they cannot be flown, and their own thrust drives them sideways."""
        cfg = self.lab.safety
        fresh = (est.drone_age <= cfg.stale_hover_s) & ~est.drone_invalid
        tilted = flying & fresh & (np.nan_to_num(tilt_deg(est.quat)) > cfg.tumble_tilt_deg)
        self._tilted_since = np.where(tilted, np.fmin(self._tilted_since, now), np.nan)
        return np.flatnonzero(tilted & (now - self._tilted_since >= cfg.tumble_s)).tolist()

    def flight(self, now: float, est: SwarmEstimate, flying: np.ndarray, action_ok: bool) -> Verdict:
        """The verdict for drones under the policy (``flying`` ``(N,)``): fly, hover or land."""
        cfg, events = self.lab.safety, []
        if self._landing:
            return Verdict("land", events)
        if self.geofence_at is None:
            left = flying & ~self.inside_soft_fence(est.pos)
            overshoots = flying & ~self.stops_inside_hard_fence(est.pos, est.vel)
            outside = left | overshoots
            for i in np.flatnonzero(outside):
                pos = np.round(est.pos[i], 2).tolist()
                why = (
                    "left the soft fence"
                    if left[i]
                    else f"at {np.linalg.norm(est.vel[i]):.2f} m/s could not stop inside the hard fence"
                )
                events.append(Event(now, "geofence_breach", f"{self.names[i]} at {pos} {why}", int(i)))
            if outside.any():
                self.geofence_at = now
        if self.geofence_at is not None:
            if now - self.geofence_at >= cfg.geofence_hover_s:
                return self._land(now, events, "geofence breached: landing every drone")
            return Verdict("hover", events)
        age = est.age
        if (age > cfg.stale_land_s).any():
            worst = int(np.argmax(age))
            message = f"data of {self.names[worst]} or its pad is {age[worst]:.2f} s old: landing every drone"
            events.append(Event(now, "stale_land", message, worst))
            return self._land(now, events, None)
        if not action_ok:
            self._bad_action_since = now if self._bad_action_since is None else self._bad_action_since
            if now - self._bad_action_since >= cfg.stale_land_s:
                return self._land(now, events, "no valid action for too long: landing every drone")
        else:
            self._bad_action_since = None
        bad = est.invalid | (age > cfg.stale_hover_s)
        if bad.any() or not action_ok:
            if not self._degraded:
                self._degraded = True
                if bad.any():
                    i = int(np.flatnonzero(bad)[0])
                    what = "rejected pose" if est.invalid[i] else f"data {age[i]:.2f} s old"
                    events.append(Event(now, "stale_hover", f"{self.names[i]} or its pad: {what}: hovering", i))
            return Verdict("hover", events)
        if self._degraded:
            self._degraded = False
            events.append(Event(now, "recovered", "every pose fresh and valid again: the policy resumes"))
        return Verdict("fly", events)

    def _land(self, now: float, events: list[Event], message: str | None) -> Verdict:
        self._landing = True
        if message:
            events.append(Event(now, "land", message))
        return Verdict("land", events)
