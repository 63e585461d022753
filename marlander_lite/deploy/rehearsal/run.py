"""A deployment rehearsed end to end in simulation: the hardware code path against a simulated lab.

:func:`rehearse` builds the simulated lab (:class:`SimulatedWorld` with the PyBullet Crazyflie
swarm or the point-mass swarm), a :class:`SimulatedPoseSource` reading it, the real
:class:`CrazyflieLink` (cflib ``Swarm`` on virtual Crazyflies), optionally a fault, and runs the
same :class:`Mission` as ``marlander deploy`` on hardware. Afterwards the world runs a few more
seconds with no commands (so a drone left to its firmware comes down), and the result says
where every drone ended up, checked against the simulator's ground truth.

With ``pad_assignment: shortest`` the drones are paired with pads as on hardware, from the simulated motion
capture's view of them at rest (:mod:`marlander_lite.deploy.pairing`). The simulators give drone ``k`` pad ``k``,
so the world is then built again from the same starts with its drones listed in the order of the pads they were
given; the result lists everything in the config's drone order.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from marlander_lite.deploy.config import LabConfig, current_simulator_name, load_lab_policy
from marlander_lite.deploy.flight_log import FlightLogWriter, flight_header
from marlander_lite.deploy.link import CrazyflieLink
from marlander_lite.deploy.mission import Mission
from marlander_lite.deploy.pairing import pair_drones_with_pads, resting_positions
from marlander_lite.deploy.rehearsal.faults import FaultInjector, FaultSpec
from marlander_lite.deploy.rehearsal.mocap import SimulatedPoseSource
from marlander_lite.deploy.rehearsal.world import SimulatedWorld, make_simulator
from marlander_lite.deploy.results import MissionResult
from marlander_lite.deploy.runner import Policy


@dataclass
class RehearsalResult:
    """A rehearsal's mission result plus the simulator's ground truth at the end."""

    mission: MissionResult
    fault: str | None
    simulator: str
    final_positions: np.ndarray
    """True drone positions at the end ``(N, 3)`` m."""
    final_speeds: np.ndarray
    """True drone speeds at the end ``(N,)`` m/s."""
    motors_on: np.ndarray
    """Whether each drone's motors still run ``(N,)``."""
    pad_positions: np.ndarray
    """True pad centres at the end ``(N, 3)`` m."""
    inside_fence: np.ndarray
    """Each drone inside the hard geofence ``(N,)``."""
    riding: np.ndarray
    """Each drone resting with its motors off on the plate, on its pad or next to it (it moves with a moving
    platform) ``(N,)``."""
    min_separation: float
    """Smallest distance between two drones during the flight (m)."""
    fence_excess: np.ndarray
    """How far each drone went outside the hard geofence at any physics step ``(N,)`` m; 0: never left it."""
    pads: list[str] = field(default_factory=list)
    """The pad each drone flew to, drone order (the config's, or the pairing's with ``pad_assignment: shortest``)."""
    firmware_events: list[tuple[str, float, str, str]] = field(default_factory=list)
    """(drone, time, kind, message) from the virtual firmwares."""
    fault_time: float | None = None
    """Mission time the fault was injected (s); None: no fault, or it never happened."""

    @property
    def fault_missed(self) -> bool:
        """A fault was asked for but never injected (the flight ended first): nothing was rehearsed."""
        return self.fault is not None and self.fault_time is None

    @property
    def passed(self) -> bool:
        """What ``marlander deploy --sim`` exits 0 on: safe, and every drone on its pad (no fault) or the
        fault injected (with a fault), and not cut short by a signal."""
        if not self.safe or self.mission.interrupted_by is not None:
            return False
        return not self.fault_missed if self.fault is not None else self.mission.success

    @property
    def at_rest(self) -> np.ndarray:
        """Motors off and still, or riding the plate ``(N,)``: down on a surface."""
        return ~self.motors_on & ((self.final_speeds < 0.05) | self.riding)

    @property
    def safe(self) -> bool:
        """Every drone inside the fence, and either down at rest or hovering (motors on, still)."""
        hovering = self.motors_on & (self.final_speeds < 0.2)
        return bool(self.inside_fence.all() and (self.at_rest | hovering).all())

    def summary(self) -> str:
        """A few human-readable lines."""
        m = self.mission
        lines = [
            f"simulator {self.simulator}, fault {self.fault or 'none'}: armed={m.armed}, on pad={m.on_pad}, "
            f"phases={m.phases}, safe={self.safe}",
            f"  landing error {np.round(np.array(m.landing_error) * 100, 2).tolist()} cm, "
            f"landing time {np.round(m.landing_time, 2).tolist()} s, min separation {self.min_separation:.2f} m",
            f"  loop work per tick: median {m.loop_ms_median:.3f} ms, p95 {m.loop_ms_p95:.3f} ms, "
            f"max {m.loop_ms_max:.2f} ms over {m.ticks} ticks ({m.overruns} over the period)",
        ]
        lines += [f"  {e.t:7.2f} s  {e.kind:16s} {e.message}" for e in m.events]
        if self.fault_missed:
            lines.append(f"  fault {self.fault} NEVER INJECTED: the flight ended before it was due; nothing rehearsed")
        after = [(t, d, msg) for d, t, kind, msg in self.firmware_events if kind == "watchdog" and t > m.duration_s]
        lines += [f"  {t:7.2f} s  {'firmware':16s} {d} firmware: {msg} (after the loop ended)" for t, d, msg in after]
        return "\n".join(lines)


