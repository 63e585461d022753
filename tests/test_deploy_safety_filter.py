"""The safety filter in the deployment loop: its config section, the runner, the mission, the flight log.

The filter itself (:mod:`marlander_lite.swarm.safety_filter`) keeps every pair of drones to
``n . (u_i - u_j) >= -gamma (d - d_s)``. Here two drones fly head-on at each other 0.4 m apart, level,
still, 1 m above their pads, the policy commanding 1 m/s each: with ``gamma`` = 6 /s and ``d_s`` = 0.19 m
(set here, whatever the filter's defaults) the pair may close at most at 6 (0.4 - 0.19) = 1.26 m/s, 0.63 m/s
each (equal shares: both equally far from their goals). Each drone is over by 1 - 0.63 = 0.37 m/s; the side
step turns it to its left by ``sidestep`` x 0.37 m/s, and the projection removes the 0.37 m/s along the line
between them: ``u_1 = (0.63, 0.37 sidestep, 0)``, ``u_2 = -u_1`` m/s, worked out by hand from the rule.
"""

from __future__ import annotations

import copy
import dataclasses
import re
from typing import get_args

import numpy as np
import pytest
import yaml

from marlander_lite.deploy.commands import safety_filter_line
from marlander_lite.deploy.config import (
    EXAMPLE_CONFIG,
    EXAMPLE_CONFIG_8,
    ConfigError,
    LabConfig,
    SafetyFilterSection,
    load_lab_config,
)
from marlander_lite.deploy.estimation import SwarmEstimate
from marlander_lite.deploy.flight_log import read_flight_log
from marlander_lite.deploy.mission import Mission
from marlander_lite.deploy.modes import DronePhase, MissionMode
from marlander_lite.deploy.rehearsal import rehearse
from marlander_lite.deploy.runner import PolicyRunner, clamp_speed
from marlander_lite.deploy.sections import NamedFilterSettings
from marlander_lite.swarm.pad_acceleration import PadAcceleration
from marlander_lite.swarm.safety_filter import NAMED_SETTINGS, SafetyFilterConfig, parse_settings
from marlander_lite.task import TaskConfig

SHARED = "data/policies/shared-quick-local.safetensors"
GAMMA, D_S, TAU = 6.0, 0.19, 0.2
SIDESTEP = SafetyFilterConfig().sidestep
"""Not a key of the lab config: the filter's own default."""
CONFIG = SafetyFilterConfig(gain=GAMMA, min_distance=D_S, reaction_time=TAU)
SECTION = SafetyFilterSection(gain=GAMMA, min_distance=D_S, reaction_time=TAU)
"""The same settings as lab-config keys."""
HEAD_ON = np.array([[-0.2, 0.0, 1.0], [0.2, 0.0, 1.0]])
"""Two drones 0.4 m apart on the x axis, 1 m up."""
GOALS = np.array([[-0.125, 0.0, 0.015], [0.125, 0.0, 0.015]])
"""Their goal points: the example's pads (plate at the origin) raised by ``landed_height``."""
FILTERED = np.array([[0.63, 0.37 * SIDESTEP, 0.0], [-0.63, -0.37 * SIDESTEP, 0.0]])
"""The filtered head-on commands, by hand (module docstring)."""


@pytest.fixture
def example() -> dict:
    return yaml.safe_load(EXAMPLE_CONFIG.read_text())


