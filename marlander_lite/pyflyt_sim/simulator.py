"""A second simulator this project did not write: PyFlyt's Crazyflie under PyFlyt's own velocity controller.

RotorPy (:mod:`marlander_lite.rotorpy_sim`) is one simulator the project does not contain; a policy tuned until it
lands there could still be tuned to it. `PyFlyt <https://github.com/jjshoots/PyFlyt>`_ [Tai2023] is another,
published independently: a PyBullet UAV library whose ``QuadX`` drone carries its own Crazyflie 2.x model and its
own cascaded PID, none of it fitted or tuned here. What it flies, as published (``PyFlyt==0.21.0``, the ``cf2x``
model and its ``cf2x.yaml``):

* PyBullet rigid-body physics at 240 Hz (PyFlyt's recommended rate), 27 g, four motors whose throttle follows its
  command through a 10 ms first-order lag with 2 % multiplicative noise (PyFlyt's ``noise_ratio``; drawn from a
  generator seeded at every reset, so a seed repeats an episode), thrust from the throttle squared, a body drag;
* flight mode 6, ``(vx, vy, yaw rate, vz)`` in the ground frame, at 120 Hz (PyFlyt's default control rate; five
  control periods per 24 Hz action; 240 Hz for the lab loop's 48 Hz, which does not divide 120): a horizontal
  velocity PID (``kp`` 0.8, ``ki`` 0.3, ``kd`` 0.5) asks for roll and pitch **clamped at 0.4 rad (23 degrees)**, an
  attitude P loop (``kp`` 2: a 0.5 s time constant) and a body-rate PID below it; a vertical velocity
  PID (``kp`` 2, ``ki`` 0.5, ``kd`` 0.05) sets the collective throttle directly, **with no hover feed-forward**, so
  a drone commanded to hold its height sinks until the integral term has built up the hover throttle (every
  episode here starts from a drone that has been hovering: its motors and integrators as they are after 20 s of
  hover, as RotorPy starts with its rotors at hover speed). Yaw rate is commanded zero.

One thing is not as 0.21.0 publishes it, by default: the order of its ``Aviary.step``. 0.21.0 reads each drone's state
before the physics step, so its controllers act on a state one physics step old, and its ``cf2x`` then never holds
still along y (a 0.17 m standard deviation in PyFlyt's own position mode, 0.01 m along x). PyFlyt reads the state
after the physics step since 0.22.0, and both axes hold to 5 mm; those releases cap numpy below 2, which our pinned
numpy is not, so ``read_state="after_physics"`` (the default) flies 0.21.0 in the later order and
``"before_physics"`` exactly as 0.21.0 steps (see :func:`aviary_class`).

Measured here (``tests/test_pyflyt.py``; docs/transfer.md, "PyFlyt"): a 1 m/s step rises from 10 to 90 % in about
0.9 s (0.18 s to 1.05 s); the point mass fitted to its go-and-brake answers (:func:`marlander_lite.crazyflie.fit.
simulator_response`) has a horizontal velocity time constant near 0.8 s, where the firmware tracker's is 0.16-0.27 s
and the training family's slowest 0.40 s, and under 15 degrees of effective tilt.

What is ours, as for RotorPy: the world around the drones. :class:`PyFlytSwarm` is the point-mass simulator's world
(plates and pads, their motion, the random starts, contacts with the floor and the plate, landed drones held on their
pads, all inherited from :class:`~marlander_lite.pointmass.simulator.PointMassSwarm`) with PyFlyt's drones flying in
place of the point mass. Each swarm is one PyFlyt ``Aviary`` (one PyBullet world), its drones placed
:data:`ALTITUDE` above our coordinates so that PyFlyt's own floor never touches them; our floor and plate are the
point mass's. A drone that reaches a surface during a control period is read no further; the inherited contact step
stops it where its path crossed the surface and reports what it touched, with its impact velocity, and its PyBullet
body is then put where our contact step left it. A landed drone is held on its pad the same way. A drone whose
motors are stopped (:meth:`stop_motors`, the rehearsal's motor fault) is switched to PyFlyt's raw motor mode with
zero throttle.
"""

from __future__ import annotations

import contextlib
import functools
import io
from typing import Any, Literal

import numpy as np

from marlander_lite.platforms import PlatformConfig
from marlander_lite.pointmass.hosted import HostedDroneSwarm, control_periods
from marlander_lite.pyflyt_sim.tuning import PyFlytTuning, apply_tuning
from marlander_lite.task import CONTACT_NONE, TaskConfig

