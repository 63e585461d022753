"""Another PyFlyt Crazyflie (``PyFlytOptions.tuning``): checked against physics and against PyFlyt as it ships.

No tuning must fly PyFlyt's ``cf2x`` unchanged; each field must change the drone the way its docstring says: the mass
and inertia of every link, a command arriving later by whole control periods, the tilt clamp reached and held (level
acceleration ``g tan(tilt)``), faster or slower loops, and a body without drag falling at exactly ``g``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("PyFlyt")

from scipy.spatial.transform import Rotation

from marlander_lite.pyflyt_sim.envs import PyFlytOptions
from marlander_lite.pyflyt_sim.simulator import hover_throttle
from marlander_lite.pyflyt_sim.tuning import PYFLYT_TILT_LIMIT_DEG, PyFlytTuning

GRAVITY = 9.81


def _build(tuning=None, seed=0, position=(0.0, 0.0, 2.0)):
    sim, _ = PyFlytOptions(num_drones=1, tuning=tuning).build(1)
    sim.reset(np.arange(1), np.random.default_rng(seed))
    sim.pos[0, 0] = position
    sim.place(0, sim.pos[0])
    return sim


def _fly(sim, command, steps):
    """Velocities and tilts (rad) after each of ``steps`` policy steps of ``command`` (m/s)."""
    velocities, tilts = [], []
    try:
        for _ in range(steps):
            sim.step(np.array([[command]], dtype=float))
            velocities.append(sim.vel[0, 0].copy())
            tilts.append(Rotation.from_quat(sim.quat[0, 0]).magnitude())
    finally:
        sim.close()
    return np.array(velocities), np.array(tilts)


def test_no_tuning_is_pyflyts_cf2x_state_for_state():
    flights = [_fly(_build(tuning), [0.6, -0.3, 0.2], 12)[0] for tuning in (None, PyFlytTuning(), {})]
    np.testing.assert_array_equal(flights[0], flights[1])
    np.testing.assert_array_equal(flights[0], flights[2])


def test_the_mass_and_inertia_of_every_link_scale_and_the_hover_carries_the_new_weight():
    nominal, heavier = _build(), _build({"mass_scale": 1.2})
    try:
        for link in range(-1, nominal.aviaries[0].getNumJoints(nominal.aviaries[0].drones[0].Id)):
            m0, _, i0, *_ = nominal.aviaries[0].getDynamicsInfo(nominal.aviaries[0].drones[0].Id, link)
            m1, _, i1, *_ = heavier.aviaries[0].getDynamicsInfo(heavier.aviaries[0].drones[0].Id, link)
            assert m1 == pytest.approx(1.2 * m0) and np.allclose(i1, 1.2 * np.array(i0))
        # Thrust ~ throttle^2: carrying 1.2 times the weight takes sqrt(1.2) times the throttle.
        ratio = hover_throttle(heavier.aviaries[0], heavier.aviaries[0].drones[0]) / hover_throttle(
            nominal.aviaries[0], nominal.aviaries[0].drones[0]
        )
        assert ratio == pytest.approx(math.sqrt(1.2), rel=1e-9)
    finally:
        nominal.close()
    start = heavier.pos[0, 0, 2]
    velocities, _ = _fly(heavier, [0.0, 0.0, 0.0], 48)  # its integrator starts warm for the true weight
    assert abs(velocities[-24:, 2]).max() < 0.05
    assert start > 1.9


def test_a_late_command_moves_the_drone_later_by_the_latency():
    rise = {}
    for latency in (0.0, 0.1):
        velocities, _ = _fly(_build({"latency_s": latency}), [1.0, 0.0, 0.0], 24)
        if latency:
            assert abs(velocities[:2, 0]).max() < 0.01  # 83 ms: the command has not arrived
        rise[latency] = int(np.argmax(velocities[:, 0] > 0.3))
    # 0.1 s is 2.4 policy steps of 1/24 s: the speed crosses 0.3 m/s two or three steps later.
    assert rise[0.1] - rise[0.0] in (2, 3)


def test_a_reset_forgets_the_commands_still_in_flight():
    sim = _build({"latency_s": 0.1})
    for _ in range(2):  # 1 m/s sent, not yet arrived
        sim.step(np.array([[[1.0, 0.0, 0.0]]]))
    sim.reset(np.arange(1), np.random.default_rng(1))
    sim.pos[0, 0] = (0.0, 0.0, 2.0)
    sim.place(0, sim.pos[0])
    velocities, _ = _fly(sim, [0.0, 0.0, 0.0], 6)
    assert abs(velocities[:, 0]).max() < 0.02


def test_the_tilt_clamp_is_reached_and_held_and_sets_the_level_acceleration():
    # PyFlyt's attitude loop is slow (its ang_pos kp of 2 /s): a 3 m/s command tilts the drone onto a 10 degree clamp
    # after about a second and holds it there while the speed error stays large.
    velocities, tilts = _fly(_build({"tilt_limit_deg": 10.0}), [3.0, 0.0, 0.0], 44)
    assert np.degrees(tilts.max()) < 11.0
    assert np.degrees(tilts[24:44]).min() > 8.5
    acceleration = (velocities[43, 0] - velocities[24, 0]) / (19 / 24)
    level = GRAVITY * math.tan(math.radians(10.0))  # thrust carrying the weight, tilted: g tan(tilt) forward
    assert 0.8 * level < acceleration < 1.05 * level  # less PyFlyt's body drag
    assert PyFlytTuning().tilt_limit_deg is None and PYFLYT_TILT_LIMIT_DEG == pytest.approx(22.92, abs=0.01)


def test_stiffer_outer_loops_answer_faster_and_softer_inner_loops_tilt_more_slowly():
    half_second = [_fly(_build({"outer_gain_scale": s}), [1.0, 0.0, 0.0], 12)[0][-1, 0] for s in (0.6, 1.0, 1.5)]
    assert half_second[0] < half_second[1] < half_second[2] and half_second[2] - half_second[0] > 0.05
    tenth = {s: _fly(_build({"inner_gain_scale": s}), [3.0, 0.0, 0.0], 3)[1][-1] for s in (0.6, 1.5)}
    assert np.degrees(tenth[0.6]) + 1.0 < np.degrees(tenth[1.5])


def test_without_body_drag_a_drone_with_stopped_motors_falls_at_g():
    sim = _build({"body_drag": False}, position=(0.0, 0.0, 3.5))
    sim.stop_motors(np.ones((1, 1), dtype=bool))
    velocities, _ = _fly(sim, [0.0, 0.0, 0.0], 10)
    acceleration = np.diff(velocities[2:, 2]) * 24.0  # after PyFlyt's 10 ms motor lag
    np.testing.assert_allclose(acceleration, -GRAVITY, rtol=2e-3)  # with drag it falls ever slower (test_pyflyt)


@pytest.mark.parametrize(
    ("tuning", "error", "message"),
    [
        ({"mass": 1.2}, TypeError, r"PyFlyt tuning got unknown option\(s\) \['mass'\]; allowed options: mass_scale"),
        ({"mass_scale": 3.0}, ValueError, r"mass_scale must be a number in \[0.5, 2\]"),
        ({"latency_s": -0.01}, ValueError, r"latency_s must be a number in \[0, 0.5\]"),
        ({"outer_gain_scale": 0.0}, ValueError, r"outer_gain_scale must be a number in \(0, 5\]"),
        ({"inner_gain_scale": float("nan")}, ValueError, "inner_gain_scale must be a number"),
        ({"tilt_limit_deg": 90.0}, ValueError, r"tilt_limit_deg must be a number in \[5, 80\]"),
        ({"body_drag": "no"}, ValueError, "body_drag must be True or False"),
        ("heavy", TypeError, "tuning must be a PyFlytTuning, a mapping of its fields or None"),
    ],
)
def test_bad_tuning_says_what_is_allowed(tuning, error, message):
    with pytest.raises(error, match=message):
        PyFlytOptions(tuning=tuning)
