"""The compiled point-mass engine (numba) against the numpy reference: the same bits, flight after flight."""

import numpy as np
import pytest

from marlander_lite import rotations, task
from marlander_lite.envs.options import policy_input
from marlander_lite.envs.vec_env import episode_summaries
from marlander_lite.episodes import LandingEpisodes
from marlander_lite.platforms import PlateGeometry, PlatformConfig
from marlander_lite.pointmass import PointMassParams, PointMassSwarm, kernels
from marlander_lite.pointmass.family import DynamicsFamily
from marlander_lite.sensing import SensingConfig
from marlander_lite.task import TaskConfig

pytest.importorskip("numba")


def brute_force_min_separation(pos: np.ndarray) -> np.ndarray:
    """Every pair's distance with np.linalg.norm, independent of both implementations."""
    n = pos.shape[1]
    if n < 2:
        return np.full(len(pos), np.inf)
    i, j = np.triu_indices(n, 1)
    return np.linalg.norm(pos[:, j] - pos[:, i], axis=-1).min(axis=1)


@pytest.mark.parametrize("num_drones", [1, 2, 3, 16])
@pytest.mark.parametrize("order", ["C", "F"])
def test_min_separation_kernel_is_the_reference_to_the_last_bit(num_drones, order):
    pos = np.random.default_rng(num_drones).uniform(-2, 2, (37, num_drones, 3))
    pos[5] = pos[5, :1]  # all drones of env 5 in one spot: separation 0
    pos = np.asarray(pos, order=order)
    reference = task.min_separation_numpy(pos)
    np.testing.assert_array_equal(kernels.min_separation(pos), reference)
    np.testing.assert_allclose(reference, brute_force_min_separation(pos), rtol=1e-15)
    if num_drones > 1:
        assert reference[5] == 0.0


def test_turn_rates_kernel_is_the_reference_to_the_last_bit():
    """Axis turns of every size, right angles and beyond included (rollouts rarely reach them), and no turn at all."""
    rng = np.random.default_rng(4)
    before, after = (v / np.linalg.norm(v, axis=-1, keepdims=True) for v in rng.normal(size=(2, 301, 3, 3)))
    after[0] = before[0]  # no turn: zero rate
    after[1] = before[1] + 1e-9 * rng.normal(size=(3, 3))
    cross = np.asfortranarray(np.cross(before, after))
    sin, cos = np.asfortranarray(np.linalg.norm(cross, axis=-1)), np.asfortranarray((before * after).sum(axis=-1))
    assert (cos < 0).any() and (cos > 0).any()
    dt = 0.05
    ang_vel = np.zeros((301, 3, 3), order="F")
    kernels.turn_rates(cross, sin, cos, dt, ang_vel)
    reference = cross * (rotations.turn_angle(sin, cos) / (np.maximum(sin, 1e-12) * dt))[..., None]
    np.testing.assert_array_equal(ang_vel, reference)
    np.testing.assert_array_equal(ang_vel[0], 0.0)
    # The rate is the turn's angle over dt, about the turn's axis.
    np.testing.assert_allclose(np.linalg.norm(ang_vel, axis=-1), np.arctan2(sin, cos) / dt, rtol=1e-14)


def test_min_separation_kernel_propagates_nan_and_inf_like_numpy():
    pos = np.random.default_rng(0).uniform(-2, 2, (4, 3, 3))
    pos[1, 2, 0] = np.nan
    pos[2, 0, 1] = np.inf  # one drone at infinity: the other pair still counts
    pos[3, :, 2] = np.inf  # inf - inf: NaN, as numpy gives
    with np.errstate(invalid="ignore"):  # inf - inf
        reference = task.min_separation_numpy(pos)
    ours = kernels.min_separation(pos)
    np.testing.assert_array_equal(ours, reference)
    assert np.isnan(ours[[1, 3]]).all() and np.isfinite(ours[[0, 2]]).all()


