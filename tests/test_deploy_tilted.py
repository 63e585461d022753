"""Tilted plates in the deployment loop (beyond the paper, its future work: "inclined surfaces").

The pad normal is the z axis of the body carrying the pad; the goal point and the touchdown are in the pad's frame,
as in the simulators (``episodes.LandingEpisodes``). The expected values are worked by hand for a plate turned by
15 degrees about +x, whose +y edge rises: ``R e_y = (0, cos 15, sin 15)``, ``R e_z = (0, -sin 15, cos 15)``.
"""

import dataclasses
import json
from types import SimpleNamespace

import numpy as np
import pytest

from marlander_lite.deploy.config import EXAMPLE_CONFIG, EXAMPLE_CONFIG_8, load_lab_config
from marlander_lite.deploy.estimation import EstimatorConfig, SwarmEstimate, SwarmEstimator
from marlander_lite.deploy.flight_log import read_flight_log
from marlander_lite.deploy.landing import contacts, surface_below
from marlander_lite.deploy.pose_sources import PoseFrame
from marlander_lite.deploy.rehearsal.run import rehearse
from marlander_lite.deploy.rehearsal.world import SimulatedWorld, make_simulator, world_platform
from marlander_lite.deploy.safety import SafetyMonitor
from marlander_lite.rotations import rotate_vector
from marlander_lite.task import pad_frame_errors

S, C = np.sin(np.radians(15.0)), np.cos(np.radians(15.0))
UP_SLOPE, NORMAL = np.array([0.0, C, S]), np.array([0.0, -S, C])
TILT_QUAT = np.array([np.sin(np.radians(7.5)), 0.0, 0.0, np.cos(np.radians(7.5))])
LANDED_HEIGHT = 0.0125
try:
    import marlander_lite.crazyflie.simulator  # noqa: F401

    REHEARSAL_SIMULATOR = "crazyflie"
except ImportError:  # the PyBullet swarm is not part of this checkout
    REHEARSAL_SIMULATOR = "pointmass"


def tilted_lab(path=EXAMPLE_CONFIG_8, inclination: float = 15.0):
    lab = load_lab_config(path)
    return lab.replace(simulation=dataclasses.replace(lab.simulation, inclination_deg=inclination))


def test_the_goal_is_raised_along_the_tracked_pad_normal():
    """Plate body at c = (0.2, -0.1, 0.3) turned 15 degrees about +x; pad1 at o = (-0.125, 0, 0.0025) in its frame:
    pad centre c + R o = (0.075, -0.1 - 0.0025 sin 15, 0.3 + 0.0025 cos 15), goal 12.5 mm further along (0, -sin 15,
    cos 15)."""
    lab = load_lab_config(EXAMPLE_CONFIG)
    estimator = SwarmEstimator(lab, EstimatorConfig(tau=0.0), landed_height=LANDED_HEIGHT)
    centre = np.array([0.2, -0.1, 0.3])
    for t in (0.0, 0.01):
        bodies = {"plate": np.concatenate((centre, TILT_QUAT))}
        bodies |= {name: np.array([i, 1.0, 0.01, 0, 0, 0, 1.0]) for i, name in enumerate(lab.drone_names)}
        estimator.ingest([PoseFrame(t, bodies)])
    est = estimator.estimate(0.01)
    pad1 = [0.075, -0.1 - 0.0025 * S, 0.3 + 0.0025 * C]
    np.testing.assert_allclose(est.pad_pos[0], pad1, atol=1e-12)
    np.testing.assert_allclose(est.pad_normal, [NORMAL, NORMAL], atol=1e-12)
    np.testing.assert_allclose(est.goal[0], np.array(pad1) + LANDED_HEIGHT * NORMAL, atol=1e-12)


def tilted_estimate(pos: np.ndarray, pads: np.ndarray) -> SwarmEstimate:
    n = len(pos)
    normals = np.tile(NORMAL, (n, 1))
    return SwarmEstimate(
        t=0.0,
        pos=pos,
        quat=np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)),
        vel=np.zeros((n, 3)),
        ang_vel=np.zeros((n, 3)),
        pad_pos=pads,
        pad_vel=np.zeros((n, 3)),
        goal=pads + LANDED_HEIGHT * normals,
        drone_age=np.zeros(n),
        pad_age=np.zeros(n),
        drone_invalid=np.zeros(n, dtype=bool),
        pad_invalid=np.zeros(n, dtype=bool),
        pad_normal=normals,
    )


