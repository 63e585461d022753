"""Safety rules: the geofence margin follows from braking physics, and a runaway drone stops inside the hard fence.

Defect 2: with ``limits.max_speed`` 2 or 3 m/s and the example's 0.3 m margin, a drone running
away at full speed ended 0.3-0.8 m outside the hard fence. The margin must hold the stopping
distance ``1.25 (v (t_lat + t_resp) + v^2 / (2 a_fw))`` from ``v = 1.1 max_speed`` (the firmware
tracker's overshoot, response delay and deceleration, measured in PyBullet); the loader refuses a
config whose margin does not, and the runtime fence brakes as soon as a drone's stopping point (at
its measured speed) leaves the hard box.
"""

import dataclasses
import math
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from marlander_lite.deploy.config import (
    EXAMPLE_CONFIG,
    GeofenceConfig,
    LabConfig,
    SimulationConfig,
    load_lab_config,
    load_lab_policy,
)
from marlander_lite.deploy.rehearsal import rehearse
from marlander_lite.deploy.rehearsal.faults import FaultSpec
from marlander_lite.deploy.safety import (
    BRAKE_DECELERATION,
    FENCE_GUARD_BUFFER,
    FIRMWARE_BRAKE_DECELERATION,
    SPEED_OVERSHOOT,
    TILT_LIMIT_DECELERATION,
    TRACKER_RESPONSE_DELAY_S,
    SafetyMonitor,
    fastest_speed_for,
    keep_inside,
    required_margin,
    stopping_distance,
)
from marlander_lite.deploy.schema import ConfigError

try:
    import marlander_lite.crazyflie.simulator  # noqa: F401

    SIMULATORS = ["pointmass", "crazyflie"]
except ImportError:  # the PyBullet swarm is not part of this checkout
    SIMULATORS = ["pointmass"]


def test_margin_formula_and_numbers():
    # the firmware brakes more gently than its tilt limit would allow, later, from an overshoot of the command
    assert TILT_LIMIT_DECELERATION == pytest.approx(9.81 * math.tan(math.radians(20)), rel=1e-9)
    assert BRAKE_DECELERATION == FIRMWARE_BRAKE_DECELERATION == pytest.approx(2.4)
    assert BRAKE_DECELERATION < TILT_LIMIT_DECELERATION
    assert (SPEED_OVERSHOOT, TRACKER_RESPONSE_DELAY_S) == (pytest.approx(1.1), pytest.approx(0.15))
    t = 0.030 + 1 / 48 + 0.15  # mocap + radio, one period of the 48 Hz loop, the tracker's response delay
    for v, expected in ((0.5, 0.217), (1.0, 0.591), (1.5, 1.123), (2.0, 1.813), (3.0, 3.664)):
        w = 1.1 * v
        assert required_margin(v, 48.0) == pytest.approx(1.25 * (w * t + w**2 / (2 * 2.4)))
        assert required_margin(v, 48.0) == pytest.approx(expected, abs=1e-3)
        assert fastest_speed_for(required_margin(v, 48.0), 48.0) == pytest.approx(v)
    # the runtime rule: measured speeds already contain the overshoot
    d2 = 1.25 * (2.0 * t + 4.0 / 4.8)
    assert stopping_distance(np.array([-2.0, 0.0, 2.0]), 48.0) == pytest.approx([d2, 0.0, d2], abs=1e-9)


def fast_lab(max_speed: float, simulator: str) -> LabConfig:
    """The example lab at ``max_speed``, its fence widened to hold the braking margin (1.7 m of soft box kept)."""
    base = load_lab_config(EXAMPLE_CONFIG)
    margin = math.ceil(required_margin(max_speed, base.rates.loop_hz) * 100) / 100
    half = 1.7 + margin
    fence = GeofenceConfig(x=(-half, half), y=(-half, half), z=(0.0, 1.7 + margin), margin=margin)
    return base.replace(
        limits=dataclasses.replace(base.limits, max_speed=max_speed),
        geofence=fence,
        simulation=SimulationConfig(simulator=simulator, max_time_s=30.0),
    )


def test_a_margin_too_narrow_for_the_speed_is_refused():
    base = load_lab_config(EXAMPLE_CONFIG)
    message = r"needs 3.67 m .* lower limits.max_speed to 1.00 m/s .* geofence.margin >= 3.67 m"
    with pytest.raises(ConfigError, match=message):
        base.replace(limits=dataclasses.replace(base.limits, max_speed=3.0))
    assert fast_lab(3.0, "pointmass").geofence.margin == pytest.approx(3.67)


