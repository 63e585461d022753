"""The shortest pairing of starts with pads (CAPT's assignment), checked against brute force and its geometry."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from marlander_lite import task
from marlander_lite.pad_assignment import assign_starts_to_pads, path_crossings, shortest_pairing
from marlander_lite.platforms import PlateGeometry
from marlander_lite.pointmass import kernels
from marlander_lite.swarm.evaluation import evaluate_cell
from marlander_lite.task import TaskConfig

SHARED_POLICY = "data/policies/shared-quick-drone-ends.safetensors"


def total_squared(starts: np.ndarray, pads: np.ndarray, order) -> float:
    return float(((starts[list(order)] - pads) ** 2).sum())


@pytest.mark.parametrize("num_drones", [1, 2, 3, 5, 7])
def test_shortest_pairing_is_the_best_of_every_permutation(num_drones):
    rng = np.random.default_rng(num_drones)
    for _ in range(20):
        starts, pads = rng.uniform(-2, 2, (num_drones, 3)), rng.uniform(-0.5, 0.5, (num_drones, 3))
        order = shortest_pairing(starts, pads)
        assert sorted(order.tolist()) == list(range(num_drones))
        best = min(total_squared(starts, pads, p) for p in itertools.permutations(range(num_drones)))
        assert total_squared(starts, pads, order) == pytest.approx(best, rel=1e-12)


def test_shortest_pairing_keeps_synchronised_straight_paths_apart():
    """No swap of two pads can shorten the pairing, so (a_i - a_j).(p_i - p_j) >= 0 for every pair; then straight
    paths flown to arrive together keep every two drones min(|a_i - a_j|, |p_i - p_j|) / sqrt(2) apart."""
    rng = np.random.default_rng(7)
    pads = np.array(PlateGeometry().pad_offsets(16))
    t = np.linspace(0, 1, 201)[:, None, None]
    for _ in range(50):
        starts = rng.uniform([-2, -2, 0.5], [2, 2, 3.7], (16, 3))
        paired = starts[shortest_pairing(starts, pads)]
        gap_a = paired[:, None] - paired[None]
        gap_p = pads[:, None] - pads[None]
        assert ((gap_a * gap_p).sum(-1) >= -1e-12).all()
        path = (1 - t) * paired + t * pads  # (time, drone, 3)
        distance = np.linalg.norm(path[:, :, None] - path[:, None], axis=-1)
        bound = np.minimum(np.linalg.norm(gap_a, axis=-1), np.linalg.norm(gap_p, axis=-1)) / np.sqrt(2)
        off_diagonal = ~np.eye(16, dtype=bool)
        assert (distance[:, off_diagonal] >= bound[off_diagonal] - 1e-12).all()


def test_assign_starts_to_pads_reorders_each_env_and_refuses_bad_shapes():
    rng = np.random.default_rng(0)
    starts, pads = rng.uniform(-2, 2, (30, 4, 3)), rng.uniform(-0.3, 0.3, (30, 4, 3))
    out = assign_starts_to_pads(starts, pads)
    for env in range(30):
        assert sorted(map(tuple, out[env])) == sorted(map(tuple, starts[env]))  # the same starts, handed out
        assert total_squared(out[env], pads[env], range(4)) <= total_squared(starts[env], pads[env], range(4))
    with pytest.raises(ValueError, match=r"\(num_envs, N, 3\)"):
        assign_starts_to_pads(starts[0], pads[0])
    with pytest.raises(ValueError, match="finite"):
        shortest_pairing(np.full((2, 3), np.nan), pads[0, :2])


@pytest.mark.parametrize("engine", ["numpy", "numba"])
def test_spawn_with_the_shortest_pairing_hands_out_the_same_draws(monkeypatch, engine):
    """The pairing draws no random number: the same seed gives the paper's starts, reordered per env, with near-pad
    starts (a training aid) kept beside their own pads."""
    monkeypatch.setenv(kernels.ENGINE_VARIABLE, engine)
    pads = np.broadcast_to(np.array(PlateGeometry().pad_offsets(8)), (200, 8, 3)).copy()
    drawn = {}
    for pairing in ("fixed", "shortest"):
        cfg = TaskConfig(num_drones=8, pad_assignment=pairing, spawn_near_pad_fraction=0.25, spawn_separation=0.2)
        rng = np.random.default_rng(5)
        drawn[pairing] = task.sample_spawn_positions(rng, np.zeros(200), cfg, pads), rng.random(3)
    (fixed, after_fixed), (paired, after_paired) = drawn["fixed"], drawn["shortest"]
    np.testing.assert_array_equal(after_fixed, after_paired)
    near = (np.hypot(*(fixed - pads)[..., :2].transpose(2, 0, 1)) <= 0.3).all(-1) & (fixed[..., 2] <= 1.0).all(-1)
    np.testing.assert_array_equal(paired[near], fixed[near])
    moved = 0
    for env in np.flatnonzero(~near):
        assert sorted(map(tuple, paired[env])) == sorted(map(tuple, fixed[env]))
        best = total_squared(paired[env], pads[env], range(8))
        assert best <= total_squared(fixed[env], pads[env], range(8)) + 1e-12
        moved += not np.array_equal(paired[env], fixed[env])
    assert moved > 0.9 * (~near).sum()  # 8 random starts are almost never in their best order already


def test_unknown_pad_assignment_and_missing_pads_are_refused():
    with pytest.raises(ValueError, match="pad_assignment must be one of fixed, shortest"):
        TaskConfig(pad_assignment="nearest")
    with pytest.raises(ValueError, match="needs the pad positions"):
        task.sample_spawn_positions(np.random.default_rng(0), np.zeros(3), TaskConfig(pad_assignment="shortest"))


def test_the_shared_policy_collides_far_less_with_the_shortest_pairing():
    """The shipped shared policy senses neighbours within 0.2 m only; with the paper's pairs 8-drone swarms collide
    where their paths cross, with the shortest pairing almost never (docs/scaling.md: 51 % and 0 % of 200)."""
    rows = {
        pairing: evaluate_cell(
            "shared", 8, 60, seed=0, policy_path=SHARED_POLICY, task_changes={"pad_assignment": pairing}
        )
        for pairing in ("fixed", "shortest")
    }
    assert rows["fixed"].collisions >= 15
    assert rows["shortest"].collisions <= 3
    assert rows["shortest"].summary.success_rate > rows["fixed"].summary.success_rate + 0.15


def test_the_paired_preset_trains_on_paired_starts():
    from marlander_lite.swarm.train import SHARED_PRESETS, make_shared_env

    config = SHARED_PRESETS["shared-quick-paired"].replace(drones_per_size=64)
    assert config.task_config().pad_assignment == "shortest"
    env = make_shared_env(config, seed=3)
    env.reset()
    checked = 0
    for episodes in env.groups:
        s = episodes.sim.state()
        near = (np.hypot(*(s.pos - s.pad_pos)[..., :2].transpose(2, 0, 1)) <= 0.3).all(-1)
        for swarm in np.flatnonzero(~near):
            best = shortest_pairing(s.pos[swarm], s.pad_pos[swarm])
            np.testing.assert_array_equal(best, np.arange(len(best)))  # already in the best order
            checked += 1
    assert checked > 20
    env.close()


def test_path_crossings_counts_what_a_drawing_shows():
    starts = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [3.0, 0.0, 1.0]])
    pads = np.array([[1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [3.0, 1.0, 0.0]])
    assert path_crossings(starts, pads) == 1  # an X and a path beside it
    assert path_crossings(starts, pads[[1, 0, 2]]) == 0  # two parallel paths and the third
    assert path_crossings(starts[:, [0, 1, 2]] * [1, 1, 5], pads) == 1  # heights do not matter, seen from above
    # The shortest pairing of 8 random starts to the 3 x 3 grid crosses far less than the paper's fixed pairs
    pads = np.array(PlateGeometry().pad_offsets(8))
    draws = task.sample_spawn_positions(np.random.default_rng(0), np.zeros(300), TaskConfig(num_drones=8))
    fixed = np.mean([path_crossings(d, pads) for d in draws])
    paired = np.mean([path_crossings(d[shortest_pairing(d, pads)], pads) for d in draws])
    assert fixed > 5 and paired < fixed / 5
