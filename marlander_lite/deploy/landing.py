"""How a drone comes down: what it touched, the surface under it, when it rests, when to hand over.

Pure functions of a :class:`SwarmEstimate` decide; :class:`LandingControl`, the landing half of
:class:`marlander_lite.deploy.mission.Mission`, acts on their answers (stops motors, hands drones
over to the high-level commander, lands them, ends their landings) and keeps what it knows in the
mission's :class:`~marlander_lite.deploy.mission_state.Landings`. Heights are world z (m);
``landed_height`` is the height of a drone's body origin above a surface it rests on
(``TaskConfig.landed_height``). Touchdowns are judged in each pad's frame, as the simulators judge them:
the height along the pad normal and the offset within the pad plane (on a level pad, the height above
the goal and the horizontal distance); on a tilted plate the surface under a drone is the plate's plane.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from marlander_lite.deploy.config import LimitsConfig
from marlander_lite.deploy.estimation import SwarmEstimate
from marlander_lite.deploy.mission_state import PlannedLanding
from marlander_lite.deploy.modes import AIRBORNE, FLYING, DronePhase, MissionMode
from marlander_lite.task import pad_frame_errors

if TYPE_CHECKING:
    from marlander_lite.deploy.config import LabConfig
    from marlander_lite.deploy.mission_state import Landings, Milestones, PoseStream, TickBook
    from marlander_lite.task import TaskConfig

SURFACE_RADIUS = 0.35
"""A drone within this horizontal distance of a pad (m) is over the plate: it lands at the pads' height."""
HANDOVER_MAX_PAD_SPEED = 0.1
"""No hand-over to the high-level commander over a pad faster than this (m/s): its land is vertical."""
HANDOVER_MAX_REL_SPEED = 0.25
"""A drone lingers above its pad when slower than this relative to it (m/s)."""
HANDOVER_DESCENT_SPEED = 0.1
"""Descent speed of a hand-over landing (m/s)."""
REST_HEIGHT = 0.05
"""A landing drone rests when it is at most this far above its resting height (m) ..."""
REST_SPEED = 0.15
"""... and slower than this relative to the surface (m/s)."""


@dataclass
class Contacts:
    """What each drone touches now, ``(N,)`` arrays."""

    landed: np.ndarray
    """On its own pad, inside the pad radius, within ``touchdown_height`` of its goal, slow: a landing."""
    hard: np.ndarray
    """On its own pad but faster than ``touchdown_speed`` relative to it: a crash in training."""
    off_pad: np.ndarray
    """Down on the floor or the plate off its pad: a crash in training."""
    rel: np.ndarray
    """Position relative to the goal point ``(N, 3)`` m."""
    height: np.ndarray
    """Height above the goal point along the pad normal ``(N,)`` m (``rel[:, 2]`` on a level pad)."""
    offset: np.ndarray
    """Distance from the pad centre within the pad plane ``(N,)`` m (the horizontal distance on a level pad): the
    landing error."""
    rel_speed: np.ndarray
    """Speed relative to the pad (m/s)."""

    @property
    def any(self) -> np.ndarray:
        """Touching anything."""
        return self.landed | self.hard | self.off_pad


PLANE_MIN_NORMAL_Z = 0.5
"""A pad whose normal is tilted more than 60 degrees (``n_z`` below this) counts as level under a drone: a plane that
steep (or a glitch in the body's attitude) would put the surface under a drone far above or below the pad."""


def plane_heights(xy: np.ndarray, est: SwarmEstimate) -> np.ndarray:
    """Height ``(N,)`` m of each pad's plane at the horizontal point ``xy`` ``(2,)`` m: the pad's own height on a
    level pad; on a tilted one ``c_z - (n_x (x - c_x) + n_y (y - c_y)) / n_z`` for its centre ``c`` and normal
    ``n`` (see :data:`PLANE_MIN_NORMAL_Z`)."""
    n, d = est.pad_normal, xy - est.pad_pos[:, :2]
    steep = ~(n[:, 2] >= PLANE_MIN_NORMAL_Z)  # NaN (unseen): the centre's height, NaN as well
    rise = (n[:, 0] * d[:, 0] + n[:, 1] * d[:, 1]) / np.where(steep, 1.0, n[:, 2])
    return est.pad_pos[:, 2] - np.where(steep, 0.0, rise)


def surface_below(pos: np.ndarray, est: SwarmEstimate, floor_z: float) -> tuple[float, int | None]:
    """Height of the surface under the point ``pos`` (m) and the pad it is over (None: the floor): the plane of the
    nearest pad within ``SURFACE_RADIUS`` horizontally whose plane is below ``pos``."""
    if np.isfinite(pos).all():
        gaps = np.hypot(*(est.pad_pos[:, :2] - pos[:2]).T)
        heights = plane_heights(pos[:2], est)
        near = np.flatnonzero((gaps < SURFACE_RADIUS) & (heights < pos[2]))
        if len(near):
            j = int(near[np.argmin(gaps[near])])
            return float(heights[j]), j
    return float(floor_z), None


