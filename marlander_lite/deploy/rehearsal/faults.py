"""Faults to rehearse: what goes wrong in a motion-capture lab, injected into the simulated one.

=================  ==========================================================================
``dropout``        the whole mocap stream stops (default 0.3 s): hover, then resume.
``latency-spike``  frames arrive 0.3 s later than usual for a while (default 1 s): hover while
                   none arrive, then fly on late data.
``occlusion``      one drone's markers are hidden (default 1 s): hover, then land every drone
                   (the hidden one lands on its firmware's dead-reckoned estimate).
``nan-pose``       one drone's pose comes as NaN (default 0.2 s): rejected, hover, resume.
``link-loss``      one drone's radio link dies: it is left to its firmware (level out after
                   0.5 s, motors off after 2 s, it drops), every other drone lands.
``geofence-breach`` one drone flies off at the lab's top speed towards the nearest wall
                   whatever it is told (a failing estimator or tracker on board, which no
                   setpoint and so no fence guard can stop) until it crosses the soft fence:
                   every drone hovers, the runaway stops inside the hard fence, every drone lands.
=================  ==========================================================================

A :class:`FaultInjector` is a :class:`marlander_lite.deploy.mission.Mission` hook: it starts
its fault ``start_s`` seconds after the policy took over and records a ``fault_injected`` event.
A fault is checked when it is made (finite start >= 0, positive duration, drone index >= 0) and
against the lab (:meth:`FaultSpec.check`: the drone exists, the start falls within the flight's
time limit); one still not injected when the flight ends (the drones landed first) makes the
rehearsal fail (:attr:`marlander_lite.deploy.rehearsal.RehearsalResult.fault_missed`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, get_args

import numpy as np

from marlander_lite.deploy.modes import MissionMode

if TYPE_CHECKING:
    from marlander_lite.deploy.mission import Mission
    from marlander_lite.deploy.rehearsal.mocap import SimulatedPoseSource
    from marlander_lite.deploy.rehearsal.world import SimulatedWorld

FaultKind = Literal["dropout", "latency-spike", "occlusion", "nan-pose", "link-loss", "geofence-breach"]
FAULT_KINDS: tuple[str, ...] = get_args(FaultKind)
DEFAULT_DURATION_S = {"dropout": 0.3, "latency-spike": 1.0, "occlusion": 1.0, "nan-pose": 0.2}
LATENCY_SPIKE_S = 0.3
"""Extra delay of frames during a latency spike (s)."""


@dataclass(frozen=True)
class FaultSpec:
    """One fault: what, when (after the policy starts), how long, to which drone."""

    kind: FaultKind
    start_s: float = 1.0
    """Seconds after the policy took over (s)."""
    duration_s: float | None = None
    """How long it lasts (s); None: the kind's default (link loss and geofence breach last)."""
    drone: int = 0
    """Index of the drone concerned (for per-drone faults)."""

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"Unknown fault {self.kind!r}; allowed: {', '.join(FAULT_KINDS)}.")
        # written so that NaN fails too (every comparison with NaN is False)
        if not (math.isfinite(self.start_s) and self.start_s >= 0):
            raise ValueError(f"A fault starts at a finite time >= 0 s after the policy starts, not {self.start_s}.")
        if self.duration_s is not None and not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise ValueError(f"A fault lasts a finite time > 0 s, not {self.duration_s}.")
        if isinstance(self.drone, bool) or not isinstance(self.drone, int | np.integer) or self.drone < 0:
            raise ValueError(f"A fault's drone is an index >= 0, not {self.drone!r}.")

    def check(self, num_drones: int, time_limit_s: float | None = None) -> None:
        """Refuse a fault that cannot happen in a flight of ``num_drones`` drones whose policy may fly at most
        ``time_limit_s`` seconds (None: unknown)."""
        if not 0 <= self.drone < num_drones:
            raise ValueError(
                f"Fault drone index {self.drone} does not exist; the lab has {num_drones} drones (0 to "
                f"{num_drones - 1})."
            )
        if time_limit_s is not None and self.start_s >= time_limit_s:
            raise ValueError(
                f"A fault {self.start_s:g} s after the policy starts would never happen: the flight ends "
                f"{time_limit_s:g} s after the policy starts at the latest."
            )

    @property
    def duration(self) -> float:
        return self.duration_s if self.duration_s is not None else DEFAULT_DURATION_S.get(self.kind, np.inf)


class FaultInjector:
    """Applies one :class:`FaultSpec` to a simulated lab, as a mission hook ``injector(mission, t)``."""

    def __init__(self, spec: FaultSpec, world: SimulatedWorld, source: SimulatedPoseSource) -> None:
        spec.check(world.n)
        self.spec, self.world, self.source = spec, world, source
        self.started_at: float | None = None
        """Mission time the fault started (s)."""

    def __call__(self, mission: Mission, t: float) -> None:
        spec = self.spec
        if self.started_at is not None or mission.policy_start is None or t < mission.policy_start + spec.start_s:
            return
        if mission.mode != MissionMode.POLICY:
            return
        self.started_at = t
        until = self.world.time + spec.duration
        name = mission.names[spec.drone]
        faults = self.source.faults
        if spec.kind == "dropout":
            faults.dropout_until = until
            what = f"motion-capture stream stops for {spec.duration:.2f} s"
        elif spec.kind == "latency-spike":
            faults.extra_latency_s, faults.latency_until = LATENCY_SPIKE_S, until
            what = f"frames {LATENCY_SPIKE_S:.2f} s late for {spec.duration:.2f} s"
        elif spec.kind == "occlusion":
            faults.occluded_until[name] = until
            what = f"{name} occluded for {spec.duration:.2f} s"
        elif spec.kind == "nan-pose":
            faults.nan_until[name] = until
            what = f"{name}'s pose is NaN for {spec.duration:.2f} s"
        elif spec.kind == "link-loss":
            uri = mission.lab.drones[spec.drone].uri
            self.world.factory.crazyflies[uri].fail_link("injected fault: radio link lost")
            what = f"{name}'s radio link is lost"
        else:  # geofence-breach
            tracks = mission.estimator.tracks
            pos = tracks.pose[tracks.index[name], :2]
            low, high = mission.lab.geofence.bounds(soft=True)
            centre = (np.array(low[:2]) + np.array(high[:2])) / 2
            away = pos - centre if np.linalg.norm(pos - centre) > 1e-6 else np.array([1.0, 0.0])
            velocity = np.array([*(away / np.linalg.norm(away)), 0.0]) * mission.lab.limits.max_speed
            self.world.run_away(self.world.index(name), velocity)  # the world may order its drones otherwise
            what = f"{name} flies {np.round(velocity, 2).tolist()} m/s whatever it is told, until the soft fence"
        mission.event("fault_injected", f"{spec.kind}: {what}", spec.drone)
