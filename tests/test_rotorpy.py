"""RotorPy's Crazyflie as a simulator: checked against RotorPy's own code and against physics.

The wrapper must fly exactly what RotorPy flies: the same states from the same commands as RotorPy's
``Multirotor`` stepped directly (so that positions, the world/body frame of the angular velocity and the rotor
speeds all pass through unchanged), hover at RotorPy's published hover rotor speed, fall under gravity once its
rotors have spun down, and hand touchdowns to the MDP as the point mass does.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

pytest.importorskip("rotorpy")

from rotorpy.vehicles.crazyflie_params import quad_params
from rotorpy.vehicles.multirotor import Multirotor

from marlander_lite.rotorpy_sim.envs import RotorPyOptions

GRAVITY = 9.81


def _swarm(num_drones: int = 1, platform: str = "static-floor", **fields):
    simulator, _ = RotorPyOptions(num_drones=num_drones, platform=platform, **fields).build(1)
    simulator.reset(np.arange(1), np.random.default_rng(0))
    return simulator


def test_hover_rotor_speed_is_rotorpys_own():
    # RotorPy's Multirotor starts at rest with its rotors at 1788.53 rad/s: thrust = weight for its 30 g Crazyflie.
    default = Multirotor(quad_params).initial_state["rotor_speeds"]
    sim = _swarm()
    np.testing.assert_allclose(sim._rotor_speeds[0, 0], default, rtol=1e-4)  # RotorPy rounds it to 0.01 rad/s
    start = sim.pos.copy()
    for _ in range(24):  # one second of zero commands
        sim.step(np.zeros((1, 1, 3)))
    assert np.abs(sim.pos - start).max() < 1e-6
    np.testing.assert_allclose(sim.quat[0, 0], [0, 0, 0, 1], atol=1e-9)


def test_a_flight_is_rotorpys_flight_state_for_state():
    sim = _swarm()
    state = {
        "x": sim.pos[0, 0].copy(),
        "v": np.zeros(3),
        "q": np.array([0.0, 0.0, 0.0, 1.0]),
        "w": np.zeros(3),
        "wind": np.zeros(3),
        "rotor_speeds": sim._rotor_speeds[0, 0].copy(),
    }
    period = sim._dt / sim.control_periods
    integrator = {"method": "RK45", "first_step": period}
    reference = Multirotor(quad_params, control_abstraction="cmd_vel", aero=True, integrator_kwargs=integrator)
    commands = [np.array([0.8, -0.3, 0.4]), np.array([-0.5, 0.6, -0.2]), np.array([0.0, 0.0, 0.3])]
    for command in commands:
        for _ in range(8):  # a third of a second each: the body tilts and turns back
            sim.step(command[None, None])
            for _ in range(sim.control_periods):
                state = reference.step(state, {"cmd_v": command}, period)
    np.testing.assert_allclose(sim.pos[0, 0], state["x"], atol=1e-9)
    np.testing.assert_allclose(sim.vel[0, 0], state["v"], atol=1e-9)
    np.testing.assert_allclose(sim.quat[0, 0], state["q"], atol=1e-9)
    np.testing.assert_allclose(sim._rotor_speeds[0, 0], state["rotor_speeds"], rtol=1e-9)
    # Our state holds the world-frame angular velocity: R(q) times RotorPy's body rates.
    rotation = Rotation.from_quat(state["q"]).as_matrix()
    np.testing.assert_allclose(sim.ang_vel[0, 0], rotation @ state["w"], atol=1e-9)
    assert np.linalg.norm(state["w"]) > 0.01  # the check above is not of zeros


def test_the_integrators_first_step_changes_the_flight_by_less_than_its_tolerance():
    """RotorPy's own integrator settings (scipy picks the first step) fly the same states to 1e-6 m and m/s."""
    sim = _swarm()
    state = {"x": sim.pos[0, 0].copy(), "v": np.zeros(3), "q": np.array([0.0, 0.0, 0.0, 1.0]), "w": np.zeros(3),
             "wind": np.zeros(3), "rotor_speeds": sim._rotor_speeds[0, 0].copy()}  # fmt: skip
    published = Multirotor(quad_params, control_abstraction="cmd_vel", aero=True)  # RotorPy's defaults
    period = sim._dt / sim.control_periods
    for k in range(48):  # hover, then a climbing turn
        command = np.zeros(3) if k < 24 else np.array([1.0, -0.5, 0.3])
        sim.step(command[None, None])
        for _ in range(sim.control_periods):
            state = published.step(state, {"cmd_v": command}, period)
    np.testing.assert_allclose(sim.pos[0, 0], state["x"], atol=1e-6)
    np.testing.assert_allclose(sim.vel[0, 0], state["v"], atol=1e-6)


def test_a_velocity_step_overshoots_and_settles():
    sim = _swarm()
    speeds = []
    for _ in range(24):
        sim.step(np.array([[[1.0, 0.0, 0.0]]]))
        speeds.append(sim.vel[0, 0, 0])
    # The response the module docstring states (overshoot to 1.27 m/s at 0.47 s), sampled at 24 Hz.
    assert 0.7 < speeds[5] < 1.0
    assert max(speeds) > 1.2
    assert abs(speeds[-1] - 1.0) < 0.15


def test_stopped_motors_spin_down_and_the_drone_falls_freely():
    sim = _swarm()
    sim.pos[0, 0, 2] = 3.5
    sim.stop_motors(np.ones((1, 1), dtype=bool))
    vz = []
    for _ in range(12):
        sim.step(np.array([[[0.0, 0.0, 1.0]]]))  # ignored: no thrust
        vz.append(sim.vel[0, 0, 2])
    # The rotors slow with RotorPy's 72 ms lag; once they have (after 0.25 s), the drone accelerates at g.
    acceleration = np.diff(vz[6:]) / sim._dt
    np.testing.assert_allclose(acceleration, -GRAVITY, rtol=0.01)
    assert np.all(sim._rotor_speeds[0, 0] < 0.01 * sim._hover_speed)


def test_bad_options_say_what_is_allowed():
    for rate in (100.0, 0.0, float("nan"), "96"):  # refused where given, before anything is built
        with pytest.raises(ValueError, match=r"control_hz must be a whole multiple of the policy rate \(24 Hz\)"):
            RotorPyOptions(control_hz=rate)
    assert RotorPyOptions(control_hz=48).build(1)[0].control_periods == 2
    with pytest.raises(ValueError, match=r"Unknown RotorPy Crazyflie parameter\(s\) \['kv'\]; allowed: .*k_v"):
        RotorPyOptions(quad_params={"kv": 7.0})
    with pytest.raises(TypeError, match="aero must be True or False"):
        RotorPyOptions(aero="yes")
    sim = _swarm()
    with pytest.raises(ValueError, match=r"velocity must have shape \(1, 1, 3\)"):
        sim.step(np.zeros((1, 3)))
    with pytest.raises(ValueError, match="finite"):
        sim.step(np.full((1, 1, 3), np.nan))


def test_changed_parameters_are_flown():
    soft = _swarm(quad_params={"k_v": 5.0})
    stiff = _swarm()
    assert soft.quad_params["k_v"] == 5.0 and stiff.quad_params["k_v"] == quad_params["k_v"]
    for _ in range(6):
        soft.step(np.array([[[1.0, 0.0, 0.0]]]))
        stiff.step(np.array([[[1.0, 0.0, 0.0]]]))
    assert soft.vel[0, 0, 0] < stiff.vel[0, 0, 0]
