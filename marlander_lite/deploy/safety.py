"""Safety rules of the deployment: when in doubt, hover; when doubt lasts, land.

The rules (thresholds in :class:`marlander_lite.deploy.config.SafetyConfig`):

=============================  ===================================================================
before take-off                :meth:`SafetyMonitor.arming_problems`: every drone and pad seen and
                               fresh, valid, inside the soft fence, still, level, apart; links up;
                               the take-off height 0.3 m above the pads.
geofence                       a flying drone outside the soft box -> every drone hovers for
                               ``geofence_hover_s``, then lands. Not resumed.
stale or missing body          any drone or pad body older than ``stale_hover_s`` -> hover (the
                               policy is centralised: one bad input spoils every command);
                               older than ``stale_land_s`` -> land. Fresh again before: resume.
NaN / out-of-range pose        rejected by the estimator -> hover at once; the body then ages
                               like a missing one.
NaN / out-of-range action      hover; if it lasts ``stale_land_s`` -> land.
lost radio link                that drone gets nothing more (its firmware levels out after
                               0.5 s and stops its motors after 2 s); every other drone lands.
Ctrl-C, emergency key          every drone lands; a second Ctrl-C stops every motor.
=============================  ===================================================================

Every decision comes with :class:`Event` s, which the loop logs.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np

from marlander_lite.deploy.config import LabConfig
from marlander_lite.deploy.estimation import SwarmEstimate

EventKind = Literal[
    "armed",
    "arming_failed",
    "takeoff",
    "policy_start",
    "geofence_breach",
    "stale_hover",
    "stale_land",
    "invalid_pose",
    "invalid_action",
    "recovered",
    "link_lost",
    "touchdown",
    "handover",
    "hard_touchdown",
    "off_pad_contact",
    "land",
    "motors_off",
    "land_timeout",
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


def tilt_deg(quat: np.ndarray) -> np.ndarray:
    """Angle between body z and world z (degrees) of ``(..., 4)`` quaternions ``(x, y, z, w)``."""
    cos = 1.0 - 2.0 * (quat[..., 0] ** 2 + quat[..., 1] ** 2)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


class SafetyMonitor:
    """Applies the rules above tick by tick. Times are mission times (s)."""

    def __init__(self, lab: LabConfig) -> None:
        self.lab = lab
        self.names = lab.drone_names
        self.pad_bodies = [p.body for p in lab.drone_pads()]
        low, high = lab.geofence.bounds(soft=True)
        self._low, self._high = np.array(low), np.array(high)
        self.geofence_at: float | None = None
        """When the geofence was breached (the flight is then aborted)."""
        self._degraded = False
        self._bad_action_since: float | None = None
        self._landing = False

    def inside_soft_fence(self, pos: np.ndarray) -> np.ndarray:
        """Per drone ``(N,)``: inside the soft box (NaN positions count as inside; staleness handles them)."""
        outside = (pos < self._low) | (pos > self._high)
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
            if not self.lab.geofence.contains(est.pad_pos[i], soft=False):
                problems.append(f"pad of {name} at {np.round(est.pad_pos[i], 2).tolist()} is outside the geofence")
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
        if pad_top + 0.3 > height:
            problems.append(f"the take-off height {height} m is not 0.3 m above the pads (z={pad_top:.2f} m)")
        for i in range(len(self.names)):
            for j in range(i + 1, len(self.names)):
                gap = float(np.linalg.norm(est.pos[i] - est.pos[j]))
                if gap < cfg.arming_min_separation:
                    problems.append(f"{self.names[i]} and {self.names[j]} are {gap:.2f} m apart")
        return problems

    def flight(self, now: float, est: SwarmEstimate, flying: np.ndarray, action_ok: bool) -> Verdict:
        """The verdict for drones under the policy (``flying`` ``(N,)``): fly, hover or land."""
        cfg, events = self.lab.safety, []
        if self._landing:
            return Verdict("land", events)
        if self.geofence_at is None:
            outside = flying & ~self.inside_soft_fence(est.pos)
            for i in np.flatnonzero(outside):
                pos = np.round(est.pos[i], 2).tolist()
                events.append(Event(now, "geofence_breach", f"{self.names[i]} at {pos} left the soft fence", int(i)))
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