class HeadOn:
    """A centralised two-drone policy sending drone 1 along +x and drone 2 along -x at 1 m/s (action 1/3 of 3 m/s)."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.array([1.0, 0.0, 0.0, -1.0, 0.0, 0.0]) / 3.0


def estimate(pos: np.ndarray, vel: np.ndarray | None = None, goals: np.ndarray = GOALS) -> SwarmEstimate:
    """A fresh estimate of level drones at ``pos`` ``(N, 3)`` moving at ``vel``, still pads under ``goals``."""
    n = len(pos)
    zeros = np.zeros((n, 3))
    return SwarmEstimate(
        t=0.0,
        pos=np.asarray(pos, dtype=float),
        quat=np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)),
        vel=zeros if vel is None else np.asarray(vel, dtype=float),
        ang_vel=zeros,
        pad_pos=goals - [0.0, 0.0, TaskConfig().landed_height],
        pad_vel=zeros,
        goal=goals,
        drone_age=np.zeros(n),
        pad_age=np.zeros(n),
        drone_invalid=np.zeros(n, dtype=bool),
        pad_invalid=np.zeros(n, dtype=bool),
    )


def closing_bound(est: SwarmEstimate, u: np.ndarray, i: int = 0, j: int = 1) -> tuple[float, float]:
    """``(n . (u_i - u_j), -gamma (d - d_s))`` for the pair's positions predicted ``reaction_time`` ahead."""
    predicted = est.pos + TAU * est.vel
    r = predicted[i] - predicted[j]
    d = float(np.linalg.norm(r))
    return float(r / d @ (u[i] - u[j])), -GAMMA * (d - D_S)


# ------------------------------------------------------------------ the config section
def test_the_examples_fly_the_filter_with_its_own_defaults_and_show_them(tmp_path):
    """The examples switch the filter on and show its keys commented out, with the filter's defaults: uncommented,
    they change nothing."""
    for path in (EXAMPLE_CONFIG, EXAMPLE_CONFIG_8):
        section = load_lab_config(path).safety_filter
        assert section.enabled
        assert section.filter_config() == SafetyFilterConfig()
        text = path.read_text()
        shown = re.findall(r"^  # (\w+): ([0-9.]+) ", text, flags=re.MULTILINE)
        assert shown and {key for key, _ in shown} <= {f.name for f in dataclasses.fields(SafetyFilterSection)}
        for key, value in shown:
            assert float(value) == getattr(SafetyFilterConfig(), key), key
        live = tmp_path / path.name
        live.write_text(re.sub(r"^  # (\w+: [0-9.]+ )", r"  \1", text, flags=re.MULTILINE))
        assert load_lab_config(live) == load_lab_config(path)
    assert LabConfig.from_dict(yaml.safe_load(EXAMPLE_CONFIG.read_text()) | {"safety_filter": {}}).safety_filter == (
        SafetyFilterSection()
    )


def test_the_keys_override_the_filter_s_settings(example):
    example["safety_filter"] = {
        "min_distance": 0.22,
        "touchdown_speed": 0.0,
        "cone_slope": 2.0,
        "reaction_time": 0.3,
        "cone_radius": 0.04,
        "settled_sink_limit": 0.8,
        "latency_compensation": 0.12,
        "low_velocity_step": 0.5,
    }
    config = LabConfig.from_dict(example).safety_filter.filter_config()
    expected = dataclasses.replace(
        SafetyFilterConfig(),
        min_distance=0.22,
        touchdown_speed=0.0,
        cone_slope=2.0,
        reaction_time=0.3,
        cone_radius=0.04,
        settled_sink_limit=0.8,
        latency_compensation=0.12,
        low_velocity_step=0.5,
    )
    assert config == expected


@pytest.mark.parametrize(
    ("values", "message"),
    [
        (
            {"min_distnce": 0.2},
            r"^safety_filter.min_distnce: unknown key; allowed: enabled, settings, min_distance, settled_min_distance",
        ),
        ({"min_distance": -0.1}, r"^safety_filter.min_distance: Input should be greater than 0 \(got -0.1\)"),
        ({"cone_slope": -1.0}, r"^safety_filter.cone_slope: Input should be greater than or equal to 0 \(got -1.0\)"),
        (
            {"latency_compensation": 0.8},
            r"^safety_filter.latency_compensation: Input should be less than or equal to 0.5 \(got 0.8\)",
        ),
        ({"cone_radius": 0.5}, r"^safety_filter.cone_radius: Input should be less than or equal to 0.1 \(got 0.5\)"),
        (
            {"low_velocity_step": -0.5},
            r"^safety_filter.low_velocity_step: Input should be greater than or equal to 0 \(got -0.5\)",
        ),
        (
            {"settled_sink_limit": -0.8},
            r"^safety_filter.settled_sink_limit: Input should be greater than or equal to 0 \(got -0.8\)",
        ),
        ({"enabled": "yes"}, r"^safety_filter.enabled: Input should be a valid boolean \(got 'yes'\)"),
        ({"gain": float("nan")}, r"^safety_filter.gain: Input should be a finite number"),
        (  # in range for the key, refused by the filter itself (its activation distance is 1 m)
            {"min_distance": 1.5},
            r"^safety_filter: the safety filter refuses these settings: .*activation_distance \(1.0 m\) must exceed "
            r"min_distance \(1.5 m\)",
        ),
        ("on", r"^safety_filter: must be a mapping of keys to values, got 'on'"),
    ],
)
def test_mistakes_in_the_section_are_refused_naming_the_key(example, values, message):
    example["safety_filter"] = values
    with pytest.raises(ConfigError, match=message):
        LabConfig.from_dict(example)


