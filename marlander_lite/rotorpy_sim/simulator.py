"""A simulator this project did not write: RotorPy's Crazyflie under RotorPy's own velocity controller.

Every policy here is trained on the point mass and checked in the PyBullet Crazyflie, whose trackers and
physics we wrote and tuned. A lab's own simulator will differ from both. `RotorPy <https://github.com/spencerfolk/
rotorpy>`_ [Folk2023] is a published multirotor simulator with its own Crazyflie model and its own velocity
controller, none of it fitted or tuned here, so flying a policy in it is the check the issue asks for: a simulator
the project does not contain (docs/transfer.md, "RotorPy").

What RotorPy simulates, as published (``rotorpy==3.0.0``, ``rotorpy.vehicles.crazyflie_params``):

* the rigid body of a 30 g Crazyflie (our PyBullet model: 27 g) with four rotors whose speeds follow their commands
  through a first-order lag of 72 ms, rotor drag (the "H force") and induced inflow (``aero=True``);
* the ``cmd_vel`` control abstraction: a world-frame velocity P loop (``k_v = 10`` 1/s, no tilt limit) asks for a
  thrust vector, an SE(3) attitude loop (``kp_att = 310``, ``kd_att = 57``) turns the body to it, zero yaw. Called
  once per control period, with the motor commands held between calls; scipy's RK45 integrates each period (its
  first step the whole period, see :class:`RotorPySwarm`).

A 1 m/s step command along x in it rises from 10 to 90 % in 0.16 s, after 0.12 s, and overshoots to 1.27 m/s at
0.47 s, the body tilting 33 degrees on the way: less damped than either PyBullet tracker (our PID does not overshoot,
the firmware tracker by 9 %; ``tests/test_rotorpy.py``; docs/transfer.md, "RotorPy").

Another RotorPy Crazyflie (:class:`~marlander_lite.rotorpy_sim.tuning.RotorPyTuning`): a mass its controller does not
know about, command latency, other velocity- and attitude-loop gains; the random Crazyflies of
:mod:`marlander_lite.experiments.variants` are drawn with it (``--variant-simulator rotorpy``).

What is ours: the world around the drones. :class:`RotorPySwarm` is the point-mass simulator's world (plates and
pads, their motion, the random starts, contacts with the floor and the plate, landed drones held on their pads: all
inherited from :class:`~marlander_lite.pointmass.simulator.PointMassSwarm`) with RotorPy's Crazyflie flying in place of
the point mass. RotorPy has a ground plane only (and we switch it off): a drone that reaches the floor or the plate
during a control period stops integrating there, and the inherited contact step stops it where its path crossed the
surface and reports what it touched, with its impact velocity, as in the point mass. A drone whose motors are stopped
(:meth:`stop_motors`, the rehearsal's motor fault) gets zero rotor-speed commands instead.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from marlander_lite.platforms import PlatformConfig
from marlander_lite.pointmass.hosted import HostedDroneSwarm, control_periods
from marlander_lite.rotations import rotate_vector
from marlander_lite.rotorpy_sim.tuning import RotorPyTuning
from marlander_lite.task import TaskConfig

ROTORPY_HINT = "the RotorPy simulator needs the rotorpy package: pip install -e .[rotorpy] (environment.lock pins it)"


def _rotorpy() -> tuple[type, dict[str, Any]]:
    """RotorPy's ``Multirotor`` class and its Crazyflie parameters, imported now (RotorPy is an optional extra)."""
    try:
        from rotorpy.vehicles.crazyflie_params import quad_params
        from rotorpy.vehicles.multirotor import Multirotor
    except ImportError as error:  # pragma: no cover - depends on the installation
        raise ImportError(ROTORPY_HINT) from error
    return Multirotor, quad_params


def _controller_with_assumed_body(multirotor: type) -> type:
    """RotorPy's ``Multirotor`` whose controller may compute with an assumed mass and inertia instead of the body's.

    RotorPy's ``cmd_vel`` controller reads ``self.mass`` and ``self.inertia``, which its dynamics read too; a drone
    heavier than its controller believes needs the two apart. ``assumed`` (``(mass, inertia)`` or None) is what the
    controller is told; the dynamics keep the body's.
    """

    class AssumedBodyMultirotor(multirotor):  # type: ignore[misc, valid-type]
        assumed: tuple[float, np.ndarray] | None = None

        def get_cmd_motor_speeds(self, state: dict, control: dict) -> np.ndarray:
            if self.assumed is None:
                return super().get_cmd_motor_speeds(state, control)
            body = self.mass, self.inertia
            self.mass, self.inertia = self.assumed
            try:
                return super().get_cmd_motor_speeds(state, control)
            finally:
                self.mass, self.inertia = body

    return AssumedBodyMultirotor