PYFLYT_HINT = "the PyFlyt simulator needs the PyFlyt package: pip install -e .[pyflyt] (environment.lock pins it)"
ALTITUDE = 100.0
"""Height (m) of our world's origin in each PyFlyt world: PyFlyt's ground plane stays 100 m below every drone."""
GRAVITY = 9.81  # PyFlyt's Aviary sets this gravity
HOVER_SETTLE_S = 20.0
"""Seconds a drone hovers, once per simulator, to give every start the controller state of a hovering drone."""
VELOCITY_MODE, MOTOR_MODE = 6, -1  # PyFlyt QuadX flight modes: (vx, vy, yaw rate, vz), and raw motor throttles


ReadState = Literal["after_physics", "before_physics"]
READ_STATES: tuple[str, ...] = ("after_physics", "before_physics")
"""When PyFlyt's ``Aviary.step`` reads the drone states its controllers act on: see :func:`aviary_class`."""


@functools.cache
def aviary_class(read_state: ReadState = "after_physics") -> type:
    """PyFlyt's ``Aviary`` (PyFlyt is an optional extra, imported now), stepped with its states read ``read_state``.

    ``"before_physics"`` is ``PyFlyt==0.21.0``'s own ``Aviary.step``: in each physics step the drones read their
    states (``update_state``) *before* ``stepSimulation``, so every control period acts on a state one physics step
    (1/240 s) old. From 0.22.0 on, PyFlyt reads them after ``stepSimulation`` [Tai2023]. The order matters: with the
    stale state, a ``cf2x`` in PyFlyt's own position mode wanders along y with a 0.17 m standard deviation while x
    holds to 0.01 m (with the state read after the physics step, both hold to 5 mm; docs/transfer.md, "PyFlyt").
    ``"after_physics"`` is 0.21.0's ``Aviary`` with that later order, the PyFlyt every release since 0.22 flies; we
    cannot install those releases, whose ``numpy<2`` requirement conflicts with our pinned numpy.
    """
    try:
        from PyFlyt.core import Aviary
    except ImportError as error:  # pragma: no cover - depends on the installation
        raise ImportError(PYFLYT_HINT) from error
    if read_state == "before_physics":
        return Aviary
    if read_state != "after_physics":
        raise ValueError(f"read_state must be one of {READ_STATES}, got {read_state!r}.")

    class AviaryReadingAfterPhysics(Aviary):
        """PyFlyt 0.21.0's ``Aviary`` whose ``step`` reads the drones' states after ``stepSimulation``, as 0.22 does."""

        def step(self) -> None:
            # 0.21.0's Aviary.step without rendering (we never render), update_state moved after stepSimulation.
            self.contact_array &= False
            for physics_step in range(self.updates_per_step):
                for drone in self.armed_drones:
                    if physics_step % drone.physics_control_ratio == 0:
                        drone.update_control()
                for drone in self.armed_drones:
                    drone.update_physics()
                self.stepSimulation()
                for drone in self.armed_drones:
                    drone.update_state()
                for collision in self.getContactPoints():
                    self.contact_array[collision[1], collision[2]] = True
                    self.contact_array[collision[2], collision[1]] = True
                self.physics_steps += 1
                self.elapsed_time = self.physics_steps / self.physics_hz
            for drone in self.armed_drones:
                drone.update_last()
            self.aviary_steps += 1

    return AviaryReadingAfterPhysics