def test_a_named_set_of_settings_flies_as_on_a_command_line(example):
    # `settings: pad-frame` is --filter-settings pad-frame: the same names, the same keys, and keys given beside the
    # name override the set's, as later items do on a command line
    assert set(get_args(NamedFilterSettings)) == set(NAMED_SETTINGS)
    for name in NAMED_SETTINGS:
        example["safety_filter"] = {"settings": name}
        section = LabConfig.from_dict(example).safety_filter
        assert section.settings == name
        assert section.filter_config() == SafetyFilterConfig.from_dict(parse_settings(name))
        example["safety_filter"] = {"settings": name, "reaction_time": 0.3, "cone_radius": 0.02}
        lab = LabConfig.from_dict(example)
        expected = SafetyFilterConfig.from_dict(parse_settings(f"{name},reaction_time=0.3,cone_radius=0.02"))
        assert lab.safety_filter.filter_config() == expected
        assert lab.replace().safety_filter == lab.safety_filter  # a copy keeps the overrides, not the set's values
        assert safety_filter_line(lab).startswith(f"Safety filter: on (settings {name}: drones kept 0.19 m apart")
    # the pad-frame set's keys are not the defaults: a name that did nothing would fail here
    assert LabConfig.from_dict(example).safety_filter.filter_config() != SafetyFilterConfig()


def test_an_unknown_named_set_is_refused_naming_the_allowed_ones(example):
    example["safety_filter"] = {"settings": "pad-frames", "reaction_time": 0.3}
    with pytest.raises(ConfigError, match=r"^safety_filter.settings: Input should be 'moving-pads' or 'pad-frame'"):
        LabConfig.from_dict(example)


def test_settings_from_a_command_line_are_checked_as_the_loader_checks_them(example):
    section = LabConfig.from_dict(example).safety_filter
    assert section.with_settings({}) == section
    assert section.with_settings({"pad_lead": 0.2, "cone_radius": 0.04}).filter_config() == SafetyFilterConfig(
        pad_lead=0.2, cone_radius=0.04
    )
    with pytest.raises(ConfigError, match=r"iterations: unknown key; allowed: .*pad_lead"):
        section.with_settings({"iterations": 3})  # a filter setting the lab config does not expose
    with pytest.raises(ConfigError, match="pad_lead: Input should be less than or equal to 1"):
        section.with_settings({"pad_lead": 5.0})


def test_a_mistake_in_a_file_names_the_file_and_the_key(tmp_path, example):
    example["safety_filter"] = {"min_distance": -0.1}
    path = tmp_path / "lab.yaml"
    path.write_text(yaml.safe_dump(example))
    with pytest.raises(ConfigError, match=r"lab.yaml: safety_filter.min_distance: Input should be greater than 0"):
        load_lab_config(path)