def contacts(
    est: SwarmEstimate,
    candidates: np.ndarray,
    pad_radius: np.ndarray,
    limits: LimitsConfig,
    landed_height: float,
    floor_z: float,
) -> Contacts:
    """Classify the ``candidates`` ``(N,)`` (flying drones with fresh data) like ``task.touchdown_outcome``."""
    rel = est.pos - est.goal
    height, offset = pad_frame_errors(rel, est.pad_normal)
    rel_speed = np.linalg.norm(est.vel - est.pad_vel, axis=-1)
    on_pad = candidates & (offset <= pad_radius) & (height <= limits.touchdown_height)
    slow = rel_speed <= limits.touchdown_speed
    surface = np.array([surface_below(p, est, floor_z)[0] for p in est.pos])
    down = candidates & ~on_pad & (est.pos[:, 2] <= surface + landed_height + limits.touchdown_height)
    return Contacts(on_pad & slow, on_pad & ~slow, down, rel, height, offset, rel_speed)


def lingering(
    est: SwarmEstimate, candidates: np.ndarray, c: Contacts, pad_radius: np.ndarray, limits: LimitsConfig
) -> np.ndarray:
    """Drones hovering just above their slow pads, within half the pad radius ``(N,)``: hand-over candidates."""
    pad_speed = np.linalg.norm(est.pad_vel, axis=-1)
    near = candidates & (c.height <= limits.handover_height) & (c.offset <= pad_radius / 2)
    return near & (c.rel_speed <= HANDOVER_MAX_REL_SPEED) & (pad_speed <= HANDOVER_MAX_PAD_SPEED)


def surface_known(est: SwarmEstimate, i: int, stale_s: float) -> bool:
    """Whether :func:`surface_below` can be trusted for drone ``i``: its pose and every pad's are valid and fresh.

    A landing is re-planned only on such data: a pad lost from view for a moment must not make the plate under a
    landing drone look like the floor."""
    drone = not est.drone_invalid[i] and est.drone_age[i] <= stale_s
    return bool(drone and not est.pad_invalid.any() and (est.pad_age <= stale_s).all())


def rests(
    est: SwarmEstimate, i: int, surface: float, surface_vel: np.ndarray, landed_height: float, stale_s: float
) -> bool:
    """Whether drone ``i`` rests on the surface at height ``surface`` moving at ``surface_vel`` (fresh data only)."""
    if est.drone_invalid[i] or not est.drone_age[i] <= stale_s:
        return False
    low = est.pos[i, 2] - surface <= landed_height + REST_HEIGHT
    return bool(low and np.linalg.norm(est.vel[i] - surface_vel) < REST_SPEED)


