"""Plate geometry and platform motions against geometry worked by hand."""

import math

import numpy as np
import pytest

from marlander_lite.platforms import PLATFORM_KINDS, PlateGeometry, PlatformConfig, PlatformMotion


def test_two_pads_sit_symmetrically_on_the_paper_plate():
    g = PlateGeometry()
    offsets = g.pad_offsets(2)
    np.testing.assert_allclose(offsets, [[-0.125, 0, 0.0025], [0.125, 0, 0.0025]])
    assert g.half_extents(2) == (0.25, 0.25)  # the paper's 0.5 x 0.5 m plate
    # Pads fit on the plate and do not overlap.
    assert abs(offsets[:, 0]).max() + g.pad_radius <= 0.25
    assert np.linalg.norm(offsets[0] - offsets[1]) >= 2 * g.pad_radius


def test_sixteen_pads_form_a_four_by_four_grid():
    offsets = PlateGeometry().pad_offsets(16)
    assert len({tuple(np.round(o, 6)) for o in offsets}) == 16
    np.testing.assert_allclose(sorted(set(np.round(offsets[:, 0], 6))), [-0.375, -0.125, 0.125, 0.375])
    assert PlateGeometry().half_extents(16) == (0.5, 0.5)


@pytest.mark.parametrize("kind", ["moving-linear", "moving-arc"])
@pytest.mark.parametrize("speed", [0.2, 0.5])
def test_moving_platforms_cruise_at_tool_speed_and_reverse_smoothly(kind, speed):
    cfg = PlatformConfig(kind=kind, speed=speed, reversal_acceleration=1.0)
    motion = PlatformMotion(cfg, 64, 2, 2.0)
    motion.sample(np.random.default_rng(0), np.arange(64))
    times = np.arange(0.0, 8.0, 0.01)
    pos, vel = zip(*(motion.state(np.full(64, t)) for t in times), strict=True)
    pos, vel = np.array(pos), np.array(vel)  # (T, envs, 3)
    speeds = np.linalg.norm(vel, axis=2)
    assert speeds.max() <= speed + 1e-12
    assert np.mean(np.isclose(speeds, speed)) > 0.5  # cruising most of the time
    # Velocity is the time derivative of position, and the acceleration never exceeds the arm's.
    fd_vel = np.gradient(pos, times, axis=0)
    np.testing.assert_allclose(fd_vel[1:-1], vel[1:-1], atol=0.02)
    tangential = np.abs(np.gradient(speeds, times, axis=0))
    assert tangential[1:-1].max() <= 1.0 + 0.05


def test_linear_stroke_turns_back_at_its_ends():
    cfg = PlatformConfig(kind="moving-linear", speed=0.5, linear_stroke=1.0, reversal_acceleration=1.0)
    motion = PlatformMotion(cfg, 1, 2, 2.0)
    motion.sample(np.random.default_rng(3), np.arange(1))
    motion.phase[:] = 0.0  # start at one end of the stroke, at rest
    times = np.linspace(0, 10, 1001)
    pos = np.array([motion.state(np.array([t]))[0][0] for t in times])
    travelled = np.linalg.norm(pos - pos[0], axis=1)
    assert travelled.max() == pytest.approx(1.0, abs=1e-9)
    # One leg: 1 m at 0.5 m/s plus the two half-second ramps = 2.5 s; there and back in 5 s.
    np.testing.assert_allclose(pos[500], pos[0], atol=1e-9)
    assert travelled[250] == pytest.approx(1.0, abs=1e-9)


def test_arc_stays_within_half_turn_of_its_heading():
    cfg = PlatformConfig(kind="moving-arc", speed=0.5)
    motion = PlatformMotion(cfg, 200, 2, 2.0)
    motion.sample(np.random.default_rng(1), np.arange(200))
    for t in np.linspace(0, 20, 41):
        pos, _ = motion.state(np.full(200, t))
        radial = pos[:, :2] - motion.anchor[:, :2]
        np.testing.assert_allclose(np.linalg.norm(radial, axis=1), cfg.arc_radius)
        angle = np.arctan2(radial[:, 1], radial[:, 0]) - motion.heading
        angle = (angle + math.pi) % (2 * math.pi) - math.pi
        assert np.abs(angle).max() <= math.pi / 2 + 1e-9


@pytest.mark.parametrize("kind", PLATFORM_KINDS)
def test_every_platform_path_stays_inside_the_arena(kind):
    motion = PlatformMotion(PlatformConfig(kind=kind), 500, 2, 2.0)
    motion.sample(np.random.default_rng(2), np.arange(500))
    hx, hy = PlateGeometry().half_extents(2)
    for t in np.linspace(0, 30, 61):
        pos, _ = motion.state(np.full(500, t))
        assert (np.abs(pos[:, 0]) + hx <= 2.0).all() and (np.abs(pos[:, 1]) + hy <= 2.0).all()
    expected_z = (0.005, 0.005) if kind == "static-floor" else (0.5, 1.0)
    assert expected_z[0] <= pos[:, 2].min() and pos[:, 2].max() <= expected_z[1]


def test_bad_platform_configs_say_what_is_allowed():
    with pytest.raises(ValueError, match="allowed: static-floor"):
        PlatformConfig(kind="trampoline")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=">= 0"):
        PlatformConfig(kind="moving-arc", speed=-0.2)
    with pytest.raises(ValueError, match="static platform"):
        PlatformConfig(kind="static-floor", speed=0.3)
    assert PlatformConfig(kind="moving-linear").resolved_speed == pytest.approx(0.35)


def test_a_speed_range_draws_one_speed_per_episode():
    cfg = PlatformConfig(kind="moving-arc", speed=(0.2, 0.5))
    motion = PlatformMotion(cfg, 1000, 2, 2.0)
    motion.sample(np.random.default_rng(0), np.arange(1000))
    assert 0.2 <= motion.speed.min() < 0.22 and 0.48 < motion.speed.max() <= 0.5
    top = np.max([np.linalg.norm(motion.state(np.full(1000, t))[1], axis=1) for t in np.arange(0, 6, 0.05)], axis=0)
    np.testing.assert_allclose(top, motion.speed)
    with pytest.raises(ValueError, match="low <= high"):
        PlatformConfig(kind="moving-arc", speed=(0.5, 0.2))