def test_pads_closer_than_the_filter_s_distance_are_refused(example):
    """The example's pads are 0.25 m apart: a filter keeping drones 0.3 m apart would push them off their pads."""
    example["safety_filter"] = {"min_distance": 0.3}
    with pytest.raises(
        ConfigError,
        match=r"safety_filter.min_distance is 0.3 m but pads 'pad1' and 'pad2' \(of drones 'cf1' and 'cf2'\) on body "
        r"'plate' are 0.250 m apart: .* Set safety_filter.min_distance to at most 0.250 m",
    ):
        LabConfig.from_dict(example)
    example["safety_filter"]["min_distance"] = 0.25  # as far apart as the pads: allowed
    assert LabConfig.from_dict(example).safety_filter.min_distance == 0.25
    off = copy.deepcopy(example)
    off["safety_filter"] = {"min_distance": 0.3, "enabled": False}  # no filter, nothing to push
    assert not LabConfig.from_dict(off).safety_filter.enabled
    example["safety_filter"]["min_distance"] = 0.3
    example["pads"]["pad2"]["body"] = "plate2"  # on another body: how far apart depends on how the bodies move
    assert LabConfig.from_dict(example).safety_filter.min_distance == 0.3


def test_a_pad_without_a_drone_does_not_count(example):
    example["pads"]["spare"] = {"body": "plate", "offset": [0.125, 0.2, 0.0025], "radius": 0.1}  # 0.2 m from pad2
    example["safety_filter"] = {"min_distance": 0.22}
    assert LabConfig.from_dict(example).num_drones == 2
    example["drones"][1]["pad"] = "spare"  # cf2 on the spare pad: 0.32 m from cf1's, pad2 is nobody's
    assert LabConfig.from_dict(example).num_drones == 2
    example["drones"][0]["pad"] = "pad2"  # cf1 on pad2, 0.2 m from cf2's pad
    with pytest.raises(ConfigError, match=r"pads 'pad2' and 'spare' .* are 0.200 m apart"):
        LabConfig.from_dict(example)


# ------------------------------------------------------------------ the runner
def test_the_runner_observes_the_pad_acceleration_as_the_simulators_estimate_it():
    """A policy trained with ``observe_platform_acceleration`` reads, last, the estimate the simulators' episodes
    make from observed pad velocities; here the pads brake at 1 m/s^2 along x, one estimate per 24 Hz tick."""
    task = TaskConfig(num_drones=2, observe_platform_velocity=True, observe_platform_acceleration=True)
    runner = PolicyRunner(HeadOn(), task, max_speed=1.0)
    reference, dt = PadAcceleration(), task.dt
    for k in range(30):
        est = dataclasses.replace(estimate(HEAD_ON), t=k * dt, pad_vel=np.tile([0.5 - k * dt, 0.0, 0.0], (2, 1)))
        obs = runner.observe(est)
        assert obs.shape == (2, 19)
        expected = reference.update(est.pad_vel, est.t)
        np.testing.assert_allclose(obs[:, 16:19], expected, atol=1e-12)
        np.testing.assert_array_equal(runner.observe(est), obs)  # the same estimate twice: not a zero-second step
    np.testing.assert_allclose(obs[:, 16], -1.0, atol=1e-4)  # 0.7^29 of the start left
    assert PolicyRunner(HeadOn(), TaskConfig(num_drones=2), max_speed=1.0).observe(est).shape == (2, 13)


def test_the_runner_stacks_one_frame_per_policy_step_as_the_simulators_do():
    """With ``observation_history`` 3 the runner hands the policy its last three frames, newest first: the first
    frame in every slot, then one new frame per new estimate time; the same instant observed again changes none of
    the older slots."""
    history = TaskConfig(num_drones=2, observe_platform_velocity=True, observation_history=3)
    single = TaskConfig(num_drones=2, observe_platform_velocity=True)
    runner, reference = PolicyRunner(HeadOn(), history, max_speed=1.0), PolicyRunner(HeadOn(), single, max_speed=1.0)
    frames = []
    for k in range(6):
        est = dataclasses.replace(
            estimate(HEAD_ON), t=k * history.dt, pos=estimate(HEAD_ON).pos + np.array([0, 0, 0.1 * k])
        )
        frames.insert(0, reference.observe(est))
        expected = np.concatenate((frames + [frames[-1]] * 2)[:3], axis=-1)
        obs = runner.observe(est)
        assert obs.shape == (2, 48)
        np.testing.assert_array_equal(obs, expected)
        np.testing.assert_array_equal(runner.observe(est), obs)  # the same estimate twice: the history stays