class LandingControl:
    """The landing half of :class:`marlander_lite.deploy.mission.Mission` (a mixin): touchdowns, hand-overs,
    high-level landings and their end, the best-effort landing after an error. It uses the mission's
    link, phases, estimates and events, and keeps its own state in :attr:`landings`; the functions
    above decide, these methods act."""

    lab: LabConfig
    link: Any
    clock: Any
    task: TaskConfig
    names: list[str]
    n: int
    t: float
    phase: list[DronePhase]
    times: Milestones
    stream: PoseStream
    book: TickBook
    landings: Landings

    # provided by Mission
    def event(self, kind: Any, message: str, drone: int | None = None) -> None:
        raise NotImplementedError

    def _set_phase(self, i: int, phase: DronePhase) -> None:
        raise NotImplementedError

    def _enter(self, mode: MissionMode) -> None:
        raise NotImplementedError

    def _touchdowns(self, est: SwarmEstimate, flying: np.ndarray) -> None:
        """Stop the motors of drones that touched something; hand lingering ones over to the planner."""
        land = self.landings
        fresh = flying & ~est.invalid & (est.age <= self.lab.safety.stale_hover_s)
        floor = self.lab.geofence.z[0]
        c = contacts(est, fresh, land.pad_radius, self.lab.limits, self.task.landed_height, floor)
        for i in np.flatnonzero(c.any):
            self._motors_off(i)
            if c.landed[i]:
                self._landed(i, c.offset[i], "touched its pad")
            elif c.hard[i]:
                message = f"{self.names[i]} hit its pad at {c.rel_speed[i]:.2f} m/s (a crash in training): motors off"
                self.event("hard_touchdown", message, i)
            else:
                message = f"{self.names[i]} touched the floor or plate off its pad (a crash in training): motors off"
                self.event("off_pad_contact", message, i)
        near = lingering(est, fresh & ~c.any, c, land.pad_radius, self.lab.limits)
        near &= self.lab.limits.handover_height > 0
        land.near_since[~near] = np.nan
        land.near_since[near & np.isnan(land.near_since)] = self.t
        for i in np.flatnonzero(near & (self.t - land.near_since >= self.lab.limits.handover_dwell_s)):
            duration = max(0.5, (c.height[i] + self.task.landed_height) / HANDOVER_DESCENT_SPEED)
            self._land(i, est, duration=duration, surface=float(plane_heights(est.pos[i, :2], est)[i]))
            land.handover[i] = True
            message = f"{self.names[i]} hovers {c.height[i] * 100:.1f} cm above its pad: high-level landing on it"
            self.event("handover", message, i)

    def _motors_off(self, i: int) -> None:
        """Stop drone ``i``'s motors: it is down, and its command is ``stop`` from now on."""
        self.link.stop_motors(i)
        self._set_phase(i, DronePhase.DOWN)
        self.book.commands[i] = {"kind": "stop"}

    def _landed(self, i: int, error: float, how: str) -> None:
        land = self.landings
        land.on_pad[i], land.error[i] = True, error
        land.time[i] = self.t - self.times.policy
        self.event("touchdown", f"{self.names[i]} {how} {error * 100:.1f} cm from the centre: motors off", i)

    def _landings(self, est: SwarmEstimate) -> None:
        """Stop the motors of landing drones once they rest (or when their landing overran); a drone handed over above
        its pad stops them when it touches the pad, as under the policy."""
        land, margin = self.landings, self.lab.safety.land_timeout_margin_s
        stale = self.lab.safety.stale_hover_s
        handed = np.zeros(self.n, dtype=bool)
        handed[[i for i in land.planned if land.handover[i] and self.phase[i] == DronePhase.LANDING]] = True
        if handed.any():
            fresh = handed & ~est.invalid & (est.age <= stale)
            touched = contacts(
                est, fresh, land.pad_radius, self.lab.limits, self.task.landed_height, self.lab.geofence.z[0]
            )
        for i, (t_land, duration, surface) in list(land.planned.items()):
            if self.phase[i] != DronePhase.LANDING:
                del land.planned[i]
                continue
            if handed[i] and touched.landed[i]:
                # Its planner would press it on down into the pad: on a tilted one, uphill rim first, until it
                # tips and slides off. Motors off within touchdown_height of the goal, as a policy touchdown.
                self._motors_off(i)
                del land.planned[i]
                self._landed(i, touched.offset[i], "touched its pad")
                continue
            below, pad = surface_below(est.pos[i], est, self.lab.geofence.z[0])
            if below < surface - REST_HEIGHT and surface_known(est, i, stale):
                # What it was landing on moved away (a UR10 carried the plate on): its land would end beside the
                # plate at the plate's height and stop the motors there, dropping it. It lands on what is below now.
                message = f"{self.names[i]}: the surface under it moved away: landing at {below:.2f} m instead"
                self.event("land_replanned", message, i)
                self._land(i, est, surface=below)
                continue
            surface_vel = np.zeros(3) if pad is None else est.pad_vel[pad]
            resting = rests(est, i, surface, surface_vel, self.task.landed_height, stale)
            elapsed = self.t - t_land
            if (elapsed >= duration and resting) or elapsed > duration + margin:
                self._motors_off(i)
                del land.planned[i]
                error = float(pad_frame_errors(est.pos[i] - est.goal[i], est.pad_normal[i])[1])
                if land.handover[i] and resting and error <= land.pad_radius[i]:
                    self._landed(i, error, "rests on its pad")
                elif resting:
                    self.event("motors_off", f"{self.names[i]} rests: motors off", i)
                else:
                    self.event("land_timeout", f"{self.names[i]} landing timed out: motors off", i)

    def _land(self, i: int, est: SwarmEstimate, duration: float | None = None, surface: float | None = None) -> None:
        """``notify_setpoint_stop`` + high-level land of drone ``i`` onto ``surface`` (default: what is under it)."""
        if surface is None:
            surface, _ = surface_below(est.pos[i], est, self.lab.geofence.z[0])
        if duration is None:
            z = est.pos[i, 2] if np.isfinite(est.pos[i, 2]) else self.lab.limits.takeoff_height
            duration = max(1.0, (z - surface) / self.lab.limits.land_speed)
        self.link.land(i, surface, duration)
        self._set_phase(i, DronePhase.LANDING)
        self.landings.planned[i] = PlannedLanding(self.t, duration, surface)
        self.book.commands[i] = {"kind": "land", "height": surface, "duration": duration}

    def _land_all(self, est: SwarmEstimate, message: str | None) -> None:
        """Land every airborne drone (mode ``landing``), after logging ``message`` as a ``land`` event if given."""
        if message:
            self.event("land", message)
        for i in range(self.n):
            if self.phase[i] in AIRBORNE:
                self._land(i, est)
        self._enter(MissionMode.LANDING)

    def _fallback_landing(self) -> None:
        """After an unexpected error: land every flying drone, wait for it, stop the motors (best effort)."""
        est, longest = self.stream.last, 0.0
        for i in range(self.n):
            if self.phase[i] in AIRBORNE and est is not None:
                try:
                    self._land(i, est)
                    longest = max(longest, self.landings.planned[i].duration)
                except Exception:  # keep trying the other drones
                    pass
        if longest:
            self.clock.sleep_until(self.clock.now() + longest + 1.0)
        for i in range(self.n):
            if self.phase[i] in FLYING:
                try:
                    self.link.stop_motors(i)
                    self._set_phase(i, DronePhase.DOWN)
                except Exception:  # keep trying the other drones
                    pass