class PyFlytSwarm(HostedDroneSwarm):
    """``num_envs`` swarms of PyFlyt Crazyflies over the point-mass simulator's plates (see the module docstring).

    Implements :class:`~marlander_lite.episodes.Simulator`; world frame, metres, m/s. Swarm ``e`` is PyFlyt world
    ``aviaries[e]``, its drone ``i`` PyFlyt's ``aviaries[e].drones[i]``; our arrays mirror their PyBullet states.

    Args:
        task_config: the MDP's constants (N drones, policy rate, arena).
        platform: the plate and its motion.
        num_envs: swarms simulated side by side (one PyFlyt world each, stepped one after the other).
        control_hz: rate of PyFlyt's flight controller (Hz), a whole multiple of the policy rate and a divisor of
            PyFlyt's 240 Hz physics. ``None``: PyFlyt's own 120 Hz where the policy rate divides it (24 Hz, as
            trained), else 240 Hz (the lab loop's 48 Hz).
        drone_model: the PyFlyt ``QuadX`` model flown (``"cf2x"``, its Crazyflie 2.x, by default).
        read_state: ``"after_physics"`` (default): the controllers read the state the physics step has just made, as
            PyFlyt does since 0.22; ``"before_physics"``: as the pinned 0.21.0 does, one physics step late (see
            :func:`aviary_class`).
        tuning: how every drone differs from PyFlyt's ``cf2x`` (:class:`~marlander_lite.pyflyt_sim.tuning.PyFlytTuning`:
            mass, command latency, gains, tilt clamp, body drag); None, the ``cf2x`` as PyFlyt ships it.
    """

    def __init__(
        self,
        task_config: TaskConfig,
        platform: PlatformConfig,
        num_envs: int = 1,
        control_hz: float | None = None,
        drone_model: str = "cf2x",
        read_state: ReadState = "after_physics",
        tuning: PyFlytTuning | None = None,
    ) -> None:
        aviary = aviary_class(read_state)
        tuning = tuning or PyFlytTuning()
        control_hz = resolve_control_hz(control_hz, task_config.policy_hz)
        periods = control_periods(control_hz, task_config.policy_hz)
        # The numpy engine: this class replaces the point mass's step, which the compiled engine would run.
        super().__init__(task_config, platform, num_envs, engine="numpy")
        self.control_periods = periods
        """PyFlyt control periods (``Aviary.step`` calls) per policy step."""
        n = task_config.num_drones
        # Placeholder starts, one metre apart; every reset puts the drones where our random starts say.
        starts = np.column_stack([np.arange(n, dtype=float), np.zeros(n), np.full(n, ALTITUDE)])
        options = {"drone_model": drone_model, "control_hz": round(control_hz)}
        with contextlib.redirect_stdout(io.StringIO()):  # PyFlyt prints terminal escape codes on every new world
            self.aviaries: list[Any] = [
                aviary(starts, np.zeros((n, 3)), drone_type="quadx", drone_options=options, render=False)
                for _ in range(num_envs)
            ]
        """One PyFlyt ``Aviary`` (a PyBullet world) per swarm."""
        self.control_hz = control_hz
        """Rate of PyFlyt's flight controller (Hz)."""
        self.read_state = read_state
        """When the controllers read the drone states: ``"after_physics"`` (PyFlyt >= 0.22) or ``"before_physics"``."""
        self.tuning = tuning
        """How the drones differ from PyFlyt's ``cf2x``."""
        for world in self.aviaries:
            for quad in world.drones:
                apply_tuning(world, quad, tuning)
        self._delay_commands(tuning.delay_periods(control_hz))
        self._hover = self._settle_hover(round(control_hz))

    # ------------------------------------------------------------------ Simulator API
    def reset(self, env_ids: np.ndarray, rng: np.random.Generator) -> None:
        super().reset(env_ids, rng)
        for env in np.atleast_1d(env_ids):
            self._reseed(int(env), rng)
            for drone in range(self.task.num_drones):
                self._take_off_fresh(int(env), drone)

    def _fly_period(self, velocity: np.ndarray, active: np.ndarray) -> None:
        velocity = self._arriving(velocity)  # the command given latency_s ago
        for env, aviary in enumerate(self.aviaries):
            for drone, quad in enumerate(aviary.drones):
                if self.motors_stopped[env, drone]:
                    if quad.mode != MOTOR_MODE:
                        quad.set_mode(MOTOR_MODE)
                    quad.setpoint = np.zeros(4)
                else:
                    vx, vy, vz = velocity[env, drone]
                    quad.setpoint = np.array([vx, vy, 0.0, vz])
            aviary.step()
        self._read(active)

    def _after_contacts(self) -> None:
        # Our contact step moved these drones (onto a surface, or onto their pad): PyBullet follows.
        for env, drone in zip(*np.nonzero(self.landed | (self.contact != CONTACT_NONE)), strict=True):
            self._write(int(env), int(drone))

    def close(self) -> None:
        for aviary in self.aviaries:
            aviary.disconnect()
        self.aviaries = []

    # ------------------------------------------------------------------ rehearsal extras
    def place(self, env_id: int, drone_pos: np.ndarray) -> None:
        super().place(env_id, drone_pos)
        for drone in range(self.task.num_drones):
            self._take_off_fresh(env_id, drone)

    def relaunch(self, drones: np.ndarray, rng: np.random.Generator, tries: int = 20) -> None:
        super().relaunch(drones, rng, tries)
        for env, drone in zip(*np.nonzero(np.asarray(drones, dtype=bool)), strict=True):
            self._take_off_fresh(int(env), int(drone))

    # ------------------------------------------------------------------ internals
    def _reseed(self, env: int, rng: np.random.Generator) -> None:
        """Seed swarm ``env``'s motor noise from ``rng``: the same reset seed, the same episode."""
        noise = np.random.RandomState(int(rng.integers(2**32)))  # PyFlyt 0.21 draws from a RandomState
        aviary = self.aviaries[env]
        aviary.np_random = noise
        for quad in aviary.drones:
            quad.np_random = quad.motors.np_random = quad.body.np_random = noise

    def _settle_hover(self, control_hz: int) -> list[np.ndarray]:
        """The motor throttles and controller integrators of a drone that has hovered :data:`HOVER_SETTLE_S`.

        Flown once, in swarm 0 (every reset puts its drones back), from the throttle that carries the drone's weight,
        with seeded motor noise: the same state on every machine.
        """
        aviary, quad = self.aviaries[0], self.aviaries[0].drones[0]
        self._reseed(0, np.random.default_rng(0))
        _fresh_controller(quad)
        quad.motors.throttle[:] = quad.z_PIDs[0]._integral[:] = hover_throttle(aviary, quad)
        aviary.resetBasePositionAndOrientation(quad.Id, (0.0, 0.0, ALTITUDE), (0.0, 0.0, 0.0, 1.0))
        for _ in range(round(HOVER_SETTLE_S * control_hz)):
            quad.setpoint = np.zeros(4)
            aviary.step()
        return [quad.motors.throttle.copy(), *(pid._integral.copy() for pid in (*quad.PIDs, *quad.z_PIDs))]

    def _take_off_fresh(self, env: int, drone: int) -> None:
        """Drone ``(env, drone)`` where our arrays put it, in PyFlyt's velocity mode, hovering (see ``_settle_hover``):
        a drone that has been hovering, as RotorPy starts with its rotors at hover speed. Built afresh, PyFlyt's
        vertical PID (no feed-forward) would let it sink for seconds while its integral builds up."""
        quad = self.aviaries[env].drones[drone]
        _fresh_controller(quad)
        throttle, *integrals = self._hover
        quad.motors.throttle[:] = throttle
        for pid, integral in zip((*quad.PIDs, *quad.z_PIDs), integrals, strict=True):
            pid._integral[:] = integral
        self._write(env, drone)

    def _write(self, env: int, drone: int) -> None:
        """Put PyBullet body ``(env, drone)`` at our position, attitude, velocity and angular velocity."""
        aviary, quad = self.aviaries[env], self.aviaries[env].drones[drone]
        position = self.pos[env, drone] + (0.0, 0.0, ALTITUDE)
        aviary.resetBasePositionAndOrientation(quad.Id, position, self.quat[env, drone])
        aviary.resetBaseVelocity(quad.Id, self.vel[env, drone], self.ang_vel[env, drone])
        quad.update_state()

    def _read(self, drones: np.ndarray) -> None:
        """Copy the PyBullet states of the drones ``drones`` ``(num_envs, N)`` selects into our arrays."""
        for env, drone in zip(*np.nonzero(drones), strict=True):
            aviary = self.aviaries[env]
            body = aviary.drones[drone].Id
            position, quat = aviary.getBasePositionAndOrientation(body)
            velocity, ang_vel = aviary.getBaseVelocity(body)  # both in the world frame, as eq. 2's
            self.pos[env, drone] = position
            self.pos[env, drone, 2] -= ALTITUDE
            self.quat[env, drone] = quat
            self.vel[env, drone] = velocity
            self.ang_vel[env, drone] = ang_vel