@pytest.mark.parametrize("max_speed", [0.5, 1.3, 2.0, 2.7, 3.0])
@pytest.mark.parametrize("margin", [0.1, 0.3, 0.6])
def test_both_fixes_the_refusal_names_are_accepted(max_speed, margin):
    base = load_lab_config(EXAMPLE_CONFIG)
    half = 1.0 + 4.0  # room for any margin up to its 4 m limit
    fence = GeofenceConfig(x=(-half, half), y=(-half, half), z=(0.0, half), margin=margin)
    try:
        base.replace(limits=dataclasses.replace(base.limits, max_speed=max_speed), geofence=fence)
        return  # fits already
    except ConfigError as error:
        message = str(error)
    slower = float(re.search(r"lower limits.max_speed to ([0-9.]+) m/s", message).group(1))
    wider = float(re.search(r"geofence.margin >= ([0-9.]+) m", message).group(1))
    base.replace(limits=dataclasses.replace(base.limits, max_speed=slower), geofence=fence)
    base.replace(
        limits=dataclasses.replace(base.limits, max_speed=max_speed), geofence=dataclasses.replace(fence, margin=wider)
    )


@pytest.fixture(scope="module")
def policy_path(p_controller_policy) -> Path:
    """The linear P-controller of conftest.py: it would land; a fault replaces one drone's action."""
    return p_controller_policy


@pytest.mark.parametrize("simulator", SIMULATORS)
@pytest.mark.parametrize("max_speed", [2.0, 3.0])
def test_a_runaway_drone_stops_inside_the_hard_fence(max_speed, simulator, policy_path):
    lab = fast_lab(max_speed, simulator)
    for seed in range(3):  # three start layouts: the runaway heads for different walls
        result = rehearse(lab, policy_path, fault=FaultSpec("geofence-breach"), seed=seed)
        kinds = [e.kind for e in result.mission.events]
        assert "geofence_breach" in kinds, result.summary()
        assert result.safe and result.inside_fence.all(), result.summary()
        low, high = lab.geofence.bounds()
        assert (result.final_positions[:, :2] > np.array(low[:2])).all()
        assert (result.final_positions[:, :2] < np.array(high[:2])).all()


def estimate(pos, vel) -> SimpleNamespace:
    pos, vel = np.atleast_2d(pos).astype(float), np.atleast_2d(vel).astype(float)
    n = len(pos)
    return SimpleNamespace(pos=pos, vel=vel, age=np.zeros(n), invalid=np.zeros(n, dtype=bool))


def test_the_runtime_fence_brakes_when_the_stopping_point_reaches_the_hard_fence():
    lab = fast_lab(2.0, "pointmass")  # hard x = 3.52, soft x = 1.7, margin 1.82
    flying = np.array([True])
    lab = lab.replace(drones=lab.drones[:1], simulation=SimulationConfig(simulator="pointmass"))
    # inside the soft box at 1 m/s towards the wall: stops after 0.51 m, well inside
    assert SafetyMonitor(lab).flight(1.0, estimate([1.5, 0, 1], [1.0, 0, 0]), flying, True).action == "fly"
    # inside the soft box, but at 4 m/s (a gust, or a speed overshoot) it needs 5.2 m: brake now
    verdict = SafetyMonitor(lab).flight(1.0, estimate([1.5, 0, 1], [4.0, 0, 0]), flying, True)
    assert verdict.action == "hover" and verdict.events[0].kind == "geofence_breach"
    assert "could not stop inside the hard fence" in verdict.events[0].message
    # moving away from the wall (stopping 1.5 m further, far from the other one), or down towards the floor
    # (a landing), is no breach
    assert SafetyMonitor(lab).flight(1.0, estimate([1.5, 0, 1], [-2.0, 0, 0]), flying, True).action == "fly"
    assert SafetyMonitor(lab).flight(1.0, estimate([0, 0, 0.3], [0, 0, -2.0]), flying, True).action == "fly"
    # NaN velocity: staleness rules handle it, not the fence
    assert SafetyMonitor(lab).flight(1.0, estimate([0, 0, 1], [np.nan] * 3), flying, True).action == "fly"
    # the old rule still holds: outside the soft box is a breach
    assert SafetyMonitor(lab).flight(1.0, estimate([1.8, 0, 1], [0, 0, 0]), flying, True).action == "hover"


