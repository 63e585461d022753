"""The opening dynamics family (a curriculum training aid): its ranges, its schedule in a run, its errors."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from stable_baselines3.common.callbacks import BaseCallback

from marlander_lite.platforms import PlatformConfig
from marlander_lite.pointmass.family import DynamicsFamily
from marlander_lite.pointmass.simulator import PointMassParams, PointMassSwarm
from marlander_lite.task import TaskConfig
from marlander_lite.training.family_curriculum import family_at, opening_start
from marlander_lite.training.presets import TrainConfig, get_preset
from marlander_lite.training.train import train

SLOW = DynamicsFamily(
    velocity_time_constant=(0.08, 1.2),
    max_tilt_deg=(12.0, 35.0),
    max_sink_acceleration=(3.0, 9.6),
    ground_cushion=(0.0, 0.1),
)
"""A family wider than the default in three ranges and narrower in one (the cushion)."""


def test_the_opening_starts_at_the_overlap_with_the_default_family() -> None:
    start = opening_start(SLOW)
    assert start.velocity_time_constant == (0.08, 0.4)  # the default's
    assert start.max_tilt_deg == (15.0, 35.0)
    assert start.max_sink_acceleration == (3.0, 7.5)
    assert start.ground_cushion == (0.0, 0.1)  # narrower than the default's: kept
    assert start.latency_s == DynamicsFamily().latency_s
    apart = opening_start(dataclasses.replace(SLOW, drag=(1.0, 2.0)))  # the default's drag is 0-0.3
    assert apart.drag == (1.0, 2.0)  # no overlap: nothing easier to start from


def test_the_family_moves_linearly_from_start_to_wanted_and_stops_there() -> None:
    start = opening_start(SLOW)
    assert family_at(start, SLOW, 0.0) == start
    assert family_at(start, SLOW, 1.0) == SLOW
    assert family_at(start, SLOW, 7.0) == SLOW and family_at(start, SLOW, -1.0) == start
    half = family_at(start, SLOW, 0.5)
    assert half.velocity_time_constant == pytest.approx((0.08, 0.8))  # (0.4 + 1.2) / 2
    assert half.max_tilt_deg == pytest.approx((13.5, 35.0))


def _swarm(family: DynamicsFamily | None) -> PointMassSwarm:
    params = PointMassParams(family=family) if family else PointMassParams()
    return PointMassSwarm(TaskConfig(num_drones=2), PlatformConfig(kind="static-floor"), 64, params)


def test_the_simulator_draws_from_the_family_it_is_given() -> None:
    swarm = _swarm(SLOW)
    narrow = DynamicsFamily.fixed(velocity_time_constant=0.9)
    swarm.set_family(narrow)
    swarm.reset(np.arange(64), np.random.default_rng(0))
    tau = 1.0 / swarm._gain[..., 0]
    np.testing.assert_allclose(tau, 0.9)
    swarm.set_family(SLOW)
    swarm.reset(np.arange(64), np.random.default_rng(0))
    tau = 1.0 / swarm._gain[..., 0]
    assert 0.08 <= tau.min() < 0.3 and 1.0 < tau.max() <= 1.2


def test_set_family_refuses_a_simulator_without_one_and_a_latency_it_cannot_hold() -> None:
    with pytest.raises(ValueError, match="built with PointMassParams"):
        _swarm(None).set_family(SLOW)
    with pytest.raises(ValueError, match="command history holds"):
        _swarm(SLOW).set_family(dataclasses.replace(SLOW, latency_s=(0.0, 0.2)))


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"family_opening": 1.5}, r"family_opening must be a fraction of total_steps in \[0, 1\]"),
        ({"family_opening": -0.1}, r"family_opening must be a fraction"),
        ({"family_opening": 0.5, "dynamics": {}}, "family_opening needs a dynamics family"),
    ],
)
def test_bad_family_openings_are_refused_with_what_is_allowed(changes: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        TrainConfig(dynamics={"family": SLOW.to_dict()}).replace(**changes)


def opening_run(steps: int, **changes) -> TrainConfig:
    """A run of rollouts of 2048 steps (64 envs x 32) on :data:`SLOW`, a second or two."""
    small = {"num_envs": 64, "n_steps": 32, "batch_size": 512, "net_arch": (16, 16), "checkpoint_every": 0}
    return get_preset("quick-cpu").replace(total_steps=steps, dynamics={"family": SLOW.to_dict()}, **small, **changes)


class _RecordFamily(BaseCallback):
    """The simulator's family at every rollout, after the run's own callbacks set it."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: list[tuple[int, tuple[float, float]]] = []

    def _on_rollout_start(self) -> None:
        family = self.training_env.unwrapped.simulator.family
        self.seen.append((self.num_timesteps, family.velocity_time_constant))

    def _on_step(self) -> bool:
        return True