def rehearse(
    lab: LabConfig,
    policy: Policy | str | Path,
    *,
    simulator: str | None = None,
    fault: FaultSpec | None = None,
    seed: int | None = None,
    log_path: str | Path | None = None,
    settle_s: float = 3.0,
    overwrite_log: bool = False,
    controller: str | None = None,
    hooks: Sequence[Callable[[Mission, float], None]] = (),
    simulator_options: Mapping[str, Any] | None = None,
) -> RehearsalResult:
    """Fly the lab's mission in simulation and report how it ended.

    Args:
        lab: the lab config (its ``simulation`` section sets the platform, noise and seed).
        policy: a policy file (loaded and checked with :func:`load_lab_policy`) or a policy object.
        simulator: ``crazyflie`` (PyBullet) or ``pointmass``; default: ``lab.simulation.simulator`` (the old
            name ``pybullet`` still works, with a ``FutureWarning``).
        fault: a fault to inject, or None.
        seed: overrides ``lab.simulation.seed``.
        log_path: where to write the flight log (None: no log).
        settle_s: simulated seconds to run after the mission with no commands.
        overwrite_log: replace an existing file at ``log_path`` (otherwise it is refused).
        controller: the PyBullet drones' controller (see :func:`make_simulator`); None: its default.
        hooks: more mission hooks, called after the rehearsal's own at the start of every tick.
        simulator_options: more keyword arguments of the simulator's swarm class (:func:`make_simulator`): a drone
            unlike the published one, e.g. ``{"tuning": {"mass_scale": 0.87}}`` in RotorPy.

    Raises:
        ValueError: a fault that cannot happen in this lab (:meth:`FaultSpec.check`).
        FileExistsError: ``log_path`` exists and ``overwrite_log`` is False.
    """
    if isinstance(policy, str | Path):
        policy = load_lab_policy(policy, lab)
    sim_cfg = lab.simulation
    seed = sim_cfg.seed if seed is None else seed
    kind = current_simulator_name(simulator, "simulator", stacklevel=2) if simulator else sim_cfg.simulator
    if fault is not None:
        fault.check(lab.num_drones, fault_time_limit(lab))
    world = SimulatedWorld(lab, make_simulator(lab, kind, controller=controller, options=simulator_options), seed=seed)
    source = _pose_source(world, seed)
    flown = lab
    if lab.pad_assignment == "shortest":
        try:
            flown = pair_drones_with_pads(lab, *resting_positions(lab, source, world))
        finally:
            world.close()
        # drone k of the simulators lands on pad k: list the drones in the order of the config's pads they now have
        by_pad = {d.pad: d for d in flown.drones}
        world_lab = dataclasses.replace(flown, drones=tuple(by_pad[d.pad] for d in lab.drones))
        starts = world.start_positions[[lab.drone_names.index(name) for name in world_lab.drone_names]]
        paired = make_simulator(world_lab, kind, controller=controller, options=simulator_options)
        world = SimulatedWorld(world_lab, paired, seed=seed, starts=starts)
        source = _pose_source(world, seed)
    all_hooks: list[Any] = [_FirmwareEvents(world), _TimeLimit(sim_cfg.max_time_s)]
    injector = None if fault is None else FaultInjector(fault, world, source)
    if injector is not None:
        all_hooks.append(injector)
    all_hooks += hooks
    link = CrazyflieLink([d.uri for d in flown.drones], flown.crazyflie, factory=world.factory)
    try:
        log = None
        if log_path is not None:
            header = flight_header(
                flown,
                policy,
                source="simulation",
                simulator=kind,
                seed=seed,
                fault=None if fault is None else fault.kind,
            )
            log = FlightLogWriter(log_path, header, overwrite=overwrite_log)
        link.open()
        result = Mission(flown, policy, source, link, clock=world, log=log, hooks=all_hooks).run()
        world.sleep_until(world.time + settle_s)
    finally:
        link.close()
        world.close()
    order = [world.index(name) for name in lab.drone_names]  # the world's drone of each config drone
    pos = world.drone_positions()[order]
    return RehearsalResult(
        mission=result,
        fault=None if fault is None else fault.kind,
        simulator=kind,
        final_positions=pos,
        final_speeds=world.drone_speeds()[order],
        motors_on=world.motors_on[order],
        pad_positions=world.pad_positions()[order],
        inside_fence=np.array([lab.geofence.contains(p) for p in pos]),
        riding=world.pad_landed[order],
        min_separation=world.min_separation,
        fence_excess=world.fence_excess[order],
        pads=[d.pad for d in flown.drones],
        firmware_events=[(fw.name, t, k, m) for fw in world.firmwares.values() for t, k, m in fw.events],
        fault_time=None if injector is None else injector.started_at,
    )