def test_the_runner_keeps_a_head_on_pair_to_the_rule():
    runner = PolicyRunner(HeadOn(), TaskConfig(num_drones=2), max_speed=1.0, safety_filter=CONFIG)
    est = estimate(HEAD_ON)
    _, velocity = runner.act(runner.observe(est), est.goal)
    np.testing.assert_allclose(velocity, [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]], atol=1e-12)  # closing at 2 m/s
    u, changed = runner.filter_velocity(velocity, est, settled=np.zeros(2, dtype=bool))
    np.testing.assert_allclose(u, FILTERED, atol=1e-9)
    assert changed.tolist() == [True, True]
    closing, bound = closing_bound(est, u)
    assert bound == pytest.approx(-1.26)  # 6 (0.4 - 0.19)
    assert closing >= bound - 1e-9
    assert closing_bound(est, velocity)[0] < bound  # the policy's own commands broke the rule


@pytest.mark.parametrize("speed", [0.0, 0.2, 0.4])  # predicted 0.4, 0.32, 0.24 m apart: still more than d_s
def test_approaching_drones_obey_the_rule_at_their_predicted_distance(speed):
    """Moving towards each other, the pair is judged where it will be ``reaction_time`` s later. (Level, as the
    filter never pushes a drone down: of a pair one above the other, the lower one's downward share is dropped.)"""
    runner = PolicyRunner(HeadOn(), TaskConfig(num_drones=2), max_speed=1.0, safety_filter=CONFIG)
    est = estimate(HEAD_ON, vel=[[speed, 0.05, 0.0], [-speed, -0.1, 0.0]])
    _, velocity = runner.act(runner.observe(est), est.goal)
    u, _ = runner.filter_velocity(velocity, est, settled=np.zeros(2, dtype=bool))
    closing, bound = closing_bound(est, u)
    assert closing >= bound - 1e-9
    assert closing == pytest.approx(bound, abs=1e-9)  # moved only as far as the rule needs: onto its boundary
    assert np.linalg.norm(u, axis=1).max() <= 1.0 + 1e-12  # the lab's speed limit still holds


def test_a_settled_drone_is_left_alone_and_its_neighbour_keeps_clear():
    """Drone 2 has landed: its command is not touched, and drone 1 alone keeps the pair to the rule.

    0.3 m apart, drone 1 may close at 6 (0.3 - 0.19) = 0.66 m/s (the whole duty): over by 0.34 m/s, turned left
    by 0.34 ``sidestep``: ``(0.66, 0.34 sidestep, 0)``.
    """
    runner = PolicyRunner(HeadOn(), TaskConfig(num_drones=2), max_speed=1.0, safety_filter=CONFIG)
    est = estimate([[-0.1, 0.0, 1.0], [0.2, 0.0, 1.0]])
    velocity = np.array([[1.0, 0.0, 0.0], [-0.4, 0.1, 0.0]])
    u, changed = runner.filter_velocity(velocity, est, settled=np.array([False, True]))
    np.testing.assert_allclose(u[0], [0.66, 0.34 * SIDESTEP, 0.0], atol=1e-9)
    assert np.array_equal(u[1], velocity[1]) and changed.tolist() == [True, False]
    r = est.pos[0] - est.pos[1]
    assert r / np.linalg.norm(r) @ u[0] == pytest.approx(-GAMMA * (0.3 - D_S))


def test_without_a_filter_the_runner_returns_the_policy_s_velocities():
    runner = PolicyRunner(HeadOn(), TaskConfig(num_drones=2), max_speed=1.0)
    est = estimate(HEAD_ON)
    _, velocity = runner.act(runner.observe(est), est.goal)
    u, changed = runner.filter_velocity(velocity, est, settled=np.zeros(2, dtype=bool))
    assert u is velocity and not changed.any()