def test_a_run_opens_its_family_over_the_asked_fraction_of_its_steps(tmp_path) -> None:
    """8 rollouts of 2048 steps, opening over half of them: tau's upper bound climbs from the default's 0.4 s to 1.2 s
    at the rollout starting at 8192 steps and stays there."""
    config = opening_run(16_384, family_opening=0.5)
    recorder = _RecordFamily()
    train(config, tmp_path / "run", callbacks=(recorder,))
    steps = [s for s, _ in recorder.seen]
    highs = [high for _, (_, high) in recorder.seen]
    assert steps == [2048 * i for i in range(8)]
    assert highs[0] == pytest.approx(0.4)
    expected = [0.4 + 0.8 * min(s / 8192, 1.0) for s in steps]
    assert highs == pytest.approx(expected)
    assert highs[4:] == pytest.approx([1.2] * 4)


def test_a_gated_opening_waits_for_the_training_success_rate_and_a_resumed_run_reads_when_it_began(tmp_path) -> None:
    """Before the gate the family stays at its start; the first rollout whose recent success reaches the gate begins
    the opening (and logs the step); the log gives that step back to a resumed run."""
    from collections import deque
    from types import SimpleNamespace

    from stable_baselines3.common.logger import configure

    from marlander_lite.make import make_vec_env
    from marlander_lite.training.family_curriculum import OPENED_AT_KEY, OpeningFamily, opened_at_in_log

    env = make_vec_env("pointmass", num_envs=4, seed=0, dynamics={"family": SLOW.to_dict()})
    logger = configure(str(tmp_path / "logs"), ["csv"])
    model = SimpleNamespace(ep_success_buffer=deque([0.0] * 100, maxlen=100), num_timesteps=0, logger=logger)
    model.get_env = lambda: env
    opening = OpeningFamily(env, SLOW, opening_steps=1000, opened_at=None, now=0, gate=0.1)
    opening.init_callback(model)  # type: ignore[arg-type]
    simulator = env.unwrapped.simulator
    start = opening_start(SLOW)
    for steps, successes in ((0, 0), (500, 9), (1000, 10), (1500, 3), (2000, 3), (2500, 0)):
        model.ep_success_buffer = deque([1.0] * successes + [0.0] * (100 - successes), maxlen=100)
        opening.num_timesteps = steps
        opening.on_rollout_start()
        logger.dump(steps)
        expected = family_at(start, SLOW, max(0, steps - 1000) / 1000)
        assert simulator.family == expected, steps  # 10 % reached at 1000 steps; later dips change nothing
    assert opening.opened_at == 1000
    assert opened_at_in_log(tmp_path / "logs" / "progress.csv") == 1000
    assert opened_at_in_log(tmp_path / "missing.csv") is None
    assert OPENED_AT_KEY in (tmp_path / "logs" / "progress.csv").read_text().splitlines()[0]
    bad_gate = TrainConfig(dynamics={"family": SLOW.to_dict()}, family_opening=0.5)
    with pytest.raises(ValueError, match=r"family_opening_gate must be a success rate in \[0, 1\]"):
        bad_gate.replace(family_opening_gate=2.0)


class _InterruptAt(BaseCallback):
    """Sends this process SIGINT once training passes ``step`` steps, as Ctrl-C would."""

    def __init__(self, step: int) -> None:
        super().__init__()
        self.step, self.sent = step, False

    def _on_step(self) -> bool:
        if not self.sent and self.num_timesteps >= self.step:
            import signal

            self.sent = True
            signal.raise_signal(signal.SIGINT)
        return True


def test_an_opening_run_interrupted_and_resumed_ends_as_one_that_never_stopped(tmp_path) -> None:
    from safetensors.numpy import load_file

    from marlander_lite.training.resume import TrainingInterrupted
    from marlander_lite.training.train import resume

    config = opening_run(8192, family_opening=1.0, seed=5)
    with pytest.raises(TrainingInterrupted):
        train(config, tmp_path / "run", callbacks=(_InterruptAt(3000),))
    recorder = _RecordFamily()
    resumed = resume(tmp_path / "run", callbacks=(recorder,))
    assert [s for s, _ in recorder.seen] == [4096, 6144]
    assert [high for _, (_, high) in recorder.seen] == pytest.approx([0.8, 1.0])  # half and three quarters open
    whole = train(config, tmp_path / "whole")
    a, b = load_file(str(resumed.policy)), load_file(str(whole.policy))
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
