"""Commands relative to the pad (``TaskConfig.command_frame`` ``"pad"``): eq. 3 plus the pad velocity, by hand, in the
simulators, the transfer matrix, the safety filter and the deployment loop."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from marlander_lite import task
from marlander_lite.cli import main
from marlander_lite.deploy.estimation import SwarmEstimate
from marlander_lite.deploy.runner import InvalidAction, PolicyRunner
from marlander_lite.episodes import LandingEpisodes
from marlander_lite.experiments import transfer
from marlander_lite.platforms import PlatformConfig
from marlander_lite.pointmass import PointMassSwarm
from marlander_lite.policy_file import PolicyContract, PolicyFileError
from marlander_lite.swarm.filtered_policy import with_safety_filter
from marlander_lite.swarm.safety_filter import SafetyFilterConfig, filter_actions
from marlander_lite.task import TaskConfig
from marlander_lite.training.presets import (
    FINETUNE_PRESETS,
    LATE_COMMANDS_FAST_VERTICAL,
    MOVING_SLOW_TRACKERS_20M,
    QUICK_SLOW_TRACKERS_20M,
    get_preset,
)

POLICY = "data/policies/quick-cpu-slow-trackers-20m.safetensors"


def test_the_pad_frame_adds_the_pad_velocity_and_clips_each_axis_by_hand():
    """``u = v_pad + a v_max`` per axis within ``+-v_max``; the world frame is eq. 3 itself."""
    action = np.array([[0.5, -1.0, 0.0], [0.9, 0.0, 2.0]])  # 2 drones; 2.0 is clipped to 1 first, as eq. 3 does
    pad_vel = np.array([[[0.4, 0.3, 0.0], [0.5, -0.2, 0.1]]])
    world = task.command_velocity(action, TaskConfig(num_drones=2), pad_vel)
    np.testing.assert_allclose(world[0], [[1.5, -3.0, 0.0], [2.7, 0.0, 3.0]])
    pad = task.command_velocity(action, TaskConfig(num_drones=2, command_frame="pad"), pad_vel)
    np.testing.assert_allclose(pad[0], [[1.9, -2.7, 0.0], [3.0, -0.2, 3.0]])  # 2.7 + 0.5 and 3 + 0.1 cut to 3 m/s


def test_an_unknown_frame_or_a_pad_velocity_that_is_not_finite_is_refused():
    with pytest.raises(ValueError, match="command_frame must be one of world, pad"):
        TaskConfig(command_frame="body")
    cfg = TaskConfig(num_drones=1, command_frame="pad")
    with pytest.raises(ValueError, match="pad velocity is not finite"):
        task.command_velocity(np.zeros(3), cfg, np.array([[[np.nan, 0.0, 0.0]]]))
    with pytest.raises(ValueError, match="--command-frame must be one of world, pad"):
        transfer.TransferConfig(POLICY, command_frame="body")


def test_a_drone_that_commands_nothing_in_the_pad_frame_follows_its_pad():
    """On the point mass, with the pad circling at 0.4 m/s: action 0 in the world frame hovers (the drone's velocity
    relative to the pad stays near the pad's 0.4 m/s); in the pad frame the tracker takes the drone to the pad's
    velocity within a few of its time constants."""
    relative = {}
    for frame in ("world", "pad"):
        cfg = TaskConfig(num_drones=2, command_frame=frame)
        sim = PointMassSwarm(cfg, PlatformConfig(kind="moving-arc", speed=0.4), num_envs=3)
        episodes = LandingEpisodes(sim, seed=1)
        episodes.reset()
        for _ in range(12):  # 0.5 s
            episodes.step(np.zeros((3, 6)))
        s = sim.state()
        relative[frame] = np.abs(s.vel - s.pad_vel)[..., :2].max()
        np.testing.assert_allclose(np.linalg.norm(s.pad_vel[..., :2], axis=-1), 0.4)
    assert relative["world"] > 0.3
    assert relative["pad"] < 0.1


def test_the_safety_filter_works_on_the_world_command_of_a_pad_frame_policy():
    """Filtering ``a`` with the pad velocity as offset is filtering the world command ``a v_max + v_pad`` and taking
    ``v_pad`` off again: nothing changes when no rule binds; a head-on pair is moved as in the world frame."""
    config = SafetyFilterConfig(gain=6.0, min_distance=0.19, reaction_time=0.2)
    obs = np.zeros((1, 2, 16))
    obs[0, :, 0:3] = [[-0.075, 0.0, 1.0], [0.075, 0.0, 1.0]]  # 0.4 m apart over pads 0.25 m apart
    obs[0, :, 3:7] = [0.0, 0.0, 0.0, 1.0]
    offsets = np.array([[-0.125, 0.0, 0.0], [0.125, 0.0, 0.0]])
    pad_vel = np.full((1, 2, 3), [0.3, 0.0, 0.0])
    apart = np.array([[[-0.1, 0.0, 0.0], [0.1, 0.0, 0.0]]])  # separating: no rule binds
    kept, correction = filter_actions(obs, apart, offsets, 3.0, config, command_offset=pad_vel)
    np.testing.assert_allclose(kept, apart, atol=1e-12)
    assert np.abs(correction).max() < 1e-12
    head_on = np.array([[[0.3, 0.0, 0.0], [-0.3, 0.0, 0.0]]])
    pad_frame, _ = filter_actions(obs, head_on, offsets, 3.0, config, command_offset=pad_vel)
    world, _ = filter_actions(obs, head_on + pad_vel / 3.0, offsets, 3.0, config)
    np.testing.assert_allclose(pad_frame * 3.0 + pad_vel, world * 3.0, atol=1e-12)
    assert not np.allclose(pad_frame, head_on)  # the rule did bind
    with pytest.raises(ValueError, match=r"pad-frame policy .* needs the pad velocity its commands carry"):
        with_safety_filter(lambda o: o, 2, offsets, 3.0, config, policy_dt=1 / 24, pads_move=True, command_frame="pad")


def test_the_simulators_filter_takes_the_pad_velocity_from_the_loop_as_deployment_does():
    """A pad-frame policy that does not observe its pad's velocity is filtered on moving pads when the loop passes the
    pad velocity (motion capture's in the lab, the simulator's here): the offset is the velocity the command carries,
    lead included, and the velocity-step limit compares world velocities."""
    config = SafetyFilterConfig(gain=6.0, min_distance=0.19, reaction_time=0.2)
    obs = np.zeros((1, 2, 13))
    obs[0, :, 0:3] = [[-0.075, 0.0, 1.0], [0.075, 0.0, 1.0]]
    obs[0, :, 3:7] = [0.0, 0.0, 0.0, 1.0]
    offsets = np.array([[-0.125, 0.0, 0.0], [0.125, 0.0, 0.0]])
    pad_vel = np.full((1, 2, 3), [0.3, 0.0, 0.0])
    carried = np.full((1, 2, 3), [0.45, 0.0, 0.0])  # the pad velocity led by its acceleration
    head_on = np.array([[0.3, 0.0, 0.0, -0.3, 0.0, 0.0]])
    filtered = with_safety_filter(
        lambda o: head_on, 2, offsets, 3.0, config, policy_dt=1 / 24, pads_move=True, command_frame="pad",
        pad_velocity=lambda: pad_vel, carried_pad_velocity=lambda: carried,
    )  # fmt: skip
    expected, _ = filter_actions(obs, head_on.reshape(1, 2, 3), offsets, 3.0, config, command_offset=carried)
    np.testing.assert_allclose(filtered(obs.reshape(1, 26)), expected.reshape(1, 6), atol=1e-12)
    without_lead = with_safety_filter(
        lambda o: head_on, 2, offsets, 3.0, config, policy_dt=1 / 24, pads_move=True, command_frame="pad",
        pad_velocity=lambda: pad_vel,
    )  # fmt: skip
    expected, _ = filter_actions(obs, head_on.reshape(1, 2, 3), offsets, 3.0, config, command_offset=pad_vel)
    np.testing.assert_allclose(without_lead(obs.reshape(1, 26)), expected.reshape(1, 6), atol=1e-12)
    step = SafetyFilterConfig(low_velocity_step=0.5)
    with_safety_filter(lambda o: head_on, 2, offsets, 3.0, step, pads_move=True, pad_velocity=lambda: pad_vel)


def test_reading_the_carried_pad_velocity_before_a_step_changes_nothing():
    """What a safety filter reads before the step is what the step adds (action 0: the command is that velocity), and
    the rollout is the one in which nobody read it, new episodes included."""
    cfg = TaskConfig(num_drones=2, command_frame="pad", pad_frame_lead=0.4)
    runs = []
    for read in (False, True):
        sim = PointMassSwarm(cfg, PlatformConfig(kind="moving-linear", speed=0.5), num_envs=3)
        episodes = LandingEpisodes(sim, seed=5)
        episodes.reset()
        commands = []
        for k in range(150):
            if read:
                carried = episodes.carried_pad_velocity().copy()
                np.testing.assert_array_equal(episodes.carried_pad_velocity(), carried)  # formed once per step
            if k % 40 == 39:
                episodes.reset(np.array([1]))
                if read:
                    np.testing.assert_array_equal(episodes.carried_pad_velocity()[1], sim.state().pad_vel[1])
                    carried = episodes.carried_pad_velocity().copy()
            episodes.step(np.zeros((3, 6)))
            commands.append(episodes.previous_command.copy())
            if read:
                np.testing.assert_array_equal(commands[-1], carried)
        runs.append(np.array(commands))
    np.testing.assert_array_equal(runs[0], runs[1])
    assert np.abs(runs[0]).max() > 0.6  # beyond the pads' 0.5 m/s: the lead carried their acceleration


def test_the_matrix_filters_a_pad_frame_policy_on_moving_pads():
    """The shipped pad-frame policy, which does not observe its pad's velocity, flown through the moving-pad filter
    settings on the moving line (the filter reads the simulator's pad velocity): it lands, as its matrix says."""
    result = transfer.fly_cell(
        "data/policies/moving-slow-trackers.safetensors", "point mass", "line 0.2-0.5 m/s", 10, 0, "vicon",
        {"cone_radius": 0.04, "reaction_time": 0.35, "low_velocity_step": 0.5},
    )  # fmt: skip
    assert result.successes >= 8


class Still:
    """A centralised two-drone policy that commands nothing."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros(6)


def two_drones_over_their_pads(pad_vel: np.ndarray) -> SwarmEstimate:
    """A fresh estimate: two level drones at rest 1 m over the example's pads, which move at ``pad_vel`` ``(2, 3)``."""
    return SwarmEstimate(
        t=0.0,
        pos=np.array([[-0.2, 0.0, 1.0], [0.2, 0.0, 1.0]]),
        quat=np.tile([0.0, 0.0, 0.0, 1.0], (2, 1)),
        vel=np.zeros((2, 3)),
        ang_vel=np.zeros((2, 3)),
        pad_pos=np.array([[-0.125, 0.0, 0.0], [0.125, 0.0, 0.0]]),
        pad_vel=np.asarray(pad_vel, dtype=float),
        goal=np.array([[-0.125, 0.0, 0.0125], [0.125, 0.0, 0.0125]]),
        drone_age=np.zeros(2),
        pad_age=np.zeros(2),
        drone_invalid=np.zeros(2, dtype=bool),
        pad_invalid=np.zeros(2, dtype=bool),
    )


def test_the_deployment_loop_carries_the_estimated_pad_velocity():
    pad_vel = np.array([[0.3, -0.1, 0.0], [0.3, -0.1, 0.0]])
    est = two_drones_over_their_pads(pad_vel)
    pad_runner = PolicyRunner(Still(), TaskConfig(num_drones=2, command_frame="pad"), max_speed=1.0)
    _, velocity = pad_runner.act(pad_runner.observe(est), est.goal, est.pad_vel)
    np.testing.assert_allclose(velocity, pad_vel)
    world_runner = PolicyRunner(Still(), TaskConfig(num_drones=2), max_speed=1.0)
    np.testing.assert_array_equal(world_runner.act(world_runner.observe(est), est.goal, est.pad_vel)[1], 0.0)
    with pytest.raises(ValueError, match="relative to its pad: pass the pads' velocities"):
        pad_runner.act(pad_runner.observe(est), est.goal)
    with pytest.raises(InvalidAction, match="not finite"):  # the mission hovers on InvalidAction
        pad_runner.act(pad_runner.observe(est), est.goal, np.full((2, 3), np.nan))


def test_a_policy_file_names_its_command_frame():
    fields = {"num_drones": 2, "max_speed": 3.0, "policy_hz": 24.0, "activation": "relu", "hidden_sizes": (8,)}
    fields["normalize_observations"] = False
    old = PolicyContract(**fields, task={})
    assert old.interface_options()["command_frame"] == "world"  # files written before the frame: the paper's
    assert PolicyContract(**fields, task={"command_frame": "pad"}).interface_options()["command_frame"] == "pad"
    with pytest.raises(PolicyFileError, match="command_frame must be one of world, pad, got 'body'"):
        PolicyContract(**fields, task={"command_frame": "body"}).interface_options()
    led = PolicyContract(**fields, task={"command_frame": "pad", "pad_frame_lead": 0.3}).interface_options()
    assert led["pad_frame_lead"] == 0.3 and old.interface_options()["pad_frame_lead"] == 0.0
    with pytest.raises(PolicyFileError, match="pad_frame_lead must be a number from 0 to 2"):
        PolicyContract(**fields, task={"command_frame": "pad", "pad_frame_lead": -1}).interface_options()


def test_the_preset_fine_tunes_the_quick_recipe_on_moving_pads_in_the_pad_frame():
    for preset, quick in (
        (MOVING_SLOW_TRACKERS_20M, QUICK_SLOW_TRACKERS_20M),  # the version its first shipped runs were trained by
        (get_preset("moving-slow-trackers"), get_preset("quick-cpu-slow-trackers")),  # the quickstart's family since
    ):
        assert preset.task == {**quick.task, "command_frame": "pad", "pad_frame_lead": 0.5}
        assert preset.platform == "moving-arc" and tuple(preset.platform_speed) == (0.0, 0.6)
        assert preset.total_steps == 6_000_000
        moving = {"task", "platform", "platform_speed", "total_steps"}  # plates from the floor to 1 m, as before
        assert {f for f in quick.__dataclass_fields__ if getattr(quick, f) != getattr(preset, f)} == moving
    assert "moving-slow-trackers" in FINETUNE_PRESETS  # marlander train refuses it without --init-from
    # The same fine-tune on the run's own family: only the three late-command ranges differ between the versions.
    late = get_preset("moving-slow-trackers").dynamics["family"]
    before = MOVING_SLOW_TRACKERS_20M.dynamics["family"]
    assert {k for k, v in late.items() if v != before[k]} == set(LATE_COMMANDS_FAST_VERTICAL)
    assert get_preset("moving-slow-trackers") == MOVING_SLOW_TRACKERS_20M.replace(dynamics={"family": late})


def test_the_matrix_flies_a_static_policy_in_the_pad_frame(tmp_path):
    """``--command-frame pad`` carries a policy trained on static pads along with a moving one: on the point-mass arc
    it lands where the world frame (its own) leaves it behind the pad."""
    cells = {}
    for frame in (None, "pad"):
        config = transfer.TransferConfig(
            POLICY, episodes=10, columns=("point mass",), rows=("arc 0.2-0.5 m/s",), workers=1, command_frame=frame
        )
        (cells[frame],) = transfer.transfer_matrix(config)
    assert cells["pad"].successes >= 9, cells["pad"]
    assert cells[None].successes <= 5, cells[None]
    out = tmp_path / "t"
    args = ["transfer", POLICY, "--command-frame", "pad", "--episodes", "1", "--rows", "floor", "--columns"]
    assert main([*args, "point mass", "--workers", "1", "--out", str(out)]) == 0
    assert "commands flown in the pad frame (trained in the world frame)" in (out / "transfer.md").read_text()
    assert json.loads((out / "transfer.json").read_text())["config"]["command_frame"] == "pad"


def test_on_pads_at_rest_the_pad_frame_is_the_world_frame():
    """The same episodes, flown in either frame on the floor pad, give the same cell to the last digit."""
    cells = [
        dataclasses.replace(transfer.fly_cell(POLICY, "point mass", "floor", 4, 0, "vicon", command_frame=f), wall_s=0)
        for f in ("world", "pad")
    ]
    assert cells[0] == cells[1]


def test_the_lead_carries_the_pads_acceleration_once_the_estimate_has_settled():
    """With ``pad_frame_lead`` ``T`` and action 0 the command is ``v_pad + T a_pad``. The pad shuttles along its line
    at 0.5 m/s, ramping at 1 m/s^2 for 0.5 s at each end; wherever its acceleration (differenced here from its true
    velocities) has held for 8 commands, the estimate has closed all but 0.7^8 of the change, and the command is
    within 3 cm/s of ``v_pad + T a_pad``. Without a lead the command is the pad's velocity exactly."""
    lead, dt = 0.4, TaskConfig().dt
    errors = {}
    for t_lead in (0.0, lead):
        cfg = TaskConfig(num_drones=2, command_frame="pad", pad_frame_lead=t_lead)
        sim = PointMassSwarm(cfg, PlatformConfig(kind="moving-linear", speed=0.5), num_envs=2)
        episodes = LandingEpisodes(sim, seed=3)
        episodes.reset()
        pad_vel, commands = [], []
        for _ in range(150):
            pad_vel.append(sim.state().pad_vel.copy())
            episodes.step(np.zeros((2, 6)))
            commands.append(episodes.previous_command.copy())
        pad_vel, commands = np.array(pad_vel), np.array(commands)
        accel = np.diff(pad_vel, axis=0, prepend=pad_vel[:1]) / dt
        held = np.array([np.allclose(accel[k - 8 : k + 1], accel[k], atol=1e-9) for k in range(8, len(accel))])
        k = np.arange(8, len(accel))[held]
        assert np.linalg.norm(accel[k], axis=-1).max() == pytest.approx(1.0)  # some held stretches brake or ramp
        errors[t_lead] = np.abs(commands[k] - (pad_vel[k] + t_lead * accel[k])).max()
    assert errors[0.0] == 0.0
    assert errors[lead] < 0.03
    with pytest.raises(ValueError, match="pad_frame_lead must be from 0 to 2 s, and above 0 only with"):
        TaskConfig(pad_frame_lead=0.3)
    with pytest.raises(ValueError, match="pad_frame_lead must be from 0 to 2 s"):
        TaskConfig(command_frame="pad", pad_frame_lead=2.5)


def test_the_deployment_loop_leads_the_pad_velocity_once_per_estimate():
    """The runner's lead is the simulators': ``T`` times :class:`PadAcceleration` of the estimates' pad velocities, one
    update per estimate time; a pad velocity that is not finite makes the loop hover (InvalidAction)."""
    from marlander_lite.swarm.pad_acceleration import PadAcceleration

    cfg = TaskConfig(num_drones=2, command_frame="pad", pad_frame_lead=0.3)
    runner, reference = PolicyRunner(Still(), cfg, max_speed=1.0), PadAcceleration()
    base = two_drones_over_their_pads(np.zeros((2, 3)))
    for k in range(20):
        est = dataclasses.replace(base, t=k * cfg.dt, pad_vel=np.tile([0.5 - k * cfg.dt, 0.0, 0.0], (2, 1)))
        carried = runner.carried_pad_velocity(est)
        np.testing.assert_allclose(carried, est.pad_vel + 0.3 * reference.update(est.pad_vel, est.t), atol=1e-12)
        np.testing.assert_array_equal(runner.carried_pad_velocity(est), carried)  # the same estimate again
        _, velocity = runner.act(runner.observe(est), est.goal, carried)
        np.testing.assert_allclose(velocity, carried)
    assert carried[0, 0] == pytest.approx(0.5 - 19 * cfg.dt - 0.3, abs=1e-3)  # braking at 1 m/s^2: led by 0.3 m/s
    bad = dataclasses.replace(est, t=est.t + cfg.dt, pad_vel=np.full((2, 3), np.nan))
    with pytest.raises(InvalidAction, match="NaN or infinite pad velocity"):
        runner.carried_pad_velocity(bad)


CLIMB = ",low_velocity_step=0.5,low_velocity_step_lag=0.45,approach_climb=1"  # the tracker-step settings, climbing


@pytest.mark.parametrize(("lead", "more_settings"), [(None, ""), (0.3, ""), (None, CLIMB)])
def test_the_lab_rehearsal_flies_the_shipped_pad_frame_policy_onto_a_shuttling_plate(lead, more_settings):
    """`marlander deploy --sim`'s loop with `moving-slow-trackers` (the lab's moving-pad settings, the plate shuttling
    at 0.4 m/s, the firmware tracker): the runner reads the policy's frame and lead from its file (or the lead from
    the lab's ``limits.pad_frame_lead``), carries the pads' tracked velocity, and both drones land on their pads (seed 0
    of the campaign in benchmarks/results/rehearsal_moving_slow_trackers_line_2026-11-30.txt), also through the
    velocity step that follows the tracker and the approach guard's climb."""
    from marlander_lite.deploy.config import EXAMPLE_CONFIG, load_lab_config
    from marlander_lite.deploy.mission import Mission
    from marlander_lite.deploy.rehearsal import rehearse
    from marlander_lite.swarm.safety_filter import parse_settings

    lab = load_lab_config(EXAMPLE_CONFIG)
    lab = lab.replace(
        simulation=dataclasses.replace(lab.simulation, platform="moving-linear", platform_speed=0.4),
        safety_filter=lab.safety_filter.with_settings(
            parse_settings("cone_radius=0.04,reaction_time=0.35" + more_settings)
        ),
        limits=dataclasses.replace(lab.limits, takeoff_height=1.4, pad_frame_lead=lead),
    )
    frames = []

    def record(mission: Mission, t: float) -> None:
        frames.append((mission.task.command_frame, mission.task.pad_frame_lead))

    result = rehearse(
        lab, "data/policies/moving-slow-trackers.safetensors", simulator="crazyflie", seed=0, hooks=[record]
    )
    assert set(frames) == {("pad", 0.5 if lead is None else lead)}
    assert result.mission.success and all(result.mission.on_pad), result.mission
    assert result.safe


def test_a_lab_config_naming_the_pad_frame_settings_lands_the_pad_frame_policy_on_a_shuttling_plate(tmp_path):
    """The lab guide's row for moving pads as a lab writes it: the example config with ``settings: pad-frame`` in its
    ``safety_filter`` section, read from a file, rehearsed with `moving-slow-trackers` on the plate shuttling at
    0.4 m/s through the firmware tracker; the mission flies the named set's filter and both drones land on their pads
    (measured: both landed in each of seeds 0-9, 3.2 cm from the pad centres on average)."""
    from marlander_lite.deploy.config import EXAMPLE_CONFIG, load_lab_config
    from marlander_lite.deploy.mission import Mission
    from marlander_lite.deploy.rehearsal import rehearse
    from marlander_lite.swarm.safety_filter import SafetyFilterConfig, parse_settings

    text = EXAMPLE_CONFIG.read_text()
    named = text.replace("  # settings: pad-frame ", "  settings: pad-frame   ", 1)
    assert named != text  # the example shows the key, commented out
    path = tmp_path / "lab.yaml"
    path.write_text(named)
    lab = load_lab_config(path)
    assert lab.safety_filter.filter_config() == SafetyFilterConfig.from_dict(parse_settings("pad-frame"))
    lab = lab.replace(
        simulation=dataclasses.replace(lab.simulation, platform="moving-linear", platform_speed=0.4),
        limits=dataclasses.replace(lab.limits, takeoff_height=1.4),
    )
    flown = set()

    def record(mission: Mission, t: float) -> None:
        flown.add(mission.runner.safety_filter)

    result = rehearse(
        lab, "data/policies/moving-slow-trackers.safetensors", simulator="crazyflie", seed=0, hooks=[record]
    )
    assert flown == {lab.safety_filter.filter_config()}
    assert result.mission.success and all(result.mission.on_pad), result.mission
    assert result.safe


def test_the_lab_may_fly_another_lead_and_only_for_a_pad_frame_policy():
    """``limits.pad_frame_lead`` replaces the file's lead of a pad-frame policy; it is refused, saying what to do,
    for a world-frame policy, and out of [0, 2] s by the config loader."""
    import yaml

    from marlander_lite.deploy.config import EXAMPLE_CONFIG, ConfigError, LabConfig, load_lab_policy
    from marlander_lite.policy_file import read_contract

    example = yaml.safe_load(EXAMPLE_CONFIG.read_text())
    moving = "data/policies/moving-slow-trackers.safetensors"
    own = LabConfig.from_dict(example)
    assert own.policy_options(read_contract(moving).interface_options())["pad_frame_lead"] == 0.5
    example["limits"] = {**example.get("limits", {}), "pad_frame_lead": 0.3}
    lab = LabConfig.from_dict(example)
    assert lab.policy_options(read_contract(moving).interface_options())["pad_frame_lead"] == 0.3
    assert load_lab_policy(moving, lab).contract.task["pad_frame_lead"] == 0.5  # the file itself is unchanged
    with pytest.raises(PolicyFileError, match=r"limits.pad_frame_lead is 0.3 s, but this policy commands .* world"):
        load_lab_policy("data/policies/quick-cpu-slow-trackers-20m.safetensors", lab)
    example["limits"]["pad_frame_lead"] = 2.5
    with pytest.raises(ConfigError, match=r"pad_frame_lead"):
        LabConfig.from_dict(example)


def test_every_evaluation_flies_a_pad_frame_policy_in_its_frame():
    """`marlander swarm evaluate --centralised` and `marlander reproduce` read the frame from the policy file with its
    observation, as the transfer matrix and the deployment loop do: a pad-frame policy flown in the world frame would
    fall behind a moving pad."""
    from marlander_lite.experiments.controllers import ControllerSpec
    from marlander_lite.swarm.evaluation import evaluate_cell

    policy = "data/policies/moving-slow-trackers.safetensors"
    assert ControllerSpec("marlander", policy_path=policy).interface_options()["command_frame"] == "pad"
    arc = PlatformConfig(kind="moving-arc", speed=0.4)
    row = evaluate_cell("centralised", 2, 20, policy_path=policy, num_envs=20, platform=arc)
    assert row.summary.success_rate >= 0.9, row


def test_swarm_evaluate_flies_a_pad_frame_policy_with_the_lead_asked_for(tmp_path, capsys):
    """``marlander swarm evaluate --pad-frame-lead``: the shipped pad-frame fine-tune, trained with a 0.5 s lead, flown
    with 0.3 s (about the firmware tracker's 0.2 s velocity time constant plus its delays) on the point mass's UR10 arc
    at 1.0 m/s. Measured at 200 trials (docs/scaling.md): 77.0 % at 7.02 cm with its own lead, 94.5 % at 2.68 cm with
    0.3 s, its touchdowns no longer ahead of the pad; here 40 trials. A world-frame policy carries no pad velocity to
    lead: refused before anything is flown or written."""
    moving = "data/policies/moving-slow-trackers-fast-vertical.safetensors"
    args = ["swarm", "evaluate", "--centralised", moving, "--sizes", "2", "--trials", "40", "--num-envs", "40"]
    args += ["--platform", "moving-arc", "--speeds", "1", "--out", str(tmp_path)]
    assert main([*args, "--stem", "own"]) == 0
    assert main([*args, "--stem", "led", "--pad-frame-lead", "0.3"]) == 0
    own, led = (json.loads((tmp_path / f"{stem}.json").read_text())[0] for stem in ("own", "led"))
    assert "--pad-frame-lead 0.3" in (tmp_path / "led.md").read_text()
    assert "--pad-frame-lead" not in (tmp_path / "own.md").read_text()
    assert led["success_rate"] >= 0.8 and led["error_mean_cm"] < 0.6 * own["error_mean_cm"], (own, led)
    with pytest.raises(SystemExit):
        main(
            [
                *args[:2],
                "--centralised",
                POLICY,
                *args[4:-2],
                "--out",
                str(tmp_path / "world"),
                "--pad-frame-lead",
                "0.3",
            ]
        )
    assert "commands in the world frame, where no pad velocity is carried to lead" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([*args[:-1], str(tmp_path / "long"), "--pad-frame-lead", "2.5"])
    assert "'2.5' is not a pad-frame lead: give seconds from 0 to 2, or 'auto'" in capsys.readouterr().err
    assert not (tmp_path / "world").exists() and not (tmp_path / "long").exists()


def test_a_longer_lead_puts_the_touchdowns_further_ahead_of_the_pad():
    """The point mass's nominal tracker follows a command with a 0.14 s velocity time constant. Led by nothing, a
    pad-frame drone trails a pad that speeds up and touches down behind its centre; led by 0.8 s, ahead of it; led by
    0.3 s, near the time constant plus the loop's delays, within 1.5 cm of it (12 episodes of the line at 0.5 m/s:
    -2.2 / +0.5 / +7.4 cm measured). A pad at rest has no track to measure along."""
    from marlander_lite.experiments.lead_offsets import touchdown_offsets

    moving = "data/policies/moving-slow-trackers-fast-vertical.safetensors"
    along = {
        lead: touchdown_offsets(moving, "point mass", "moving-linear", 0.5, lead, episodes=12).along.mean()
        for lead in (0.0, 0.3, 0.8)
    }
    assert along[0.0] < -0.01 and abs(along[0.3]) < 0.015 and along[0.8] > 0.05, along
    with pytest.raises(ValueError, match="a pad at rest has no track"):
        touchdown_offsets(moving, "point mass", "static-floor", 0.0, None, episodes=1)
