"""The simulated lab: a swarm simulator, one virtual Crazyflie firmware per drone, and the clock.

:class:`SimulatedWorld` stands for everything outside the control station: the drones (any
simulator of the :class:`marlander_lite.episodes.Simulator` protocol with the rehearsal extras
``place`` and ``stop_motors``, one environment), the platform, the motion-capture truth
(:meth:`true_poses`) and the Crazyflies' firmware (:class:`VirtualFirmware`, reached through
cflib via :attr:`factory`). It is also the loop's clock: ``sleep_until(t)`` advances physics one
loop period at a time, so the deployment loop runs unchanged against it.

Each step the firmware of every drone says what its drone does (a velocity to track, or
motors off); drones whose motors stop fall until they touch something, and a drone resting
with its motors off on its own pad is fixed to the pad (it rides along on a moving platform).
The simulators can only restart motors with ``place``, which puts every drone of the
environment at rest: take-offs are therefore expected together (the loop takes off all drones
in the same tick), and a restart while another drone flies is logged as an event.
"""

from __future__ import annotations

import importlib
from typing import Any

import numpy as np

from marlander_lite import task
from marlander_lite.deploy.config import ConfigError, LabConfig
from marlander_lite.deploy.virtual_crazyflie import VirtualCfFactory
from marlander_lite.deploy.virtual_firmware import VirtualFirmware
from marlander_lite.platforms import PlateGeometry, PlatformConfig
from marlander_lite.rotations import IDENTITY_QUAT
from marlander_lite.task import TaskConfig

PYBULLET_SIMULATOR = "marlander_lite.crazyflie.simulator:CrazyflieSwarm"
"""Where the PyBullet Crazyflie swarm lives."""


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
    """The simulated plate: the lab's platform motion and pad radius."""
    sim = lab.simulation
    geometry = PlateGeometry(pad_radius=lab.drone_pads()[0].radius)
    return PlatformConfig(kind=sim.platform, speed=sim.platform_speed, geometry=geometry)


def make_simulator(lab: LabConfig, kind: str | None = None) -> Any:
    """The swarm simulator for ``kind`` (``pybullet`` or ``pointmass``; default: the config's)."""
    kind = kind or lab.simulation.simulator
    task_config, platform = world_task(lab), world_platform(lab)
    if kind == "pointmass":
        from marlander_lite.pointmass.simulator import PointMassSwarm

        return PointMassSwarm(task_config, platform, num_envs=1)
    if kind == "pybullet":
        module, name = PYBULLET_SIMULATOR.split(":")
        try:
            swarm_class = getattr(importlib.import_module(module), name)
        except (ModuleNotFoundError, AttributeError) as error:
            raise SimulatorUnavailable(
                f"The PyBullet Crazyflie simulator ({PYBULLET_SIMULATOR}) is not available ({error}); "
                "rehearse with simulator 'pointmass' instead."
            ) from None
        return swarm_class(task_config, platform)
    raise ValueError(f"Unknown simulator {kind!r}; allowed: pybullet, pointmass.")


class SimulatedWorld:
    """The lab in simulation; see the module docstring.

    Args:
        lab: the lab config (drones, pads, geofence, simulation section).
        simulator: a one-environment swarm simulator stepping ``1 / lab.rates.loop_hz`` per step.
        seed: seed of the platform placement and start positions (default: ``lab.simulation.seed``).
    """

    def __init__(self, lab: LabConfig, simulator: Any, seed: int | None = None) -> None:
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
        """Drones resting with motors off on their own pads (fixed to them)."""
        self.min_separation = np.inf
        """Smallest distance between two drone centres so far (m)."""
        self.speeds = np.zeros(self.n)
        """Drone speeds over the last step from their change of position (m/s): simulators need not zero
        the velocity of a drone resting with its motors off."""
        rng = np.random.default_rng(lab.simulation.seed if seed is None else seed)
        simulator.reset(np.array([0]), rng)
        self._pad_body_offsets = self._check_pads()
        starts = self._start_positions(rng)
        simulator.place(0, starts)
        simulator.stop_motors(np.ones((1, self.n), dtype=bool))
        self.start_positions = starts

    # ------------------------------------------------------------------ setup
    def _check_pads(self) -> dict[str, tuple[int, np.ndarray]]:
        """Each pad body -> (a drone using it, its offset); refuses offsets that do not fit the simulated plate."""
        pads = self.sim.state().pad_pos[0]
        bodies: dict[str, tuple[int, np.ndarray]] = {}
        for i, pad in enumerate(self.lab.drone_pads()):
            offset = np.asarray(pad.offset, dtype=float)
            if pad.body in bodies:
                j, other = bodies[pad.body]
                mismatch = np.abs((pads[i] - offset) - (pads[j] - other)).max()
                if mismatch > 1e-3:
                    expected = np.round(self.sim.platform.geometry.pad_offsets(self.n), 4).tolist()
                    raise ConfigError(
                        f"The pad offsets of body {pad.body!r} do not match the simulated plate (off by "
                        f"{mismatch * 1000:.1f} mm): its pads are {expected} from the plate's top-face centre, "
                        "in drone order."
                    )
            else:
                bodies[pad.body] = (i, offset)
        return bodies

    def _start_positions(self, rng: np.random.Generator) -> np.ndarray:
        z = self.sim.task.landed_height
        given = self.lab.simulation.start_positions
        if given is not None:
            return np.array([[x, y, z] for x, y in given])
        low, high = self.lab.geofence.bounds(soft=True)
        plate = self.sim.state().pad_pos[0].mean(axis=0)
        chosen: list[np.ndarray] = []
        for _ in range(10_000):
            xy = rng.uniform(np.array(low[:2]) + 0.2, np.array(high[:2]) - 0.2)
            if np.linalg.norm(xy - plate[:2]) < 0.8 or any(np.linalg.norm(xy - c[:2]) < 0.6 for c in chosen):
                continue
            chosen.append(np.array([xy[0], xy[1], z]))
            if len(chosen) == self.n:
                return np.array(chosen)
        raise ConfigError("Could not place the drones on the floor 0.6 m apart, away from the plate; widen the fence.")

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
        before = state.pos[0].copy()
        self.sim.step(command)
        self.time += self.dt
        state = self.sim.state()
        self.speeds = np.linalg.norm(state.pos[0] - before, axis=-1) / self.dt
        rest = (~self.motors_on) & (state.contact[0] == task.CONTACT_OWN_PAD) & ~self.pad_landed
        if rest.any():
            self.sim.land(rest[None])
            self.pad_landed |= rest
        if self.n > 1:
            self.min_separation = min(self.min_separation, float(task.min_separation(state.pos)[0]))

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
            poses[body] = np.concatenate((state.pad_pos[0, i] - offset, IDENTITY_QUAT))
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