def test_the_takeoff_height_check_matches_arming():
    base = load_lab_config(EXAMPLE_CONFIG)
    assert base.replace(limits=dataclasses.replace(base.limits, takeoff_height=0.3)).limits.takeoff_height == 0.3
    with pytest.raises(ConfigError, match="arming always refuses"):
        base.replace(limits=dataclasses.replace(base.limits, takeoff_height=0.29))


def test_a_drone_tilted_past_the_tumble_limit_for_long_enough_has_tumbled():
    """``safety.tumble_tilt_deg`` (60) held for ``safety.tumble_s`` (0.1 s): a drone lying on its side (90 degrees) is
    flagged once it has lain there 0.1 s; a single tilted frame, a tilt within the limit (45 degrees), a stale pose or
    a drone not flying are not."""
    lab = load_lab_config(EXAMPLE_CONFIG)
    assert (lab.safety.tumble_tilt_deg, lab.safety.tumble_s) == (60.0, 0.1)
    monitor = SafetyMonitor(lab)

    def tilted(degrees: float, age: float = 0.0) -> SimpleNamespace:
        half = math.radians(degrees) / 2  # about x: tilt_deg of (sin, 0, 0, cos) is the angle itself
        level = [0.0, 0.0, 0.0, 1.0]
        return SimpleNamespace(
            quat=np.array([[math.sin(half), 0.0, 0.0, math.cos(half)], level]),
            drone_age=np.array([age, 0.0]),
            drone_invalid=np.zeros(2, dtype=bool),
        )

    flying = np.array([True, True])
    assert monitor.tumbled(0.00, tilted(90.0), flying) == []  # the first tilted frame
    assert monitor.tumbled(0.02, tilted(0.0), flying) == []  # one bad frame: the clock restarts
    assert monitor.tumbled(0.04, tilted(90.0), flying) == []
    assert monitor.tumbled(0.12, tilted(90.0), flying) == []  # 0.08 s
    assert monitor.tumbled(0.14, tilted(90.0), flying) == [0]  # 0.10 s
    assert monitor.tumbled(0.16, tilted(45.0), flying) == []  # within the limit
    assert monitor.tumbled(0.50, tilted(90.0, age=1.0), flying) == []  # a stale pose says nothing
    assert monitor.tumbled(0.60, tilted(90.0), np.array([False, True])) == []  # down already


# ------------------------------------------------------------------ the fence guard
def test_the_fence_guard_cuts_what_heads_for_a_wall_to_what_stops_in_the_room_left():
    """By hand: the firmware overshoots a command u to 1.1 u, and from there a drone needs 1.25 (1.1 u t + (1.1 u)^2 /
    (2 x 2.4)) with t = 0.030 + 1/48 + 0.15 s; 0.15 m from the wall, with the guard's 5 cm buffer, it has 0.1 m."""
    loop_hz = 48.0
    t, a = 0.030 + 1 / 48 + 0.15, 2.4

    def by_hand(room: float) -> float:  # the root u of 1.25 (1.1 u t + (1.1 u)^2 / (2 a)) = room
        overshot = (-t + math.sqrt(t * t + 4 * (room / 1.25) / (2 * a))) / (2 / (2 * a))
        return overshot / 1.1

    low, high = np.array([-1.0, -1.0, -np.inf]), np.array([1.0, 1.0, 2.0])
    pos = np.array([[0.85, 0, 1], [0.85, 0, 1], [0, -1.05, 1], [0, 0, 0.05], [0, 0, 1.9], [np.nan] * 3, [0.5, 0, 1]])
    vel = np.array([[2.0, 0.5, -0.3], [-1.0, 0.5, -0.3], [0.4, -0.4, 0.2], [0, 0, -1], [0, 0, 1], [3, 0, 0], [2, 0, 0]])
    measured = np.zeros_like(vel)  # at rest, but the last one already flies 2 m/s at the wall 0.5 m away
    measured[6, 0] = 2.0
    guarded, changed = keep_inside(vel, pos, measured, low, high, loop_hz)
    assert FENCE_GUARD_BUFFER == 0.05
    assert guarded[0, 0] == pytest.approx(by_hand(0.1), rel=1e-9)
    assert stopping_distance(SPEED_OVERSHOOT * guarded[0, 0], loop_hz) == pytest.approx(0.1)
    np.testing.assert_array_equal(guarded[0, 1:], [0.5, -0.3])  # the other axes as the policy asked
    np.testing.assert_array_equal(guarded[1], vel[1])  # away from the wall, slower than the far one allows: untouched
    # 5 cm beyond a wall, 10 cm beyond the buffer: pushed back in at what stops in 10 cm; the other axes kept
    np.testing.assert_allclose(guarded[2], [0.4, by_hand(0.1), 0.2], rtol=1e-9)
    np.testing.assert_array_equal(guarded[3], vel[3])  # the floor is not guarded: landing goes down to it
    assert guarded[4, 2] == pytest.approx(by_hand(0.05), rel=1e-9)  # the ceiling is
    np.testing.assert_array_equal(guarded[5], vel[5])  # a NaN position is the stale-data rules' business
    # at rest there it could be sent at by_hand(0.45) m/s; at 2 m/s it needs more than the 0.45 m left: brake now
    assert stopping_distance(2.0, loop_hz) > 0.45 and by_hand(0.45) > 0.5
    np.testing.assert_array_equal(guarded[6], [0.0, 0.0, 0.0])
    assert changed.tolist() == [True, False, True, False, True, False, True]