def test_a_drone_resting_uphill_on_its_tilted_pad_has_landed_on_it():
    """cf1 rests on its pad 8 cm up the slope from the centre: 0 m above its goal along the normal, 8 cm off in the pad
    plane. Its centre is 8 sin 15 = 2.07 cm higher than the goal, more than ``touchdown_height`` (2 cm): judged in
    the world frame it would hover over its pad. cf2 flies 0.5 m above its pad."""
    lab = load_lab_config(EXAMPLE_CONFIG)
    pads = np.array([[-0.125, 0.0, 0.3], [0.125, 0.0, 0.3]])
    pos = pads + LANDED_HEIGHT * NORMAL + np.array([0.08 * UP_SLOPE, 0.5 * NORMAL])
    est = tilted_estimate(pos, pads)
    c = contacts(est, np.ones(2, dtype=bool), np.full(2, 0.1), lab.limits, LANDED_HEIGHT, floor_z=0.0)
    assert (est.pos - est.goal)[0, 2] > lab.limits.touchdown_height
    assert c.landed.tolist() == [True, False] and not c.off_pad.any() and not c.hard.any()
    np.testing.assert_allclose(c.offset, [0.08, 0.0], atol=1e-12)
    np.testing.assert_allclose(c.height, [0.0, 0.5], atol=1e-12)


def test_the_surface_under_a_drone_is_the_tilted_plane():
    """10 cm up the slope's horizontal direction (+y) from pad1's centre, the plate is 10 tan 15 = 2.68 cm higher;
    10 cm down it, as much lower."""
    pads = np.array([[-0.125, 0.0, 0.3], [0.125, 0.0, 0.3]])
    est = tilted_estimate(pads + np.array([0.0, 0.0, 0.5]), pads)
    above_uphill = np.array([-0.125, 0.1, 0.6])
    height, pad = surface_below(above_uphill, est, 0.0)
    assert pad == 0 and height == pytest.approx(0.3 + 0.1 * S / C, abs=1e-12)
    height, pad = surface_below(np.array([-0.125, -0.1, 0.6]), est, 0.0)
    assert pad == 0 and height == pytest.approx(0.3 - 0.1 * S / C, abs=1e-12)


def test_preflight_refuses_a_pad_tilted_beyond_the_limit():
    """cf1's pad is tilted 15 degrees (allowed: ``max_pad_tilt_deg`` is 20), cf2's 30 degrees: only cf2's refused, and
    the message says how to fix a body whose z axis is not the pad normal."""
    lab = load_lab_config(EXAMPLE_CONFIG)
    monitor = SafetyMonitor(lab)
    steep = np.array([0.0, -np.sin(np.radians(30.0)), np.cos(np.radians(30.0))])
    est = SimpleNamespace(
        pos=np.array([[-1.0, 0.0, 0.01], [-1.0, 0.5, 0.01]]),
        vel=np.zeros((2, 3)),
        quat=np.array([[0.0, 0.0, 0.0, 1.0]] * 2),
        pad_pos=np.array([[-0.125, 0.0, 0.02], [0.125, 0.0, 0.02]]),
        pad_normal=np.array([NORMAL, steep]),
        drone_age=np.zeros(2),
        pad_age=np.zeros(2),
        drone_invalid=np.zeros(2, dtype=bool),
        pad_invalid=np.zeros(2, dtype=bool),
    )
    problems = monitor.arming_problems(est, [None, None])
    assert len(problems) == 1, problems
    assert problems[0].startswith("pad of cf2 is tilted 30 degrees (limit 20.0)"), problems
    assert "define the body with its z axis perpendicular to the pads" in problems[0]


@pytest.mark.parametrize("simulator", sorted({"pointmass", REHEARSAL_SIMULATOR}))
def test_the_simulated_mocap_reports_the_tilted_plate(simulator):
    """The plate body's pose carries every configured pad offset (plate frame) onto the simulator's tilted pad."""
    lab = tilted_lab()
    geometry = world_platform(lab).geometry
    assert geometry.inclination_deg == 15.0 and geometry.pad_spacing == 0.25
    world = SimulatedWorld(lab, make_simulator(lab, simulator))
    try:
        plate = world.true_poses()["plate"]
        offsets = np.array([p.offset for p in lab.drone_pads()])
        np.testing.assert_allclose(plate[:3] + rotate_vector(plate[3:], offsets), world.pad_positions(), atol=1e-9)
        np.testing.assert_allclose(rotate_vector(plate[3:], np.array([0.0, 0.0, 1.0])), NORMAL, atol=1e-12)
    finally:
        world.close()


