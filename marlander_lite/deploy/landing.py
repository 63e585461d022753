"""How a drone comes down: what it touched, the surface under it, when it rests, when to hand over.

Pure functions of a :class:`SwarmEstimate`; :class:`marlander_lite.deploy.mission.Mission` acts on
their answers. Heights are world z (m); ``landed_height`` is the height of a drone's body origin
above a surface it rests on (``TaskConfig.landed_height``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from marlander_lite.deploy.config import LimitsConfig
from marlander_lite.deploy.estimation import SwarmEstimate

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
    horizontal: np.ndarray
    """Horizontal distance from the pad centre (m)."""
    rel_speed: np.ndarray
    """Speed relative to the pad (m/s)."""

    @property
    def any(self) -> np.ndarray:
        """Touching anything."""
        return self.landed | self.hard | self.off_pad


def surface_below(pos: np.ndarray, est: SwarmEstimate, floor_z: float) -> tuple[float, int | None]:
    """Height of the surface under the point ``pos`` (m) and the pad it is over (None: the floor)."""
    if np.isfinite(pos).all():
        gaps = np.hypot(*(est.pad_pos[:, :2] - pos[:2]).T)
        near = np.flatnonzero((gaps < SURFACE_RADIUS) & (est.pad_pos[:, 2] < pos[2]))
        if len(near):
            j = int(near[np.argmin(gaps[near])])
            return float(est.pad_pos[j, 2]), j
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
    horizontal = np.hypot(rel[:, 0], rel[:, 1])
    rel_speed = np.linalg.norm(est.vel - est.pad_vel, axis=-1)
    on_pad = candidates & (horizontal <= pad_radius) & (rel[:, 2] <= limits.touchdown_height)
    slow = rel_speed <= limits.touchdown_speed
    surface = np.array([surface_below(p, est, floor_z)[0] for p in est.pos])
    down = candidates & ~on_pad & (est.pos[:, 2] <= surface + landed_height + limits.touchdown_height)
    return Contacts(on_pad & slow, on_pad & ~slow, down, rel, horizontal, rel_speed)


def lingering(
    est: SwarmEstimate, candidates: np.ndarray, c: Contacts, pad_radius: np.ndarray, limits: LimitsConfig
) -> np.ndarray:
    """Drones hovering just above their slow pads, within half the pad radius ``(N,)``: hand-over candidates."""
    pad_speed = np.linalg.norm(est.pad_vel, axis=-1)
    near = candidates & (c.rel[:, 2] <= limits.handover_height) & (c.horizontal <= pad_radius / 2)
    return near & (c.rel_speed <= HANDOVER_MAX_REL_SPEED) & (pad_speed <= HANDOVER_MAX_PAD_SPEED)


def rests(
    est: SwarmEstimate, i: int, surface: float, surface_vel: np.ndarray, landed_height: float, stale_s: float
) -> bool:
    """Whether drone ``i`` rests on the surface at height ``surface`` moving at ``surface_vel`` (fresh data only)."""
    if est.drone_invalid[i] or not est.drone_age[i] <= stale_s:
        return False
    low = est.pos[i, 2] - surface <= landed_height + REST_HEIGHT
    return bool(low and np.linalg.norm(est.vel[i] - surface_vel) < REST_SPEED)