def _fresh_controller(quad: Any) -> None:
    """PyFlyt drone ``quad``'s controller and motors as PyFlyt builds a new drone, in its velocity mode."""
    quad.reset()  # mode 0, zero setpoint, throttle and body state; PyFlyt's own reset builds drones anew
    for pid in quad.z_PIDs:  # set_mode builds new attitude and velocity PIDs, but keeps the vertical ones
        pid.reset()
    quad.set_mode(VELOCITY_MODE)


def hover_throttle(aviary: Any, quad: Any) -> float:
    """The throttle (0-1, every motor alike) whose thrust equals ``quad``'s weight in ``aviary``.

    PyFlyt's motors give ``thrust_coef (throttle max_rpm)^2`` each; the mass is the PyBullet body's, links included.
    """
    mass = sum(aviary.getDynamicsInfo(quad.Id, link)[0] for link in range(-1, aviary.getNumJoints(quad.Id)))
    motors = quad.motors
    per_motor = mass * GRAVITY / len(motors.max_rpm)
    return float(np.sqrt(per_motor / np.ravel(motors.thrust_coef)[0]) / np.ravel(motors.max_rpm)[0])


def resolve_control_hz(control_hz: float | None, policy_hz: float) -> float:
    """The controller rate flown for ``control_hz`` (``None``: 120 Hz, PyFlyt's own, if ``policy_hz`` divides it,
    else 240 Hz); checked as :func:`check_control_hz` does."""
    if control_hz is None:
        control_hz = 120.0 if (120.0 / policy_hz).is_integer() else 240.0
    control_periods(control_hz, policy_hz)
    check_control_hz(control_hz)
    return control_hz


def check_control_hz(control_hz: float) -> None:
    """Raise ``ValueError`` unless ``control_hz`` divides PyFlyt's 240 Hz physics into whole steps."""
    if not (isinstance(control_hz, int | float) and control_hz > 0 and (240.0 / control_hz).is_integer()):
        raise ValueError(
            f"control_hz must divide PyFlyt's 240 Hz physics rate into whole steps, got {control_hz!r}; "
            "for example 120 or 240."
        )
