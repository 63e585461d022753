"""Deployment for N drones: lab configs of any size, the shared policy through the runner, an 8-drone rehearsal.

The shared policy's input is checked against one built by hand from its definition (paper eq. 2 plus
``[x_j - x_i, v_j - v_i, 1]`` for the k nearest neighbours within the sensing range), and against the
swarm package's own :class:`~marlander_lite.swarm.policy.SharedPolicy` on the simulators' plate.
The rehearsals are checked against the simulator's ground truth.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from marlander_lite.deploy.config import (
    EXAMPLE_CONFIG,
    EXAMPLE_CONFIG_8,
    EXAMPLE_CONFIG_16,
    ConfigError,
    LabConfig,
    load_lab_config,
    load_lab_policy,
)
from marlander_lite.deploy.estimation import SwarmEstimate, SwarmEstimator
from marlander_lite.deploy.pose_sources import PoseFrame
from marlander_lite.deploy.rehearsal import rehearse
from marlander_lite.deploy.rehearsal.faults import FaultSpec
from marlander_lite.deploy.rehearsal.world import world_platform
from marlander_lite.deploy.runner import InvalidAction, PolicyRunner
from marlander_lite.platforms import PlateGeometry
from marlander_lite.policy_file import PolicyFileError
from marlander_lite.swarm.policy import SharedPolicy
from marlander_lite.task import OBS_PER_DRONE, observe

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT / "data/policies/shared-quick-local.safetensors"
CENTRALISED = ROOT / "data/policies/quick-cpu.safetensors"

try:
    import marlander_lite.crazyflie.simulator  # noqa: F401

    REHEARSAL_SIMULATOR = "crazyflie"  # what `marlander deploy --sim` flies by default
except ImportError:  # the PyBullet swarm is not part of this checkout
    REHEARSAL_SIMULATOR = "pointmass"


@pytest.fixture(scope="module")
def lab8() -> LabConfig:
    return load_lab_config(EXAMPLE_CONFIG_8)


def estimate(lab: LabConfig, pos: np.ndarray, vel: np.ndarray, plate: np.ndarray) -> SwarmEstimate:
    """A fresh estimate: drones at ``pos`` ``(N, 3)`` moving at ``vel``, level; a still, level plate at ``plate``."""
    n = lab.num_drones
    pad_pos = plate + np.array([p.offset for p in lab.drone_pads()])
    zeros = np.zeros((n, 3))
    return SwarmEstimate(
        t=0.0,
        pos=pos,
        quat=np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)),
        vel=vel,
        ang_vel=zeros,
        pad_pos=pad_pos,
        pad_vel=zeros,
        goal=pad_pos + np.array([0.0, 0.0, lab.task_config().landed_height]),
        drone_age=np.zeros(n),
        pad_age=np.zeros(n),
        drone_invalid=np.zeros(n, dtype=bool),
        pad_invalid=np.zeros(n, dtype=bool),
    )


def crowded_state(lab: LabConfig, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Drones 5-15 cm above their pads, scattered by 10 cm: several within 0.2 m of each other, some not."""
    rng = np.random.default_rng(seed)
    plate = np.array([0.3, -0.2, 0.0])
    pads = plate + np.array([p.offset for p in lab.drone_pads()])
    pos = (
        pads + rng.normal(0.0, 0.1, pads.shape) * [1, 1, 0] + np.c_[0 * pads[:, :2], rng.uniform(0.05, 0.15, len(pads))]
    )
    return pos, rng.normal(0.0, 0.4, pos.shape), plate


# ------------------------------------------------------------------ the lab config for N drones
@pytest.mark.parametrize(("path", "n"), [(EXAMPLE_CONFIG_8, 8), (EXAMPLE_CONFIG_16, 16)])
def test_the_n_drone_examples_have_the_simulated_plate_s_pads(path, n):
    lab = load_lab_config(path)
    offsets = np.array([p.offset for p in lab.drone_pads()])
    np.testing.assert_allclose(offsets, PlateGeometry().pad_offsets(n), atol=1e-9)  # the plate it was trained on
    assert world_platform(lab).geometry == PlateGeometry()  # and the one the rehearsal simulates
    gaps = np.linalg.norm(offsets[:, None] - offsets[None], axis=-1) + np.eye(n)
    assert gaps.min() >= 0.25 - 1e-9  # no two pads (radius 0.1) overlap
    assert len({d.uri for d in lab.drones}) == n and lab.num_drones == n
    radios = [d.uri.split("/")[2] for d in lab.drones]
    assert max(radios.count(r) for r in set(radios)) == 4  # a radio shared by more than 4 drops packets at 48 Hz