def _pose_source(world: SimulatedWorld, seed: int) -> SimulatedPoseSource:
    """The simulated motion capture of ``world``, with its lab's ``simulation`` noise, latency and losses."""
    sim_cfg = world.lab.simulation
    return SimulatedPoseSource(
        world,
        pos_noise_std=sim_cfg.pos_noise_std,
        quat_noise_std=sim_cfg.quat_noise_std,
        latency_s=sim_cfg.latency_s,
        drop_rate=sim_cfg.drop_rate,
        occlusion_rate=sim_cfg.occlusion_rate,
        seed=seed,
    )


def fault_time_limit(lab: LabConfig) -> float:
    """The latest a fault can start after the policy took over (s): the policy flies at most
    ``limits.max_flight_s``, and the simulated lab runs at most ``simulation.max_time_s`` in all."""
    return min(lab.limits.max_flight_s, lab.simulation.max_time_s)


class _FirmwareEvents:
    """Mission hook: copies the virtual firmwares' watchdog and refusal events into the flight log."""

    def __init__(self, world: SimulatedWorld) -> None:
        self.world = world
        self.seen = {uri: 0 for uri in world.firmwares}

    def __call__(self, mission: Mission, t: float) -> None:
        for uri, fw in self.world.firmwares.items():
            for _, kind, message in fw.events[self.seen[uri] :]:
                if kind in ("watchdog", "ignored", "refused", "unsupported", "locked"):
                    mission.event("firmware", f"{fw.name} firmware: {message}", mission.names.index(fw.name))
            self.seen[uri] = len(fw.events)


class _TimeLimit:
    """Mission hook: lands every drone at the simulated time limit, stops the motors 20 s later."""

    def __init__(self, max_time_s: float) -> None:
        self.max_time_s, self.landing = max_time_s, False

    def __call__(self, mission: Mission, t: float) -> None:
        if t > self.max_time_s + 20.0:
            mission.request_kill("simulated time limit + 20 s")
        elif t > self.max_time_s and not self.landing:
            self.landing = True
            mission.request_land("simulated time limit")
