"""The simulated lab: a swarm simulator, one virtual Crazyflie firmware per drone, and the clock.

:class:`SimulatedWorld` stands for everything outside the control station: the drones (any
simulator of the :class:`marlander_lite.episodes.Simulator` protocol with the rehearsal extras
``place`` and ``stop_motors``, one environment), the platform, the motion-capture truth
(:meth:`true_poses`) and the Crazyflies' firmware (:class:`VirtualFirmware`, reached through
cflib via :attr:`factory`). It is also the loop's clock: ``sleep_until(t)`` advances physics one
loop period at a time, so the deployment loop runs unchanged against it.

Each step the firmware of every drone says what its drone does (a velocity to track, or
motors off); drones whose motors stop fall until they touch something, and a drone resting
with its motors off on the plate (on its pad, or crashed next to it) is fixed to it: it rides
along on a moving platform, as friction would carry it. The drones start on the floor away from
everywhere a moving plate goes during the rehearsal. Every physics step checks the true drone
positions against the hard geofence (:attr:`SimulatedWorld.fence_excess`).
The simulators can only restart motors with ``place``, which puts every drone of the
environment at rest: take-offs are therefore expected together (the loop takes off all drones
in the same tick), and a restart while another drone flies is logged as an event.
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Mapping
from typing import Any, Literal, get_args

import numpy as np
from scipy.spatial.transform import Rotation

from marlander_lite import task
from marlander_lite.deploy.config import ConfigError, LabConfig, current_simulator_name
from marlander_lite.deploy.rehearsal.virtual_crazyflie import VirtualCfFactory
from marlander_lite.deploy.rehearsal.virtual_firmware import VirtualFirmware
from marlander_lite.platforms import PAD_LAYOUTS, PlateGeometry, PlatformConfig
from marlander_lite.rotations import IDENTITY_QUAT
from marlander_lite.simulators import simulator_entry
from marlander_lite.task import TaskConfig

FLOOR_CONTACT_TOLERANCE = 0.05
"""A falling drone's centre sinks up to this far below the floor (the fence's lower bound) when it hits it in
PyBullet after a fall of up to 2.5 m (m): contact penetration, not a drone leaving the fence."""
PAD_REST_HEIGHT = 0.02
"""A drone touching something with its centre this close to its resting height on the plate rests on it (m)."""
Controller = Literal["firmware", "pid"]
CONTROLLERS: tuple[str, ...] = get_args(Controller)
DEFAULT_CONTROLLER: Controller = "firmware"
"""The rehearsal's PyBullet drones fly through the firmware's velocity tracker: what runs on the drone."""


class SimulatorUnavailable(RuntimeError):
    """The requested simulator cannot be loaded."""


def world_task(lab: LabConfig) -> TaskConfig:
    """The simulator's task: the lab's drones, stepped once per loop tick, arena inside the soft fence."""
    low, high = lab.geofence.bounds(soft=True)
    half = min(high[0], -low[0], high[1], -low[1])
    if half <= 0.5:
        raise ConfigError("The simulated lab needs the soft geofence to contain a square of half width > 0.5 m at 0.")
    return lab.task_config().replace(policy_hz=lab.rates.loop_hz, arena_half_width=half)


def world_platform(lab: LabConfig) -> PlatformConfig:
    """The simulated plate: the lab's platform motion, pad radius, pad layout and inclination.

    The layout is the first of :data:`~marlander_lite.platforms.PAD_LAYOUTS` (the default grid 0.25 m apart
    first, then each layout at the config's smallest pad spacing) whose pad offsets are the config's (within
    1 mm): a config written from ``PlateGeometry(...).pad_offsets(N)`` (``LabConfig.with_drones``) rehearses on
    that very plate. Otherwise the default grid, which :class:`SimulatedWorld` then refuses, saying its offsets.
    The offsets are in the plate's own frame; ``simulation.inclination_deg`` then tilts the plate and its pads.
    """
    sim = lab.simulation
    pads = lab.drone_pads()
    radius = pads[0].radius
    candidates = [PlateGeometry(pad_radius=radius)]
    offsets = np.array([p.offset for p in pads], dtype=float)
    if len(pads) > 1 and len({p.body for p in pads}) == 1:
        gaps = np.linalg.norm(offsets[:, None] - offsets[None], axis=-1)[np.triu_indices(len(pads), 1)]
        spacing = round(float(gaps.min()), 6)  # offsets in a file are rounded
        if spacing >= 2 * radius:
            candidates += [PlateGeometry(pad_radius=radius, pad_spacing=spacing, layout=k) for k in PAD_LAYOUTS]
    geometry = next((g for g in candidates if np.abs(g.pad_offsets(len(pads)) - offsets).max() <= 1e-3), candidates[0])
    if sim.inclination_deg:
        geometry = dataclasses.replace(
            geometry, inclination_deg=float(sim.inclination_deg), tilt_axis_deg=float(sim.tilt_axis_deg)
        )
    return PlatformConfig(kind=sim.platform, speed=sim.platform_speed, geometry=geometry)


def make_simulator(
    lab: LabConfig,
    kind: str | None = None,
    controller: Controller | None = None,
    options: Mapping[str, Any] | None = None,
) -> Any:
    """The one-environment swarm simulator ``kind`` of :mod:`marlander_lite.simulators` for the lab's world.

    Args:
        lab: the lab config.
        kind: a simulator's name, ``crazyflie`` (the PyBullet Crazyflie swarm) or ``pointmass``; default:
            ``lab.simulation.simulator``. The old name ``pybullet`` still works, with a ``FutureWarning``.
        controller: how the PyBullet drones track their velocity setpoints: ``firmware`` (the
            default: the Crazyflie firmware's velocity tracker, what runs on the drone) or ``pid``
            (the simulator's own cascaded PID, the one the policies were trained with). A simulator
            without a controller (the point mass) ignores it.
        options: more keyword arguments of the simulator's swarm class, a drone unlike the published one: e.g.
            ``{"tuning": {"mass_scale": 0.87}}`` for a RotorPy Crazyflie 13 % lighter than its controller believes
            (:class:`~marlander_lite.rotorpy_sim.tuning.RotorPyTuning`). None: the simulator as it is.

    Raises:
        ValueError: an unknown simulator, controller or option.
        SimulatorUnavailable: the simulator's module cannot be imported (PyBullet missing, say).
    """
    kind = current_simulator_name(kind, "simulator", stacklevel=2) if kind else lab.simulation.simulator
    if controller is not None and controller not in CONTROLLERS:
        raise ValueError(f"Unknown controller {controller!r}; allowed: {', '.join(CONTROLLERS)}.")
    task_config, platform = world_task(lab), world_platform(lab)
    entry = simulator_entry(kind)
    try:
        swarm_class = entry.swarm_class()
    except (ModuleNotFoundError, AttributeError) as error:
        hint = "; rehearse with simulator 'pointmass' instead." if kind != "pointmass" else "."
        raise SimulatorUnavailable(f"The {kind} simulator ({entry.swarm}) is not available ({error}){hint}") from None
    accepted = inspect.signature(swarm_class).parameters
    extra = dict(options or {})
    reserved = ("self", "task_config", "platform", "num_envs", "controller")  # set here, not by the options
    allowed = [name for name in accepted if name not in reserved]
    unknown = sorted(set(extra) - set(allowed))
    if unknown:
        raise ValueError(f"Unknown {kind} simulator option(s) {', '.join(unknown)}; allowed: {', '.join(allowed)}.")
    if "tuning" in extra and isinstance(extra["tuning"], Mapping):
        extra["tuning"] = entry.options_class()(tuning=extra["tuning"]).tuning_config  # checked: says what is allowed
    if "controller" in accepted:
        extra["controller"] = controller or DEFAULT_CONTROLLER
    return swarm_class(task_config, platform, num_envs=1, **extra)


class SimulatedWorld:
    """The lab in simulation; see the module docstring.

    Args:
        lab: the lab config (drones, pads, geofence, simulation section).
        simulator: a one-environment swarm simulator stepping ``1 / lab.rates.loop_hz`` per step.
        seed: seed of the platform placement and start positions (default: ``lab.simulation.seed``).
        starts: where the drones rest at first ``(N, 3)`` m, drone order (default: ``lab.simulation.start_positions``
            or, without them, places drawn with ``seed``).
    """

    def __init__(
        self, lab: LabConfig, simulator: Any, seed: int | None = None, starts: np.ndarray | None = None
    ) -> None:
        if simulator.num_envs != 1:
            raise ValueError(f"The simulated lab needs a simulator with num_envs=1, got {simulator.num_envs}.")
        if not np.isclose(simulator.task.dt, 1.0 / lab.rates.loop_hz):
            raise ValueError(
                f"The simulator steps {simulator.task.dt} s; the loop runs at {lab.rates.loop_hz} Hz. "
                "Build it with world_task(lab)."
            )
        self.lab, self.sim = lab, simulator
        self.n = lab.num_drones
        self.dt = simulator.task.dt
        self.time = 0.0
        arming = lab.crazyflie.arm  # a lab that arms its drones has drones that need it: model that
        self.firmwares = {d.uri: VirtualFirmware(d.name, self.now, requires_arming=arming) for d in lab.drones}
        self._fw = list(self.firmwares.values())
        self.factory = VirtualCfFactory(self.firmwares)
        """Pass to ``Swarm`` (through :class:`marlander_lite.deploy.link.CrazyflieLink`)."""
        self.events: list[tuple[float, str, str]] = []
        self.motors_on = np.zeros(self.n, dtype=bool)
        self.pad_landed = np.zeros(self.n, dtype=bool)
        """Drones resting with motors off on the plate, on their pads or next to them (fixed to it: they ride along)."""
        self.min_separation = np.inf
        """Smallest distance between two drone centres so far (m)."""
        self.speeds = np.zeros(self.n)
        low, high = lab.geofence.bounds()
        low = np.array(low, dtype=float) - [0.0, 0.0, FLOOR_CONTACT_TOLERANCE]
        self._fence = (low, np.array(high, dtype=float))
        self._soft_fence = tuple(np.array(b, dtype=float) for b in lab.geofence.bounds(soft=True))
        self.runaway: tuple[int, np.ndarray] | None = None
        """``(drone, velocity (3,) m/s)``: a drone that flies this velocity whatever its firmware is told, until it is
        outside the soft fence (the ``geofence-breach`` fault, :meth:`run_away`); None: none."""
        self.fence_excess = np.zeros(self.n)
        """How far each drone has been outside the hard geofence so far (m; 0: it never left it), checked every
        physics step against the simulator's truth (a drone sinking into the floor on impact is not outside)."""
        """Drone speeds over the last step from their change of position (m/s): simulators need not zero
        the velocity of a drone resting with its motors off."""
        rng = np.random.default_rng(lab.simulation.seed if seed is None else seed)
        simulator.reset(np.array([0]), rng)
        self._plate_rotation = simulator.platform.geometry.rotation()
        """Plate frame -> world ``(3, 3)``: the identity unless the plate is inclined."""
        inclined = simulator.platform.geometry.inclination_deg != 0
        self._plate_quat = Rotation.from_matrix(self._plate_rotation).as_quat() if inclined else IDENTITY_QUAT
        self._pad_body_offsets = self._check_pads()
        starts = self._start_positions(rng) if starts is None else np.array(starts, dtype=float)
        simulator.place(0, starts)
        simulator.stop_motors(np.ones((1, self.n), dtype=bool))
        self.start_positions = starts

    # ------------------------------------------------------------------ setup
    def _check_pads(self) -> dict[str, tuple[int, np.ndarray]]:
        """Each pad body -> (a drone using it, its offset in the world frame); refuses offsets that do not fit the
        simulated plate."""
        pads = self.sim.state().pad_pos[0]
        bodies: dict[str, tuple[int, np.ndarray]] = {}
        for i, pad in enumerate(self.lab.drone_pads()):
            offset = self._plate_rotation @ np.asarray(pad.offset, dtype=float)
            if pad.body in bodies:
                j, other = bodies[pad.body]
                mismatch = np.abs((pads[i] - offset) - (pads[j] - other)).max()
                if mismatch > 1e-3:
                    level = dataclasses.replace(self.sim.platform.geometry, inclination_deg=0.0)
                    expected = np.round(level.pad_offsets(self.n), 4).tolist()
                    raise ConfigError(
                        f"The pad offsets of body {pad.body!r} do not match the simulated plate (off by "
                        f"{mismatch * 1000:.1f} mm): its pads are {expected} from the plate's top-face centre, "
                        "in drone order."
                    )
            else:
                bodies[pad.body] = (i, offset)
        return bodies

    def _start_positions(self, rng: np.random.Generator) -> np.ndarray:
        """Drones on the floor 0.6 m apart and 0.8 m from the plate, wherever a moving plate goes during the
        rehearsal (a UR10 sweeping its plate over a drone would hit it on take-off); if no such places exist,
        0.8 m from where the plate starts."""
        z = self.sim.task.landed_height
        given = self.lab.simulation.start_positions
        if given is not None:
            return np.array([[x, y, z] for x, y in given])
        low, high = self.lab.geofence.bounds(soft=True)
        plate = self.sim.state().pad_pos[0].mean(axis=0)
        for keep_away in (self._plate_path(plate), plate[None, :2]):
            chosen: list[np.ndarray] = []
            for _ in range(10_000):
                xy = rng.uniform(np.array(low[:2]) + 0.2, np.array(high[:2]) - 0.2)
                near_plate = np.linalg.norm(keep_away - xy, axis=1).min() < 0.8
                if near_plate or any(np.linalg.norm(xy - c[:2]) < 0.6 for c in chosen):
                    continue
                chosen.append(np.array([xy[0], xy[1], z]))
                if len(chosen) == self.n:
                    return np.array(chosen)
        raise ConfigError("Could not place the drones on the floor 0.6 m apart, away from the plate; widen the fence.")

    def _plate_path(self, plate: np.ndarray) -> np.ndarray:
        """Where the plate centre goes ``(K, 2)`` during the rehearsal (time limit + 20 s) (m)."""
        motion = getattr(self.sim, "motion", None)
        if motion is None or not self.sim.platform.is_moving:
            return plate[None, :2]
        offset = plate - motion.state(np.zeros(1))[0][0]  # plate centre relative to the motion's reference
        times = np.linspace(0.0, self.lab.simulation.max_time_s + 20.0, 600)
        return np.array([motion.state(np.array([t]))[0][0, :2] for t in times]) + offset[:2]

    # ------------------------------------------------------------------ the loop's clock
    def now(self) -> float:
        """Simulated time (s)."""
        return self.time

    def sleep_until(self, t: float) -> None:
        """Advance physics until the simulated time reaches ``t`` (s)."""
        while self.time < t - 1e-9:
            self.step()

    # ------------------------------------------------------------------ physics
    def step(self) -> None:
        """One loop period: firmware outputs -> simulator -> contacts."""
        state = self.sim.state()
        vel = state.vel[0]
        command = np.zeros((1, self.n, 3))
        want_on = np.zeros(self.n, dtype=bool)
        for i, fw in enumerate(self._fw):
            command[0, i], want_on[i] = fw.output(self.time, vel[i])
        start, stop = want_on & ~self.motors_on, ~want_on & self.motors_on
        if start.any():
            self._start_motors(start, want_on)
        if stop.any():
            self.sim.stop_motors(stop[None])
        self.motors_on = want_on
        if self.runaway is not None:
            i, velocity = self.runaway
            low, high = self._soft_fence
            if ((state.pos[0, i] >= low) & (state.pos[0, i] <= high)).all():
                command[0, i] = velocity
            else:  # out: its firmware obeys again, and the loop's rules take over
                self.runaway = None
        before = state.pos[0].copy()
        self.sim.step(command)
        self.time += self.dt
        state = self.sim.state()
        self.speeds = np.linalg.norm(state.pos[0] - before, axis=-1) / self.dt
        rest = (~self.motors_on) & self._on_plate(state) & ~self.pad_landed
        if rest.any():
            self.sim.land(rest[None])
            self.pad_landed |= rest
        if self.n > 1:
            self.min_separation = min(self.min_separation, float(task.min_separation(state.pos)[0]))
        low, high = self._fence
        excess = np.maximum(low - state.pos[0], state.pos[0] - high).max(axis=1)
        self.fence_excess = np.maximum(self.fence_excess, excess)

    def index(self, name: str) -> int:
        """The index of the drone named ``name`` in this world's order (the order of its lab config's drones)."""
        return self.lab.drone_names.index(name)

    def run_away(self, drone: int, velocity: np.ndarray) -> None:
        """Make ``drone`` fly ``velocity`` ``(3,)`` m/s, world frame, whatever it is told, until it leaves the soft
        fence: a fault on board (estimator, tracker) that no setpoint corrects."""
        self.runaway = (int(drone), np.asarray(velocity, dtype=float))

    def _on_plate(self, state: Any) -> np.ndarray:
        """Drones resting on the plate ``(N,)``: the simulator says they touch their own pad, or they touch
        something while their centre is over the plate and at most ``PAD_REST_HEIGHT`` off the height they
        rest at on it (both in the plate's frame, which an inclined plate tilts).

        The second test matters on a moving plate: PyBullet reports a drone touching its pad and the plate
        around it as touching "something else", and without the friction that would carry it, the plate
        slides away under a drone resting on it (on its pad, or crashed next to it) and drops it.
        """
        contact = state.contact[0]
        pads = state.pad_pos[0]
        centre = pads.mean(axis=0)
        half = np.asarray(self.sim.platform.geometry.half_extents(self.n))
        in_plate = (state.pos[0] - centre) @ self._plate_rotation  # rows: plate-frame coordinates from the centre
        over = (np.abs(in_plate[:, :2]) <= half).all(axis=1)
        pad_height = (pads - centre) @ self._plate_rotation[:, 2]  # all pads sit at one height in the plate frame
        low = np.abs(in_plate[:, 2] - pad_height - self.sim.task.landed_height) <= PAD_REST_HEIGHT
        return (contact == task.CONTACT_OWN_PAD) | ((contact != task.CONTACT_NONE) & over & low)

    def _start_motors(self, start: np.ndarray, want_on: np.ndarray) -> None:
        state = self.sim.state()
        moving = np.linalg.norm(state.vel[0], axis=-1) > 0.05
        if (moving & ~start).any():
            self.events.append((self.time, "restart", "motors restarted while another drone moved: it was stopped"))
        self.sim.place(0, state.pos[0].copy())
        if (~want_on).any():
            self.sim.stop_motors((~want_on)[None])
        self.pad_landed[:] = False  # place() un-fixes every drone; resting ones are fixed again after the step

    # ------------------------------------------------------------------ what the cameras see
    def true_poses(self) -> dict[str, np.ndarray]:
        """Rigid-body name -> true pose ``[x, y, z, qx, qy, qz, qw]`` of every drone and pad body."""
        state = self.sim.state()
        poses = {}
        for i, name in enumerate(self.lab.drone_names):
            poses[name] = np.concatenate((state.pos[0, i], state.quat[0, i]))
        for body, (i, offset) in self._pad_body_offsets.items():
            poses[body] = np.concatenate((state.pad_pos[0, i] - offset, self._plate_quat))
        return poses

    def drone_positions(self) -> np.ndarray:
        """True drone positions ``(N, 3)`` m."""
        return self.sim.state().pos[0].copy()

    def drone_speeds(self) -> np.ndarray:
        """True drone speeds ``(N,)`` m/s over the last step (from the change of position)."""
        return self.speeds.copy()

    def pad_positions(self) -> np.ndarray:
        """True pad top-face centres ``(N, 3)`` m."""
        return self.sim.state().pad_pos[0].copy()

    def close(self) -> None:
        self.sim.close()