def test_the_runner_leads_a_braking_pad_by_the_pad_lead():
    """With ``pad_lead`` the runner adds ``pad_lead`` times the pads' acceleration, which it estimates from the pads'
    tracked velocities and the estimates' times: a plate braking at 1 m/s^2 along x, 0.2 s lead, -0.2 m/s."""
    apart = np.array([[-0.6, 0.0, 1.0], [0.6, 0.0, 1.0]])  # 1.2 m apart: no pair rule; 1 m up: no guard
    goals = apart - [0.0, 0.0, 1.0]
    runner = PolicyRunner(HeadOn(), TaskConfig(num_drones=2), 1.0, safety_filter=SafetyFilterConfig(pad_lead=0.2))
    still, idle = np.zeros((2, 3)), np.zeros(2, dtype=bool)
    for k in range(48):  # 48 Hz, 1 s
        moving = dataclasses.replace(
            estimate(apart, goals=goals), t=k / 48, pad_vel=np.tile([0.5 - k / 48, 0, 0], (2, 1))
        )
        u, changed = runner.filter_velocity(still, moving, idle)
    np.testing.assert_allclose(u, [[-0.2, 0.0, 0.0]] * 2, atol=1e-6)
    assert changed.all()
    # Without the lead the same estimates change nothing.
    runner = PolicyRunner(HeadOn(), TaskConfig(num_drones=2), 1.0, safety_filter=SafetyFilterConfig())
    u, changed = runner.filter_velocity(still, moving, idle)
    assert runner.pad_acceleration is None and not changed.any() and not u.any()


def test_the_runner_compensates_latency_on_the_estimate_it_predicts():
    """With ``latency_compensation`` ``L`` the policy reads and the filter guards the estimate ``L`` ahead. By hand,
    ``L`` = 0.05 s: a drone 0.5 m above its goal sinking at 1 m/s over a pad moving at 0.4 m/s along x has ``p`` =
    (0, 0, 0.5) now and (-0.02, 0, 0.45) ahead; the descent guard then lets it sink at most
    sqrt(0.3^2 + 2 x 1.5 x 0.45) = 1.2 m/s (sqrt(0.3^2 + 2 x 1.5 x 0.5) = 1.261 m/s on the estimate as measured)."""
    goals, up = np.array([[-0.6, 0.0, 0.0], [0.6, 0.0, 0.0]]), np.array([0.0, 0.0, 0.5])
    est = dataclasses.replace(
        estimate(goals + up, vel=np.tile([0.0, 0.0, -1.0], (2, 1)), goals=goals),
        pad_vel=np.tile([0.4, 0.0, 0.0], (2, 1)),
    )
    down, idle = np.tile([0.0, 0.0, -1.5], (2, 1)), np.zeros(2, dtype=bool)
    for compensation, p, sink in ((0.0, [0.0, 0.0, 0.5], np.sqrt(1.59)), (0.05, [-0.02, 0.0, 0.45], 1.2)):
        runner = PolicyRunner(
            HeadOn(), TaskConfig(num_drones=2), 2.0, SafetyFilterConfig(latency_compensation=compensation)
        )
        np.testing.assert_allclose(runner.observe(est)[:, :3], [p, p], atol=1e-12)
        u, _ = runner.filter_velocity(down, est, idle)
        np.testing.assert_allclose(u[:, 2], [-sink, -sink], atol=1e-9)
    np.testing.assert_array_equal(est.pos, goals + up)  # the measured estimate is kept


def test_the_runner_limits_the_velocity_step_against_the_world_velocity():
    """The runner's estimate holds world-frame velocities, so the velocity-step limit (0.5 m/s) needs no pad velocity.
    Two drones 0.1 m above goals on a pad moving at 0.8 m/s along x, flying with it: a setpoint of the pad's 0.8 m/s
    passes unchanged (a limit read against the velocity relative to the pad would cut it to 0.5 m/s), one reversing to
    -1 m/s becomes 0.8 - 0.5 = 0.3 m/s."""
    goals, up = np.array([[-0.6, 0.0, 0.0], [0.6, 0.0, 0.0]]), np.array([0.0, 0.0, 0.1])
    est = dataclasses.replace(
        estimate(goals + up, vel=np.tile([0.8, 0.0, 0.0], (2, 1)), goals=goals),
        pad_vel=np.tile([0.8, 0.0, 0.0], (2, 1)),
    )
    config = SafetyFilterConfig(low_velocity_step=0.5, cone_slope=0.0, centring_gain=0.0)
    runner = PolicyRunner(HeadOn(), TaskConfig(num_drones=2), 2.0, config)
    setpoints, idle = np.array([[0.8, 0.0, 0.0], [-1.0, 0.0, 0.0]]), np.zeros(2, dtype=bool)
    u, changed = runner.filter_velocity(setpoints, est, idle)
    np.testing.assert_allclose(u, [[0.8, 0.0, 0.0], [0.3, 0.0, 0.0]], atol=1e-12)
    np.testing.assert_array_equal(changed, [False, True])