def test_eight_drones_land_on_a_tilted_plate_in_the_rehearsal(tmp_path):
    """The 8-drone lab, its plate tilted 15 degrees, the steeper-cone shared policy through the safety filter (point
    mass, seed 0): every drone lands on its pad, and the error the loop reports from motion capture is the
    simulator's own pad-frame offset to within 1.5 cm. The flight log keeps the tracked pad normals; a log written
    before they were logged reads as level pads."""
    lab = tilted_lab().replace(pad_assignment="shortest")
    log_path = tmp_path / "tilted.jsonl"
    result = rehearse(
        lab, "data/policies/shared-quick-cone2.safetensors", simulator="pointmass", seed=0, log_path=log_path
    )
    normals = read_flight_log(log_path).estimates("pad_normal")
    np.testing.assert_allclose(normals[-1], np.tile(NORMAL, (8, 1)), atol=0.01)  # 0.002 quaternion noise
    lines = [json.loads(line) for line in log_path.read_text().splitlines()]
    for record in lines:
        record.get("est", {}).pop("pad_normal", None)
    log_path.write_text("\n".join(json.dumps(record) for record in lines) + "\n")
    assert (read_flight_log(log_path).estimates("pad_normal") == [0.0, 0.0, 1.0]).all()
    assert result.safe and all(result.mission.on_pad), result.summary()
    # the pads were handed out again at take-off: each drone's pad is the nearest one, in the simulator's truth
    rel = result.final_positions[:, None] - result.pad_positions[None] - LANDED_HEIGHT * NORMAL
    height, offset = pad_frame_errors(rel, NORMAL)
    own = offset.argmin(axis=1)
    assert sorted(own.tolist()) == list(range(8))  # one drone on each pad
    assert np.abs(height[np.arange(8), own]).max() < 0.005  # resting on the tilted pads
    # the loop stops the motors up to touchdown_height (2 cm) above the goal; the last drop and the drone's sideways
    # speed then move it up to about a centimetre further
    np.testing.assert_allclose(result.mission.landing_error, offset[np.arange(8), own], atol=0.015)
    assert max(result.mission.landing_error) < 0.05


@pytest.mark.skipif(REHEARSAL_SIMULATOR != "crazyflie", reason="needs the PyBullet Crazyflie swarm")
def test_a_drone_handed_over_above_a_tilted_pad_lands_on_it():
    """PyBullet, firmware tracker, 15 degrees, seed 2: cf6 lingers 5 cm above its pad and is handed over to the
    high-level commander. Its land would press it on into the pad, uphill rim first, until it slid 15 cm downhill off
    the pad (measured before the loop stopped the motors at the touchdown); now it lands on its pad like the rest."""
    lab = tilted_lab().replace(pad_assignment="shortest")
    result = rehearse(lab, "data/policies/shared-quick-cone2.safetensors", simulator="crazyflie", seed=2)
    events = [(e.kind, e.drone) for e in result.mission.events]
    assert ("handover", 5) in events, events
    assert result.safe and all(result.mission.on_pad), result.summary()
    assert max(result.mission.landing_error) < 0.05


def test_a_pad_normal_beyond_60_degrees_does_not_move_the_surface():
    """A glitch in the plate body's attitude (its z axis nearly horizontal) must not put the plate far above or below
    a drone: beyond 60 degrees the surface under it is the pad centre's height."""
    pads = np.array([[-0.125, 0.0, 0.3], [0.125, 0.0, 0.3]])
    est = tilted_estimate(pads + np.array([0.0, 0.0, 0.5]), pads)
    est.pad_normal[0] = [0.0, -np.sin(np.radians(85.0)), np.cos(np.radians(85.0))]
    height, pad = surface_below(np.array([-0.125, 0.1, 0.6]), est, 0.0)
    assert pad == 0 and height == 0.3
