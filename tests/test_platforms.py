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


def test_mixed_platform_flies_the_line_or_the_arc_half_each():
    mixed = PlatformMotion(PlatformConfig(kind="moving-mixed", speed=(0.2, 0.5)), 400, 2, 2.0)
    mixed.sample(np.random.default_rng(5), np.arange(400))
    assert 0.4 < mixed.on_line.mean() < 0.6
    # Each env follows exactly the single-kind path with the same anchor, heading, phase and speed.
    for kind, envs in (("moving-linear", mixed.on_line), ("moving-arc", ~mixed.on_line)):
        single = PlatformMotion(PlatformConfig(kind=kind, speed=(0.2, 0.5)), 400, 2, 2.0)
        for name in ("anchor", "heading", "phase", "speed"):
            setattr(single, name, getattr(mixed, name).copy())
        for t in (0.0, 1.3, 4.7):
            np.testing.assert_allclose(mixed.state(np.full(400, t))[0][envs], single.state(np.full(400, t))[0][envs])
    # A new episode draws the kind again; a single kind never changes it.
    before = mixed.on_line.copy()
    mixed.sample(np.random.default_rng(6), np.arange(400))
    assert (mixed.on_line != before).any()
    arc = PlatformMotion(PlatformConfig(kind="moving-arc"), 50, 2, 2.0)
    arc.sample(np.random.default_rng(0), np.arange(50))
    assert not arc.on_line.any()


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


# ---------------------------------------------------------------------------- layouts for N drones (issue 13)


def test_line_and_ring_layouts_worked_by_hand():
    line = PlateGeometry(layout="line")
    np.testing.assert_allclose(line.pad_offsets(3)[:, :2], [[-0.25, 0], [0, 0], [0.25, 0]])
    assert line.half_extents(3) == (0.375, 0.25)  # 3 x 0.25 m long, the paper's 0.5 m wide
    ring = PlateGeometry(layout="ring")
    r = 0.25 / (2 * math.sin(math.pi / 4))  # square of side 0.25: circumradius 0.177 m
    np.testing.assert_allclose(ring.pad_offsets(4)[:, :2], [[r, 0], [0, r], [-r, 0], [0, -r]], atol=1e-15)
    assert ring.half_extents(4)[0] == pytest.approx(r + 0.125)


@pytest.mark.parametrize("layout", ["grid", "line", "ring"])
@pytest.mark.parametrize("n", [1, 2, 3, 8, 16])
def test_every_layout_keeps_pads_apart_and_on_the_plate(layout, n):
    g = PlateGeometry(layout=layout, pad_spacing=0.3)
    offsets = g.pad_offsets(n)
    assert offsets.shape == (n, 3) and np.allclose(offsets[:, 2], g.pad_thickness)
    if n > 1:
        gaps = np.linalg.norm(offsets[:, None, :2] - offsets[None, :, :2], axis=-1) + np.eye(n) * 9
        assert gaps.min() == pytest.approx(0.3)  # neighbours exactly one spacing apart, none closer
    hx, hy = g.half_extents(n)
    assert (np.abs(offsets[:, 0]) + g.pad_radius <= hx + 1e-12).all()
    assert (np.abs(offsets[:, 1]) + g.pad_radius <= hy + 1e-12).all()


def test_the_default_grid_is_unchanged_and_a_bigger_plate_keeps_its_pads():
    old = {2: [[-0.125, 0], [0.125, 0]], 3: [[-0.125, -0.125], [0.125, -0.125], [-0.125, 0.125]]}
    for n, xy in old.items():
        np.testing.assert_array_equal(PlateGeometry(layout="grid").pad_offsets(n)[:, :2], xy)
    # 8 drones on a 16-pad plate use its first 8 pads; the plate is sized for all 16.
    plate16 = PlateGeometry(num_pads=16)
    np.testing.assert_array_equal(plate16.pad_offsets(8), PlateGeometry().pad_offsets(16)[:8])
    assert plate16.half_extents(8) == (0.5, 0.5)


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: PlateGeometry().pad_offsets(0), "num_drones must be an integer >= 1, got 0"),
        (lambda: PlateGeometry(num_pads=4).pad_offsets(5), "More drones than pads: 5 drones but the plate has 4"),
        (lambda: PlatformMotion(PlatformConfig(geometry=PlateGeometry(num_pads=2)), 1, 3, 2.0), "More drones"),
        (lambda: PlateGeometry(pad_spacing=0.15), r"Pads overlap: pad_spacing 0.15 m is less than twice"),
        (lambda: PlateGeometry(inclination_deg=90), r"inclination_deg must be in \[0, 90\)"),
        (lambda: PlateGeometry(inclination_deg=-5), r"inclination_deg must be in \[0, 90\)"),
        (lambda: PlateGeometry(layout="star"), "allowed: grid, line, ring"),  # type: ignore[arg-type]
        (lambda: PlateGeometry(num_pads=0), "num_pads must be None"),
        (lambda: PlateGeometry(pad_radius=float("nan")), "finite numbers > 0"),
    ],
)
def test_bad_plates_say_what_is_allowed(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_an_inclined_plate_turns_its_pads_and_normal_about_the_tilt_axis():
    level, tilted = PlateGeometry(), PlateGeometry(inclination_deg=15.0)  # about +x: the +y edge rises
    s, c = math.sin(math.radians(15)), math.cos(math.radians(15))
    np.testing.assert_allclose(tilted.normal(), [0, -s, c])
    np.testing.assert_array_equal(level.normal(), [0, 0, 1])
    rot = tilted.rotation()
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-15)
    # Pads on the x axis stay put apart from their thickness turning with the plate; distances are kept.
    np.testing.assert_allclose(
        tilted.pad_offsets(2), [[-0.125, -0.0025 * s, 0.0025 * c], [0.125, -0.0025 * s, 0.0025 * c]]
    )
    four = tilted.pad_offsets(4)
    assert four[2, 2] - four[0, 2] == pytest.approx(0.25 * s)  # the +y row sits 0.25 sin(15 deg) higher
    np.testing.assert_allclose(
        np.linalg.norm(four[0] - four[3]), np.linalg.norm(level.pad_offsets(4)[0] - level.pad_offsets(4)[3])
    )
    # A tilted plate on the floor is raised so its lowest corner stays on the floor.
    motion = PlatformMotion(PlatformConfig(geometry=tilted), 3, 4, 2.0)
    motion.sample(np.random.default_rng(0), np.arange(3))
    _, hy = tilted.half_extents(4)
    assert motion.anchor[0, 2] - hy * s == pytest.approx(tilted.plate_thickness)
    np.testing.assert_allclose(motion.pad_normal, tilted.normal())