# ------------------------------------------------------------------ the mission
class RecordingLink:
    """The Crazyflies of a mission unit test: never lost; velocity setpoints recorded per tick."""

    def __init__(self) -> None:
        self.sent: dict[int, np.ndarray] = {}

    def lost(self, i: int) -> None:
        return None

    def send_velocity(self, i: int, v: np.ndarray) -> None:
        self.sent[i] = np.array(v, dtype=float)


def flying_mission(enabled: bool = True, phases: tuple[DronePhase, ...] = (DronePhase.POLICY,) * 2) -> Mission:
    """The example lab's mission, already under the policy (take-off done), with a recording link."""
    lab = load_lab_config(EXAMPLE_CONFIG).replace(safety_filter=dataclasses.replace(SECTION, enabled=enabled))
    mission = Mission(lab, HeadOn(), source=None, link=RecordingLink(), clock=None)
    mission.mode, mission.phase = MissionMode.POLICY, list(phases)
    mission.times.takeoff = mission.times.policy = 0.0
    return mission


def tick(mission: Mission, est: SwarmEstimate, k: int) -> None:
    """What :meth:`Mission._tick` does around :meth:`Mission.decide` at tick ``k`` (48 Hz), without poses or a log."""
    mission.link.sent.clear()
    mission.tick, mission.t = k, k / mission.lab.rates.loop_hz
    mission.book.commands = [{"kind": "none"} for _ in range(mission.n)]
    mission.decide(est)


def test_the_mission_sends_filtered_commands_and_logs_them_once_per_spell():
    mission = flying_mission()
    est = estimate(HEAD_ON)
    for k in range(4):  # a new action at ticks 0 and 2 (24 Hz), the same setpoint re-sent at ticks 1 and 3
        tick(mission, est, k)
        assert sorted(mission.link.sent) == [0, 1]
        for i in range(2):
            np.testing.assert_allclose(mission.link.sent[i], FILTERED[i], atol=1e-9)
            record = mission.book.commands[i]
            assert record["kind"] == "velocity" and record["filtered"] is True
            np.testing.assert_allclose(record["v"], FILTERED[i], atol=1e-6)
            np.testing.assert_allclose(record["v_policy"], [1.0 - 2 * i, 0.0, 0.0], atol=1e-6)
    events = [e for e in mission.events if e.kind == "safety_filter"]
    assert [e.drone for e in events] == [0, 1]  # one event per drone for the whole spell
    assert "nearest drone cf2 0.40 m away" in events[0].message and "[1.0, 0.0, 0.0] -> [0.63, " in events[0].message
    assert mission.phase == [DronePhase.POLICY] * 2


def test_a_drone_already_down_is_not_commanded():
    mission = flying_mission(phases=(DronePhase.POLICY, DronePhase.DOWN))
    est = estimate([[-0.1, 0.0, 1.0], [0.2, 0.0, 1.0]])
    tick(mission, est, 0)
    assert list(mission.link.sent) == [0] and mission.book.commands[1] == {"kind": "none"}
    np.testing.assert_allclose(mission.link.sent[0], [0.66, 0.34 * SIDESTEP, 0.0], atol=1e-9)  # drone 1 alone
    assert [e.drone for e in mission.events if e.kind == "safety_filter"] == [0]