@pytest.mark.parametrize(("layout", "n"), [("grid", 16), ("ring", 6), ("line", 3)])
def test_a_lab_for_n_drones_rehearses_on_its_own_layout(layout, n):
    geometry = PlateGeometry(layout=layout, pad_spacing=0.3)
    lab = load_lab_config(EXAMPLE_CONFIG).with_drones(n, geometry)
    assert lab.num_drones == n and lab.drone_names[-1] == f"cf{n}"
    np.testing.assert_allclose([p.offset for p in lab.drone_pads()], geometry.pad_offsets(n), atol=1e-8)
    np.testing.assert_allclose(world_platform(lab).geometry.pad_offsets(n), geometry.pad_offsets(n), atol=1e-6)


def test_more_drones_than_pads_is_refused(lab8):
    data = dataclasses.asdict(lab8)
    del data["pads"]["pad8"]
    with pytest.raises(ConfigError, match=r"8 drones but only 7 pads under pads .*every drone needs a pad of its own"):
        LabConfig.from_dict(data)


def test_overlapping_pads_are_refused(lab8):
    data = dataclasses.asdict(lab8)
    data["pads"]["pad2"]["offset"] = [-0.1, -0.25, 0.0025]  # 0.15 m from pad1; radii 0.1 + 0.1
    with pytest.raises(ConfigError, match=r"pads 'pad1' and 'pad2' on body 'plate' overlap: .* 0.150 m apart"):
        LabConfig.from_dict(data)
    data["pads"]["pad2"]["body"] = "plate2"  # on another body: no fixed offset between them, nothing to check
    assert LabConfig.from_dict(data).num_drones == 8


# ------------------------------------------------------------------ which policies fly
@pytest.mark.parametrize("n", [1, 2, 3, 8, 16])
def test_a_shared_policy_flies_any_number_of_drones(n):
    policy = load_lab_policy(SHARED, load_lab_config(EXAMPLE_CONFIG).with_drones(n))
    assert policy.contract.is_shared and policy.contract.num_drones is None


def test_a_shared_policy_must_still_fit_the_lab(lab8):
    faster = lab8.replace(limits=dataclasses.replace(lab8.limits, policy_max_speed=2.0))
    with pytest.raises(PolicyFileError, match=r"its max_speed is 3.0 m/s, the task's is 2.0 m/s"):
        load_lab_policy(SHARED, faster)
    slower = lab8.replace(rates=dataclasses.replace(lab8.rates, policy_hz=12.0))
    with pytest.raises(PolicyFileError, match=r"it acts at 24.0 Hz, the task at 12.0 Hz"):
        load_lab_policy(SHARED, slower)


def test_a_centralised_policy_for_another_swarm_size_is_refused(lab8):
    with pytest.raises(PolicyFileError, match=r"trained for: this one 2, the lab config lists 8.*or a shared policy"):
        load_lab_policy(CENTRALISED, lab8)
    assert not load_lab_policy(CENTRALISED, load_lab_config(EXAMPLE_CONFIG)).contract.is_shared  # N = 2: it flies


# ------------------------------------------------------------------ the shared policy through the runner
def test_the_runner_feeds_each_drone_its_own_neighbours(lab8):
    """Against the definition, built by hand drone by drone, and against the swarm package's SharedPolicy."""
    policy = load_lab_policy(SHARED, lab8)
    k, radius = policy.contract.neighbours, policy.contract.neighbour_radius
    task = lab8.task_config()
    runner = PolicyRunner(policy, task, max_speed=3.0)  # no lab clamp: compare the policy's own velocities
    pos, vel, plate = crowded_state(lab8, seed=1)  # 10 of its 56 ordered pairs within 0.2 m
    est = estimate(lab8, pos, vel, plate)
    obs = runner.observe(est)
    action, velocity = runner.act(obs, est.goal)
    sensed = 0
    for i in range(8):
        own = observe(pos[i] - est.goal[i], est.quat[i], vel[i], np.zeros(3))
        others = sorted((np.linalg.norm(pos[j] - pos[i]), j) for j in range(8) if j != i)
        features = np.zeros((k, 7))
        for m, (dist, j) in enumerate(others[:k]):
            if dist <= radius:
                features[m] = [*(pos[j] - pos[i]), *(vel[j] - vel[i]), 1.0]
                sensed += 1
        by_hand = policy.act(np.concatenate([own, features.ravel()]))  # one drone at a time
        np.testing.assert_allclose(action[3 * i : 3 * i + 3], by_hand, atol=1e-9)
    assert 4 <= sensed < 8 * k  # neighbours in range and out of range were both exercised
    np.testing.assert_allclose(velocity, action.reshape(8, 3) * 3.0, atol=1e-12)
    swarm = SharedPolicy(policy, task, PlateGeometry())  # the evaluation's path: pads of the simulators' plate
    np.testing.assert_allclose(action, swarm.act(obs.reshape(-1)), atol=1e-9)