@pytest.mark.parametrize("order", ["C", "F"])
@pytest.mark.parametrize("shape", [(1, 1, 13), (37, 2, 13), (5, 16, 19)])
def test_compiled_policy_input_is_numpys_cast_to_the_last_bit(monkeypatch, order, shape):
    """``policy_input`` through ``kernels.policy_rows``: numpy's float32 rounding, one env per row, drone by drone."""
    rng = np.random.default_rng(shape[1])
    obs = np.asarray(rng.normal(0, 50, shape) * 10.0 ** rng.integers(-8, 3, shape), order=order)
    obs[0, 0, :3] = (1.0 + 2.0**-24, -0.0, 1e-46)  # halfway between two float32 (to even), signed zero, underflow
    monkeypatch.setenv(kernels.ENGINE_VARIABLE, "numba")
    compiled = policy_input(obs)
    monkeypatch.setenv(kernels.ENGINE_VARIABLE, "numpy")
    reference = policy_input(obs)
    assert compiled.dtype == np.float32 and compiled.flags.c_contiguous
    np.testing.assert_array_equal(compiled.view(np.uint32), reference.view(np.uint32))
    rows = compiled.reshape(shape)  # drone i's numbers are i d ... (i + 1) d - 1 of its env's row
    np.testing.assert_array_equal(rows, obs.astype(np.float32))
    assert rows[0, 0, 0] == 1.0 and np.signbit(rows[0, 0, 1]) and rows[0, 0, 2] == 0.0


@pytest.mark.parametrize("num_drones", [1, 2, 3, 8, 9, 16, 33, 128, 200])
@pytest.mark.parametrize("order", ["C", "F"])
def test_compiled_episode_summaries_are_the_reference_to_the_last_bit(monkeypatch, num_drones, order):
    """The infos' ``landing_error`` (mean over the landed drones) and ``landing_time`` (the last drone's): numpy's row
    sum (one by one below 8 drones, pairwise from 8) to the bit, and values worked by hand."""
    rng = np.random.default_rng(num_drones)
    landed = rng.random((60, num_drones)) < 0.7
    landed[0], landed[1] = True, False  # all landed, none landed
    error = np.asarray(np.where(landed, rng.uniform(0, 0.05, landed.shape), np.nan), order=order)
    time = np.asarray(np.where(landed, rng.uniform(0, 30, landed.shape), np.nan), order=order)
    landed = np.asarray(landed, order=order)
    ids = np.array([0, 1, *np.sort(rng.choice(np.arange(2, 60), 30, replace=False))])
    monkeypatch.setenv(kernels.ENGINE_VARIABLE, "numba")
    compiled = episode_summaries(ids, landed, error, time)
    monkeypatch.setenv(kernels.ENGINE_VARIABLE, "numpy")
    reference = episode_summaries(ids, landed, error, time)
    for ours, theirs in zip(compiled, reference, strict=True):
        np.testing.assert_array_equal(ours, theirs)
    mean_error, last_landing = compiled
    assert mean_error[0] == pytest.approx(error[0].mean(), rel=1e-15) and last_landing[0] == time[0].max()
    assert np.isnan(mean_error[1]) and np.isnan(last_landing[1])
    for row, k in enumerate(ids):
        assert np.isnan(last_landing[row]) == (not landed[k].all())
        if landed[k].any():
            assert mean_error[row] == pytest.approx(error[k][landed[k]].mean(), rel=1e-14)


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int64])
def test_compiled_velocity_commands_are_eq3_to_the_last_bit_and_refuse_nan(monkeypatch, dtype):
    """``task.action_to_velocity`` through ``task_kernels.velocity_commands``: numpy's clip and scale of every
    entry, and the same error for a NaN or infinite one."""
    rng = np.random.default_rng(int(np.dtype(dtype).itemsize))
    action = (rng.uniform(-1.6, 1.6, (37, 3 * 5)) * (3 if dtype == np.int64 else 1)).astype(dtype)
    monkeypatch.setenv(kernels.ENGINE_VARIABLE, "numpy")
    reference = task.action_to_velocity(action, 5, 2.5)
    monkeypatch.setenv(kernels.ENGINE_VARIABLE, "numba")
    compiled = task.action_to_velocity(action, 5, 2.5)
    assert compiled.dtype == np.float64 and compiled.shape == (37, 5, 3) and compiled.flags.f_contiguous
    np.testing.assert_array_equal(compiled, reference)
    expected = np.clip(action.astype(np.float64), -1, 1).reshape(37, 5, 3) * 2.5  # eq. 3 by hand
    np.testing.assert_array_equal(compiled, expected)
    if dtype != np.int64:
        for bad in (np.nan, np.inf, -np.inf):
            action[4, 7] = bad
            for engine in ("numpy", "numba"):
                monkeypatch.setenv(kernels.ENGINE_VARIABLE, engine)
                with pytest.raises(ValueError, match="NaN or infinite"):
                    task.action_to_velocity(action, 5, 2.5)


