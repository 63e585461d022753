"""PyFlyt's Crazyflie as a simulator: checked against PyFlyt's own code and against physics.

The wrapper must fly exactly what PyFlyt flies: the same states from the same commands as a PyFlyt ``Aviary`` stepped
directly (so that positions, attitudes and the world frame of both velocities pass through unchanged), hold a hover,
follow a velocity step as slowly as PyFlyt's published gains make it, fall under gravity once its motors are cut,
and hand touchdowns to the MDP as the point mass does.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

pytest.importorskip("PyFlyt")

from PyFlyt.core import Aviary
from scipy.spatial.transform import Rotation

from marlander_lite.crazyflie.fit import fit_commands, fit_point_mass, position_hold, simulator_response
from marlander_lite.pointmass.family import DynamicsFamily
from marlander_lite.pyflyt_sim.envs import PyFlytOptions
from marlander_lite.pyflyt_sim.simulator import ALTITUDE, hover_throttle
from marlander_lite.task import TaskConfig

GRAVITY = 9.81


@pytest.fixture(scope="module")
def swarm():
    """One PyFlyt drone over the floor plate (built once: PyFlyt compiles its kernels and settles a hover)."""
    simulator, _ = PyFlytOptions(num_drones=1).build(1)
    yield simulator
    simulator.close()


@pytest.fixture(scope="module")
def swarm_021():
    """The same, stepped as the pinned PyFlyt 0.21.0 steps it (its controllers read every state before the physics)."""
    simulator, _ = PyFlytOptions(num_drones=1, read_state="before_physics").build(1)
    yield simulator
    simulator.close()


def _start(sim, position=(0.0, 0.0, 2.0), seed=0):
    sim.reset(np.arange(1), np.random.default_rng(seed))
    sim.pos[0, 0] = position
    sim.place(0, sim.pos[0])  # at rest, level, a hovering drone's controller
    return sim


def test_the_hover_throttle_carries_the_weight():
    # PyFlyt's motor: thrust_coef (throttle max_rpm)^2 per motor; four of them at the hover throttle = m g.
    aviary = Aviary(
        start_pos=np.array([[0.0, 0.0, 10.0]]), start_orn=np.zeros((1, 3)), render=False, drone_type="quadx"
    )
    quad = aviary.drones[0]
    throttle = hover_throttle(aviary, quad)
    thrust = 4 * np.ravel(quad.motors.thrust_coef)[0] * (throttle * np.ravel(quad.motors.max_rpm)[0]) ** 2
    np.testing.assert_allclose(thrust, 0.027 * GRAVITY, rtol=1e-9)  # the cf2x URDF's 27 g
    aviary.disconnect()


def test_a_flight_is_pyflyts_flight_state_for_state(swarm_021):
    # PyFlyt 0.21.0's own Aviary.step is the reference for the wrapper that steps it unchanged.
    sim = _start(swarm_021)
    quad = sim.aviaries[0].drones[0]
    start = np.array([sim.pos[0, 0] + (0.0, 0.0, ALTITUDE)])
    reference = Aviary(start_pos=start, start_orn=np.zeros((1, 3)), render=False, drone_type="quadx")
    twin = reference.drones[0]
    twin.set_mode(6)
    # The same controller state and the same motor-noise stream as the wrapped drone.
    twin.motors.throttle[:] = quad.motors.throttle
    for mine, theirs in zip((*quad.PIDs, *quad.z_PIDs), (*twin.PIDs, *twin.z_PIDs), strict=True):
        theirs._integral[:], theirs._prev_error[:] = mine._integral, mine._prev_error
    twin.motors.np_random = copy.deepcopy(quad.motors.np_random)
    twin.update_state()
    commands = [np.array([0.8, -0.3, 0.4]), np.array([-0.5, 0.6, -0.2]), np.array([0.0, 0.0, 0.3])]
    for command in commands:
        for _ in range(8):
            sim.step(command[None, None])
            twin.setpoint = np.array([command[0], command[1], 0.0, command[2]])
            for _ in range(sim.control_periods):
                reference.step()
        position, quat = reference.getBasePositionAndOrientation(twin.Id)
        velocity, ang_vel = reference.getBaseVelocity(twin.Id)
        np.testing.assert_array_equal(sim.pos[0, 0], np.array(position) - (0.0, 0.0, ALTITUDE))
        np.testing.assert_array_equal(sim.quat[0, 0], quat)
        np.testing.assert_array_equal(sim.vel[0, 0], velocity)
        np.testing.assert_array_equal(sim.ang_vel[0, 0], ang_vel)
    reference.disconnect()


def test_a_hovering_drone_holds_its_height(swarm):
    sim = _start(swarm)
    heights, tilts = [], []
    for _ in range(48):  # two seconds of zero commands
        sim.step(np.zeros((1, 1, 3)))
        heights.append(sim.pos[0, 0, 2])
        tilts.append(Rotation.from_quat(sim.quat[0, 0]).magnitude())
    assert np.ptp(heights) < 0.05 and abs(heights[-1] - 2.0) < 0.05
    assert max(tilts) < np.radians(10)


def test_a_velocity_step_is_slow_and_the_tilt_stays_within_pyflyts_clamp(swarm):
    sim = _start(swarm)
    speeds, tilts = [], []
    for _ in range(36):
        sim.step(np.array([[[1.0, 0.0, 0.0]]]))
        speeds.append(sim.vel[0, 0, 0])
        tilts.append(Rotation.from_quat(sim.quat[0, 0]).magnitude())
    # The response the module docstring states: 10-90 % rise in about 0.9 s (0.18 s to 1.05 s), sampled at 24 Hz.
    assert 0.35 < speeds[11] < 0.6  # 0.5 s
    assert 0.8 < speeds[23] < 1.0  # 1.0 s
    assert speeds[-1] > 0.95  # 1.5 s
    assert max(tilts) < 0.4 + 0.05  # roll and pitch setpoints clamped at 0.4 rad, plus the attitude loop's error


def test_stopped_motors_spin_down_and_the_drone_falls_freely(swarm):
    sim = _start(swarm, (0.0, 0.0, 3.5))
    sim.stop_motors(np.ones((1, 1), dtype=bool))
    vz = []
    for _ in range(10):
        sim.step(np.array([[[0.0, 0.0, 1.0]]]))  # ignored: no thrust
        vz.append(sim.vel[0, 0, 2])
    # The motors stop within PyFlyt's 10 ms lag; the drone then falls at g, less PyFlyt's body drag, which grows
    # with the speed (0.25 m/s^2 of it at 3 m/s).
    acceleration = np.diff(vz[2:]) / sim._dt
    assert abs(acceleration[0] + GRAVITY) < 0.01 * GRAVITY
    assert np.all(acceleration > -GRAVITY * 1.005) and np.all(acceleration < -0.9 * GRAVITY)
    assert np.all(np.diff(acceleration) > 0)  # the drag grows as it falls faster
    assert np.all(sim.aviaries[0].drones[0].motors.throttle < 1e-3)


def test_the_controllers_read_the_state_the_physics_step_made(swarm, swarm_021):
    # PyFlyt >= 0.22 reads each drone's state after stepSimulation; 0.21.0 before it, so after a step the state its
    # controller holds is one physics step behind the body.
    for sim, current in ((swarm, True), (swarm_021, False)):
        _start(sim).step(np.array([[[0.5, 0.0, 0.5]]]))
        quad = sim.aviaries[0].drones[0]
        body, _ = sim.aviaries[0].getBasePositionAndOrientation(quad.Id)
        assert np.array_equal(quad.state[3], body) == current


def test_read_after_the_physics_a_symmetric_drone_holds_x_and_y_alike():
    # The cf2x is symmetric (same inertia about x and y, motors on the diagonals), so a position hold around its
    # velocity loop must hold x and y alike. Stepped as 0.21.0 steps it, y wanders for ever (PyFlyt's own position
    # mode does the same: docs/transfer.md, "PyFlyt"); with the state read after the physics step both hold.
    task = TaskConfig(num_drones=1)
    rms = {
        read_state: np.sqrt(np.mean(np.square(position_hold(task, "pyflyt", 12.0, read_state=read_state)[96:]), axis=0))
        for read_state in ("after_physics", "before_physics")
    }
    assert rms["after_physics"][0] < 0.02 and rms["after_physics"][1] < 0.02
    assert rms["before_physics"][0] < 0.02 and rms["before_physics"][1] > 0.1


def test_bad_options_say_what_is_allowed():
    with pytest.raises(ValueError, match="whole multiple of the policy rate"):
        PyFlytOptions(control_hz=100.0)
    with pytest.raises(ValueError, match="divide PyFlyt's 240 Hz"):
        PyFlytOptions(control_hz=72.0)  # 3 x 24 Hz, but 240 / 72 is no whole number of physics steps
    with pytest.raises(ValueError, match="drone_model must be one of"):
        PyFlytOptions(drone_model="fixedwing")
    with pytest.raises(ValueError, match="read_state must be one of"):
        PyFlytOptions(read_state="during_physics")


def test_identified_as_the_pybullet_trackers_pyflyts_tracker_is_slower_than_the_family():
    # The system identification that bounds the training family (crazyflie/fit.py), run on PyFlyt: its horizontal
    # velocity loop answers with a time constant near 0.8 s, twice the family's slowest (0.40 s), and it tilts
    # at most 0.4 rad (about 13 degrees of effective tilt in the fit, under the family's 15).
    task = TaskConfig(num_drones=1)
    commands = fit_commands()
    fit = fit_point_mass(commands, simulator_response(commands, task, "pyflyt"), task, iterations=8)
    family = DynamicsFamily()
    assert fit.rms_error < 0.15
    assert fit.params.velocity_time_constant > 1.5 * family.velocity_time_constant[1]
    assert fit.params.max_tilt_deg < family.max_tilt_deg[0]


def test_a_landed_drones_pybullet_body_is_held_on_its_pad(swarm):
    sim = _start(swarm)
    on_pad = sim.state().pad_pos[0, 0] + np.array([0.0, 0.0, 0.01])
    sim.place(0, on_pad[None])
    sim.land(np.ones((1, 1), dtype=bool))
    for _ in range(3):  # its PyFlyt controller is still flying it; we put it back on the pad after every step
        sim.step(np.array([[[0.5, 0.0, 0.5]]]))
    held, _ = sim.aviaries[0].getBasePositionAndOrientation(sim.aviaries[0].drones[0].Id)
    np.testing.assert_allclose(np.array(held) - (0.0, 0.0, ALTITUDE), sim.pos[0, 0])
    np.testing.assert_allclose(sim.pos[0, 0], on_pad)