def test_the_shared_policy_runs_once_per_tick_on_the_whole_swarm(lab8):
    policy = load_lab_policy(SHARED, lab8)
    calls = []

    class Counting:
        contract = policy.contract

        def act(self, x):
            calls.append(np.shape(x))
            return policy.act(x)

    runner = PolicyRunner(Counting(), lab8.task_config(), lab8.limits.max_speed)
    est = estimate(lab8, *crowded_state(lab8, seed=1))
    _, velocity = runner.act(runner.observe(est), est.goal)
    assert calls == [(8, OBS_PER_DRONE + 7 * policy.contract.neighbours)]  # one forward pass, an (N, obs) batch
    assert np.linalg.norm(velocity, axis=1).max() <= lab8.limits.max_speed + 1e-12  # the lab's speed clamp


@pytest.mark.parametrize(
    ("returned", "message"),
    [
        (np.full((8, 3), np.nan), "not finite and within"),
        (np.full((8, 3), 1.5), "not finite and within"),
        (np.zeros((7, 3)), "returned 21 numbers; 24 expected"),
    ],
)
def test_bad_shared_actions_are_refused(lab8, returned, message):
    policy = load_lab_policy(SHARED, lab8)

    class Broken:
        contract = policy.contract

        def act(self, x):
            return returned

    runner = PolicyRunner(Broken(), lab8.task_config(), lab8.limits.max_speed)
    est = estimate(lab8, *crowded_state(lab8))
    with pytest.raises(InvalidAction, match=message):
        runner.act(runner.observe(est), est.goal)
    with pytest.raises(ValueError, match="needs the drones' goal points"):
        runner.act(runner.observe(est))


def test_permuting_the_drones_in_the_config_permutes_the_commands_and_nothing_else(lab8):
    """Same motion-capture frames, the drone list in another order: every drone gets the same command."""
    policy = load_lab_policy(SHARED, lab8)
    perm = np.random.default_rng(3).permutation(8)
    permuted = LabConfig.from_dict(
        dataclasses.asdict(lab8) | {"drones": [dataclasses.asdict(lab8.drones[i]) for i in perm]}
    )
    pos, vel, plate = crowded_state(lab8, seed=2)
    frames = []
    for t in (0.0, 1.0 / 48):
        bodies = {"plate": np.array([*plate, 0.0, 0.0, 0.0, 1.0])}
        bodies |= {
            name: np.array([*(pos[i] + vel[i] * t), 0.0, 0.0, 0.0, 1.0]) for i, name in enumerate(lab8.drone_names)
        }
        frames.append(PoseFrame(t=t, bodies=bodies))
    commands = []
    for lab in (lab8, permuted):
        estimator = SwarmEstimator(lab, landed_height=lab.task_config().landed_height)
        estimator.ingest(frames)
        est = estimator.estimate(frames[-1].t)
        runner = PolicyRunner(policy, lab.task_config(), lab.limits.max_speed)
        _, velocity = runner.act(runner.observe(est), est.goal)
        commands.append(dict(zip(lab.drone_names, velocity, strict=True)))
    assert set(commands[0]) == set(commands[1])
    for name, v in commands[0].items():
        np.testing.assert_allclose(commands[1][name], v, atol=1e-9)
    assert np.ptp([np.linalg.norm(v) for v in commands[0].values()]) > 0.05  # the drones do get different commands