@pytest.mark.parametrize("kind", ["moving-linear", "moving-arc"])
def test_ur10_tool_speeds_up_to_one_metre_per_second_are_accepted(kind):
    cfg = PlatformConfig(kind=kind, speed=1.0)
    motion = PlatformMotion(cfg, 16, 2, 2.0)
    motion.sample(np.random.default_rng(0), np.arange(16))
    top = max(np.linalg.norm(motion.state(np.full(16, t))[1], axis=1).max() for t in np.arange(0, 8, 0.01))
    assert top == pytest.approx(1.0, abs=0.01)  # the 1 m stroke at 1 m/s^2 just reaches 1 m/s
    assert PlatformConfig(kind=kind, speed=(0.0, 1.0)).speed_range == (0.0, 1.0)


def test_point_mass_drones_touch_an_inclined_plate_where_its_tilted_top_face_is():
    from marlander_lite.episodes import LandingEpisodes
    from marlander_lite.pointmass.simulator import PointMassSwarm
    from marlander_lite.task import CONTACT_OTHER, CONTACT_OWN_PAD, TaskConfig, pad_frame_errors

    tilt = 15.0
    s, c = math.sin(math.radians(tilt)), math.cos(math.radians(tilt))
    geometry = PlateGeometry(inclination_deg=tilt)  # about +x: the +y edge rises
    episodes = LandingEpisodes(PointMassSwarm(TaskConfig(num_drones=2), PlatformConfig(geometry=geometry), 1), seed=0)
    episodes.reset()
    state = episodes.sim.state()
    plate = episodes.sim.motion.anchor[0]
    lift = geometry.pad_thickness + episodes.task.landed_height
    # Drone 0 sinks onto its own pad; drone 1 onto the plate 0.2 m up the slope (plate frame y = +0.2), off its pad.
    up_slope = plate + 0.2 * geometry.rotation()[:, 1]
    above = np.array([0.0, 0.0, 0.05])
    start = np.array([state.pad_pos[0, 0] + above, up_slope + above])
    episodes.sim.place(0, start)
    sink = np.array([[[0.0, 0.0, -0.1], [0.0, 0.0, -0.1]]])  # 0.3 m/s down
    touched, landing_error = {}, np.nan
    for _ in range(20):
        out = episodes.step(sink)
        for i in range(2):
            if out.landed_now[0, i] or out.crashed[0, i]:
                touched.setdefault(i, (episodes.sim.pos[0, i].copy(), int(episodes.sim.contact[0, i])))
            if out.landed_now[0, 0]:
                landing_error = float(out.landing_error[0, 0])
        if len(touched) == 2:
            break
    pad = state.pad_pos[0, 0]
    # On the pad (whose top face is pad_thickness above the plate's, along the normal) the centre rests
    # landed_height along the normal above it: straight down onto the tilted face, landed_height / cos(tilt) higher.
    rest = episodes.task.landed_height
    assert touched[0][1] == CONTACT_OWN_PAD and bool(out.landed[0, 0])
    assert touched[0][0][2] == pytest.approx(pad[2] + rest / c, abs=1e-9)
    # Up the slope the plate is 0.2 sin(tilt) = 5.2 cm higher than at its centre: drone 1 touches there and crashes.
    assert touched[1][1] == CONTACT_OTHER
    assert touched[1][0][2] == pytest.approx(up_slope[2] + lift / c, abs=1e-9)
    # In the pad frame drone 0, straight above the pad centre, sits landed_height along the normal, rest tan(tilt) off.
    height, offset = pad_frame_errors(touched[0][0] - pad, geometry.normal())
    assert height == pytest.approx(rest, abs=1e-9) and offset == pytest.approx(rest * s / c, abs=1e-9)
    # The episode judges the landing in that frame too: its error is the in-plane offset, not the horizontal 0.
    assert landing_error == pytest.approx(rest * s / c, abs=1e-9)


def test_pad_frame_errors_worked_by_hand():
    from marlander_lite.task import pad_frame_errors

    height, offset = pad_frame_errors(np.array([[0.03, 0.04, 0.5]]), np.array([0.0, 0.0, 1.0]))
    assert height[0] == pytest.approx(0.5) and offset[0] == pytest.approx(0.05)  # level: z and horizontal distance
    n = np.array([0.0, -math.sin(0.3), math.cos(0.3)])
    height, offset = pad_frame_errors(0.2 * n + np.array([0.01, 0.0, 0.0]), n)
    assert height == pytest.approx(0.2) and offset == pytest.approx(0.01)