def crazyflie_params(changes: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """RotorPy's Crazyflie parameters (``rotorpy.vehicles.crazyflie_params.quad_params``) with ``changes`` applied.

    Raises:
        ValueError: a name in ``changes`` is not one of RotorPy's Crazyflie parameters (the message lists them).
    """
    _, params = _rotorpy()
    changes = dict(changes or {})
    unknown = sorted(set(changes) - set(params))
    if unknown:
        raise ValueError(f"Unknown RotorPy Crazyflie parameter(s) {unknown}; allowed: {', '.join(sorted(params))}.")
    return {**params, **changes}


class RotorPySwarm(HostedDroneSwarm):
    """``num_envs`` swarms of RotorPy Crazyflies over the point-mass simulator's plates (see the module docstring).

    Implements :class:`~marlander_lite.episodes.Simulator`; world frame, metres, m/s. Each drone is one RotorPy state
    (position, velocity, attitude, body rates, rotor speeds), stepped by one shared ``Multirotor`` model.

    Args:
        task_config: the MDP's constants (N drones, policy rate, arena).
        platform: the plate and its motion.
        num_envs: swarms simulated side by side (one after the other: RotorPy steps one drone per call).
        control_hz: rate of RotorPy's velocity controller and of the integration periods (Hz): a whole multiple of
            the policy rate. Default 96 Hz, four periods per 24 Hz action, the nearest to RotorPy's own 100 Hz.
        quad_params: changes to RotorPy's Crazyflie parameters (e.g. ``{"k_v": 7.0}``); ``None``: as published.
        aero: RotorPy's rotor drag and induced inflow (its default, on).
        tuning: how every drone differs from the one ``quad_params`` describe: a mass its controller does not know
            about, command latency, loop gains (:class:`~marlander_lite.rotorpy_sim.tuning.RotorPyTuning`); None,
            none.
    """

    def __init__(
        self,
        task_config: TaskConfig,
        platform: PlatformConfig,
        num_envs: int = 1,
        control_hz: float = 96.0,
        quad_params: Mapping[str, Any] | None = None,
        aero: bool = True,
        tuning: RotorPyTuning | None = None,
    ) -> None:
        periods = control_periods(control_hz, task_config.policy_hz)
        # The numpy engine: this class replaces the point mass's step, which the compiled engine would run.
        super().__init__(task_config, platform, num_envs, engine="numpy")
        multirotor, _ = _rotorpy()
        tuning = tuning or RotorPyTuning()
        assumed = crazyflie_params(quad_params)
        params = tuning.vehicle_params(assumed)
        self.control_periods = periods
        """RotorPy control periods per policy step."""
        self.quad_params = params
        """RotorPy's Crazyflie parameters as flown (the body's mass and inertia, the tuned gains)."""
        self.tuning = tuning
        """How the drones differ from the Crazyflie ``quad_params`` describe."""
        # RotorPy's integrator (RK45, scipy's tolerances) with its first step set to the whole period: left to choose,
        # scipy starts a near-hover flight at about 1 us and needs 32 evaluations a period instead of 7, for the same
        # states to 1e-6 m and m/s (tests/test_rotorpy.py).
        integrator = {"method": "RK45", "first_step": task_config.dt / self.control_periods}
        vehicle = _controller_with_assumed_body(multirotor) if tuning.mass_scale != 1.0 else multirotor
        self._vehicle, self._unpowered = (
            vehicle(params, control_abstraction=control, aero=aero, enable_ground=False, integrator_kwargs=integrator)
            for control in ("cmd_vel", "cmd_motor_speeds")
        )
        if tuning.mass_scale != 1.0:  # the controller keeps the published mass and inertia
            told = multirotor(assumed, control_abstraction="cmd_vel", aero=aero, enable_ground=False)
            self._vehicle.assumed = (told.mass, told.inertia)
        self._hover_speed = float(np.sqrt(params["mass"] * self._vehicle.g / (params["num_rotors"] * params["k_eta"])))
        self._rotor_speeds = np.full((num_envs, task_config.num_drones, params["num_rotors"]), self._hover_speed)
        self._delay_commands(tuning.delay_periods(control_hz))

    # ------------------------------------------------------------------ Simulator API
    def reset(self, env_ids: np.ndarray, rng: np.random.Generator) -> None:
        super().reset(env_ids, rng)
        self._rotor_speeds[env_ids] = self._hover_speed

    def _fly_period(self, velocity: np.ndarray, active: np.ndarray) -> None:
        velocity = self._arriving(velocity)  # the command given latency_s ago
        period = self._dt / self.control_periods
        for env, drone in zip(*np.nonzero(active), strict=True):
            self._advance(env, drone, velocity[env, drone], period)

    # ------------------------------------------------------------------ rehearsal extras
    def place(self, env_id: int, drone_pos: np.ndarray) -> None:
        super().place(env_id, drone_pos)
        self._rotor_speeds[env_id] = self._hover_speed

    def relaunch(self, drones: np.ndarray, rng: np.random.Generator, tries: int = 20) -> None:
        super().relaunch(drones, rng, tries)
        self._rotor_speeds[np.asarray(drones, dtype=bool)] = self._hover_speed

    # ------------------------------------------------------------------ internals
    def _advance(self, env: int, drone: int, command: np.ndarray, period: float) -> None:
        """One RotorPy control period for one drone: its state from our arrays, RotorPy's step, back again."""
        quat = self.quat[env, drone]
        state = {
            "x": self.pos[env, drone].copy(),
            "v": self.vel[env, drone].copy(),
            "q": quat.copy(),
            # RotorPy keeps body rates; our state holds the angular velocity in the world frame (eq. 2's omega).
            "w": rotate_vector(quat * np.array([-1.0, -1.0, -1.0, 1.0]), self.ang_vel[env, drone]),
            "wind": np.zeros(3),
            "rotor_speeds": self._rotor_speeds[env, drone].copy(),
        }
        if self.motors_stopped[env, drone]:
            state = self._unpowered.step(state, {"cmd_motor_speeds": np.zeros(len(state["rotor_speeds"]))}, period)
        else:
            state = self._vehicle.step(state, {"cmd_v": command}, period)
        self.pos[env, drone] = state["x"]
        self.vel[env, drone] = state["v"]
        self.quat[env, drone] = state["q"]
        self.ang_vel[env, drone] = rotate_vector(state["q"], state["w"])
        self._rotor_speeds[env, drone] = state["rotor_speeds"]