class Sinking:
    """A centralised two-drone policy sending both drones straight down at 1 m/s."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.array([0.0, 0.0, -1.0, 0.0, 0.0, -1.0]) / 3.0


def test_the_filter_logs_nothing_for_a_drone_no_longer_under_the_policy():
    """Drone 2 is down, resting on its goal; the policy still asks it to sink at 1 m/s, which the filter would cap at
    0.8 m/s for a settled drone. Nothing is sent to it, so no safety_filter event may name it (the 8-drone
    rehearsal logged one such event per second for a drone at rest after an off-pad contact)."""
    mission = flying_mission(phases=(DronePhase.POLICY, DronePhase.DOWN))
    mission.runner.policy = Sinking()
    est = estimate([[GOALS[0][0], GOALS[0][1], 1.5], GOALS[1]])
    for k in range(4):
        tick(mission, est, k)
        assert list(mission.link.sent) == [0]
    assert all(e.drone != 1 for e in mission.events if e.kind == "safety_filter")
    assert not mission.output.filtered[1]


def test_with_the_filter_off_the_mission_sends_the_policy_s_commands_unchanged():
    mission = flying_mission(enabled=False)
    assert mission.runner.safety_filter is None
    est = estimate(HEAD_ON)
    for k in range(2):
        tick(mission, est, k)
        assert np.array_equal(mission.link.sent[0], [1.0, 0.0, 0.0])
        assert np.array_equal(mission.link.sent[1], [-1.0, 0.0, 0.0])
        assert mission.book.commands == [
            {"kind": "velocity", "v": [1.0, 0.0, 0.0]},
            {"kind": "velocity", "v": [-1.0, 0.0, 0.0]},
        ]
    assert not [e for e in mission.events if e.kind == "safety_filter"]


# ------------------------------------------------------------------ the flight log
def test_the_flight_log_marks_filtered_commands(tmp_path):
    """8 drones on the point mass: each velocity record says whether the filter changed it; changed ones also hold
    the policy's command, which is the logged action in m/s (clamped); unchanged ones are that command."""
    lab = load_lab_config(EXAMPLE_CONFIG_8)
    rehearse(lab, SHARED, simulator="pointmass", seed=0, log_path=tmp_path / "on.jsonl")
    log = read_flight_log(tmp_path / "on.jsonl")
    policy_v, counts, spells, was = None, np.zeros(2, dtype=int), 0, np.zeros(8, dtype=bool)
    for record in log.ticks:
        if record["action"] is not None:
            policy_v = clamp_speed(np.reshape(record["action"], (8, 3)) * 3.0, lab.limits.max_speed)
        now = np.zeros(8, dtype=bool)
        for i, command in enumerate(record["cmd"]):
            if command["kind"] != "velocity":
                assert "filtered" not in command
                continue
            now[i] = command["filtered"]
            counts[int(command["filtered"])] += 1
            expected = command["v_policy"] if command["filtered"] else command["v"]
            np.testing.assert_allclose(expected, policy_v[i], atol=2e-6)
            if command["filtered"]:
                assert np.abs(np.subtract(command["v"], command["v_policy"])).max() > 1e-6
        spells += int((now & ~was).sum())
        was = now
        for event in record["events"]:
            if event["kind"] == "safety_filter":
                assert record["cmd"][event["drone"]]["filtered"]  # logged with the first filtered command
    events = [e for e in log.events if e["kind"] == "safety_filter"]
    assert counts.min() > 50  # both kinds of record, many of each
    assert 8 <= len(events) <= spells  # at least one per drone here; never more than one per spell
    rehearse(
        lab.replace(safety_filter=SafetyFilterSection(enabled=False)),
        SHARED,
        simulator="pointmass",
        seed=0,
        log_path=tmp_path / "off.jsonl",
    )
    off = read_flight_log(tmp_path / "off.jsonl")
    assert not any("filtered" in c for record in off.ticks for c in record["cmd"])
    assert not [e for e in off.events if e["kind"] == "safety_filter"]


def test_deploy_says_whether_the_filter_is_on() -> None:
    lab = load_lab_config(EXAMPLE_CONFIG)
    assert safety_filter_line(lab).startswith("Safety filter: on (drones kept 0.19 m apart")
    off = lab.replace(safety_filter=SafetyFilterSection(enabled=False))
    assert "OFF" in safety_filter_line(off) and "safety_filter.enabled: false" in safety_filter_line(off)