def spawn(monkeypatch, engine, num_drones, near_fraction, separation, swarms=60, seed=3, near_low=0.15):
    """Starting positions of ``swarms`` swarms over plates of random heights with pads 0.25 m apart (near-pad
    starts included), and the next numbers of the generator, drawn through ``engine``."""
    monkeypatch.setenv(kernels.ENGINE_VARIABLE, engine)
    rng = np.random.default_rng(seed)
    cfg = TaskConfig(
        num_drones=num_drones,
        spawn_near_pad_fraction=near_fraction,
        spawn_separation=separation,
        spawn_near_pad_height_min=near_low,
    )
    grid = np.stack([0.25 * (np.arange(num_drones) % 4), 0.25 * (np.arange(num_drones) // 4), np.zeros(num_drones)], -1)
    pads = rng.uniform(-1, 1, (swarms, 1, 3)) + grid
    pos = task.sample_spawn_positions(rng, rng.uniform(0, 0.8, swarms), cfg, pads)
    return pos, rng.random(5)


@pytest.mark.parametrize("num_drones", [1, 2, 3, 16])
@pytest.mark.parametrize("near_fraction", [0.0, 0.25, 1.0])
def test_compiled_spawn_sampler_is_the_reference_to_the_last_bit(monkeypatch, num_drones, near_fraction):
    separation = 0.5 if near_fraction == 0 else 0.2  # 16 drones near pads 0.25 m apart cannot be 0.5 m apart
    for near_low in (0.15, 0.05):
        pos, after = spawn(monkeypatch, "numpy", num_drones, near_fraction, separation, near_low=near_low)
        compiled_pos, compiled_after = spawn(
            monkeypatch, "numba", num_drones, near_fraction, separation, near_low=near_low
        )
        np.testing.assert_array_equal(compiled_pos, pos)
        np.testing.assert_array_equal(compiled_after, after)  # the generator is left in the same state
    if num_drones > 1:  # and the placement is what the task asks for, measured independently
        assert brute_force_min_separation(pos).min() >= separation


def test_both_spawn_samplers_give_up_alike(monkeypatch):
    for engine in ("numpy", "numba"):
        with pytest.raises(ValueError, match=r"Could not place 16 drones 1.5 m apart .* after 100 tries"):
            spawn(monkeypatch, engine, 16, 0.0, 1.5)


def go_to_pad(obs: np.ndarray, num_drones: int) -> np.ndarray:
    """Fly down a cone onto the own pad (lands most drones), as in tests/test_pointmass.py."""
    p = obs.reshape(len(obs), num_drones, -1)[..., 0:3].copy()
    p[..., 2] -= np.minimum(2.0 * np.linalg.norm(p[..., :2], axis=-1), 1.0) - 0.05
    v = -2.0 * p
    v *= np.minimum(1.0, 1.0 / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-9))
    return (v / 3.0).reshape(len(p), -1)


def rollout(engine, platform, num_drones, params, sensing, num_envs=24, steps=120, **task_options):
    """Every state and outcome of a seeded rollout: landing controller or random actions, auto-resets, and
    stopped motors in some drones half way."""
    cfg = TaskConfig(num_drones=num_drones, **task_options)
    sim = PointMassSwarm(cfg, PlatformConfig(kind=platform), num_envs, params, engine)
    episodes = LandingEpisodes(sim, sensing, seed=7)
    assert episodes.compiled == (engine == "numba")  # the MDP step follows the simulator's engine
    obs = episodes.reset()
    rng = np.random.default_rng(1)
    careful = rng.random(num_envs) < 0.7  # these envs fly the landing controller, the others at random
    records, events = [], np.zeros(4, dtype=int)
    for step in range(steps):
        action = np.where(careful[:, None], go_to_pad(obs, num_drones), rng.uniform(-1, 1, (num_envs, 3 * num_drones)))
        if step == steps // 2:
            sim.stop_motors(rng.random((num_envs, num_drones)) < 0.1)
        out = episodes.step(action)
        obs = out.obs
        state = [sim.pos, sim.vel, sim.quat, sim.ang_vel, sim.contact]  # updated in place: copy now
        outcome = [out.obs, out.reward, out.drone_rewards, out.landed_now, out.crashed, out.out_of_arena, out.rel_speed]
        outcome += [out.landing_error, out.landing_time, out.min_separation, out.terminated, out.truncated]
        records.append([*outcome, *(np.array(a, copy=True) for a in state)])
        events += (out.landed_now.sum(), out.crashed.sum(), out.collided.sum(), (sim.contact != 0).sum())
        if out.done.any():
            ids = np.flatnonzero(out.done)
            obs = obs.copy()
            obs[ids] = episodes.reset(ids)
            book = (episodes.prev_dist, episodes.min_separation, episodes.landed, episodes.landing_error)
            records.append([obs.copy(), episodes.steps.copy(), *(np.array(a, copy=True) for a in book)])
    return sim, records, events


# The observation's extras and the training aids (which read p) go through the compiled MDP step's other branches.
EXTRAS = {"observe_platform_velocity": True, "observe_previous_command": True}
AIDS = {"landing_precision_bonus": 50.0, "approach_cone_penalty": 0.5, "action_change_penalty": 0.1}


@pytest.mark.parametrize(
    ("platform", "num_drones", "family", "sensing", "task_options"),
    [
        ("static-floor", 2, False, None, {}),
        ("static-floor", 3, True, SensingConfig.vicon(), AIDS),
        ("static-elevated", 1, True, SensingConfig.vicon(), {}),
        ("static-floor", 2, "integral", None, {}),
        ("moving-linear", 2, False, None, EXTRAS),
        ("moving-arc", 4, False, SensingConfig.robust(), {}),
    ],
)
def test_compiled_engine_flies_the_reference_bit_for_bit(platform, num_drones, family, sensing, task_options):
    integral = DynamicsFamily(velocity_integral_gain=(0.0, 0.5))  # a PI velocity loop
    params = PointMassParams(family=integral if family == "integral" else DynamicsFamily()) if family else None
    sim, reference, events = rollout("numpy", platform, num_drones, params, sensing, **task_options)
    compiled_sim, compiled, compiled_events = rollout("numba", platform, num_drones, params, sensing, **task_options)
    assert (sim.engine, compiled_sim.engine) == ("numpy", "numba")
    landings, crashes, _, contacts = events
    assert crashes > 0 and contacts > 0, events  # the rollouts reach the contact branches ...
    assert landings > 0 or platform.startswith("moving"), events  # ... and the landed one (static plates)
    np.testing.assert_array_equal(compiled_events, events)
    assert len(compiled) == len(reference)
    for step, (ours, theirs) in enumerate(zip(compiled, reference, strict=True)):
        for a, b in zip(ours, theirs, strict=True):
            assert np.array_equal(a, b, equal_nan=True), f"first difference at record {step}"


def test_collisions_are_judged_alike_on_both_engines():
    """Random commands with 8 drones in the arena: collisions happen, and both engines see the same ones."""
    collided = {}
    for engine in ("numpy", "numba"):
        sim = PointMassSwarm(TaskConfig(num_drones=8, spawn_separation=0.2), PlatformConfig(), 64, engine=engine)
        episodes = LandingEpisodes(sim, seed=3)
        episodes.reset()
        rng = np.random.default_rng(0)
        collided[engine] = np.array([episodes.step(rng.uniform(-1, 1, (64, 24))).collided for _ in range(10)])
    assert collided["numpy"].any()
    np.testing.assert_array_equal(collided["numba"], collided["numpy"])


def test_engine_choice_and_its_errors(monkeypatch):
    cfg, plate = TaskConfig(), PlatformConfig()
    monkeypatch.delenv(kernels.ENGINE_VARIABLE, raising=False)
    assert PointMassSwarm(cfg, plate, 2).engine == "numba"  # auto, numba installed
    monkeypatch.setenv(kernels.ENGINE_VARIABLE, "numpy")
    assert PointMassSwarm(cfg, plate, 2).engine == "numpy"
    assert PointMassSwarm(cfg, plate, 2, engine="numba").engine == "numba"  # an explicit choice wins
    monkeypatch.setenv(kernels.ENGINE_VARIABLE, "fortran")
    with pytest.raises(ValueError, match="MARLANDER_LITE_ENGINE must be one of"):
        PointMassSwarm(cfg, plate, 2)
    with pytest.raises(ValueError, match="engine must be one of"):
        PointMassSwarm(cfg, plate, 2, engine="jax")
    inclined = PlatformConfig(geometry=PlateGeometry(inclination_deg=10.0))
    assert PointMassSwarm(cfg, inclined, 2, engine="numba").engine == "numpy"  # level plates only
    sim = PointMassSwarm(cfg, plate, 2, engine="numba")
    with pytest.raises(ValueError, match=r"velocity must have shape \(2, 2, 3\)"):
        sim.step(np.zeros((2, 6)))


def test_asking_for_numba_without_it_says_how_to_get_it(monkeypatch):
    monkeypatch.setattr(kernels, "numba", None)
    assert kernels.resolve_engine("auto") == "numpy"
    with pytest.raises(ValueError, match="pip install numba"):
        kernels.resolve_engine("numba")


def test_the_compiled_mdp_step_judges_a_pybullet_flight_as_the_numpy_one(monkeypatch):
    """The MDP's kernels (``task_kernels``) serve every simulator: over the PyBullet Crazyflie (its own compiled
    ticks in both runs) the episodes with and without them give the same observations, rewards and touchdowns."""
    from marlander_lite.crazyflie.simulator import CrazyflieSwarm

    records = {}
    for engine in ("numpy", "numba"):
        monkeypatch.setenv(kernels.ENGINE_VARIABLE, engine)  # the MDP's choice; the simulator's is fixed below
        sim = CrazyflieSwarm(TaskConfig(num_drones=2), PlatformConfig(), controller="firmware", engine="numba")
        episodes = LandingEpisodes(sim, SensingConfig.vicon(), seed=4)
        assert episodes.compiled == (engine == "numba")
        obs, rows = episodes.reset(), []
        for _ in range(200):  # descend onto the pads: touchdowns (landed or crashed) within the flight
            out = episodes.step(go_to_pad(obs.reshape(1, -1), 2))
            obs = out.obs
            rows.append([out.obs, out.reward, out.drone_rewards, out.landed_now, out.crashed, out.rel_speed])
            if out.done.any():
                obs = episodes.reset()
        sim.close()
        records[engine] = rows
    touchdowns = sum(int(r[3].sum() + r[4].sum()) for r in records["numpy"])
    assert touchdowns > 0
    for ours, theirs in zip(records["numba"], records["numpy"], strict=True):
        for a, b in zip(ours, theirs, strict=True):
            assert np.array_equal(a, b, equal_nan=True)