class Runaway:
    """Wraps a policy; drone ``drone``'s action is always full speed along +x: a policy that cannot see the walls."""

    def __init__(self, policy, drone: int) -> None:
        self.policy, self.drone, self.contract = policy, drone, policy.contract

    def act(self, obs):
        out = np.array(self.policy.act(obs), dtype=float)
        out.reshape(-1, 3)[self.drone] = [1.0, 0.0, 0.0]
        return out


@pytest.mark.parametrize("simulator", SIMULATORS)
def test_a_policy_heading_for_a_wall_is_held_inside_the_soft_fence(simulator, policy_path):
    """The runaway of the policy, not of the drone: the guard slows it to a stop 5 cm inside the soft fence, so the
    flight is not aborted; it runs to its time limit, which lands every drone, and nothing leaves the box."""
    base = load_lab_config(EXAMPLE_CONFIG)
    lab = base.replace(
        limits=dataclasses.replace(base.limits, max_flight_s=8.0),
        simulation=dataclasses.replace(base.simulation, simulator=simulator),
    )
    policy = Runaway(load_lab_policy(policy_path, lab), drone=0)
    seen: list[np.ndarray] = []
    result = rehearse(lab, policy, seed=0, hooks=[lambda m, t: m.stream.last and seen.append(m.stream.last.pos[0])])
    kinds = [e.kind for e in result.mission.events]
    guard = [e for e in result.mission.events if e.kind == "fence_guard"]
    assert "geofence_breach" not in kinds and guard and guard[0].drone == 0, kinds
    assert result.safe and result.at_rest.all() and (result.fence_excess == 0).all(), result.summary()
    soft_x = lab.geofence.bounds(soft=True)[1][0]
    closest = soft_x - np.nanmax([p[0] for p in seen])  # NaN before the first pose
    assert 0.0 < closest < 0.1, closest  # it came up to the soft fence and stopped short of it
    assert "flight_timeout" in kinds, kinds  # the flight went on under the policy to its end


def test_arming_refuses_a_pad_the_fence_guard_would_keep_its_drone_from():
    """cf1's pad 3 cm inside the soft fence: the guard holds drones 5 cm inside it, so cf1 could never land there.
    cf2's pad, 10 cm inside, is reachable. Both drones stand still, level and apart on the floor."""
    lab = load_lab_config(EXAMPLE_CONFIG)
    soft_x = lab.geofence.bounds(soft=True)[1][0]
    monitor = SafetyMonitor(lab)
    est = SimpleNamespace(
        pos=np.array([[0.0, 0.0, 0.01], [0.0, 0.5, 0.01]]),
        vel=np.zeros((2, 3)),
        quat=np.array([[0.0, 0.0, 0.0, 1.0]] * 2),
        pad_pos=np.array([[soft_x - 0.03, 0.0, 0.0], [soft_x - 0.10, 0.5, 0.0]]),
        pad_normal=np.array([[0.0, 0.0, 1.0]] * 2),
        drone_age=np.zeros(2),
        pad_age=np.zeros(2),
        drone_invalid=np.zeros(2, dtype=bool),
        pad_invalid=np.zeros(2, dtype=bool),
    )
    problems = monitor.arming_problems(est, [None, None])
    assert len(problems) == 1 and "pad of cf1" in problems[0], problems
    assert "is not 5 cm inside the soft geofence" in problems[0] and "could not reach its pad" in problems[0]
    assert not monitor.guard_lets_reach(est.pad_pos[0]) and monitor.guard_lets_reach(est.pad_pos[1])