# ------------------------------------------------------------------ the 8-drone rehearsal
def test_eight_drones_rehearse_safely_with_the_shared_policy(lab8):
    """Seeds 0-4 of the 8-drone example through the firmware tracker, with the safety filter (the example's
    default): measured 35 of 40 drones on their pads (6, 6, 8, 7, 8), and never closer than 0.162 m; without the
    filter 27 (6, 5, 4, 5, 7), down to 0.073 m. The others end with a hard or off-pad touchdown (motors off, as in
    training) or, at seeds 0 and 1, hover a few cm over their pads, held off by landed neighbours, until the
    simulated time limit lands them. Whatever happens, every drone ends at rest inside the fence and never left it."""
    assert lab8.safety_filter.enabled
    landed, closest = 0, np.inf
    for seed in range(5):
        result = rehearse(lab8, SHARED, simulator=REHEARSAL_SIMULATOR, seed=seed)
        m = result.mission
        assert m.armed and result.safe, result.summary()
        assert result.at_rest.all() and result.inside_fence.all(), result.summary()
        assert (result.fence_excess == 0).all(), result.summary()  # no drone ever outside the hard fence
        assert set(m.phases) == {"down"}, result.summary()  # every drone came down under the rules
        touched = [e.drone for e in m.events if e.kind in ("touchdown", "hard_touchdown", "off_pad_contact")]
        rested = [e.drone for e in m.events if e.kind == "motors_off"]  # landed by the loop (the time limit)
        assert sorted(touched + rested) == list(range(8)), result.summary()  # each one once, each one accounted for
        assert [e.kind for e in m.events].count("touchdown") == sum(m.on_pad)
        landed += sum(m.on_pad)
        closest = min(closest, result.min_separation)
    assert landed >= 32, landed  # measured 35 (point mass: 40); a policy fed wrong neighbours lands far fewer
    assert closest >= 0.14, closest  # measured 0.162 m (point mass: 0.174 m); 0.073 m (0.013 m) without the filter


@pytest.mark.parametrize(("fault", "drone"), [("geofence-breach", 7), ("occlusion", 5), ("link-loss", 3)])
def test_every_drone_of_eight_obeys_the_safety_rules(lab8, fault, drone):
    """A fault on one drone of eight: every drone hovers (or the lost one is dropped) and then lands, inside the
    fence."""
    result = rehearse(lab8, SHARED, simulator="pointmass", fault=FaultSpec(fault, start_s=0.5, drone=drone))
    m = result.mission
    kinds = [e.kind for e in m.events]
    assert result.safe and result.at_rest.all() and (result.fence_excess == 0).all(), result.summary()
    assert "fault_injected" in kinds
    if fault == "geofence-breach":
        breach = next(e for e in m.events if e.kind == "geofence_breach")
        assert breach.drone == drone and kinds.index("geofence_breach") < kinds.index("land"), kinds
    if fault == "occlusion":
        assert kinds.index("stale_hover") < kinds.index("stale_land"), kinds
    if fault == "link-loss":
        assert m.phases[drone] == "lost" and all(p == "down" for i, p in enumerate(m.phases) if i != drone)


def test_a_landing_is_replanned_only_on_fresh_poses_of_the_drone_and_every_pad(lab8):
    """Over the plate ``surface_below`` gives the pads' height; a drone beside it and below it, the floor. That drop is
    what re-plans a landing, and only when the drone's pose and every pad's are valid and fresh."""
    from marlander_lite.deploy.landing import surface_below, surface_known

    plate = np.array([0.0, 0.0, 0.78])
    pads = plate + np.array([p.offset for p in lab8.drone_pads()])
    over = pads + np.array([0.0, 0.0, 0.05])
    beside = over + np.array([1.0, 0.0, -0.08])  # the plate moved on: 1 m away, 3 cm below its pad tops
    est = estimate(lab8, beside, np.zeros_like(beside), plate)
    assert surface_below(over[0], est, 0.0) == (pads[0, 2], 0)
    assert surface_below(beside[0], est, 0.0) == (0.0, None)
    assert surface_known(est, 0, 0.25)
    for field, value in (("drone_invalid", True), ("pad_invalid", True), ("drone_age", 1.0), ("pad_age", 1.0)):
        stale = dataclasses.replace(est, **{field: np.full(lab8.num_drones, value)})
        assert not surface_known(stale, 0, 0.25), field
    one_pad = dataclasses.replace(est, pad_age=np.r_[np.zeros(lab8.num_drones - 1), 1.0])
    assert not surface_known(one_pad, 0, 0.25)  # any pad: surface_below looks at every one
