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
from marlander_lite.rotorpy_sim.tuning import RotorPyTuning

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


# ----------------------------------------------------------------------------- another RotorPy Crazyflie


def _hold_then_step(sim, steps: int = 48, step_at: int = 24) -> np.ndarray:
    """``(steps, 3)`` velocities: zero commands, then 0.5 m/s along x from step ``step_at``."""
    velocities = []
    for k in range(steps):
        command = np.array([[[0.5 if k >= step_at else 0.0, 0.0, 0.0]]])
        sim.step(command)
        velocities.append(sim.vel[0, 0].copy())
    return np.array(velocities)


def test_the_default_tuning_changes_nothing():
    plain, tuned = _swarm(), _swarm(tuning=RotorPyTuning())
    np.testing.assert_array_equal(_hold_then_step(plain), _hold_then_step(tuned))


def test_a_mass_the_controller_does_not_know_sinks_at_the_p_loops_steady_error():
    """RotorPy's velocity loop is proportional: asked to hover, a drone 20 % heavier than its controller believes
    settles where ``m_told (k_v (0 - v) + g) = m g``, i.e. sinking at ``v = -g (m / m_told - 1) / k_v``."""
    sim = _swarm(tuning={"mass_scale": 1.2})
    assert sim.quad_params["mass"] == pytest.approx(1.2 * quad_params["mass"])
    assert sim.quad_params["Ixx"] == pytest.approx(1.2 * quad_params["Ixx"])
    for _ in range(48):  # two seconds, about 20 time constants of 1 / k_v
        sim.step(np.zeros((1, 1, 3)))
    expected = -GRAVITY * (1.2 - 1.0) / quad_params["k_v"]
    assert sim.vel[0, 0, 2] == pytest.approx(expected, rel=0.02)
    assert _swarm().vel[0, 0, 2] == 0.0


def test_latency_delays_every_command_by_whole_control_periods():
    """One policy step of latency (4 periods at 96 Hz): the late drone flies what the prompt one flew a step before."""
    late = _hold_then_step(_swarm(tuning={"latency_s": 1 / 24}))
    prompt = _hold_then_step(_swarm())
    assert RotorPyTuning(latency_s=0.0625).delay_periods(96.0) == 6
    np.testing.assert_allclose(late[1:], prompt[:-1], atol=1e-9)
    assert late[24, 0] == 0.0 < prompt[24, 0]


def test_scaled_gains_are_rotorpys_gains_scaled():
    sim = _swarm(tuning={"outer_gain_scale": 0.5, "inner_gain_scale": 2.0})
    changed = {name: sim.quad_params[name] for name in ("k_v", "kp_att", "kd_att")}
    assert changed == pytest.approx({"k_v": 5.0, "kp_att": 620.0, "kd_att": 114.0})
    soft = _hold_then_step(sim)
    assert soft[26, 0] < _hold_then_step(_swarm())[26, 0]  # a softer velocity loop answers the step later


@pytest.mark.parametrize(
    ("tuning", "error", "message"),
    [
        ({"mass_scale": 0.2}, ValueError, r"RotorPyTuning.mass_scale must be a number in \[0.5, 2\], got 0.2"),
        ({"latency_s": -0.01}, ValueError, r"RotorPyTuning.latency_s must be a number in \[0, 0.5\]"),
        ({"outer_gain_scale": 0.0}, ValueError, r"outer_gain_scale must be a number in \(0, 5\]"),
        ({"inner_gain_scale": float("nan")}, ValueError, "inner_gain_scale must be a number"),
        ({"tilt_limit_deg": 20}, TypeError, r"got unknown option\(s\) \['tilt_limit_deg'\]; allowed options: mass"),
        ("heavy", TypeError, "must be a RotorPyTuning, a mapping of its fields or None, got str"),
    ],
)
def test_a_bad_tuning_says_what_is_allowed(tuning, error, message):
    with pytest.raises(error, match=message):
        RotorPyOptions(tuning=tuning)
