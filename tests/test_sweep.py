"""Sweeps over seeds: planning, resuming, refusing, the Ray backend, and the statistics over seeds."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import socket
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy import stats
from stable_baselines3.common.callbacks import BaseCallback

from marlander_lite.cli import main
from marlander_lite.distributed import connect_ray, map_jobs
from marlander_lite.experiments import seed_stats
from marlander_lite.training.presets import get_preset
from marlander_lite.training.provenance import policy_digest
from marlander_lite.training.sweep import (
    SWEEP_CONDITIONS,
    SWEEP_FILE,
    evaluate_sweep,
    open_sweep,
    parse_seeds,
    read_evaluation,
    run_sweep,
    seed_folder,
    write_evaluation,
)

TINY = get_preset("quick-cpu").replace(total_steps=2048, num_envs=16, batch_size=256, checkpoint_every=0)
"""Two PPO updates: seconds per seed, enough to produce a complete run folder."""


def _square(x: int) -> int:
    if x == 3:
        raise RuntimeError("three is unlucky")
    return x * x


def test_parse_seeds_ranges_lists_and_errors() -> None:
    assert parse_seeds("0-4") == (0, 1, 2, 3, 4)
    assert parse_seeds("7, 2,2") == (2, 7)
    assert parse_seeds("0-2,5") == (0, 1, 2, 5)
    for bad in ("", "a", "3-1", "-1", "1-"):
        with pytest.raises(ValueError, match="--seeds"):
            parse_seeds(bad)


def test_local_map_returns_every_result_and_each_failure() -> None:
    results = dict(map_jobs(_square, [1, 2, 3, 4], workers=2))
    assert {k: v for k, v in results.items() if k != 3} == {1: 1, 2: 4, 4: 16}
    assert isinstance(results[3], RuntimeError)
    assert dict(map_jobs(_square, [2, 3], workers=1))[2] == 4  # in-process path


def test_sweep_trains_skips_finished_seeds_and_refuses_another_config(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    first = run_sweep(TINY, [0, 1], out, preset="quick-cpu", workers=2, report=lambda _: None)
    assert [(o.seed, o.status) for o in first] == [(0, "done"), (1, "done")]
    record = json.loads((out / SWEEP_FILE).read_text())
    digest = policy_digest(seed_folder(out, 0) / "policy.safetensors")
    assert record["seeds"]["0"]["policy_digest"] == digest
    run_config = json.loads((seed_folder(out, 1) / "config.json").read_text())
    assert run_config["train"]["seed"] == 1 and run_config["provenance"]["policy_digest"]

    # Same config, overlapping seeds: the finished ones are skipped, never retrained or overwritten.
    mtime = (seed_folder(out, 0) / "policy.safetensors").stat().st_mtime_ns
    again = run_sweep(TINY, [0, 1], out, preset="quick-cpu", report=lambda _: None)
    assert [o.message for o in again] == ["already trained", "already trained"]
    assert (seed_folder(out, 0) / "policy.safetensors").stat().st_mtime_ns == mtime

    with pytest.raises(ValueError, match="differs in learning_rate"):
        run_sweep(TINY.replace(learning_rate=1e-4), [2], out, report=lambda _: None)


def test_same_seed_gives_the_same_policy_in_a_sweep_and_alone(tmp_path: Path) -> None:
    from marlander_lite.training.train import train

    run_sweep(TINY, [3], tmp_path / "sweep", report=lambda _: None)
    alone = train(TINY.replace(seed=3), tmp_path / "alone")
    assert policy_digest(alone.policy) == policy_digest(seed_folder(tmp_path / "sweep", 3) / "policy.safetensors")


def test_a_failed_seed_is_kept_aside_and_trained_again(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    open_sweep(out, TINY, "quick-cpu")
    broken = seed_folder(out, 0)
    broken.mkdir()
    (broken / "config.json").write_text("{}")  # started, never finished, no checkpoint: a crash
    (broken / "notes.txt").write_text("keep me")
    lines: list[str] = []
    (outcome,) = run_sweep(TINY, [0], out, workers=1, report=lines.append)
    assert outcome.status == "done"
    assert (out / "seed-0.failed-1" / "notes.txt").read_text() == "keep me"
    assert any("seed-0.failed-1" in line for line in lines)


def test_a_folder_that_is_not_a_sweep_is_refused(tmp_path: Path) -> None:
    (tmp_path / "precious.txt").write_text("data")
    with pytest.raises(FileExistsError, match="not a sweep folder"):
        open_sweep(tmp_path, TINY, None)


def test_sweep_command_interrupted_seed_resumes_to_the_same_policy(tmp_path: Path) -> None:
    """A seed stopped by a signal resumes on the next sweep and ends as if never stopped."""
    from marlander_lite.training.resume import RESUME_DIR
    from marlander_lite.training.train import train

    config = TINY.replace(total_steps=4096)
    out = tmp_path / "sweep"
    open_sweep(out, config, "quick-cpu")
    stop_after_first_rollout = _StopAfter(rollouts=1)
    with pytest.raises(KeyboardInterrupt):
        train(config.replace(seed=0), seed_folder(out, 0), preset="quick-cpu", callbacks=(stop_after_first_rollout,))
    assert (seed_folder(out, 0) / RESUME_DIR).is_dir()
    (outcome,) = run_sweep(config, [0], out, workers=1, report=lambda _: None)
    assert outcome.status == "done"
    alone = train(config.replace(seed=0), tmp_path / "alone", preset="quick-cpu")
    assert policy_digest(alone.policy) == policy_digest(seed_folder(out, 0) / "policy.safetensors")


class _StopAfter(BaseCallback):
    """Sends this process SIGINT (a user's Ctrl-C) at the end of rollout number ``rollouts``."""

    def __init__(self, rollouts: int) -> None:
        super().__init__()
        self.rollouts, self.seen = rollouts, 0

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        self.seen += 1
        if self.seen == self.rollouts:
            os.kill(os.getpid(), signal.SIGINT)


@pytest.fixture(scope="module")
def local_ray() -> Any:
    """A private 2-CPU Ray instance on loopback, shared by this module's Ray tests."""
    ray = pytest.importorskip("ray")
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    try:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    except Exception as error:  # Ray gives its node 30 s to start; a heavily loaded machine can miss that once
        if "timed out during startup" not in str(error):
            raise
        ray.shutdown()
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


@pytest.mark.slow
def test_ray_sweep_equals_the_local_one(tmp_path: Path, local_ray: Any) -> None:
    local = run_sweep(TINY, [0, 1], tmp_path / "local", workers=2, report=lambda _: None)
    remote = run_sweep(TINY, [0, 1], tmp_path / "ray", backend="ray", report=lambda _: None)
    assert [o.status for o in local] == [o.status for o in remote] == ["done", "done"]
    for seed in (0, 1):
        assert policy_digest(seed_folder(tmp_path / "local", seed) / "policy.safetensors") == policy_digest(
            seed_folder(tmp_path / "ray", seed) / "policy.safetensors"
        )
    record = json.loads((tmp_path / "ray" / SWEEP_FILE).read_text())
    assert set(record["seeds"]) == {"0", "1"}


@pytest.mark.slow
def test_reproduce_on_ray_flies_the_same_trials_as_locally(local_ray: Any) -> None:
    from marlander_lite.experiments.protocol import ProtocolConfig, run_protocol

    config = ProtocolConfig(
        controllers=("baseline",), conditions=("static-floor", "moving-arc-0.5"), trials=6, block_size=3
    )
    local = run_protocol(config)
    remote = run_protocol(config, backend="ray")
    assert len(local) == 12
    # repr, so that a NaN metric (e.g. no landing time) compares equal to the same NaN
    assert repr([dataclasses.asdict(r) for r in local]) == repr([dataclasses.asdict(r) for r in remote])


def test_unreachable_ray_address_fails_fast_with_a_clear_message() -> None:
    pytest.importorskip("ray")
    with socket.socket() as probe:  # a port nobody listens on: bind, read it, close
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    started = time.perf_counter()
    with pytest.raises(ValueError, match="no Ray head answers"):
        connect_ray(f"127.0.0.1:{port}")
    assert time.perf_counter() - started < 10  # not ray.init's minutes of retries
    with pytest.raises(ValueError, match="HOST:PORT"):
        connect_ray("nonsense")


def test_sweep_cli_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["sweep", "--seeds", "2-1", "--out", str(tmp_path / "s")])
    assert stop.value.code == 2
    assert "--seeds" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["sweep", "--seeds", "0", "--address", "auto", "--out", str(tmp_path / "s")])
    assert "--backend ray" in capsys.readouterr().err


# ---------------------------------------------------------------- statistics over seeds


def test_iqm_is_the_mean_of_the_middle_half() -> None:
    assert seed_stats.iqm([0, 1, 2, 3, 4, 5, 6, 100]) == pytest.approx(np.mean([2, 3, 4, 5]))


def test_single_condition_interval_matches_scipy_bootstrap_of_the_mean() -> None:
    scores = np.array([0.91, 0.95, 0.97, 0.99, 0.80])
    ours = seed_stats.estimate([scores], np.mean, seed=4)
    reference = stats.bootstrap(
        (scores,), np.mean, n_resamples=2000, method="percentile", rng=np.random.default_rng(4)
    ).confidence_interval
    assert ours.value == pytest.approx(scores.mean())
    assert (ours.low, ours.high) == pytest.approx((reference.low, reference.high))
    assert ours.low < scores.mean() < ours.high


def test_bootstrap_of_a_statistic_with_an_axis_is_the_one_resample_at_a_time_to_the_last_bit() -> None:
    """``iqm`` and ``np.mean`` take an ``axis``, so all resamples go to scipy in one call; a wrapper without one is
    called once per resample. Same resamples, same numbers, bit for bit, stratified or not."""
    rng = np.random.default_rng(7)
    strata = [rng.uniform(0, 1, 5), rng.normal(2, 1, 4), rng.uniform(0, 1, 7)]
    for statistic in (seed_stats.iqm, np.mean):
        for samples in (strata[:1], strata):
            at_once = seed_stats.estimate(samples, statistic, seed=3)
            one_by_one = seed_stats.estimate(samples, lambda x, statistic=statistic: statistic(x), seed=3)
            assert (at_once.value, at_once.low, at_once.high) == (one_by_one.value, one_by_one.low, one_by_one.high)
            assert at_once.low < at_once.value < at_once.high


def test_stratified_bootstrap_never_mixes_conditions() -> None:
    """Resampling within each condition keeps every pooled resample half 'easy', half 'hard'."""
    easy, hard = np.array([1.0, 1.0, 1.0]), np.array([0.0, 0.0, 0.0])
    pooled = seed_stats.estimate([easy, hard], np.mean)
    assert (pooled.value, pooled.low, pooled.high) == (0.5, 0.5, 0.5)


def test_performance_profile_counts_runs_above_each_threshold() -> None:
    scores = np.array([[0.2, 0.9], [0.6, 1.0]])
    assert seed_stats.performance_profile(scores, np.array([0.0, 0.5, 0.95])).tolist() == [1.0, 0.75, 0.25]


def test_profile_band_resamples_seeds_within_each_condition() -> None:
    # Condition a: both seeds land every time; condition b: one seed 0 %, the other 60 %.
    scores = np.array([[1.0, 0.0], [1.0, 0.6]])
    profile = seed_stats.profile_with_band(scores, np.array([0.5, 0.99]), ("a", "b"))
    assert profile.fraction.tolist() == [0.75, 0.5] and profile.conditions == ("a", "b")
    # Above 0.5, a always gives 2 of 4 runs and b gives 0, 1 or 2 more (both seeds drawn alike 1 time in 4):
    # the band is [0.5, 1.0]. Above 0.99 only a counts, whatever the draw: a zero-width band.
    assert profile.low.tolist() == [0.5, 0.5] and profile.high.tolist() == [1.0, 0.5]
    with pytest.raises(ValueError, match=r"\(seeds, conditions\)"):
        seed_stats.profile_with_band(np.array([0.5, 0.6]), np.array([0.5]))


def test_protocol_profile_of_a_sweep_and_its_plot_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    names = [c.name for c in SWEEP_CONDITIONS["protocol"]]
    assert len(names) == 10 and names[0] == "point mass, floor" and "point mass, arc 0.5 m/s" in names
    rows = [
        {"seed": seed, "condition": name, "episodes": 10, "success_rate": 0.9 if i < 2 else 0.1 * seed}
        for seed in (0, 1)
        for i, name in enumerate(names)
    ]
    rows.append({"seed": 2, "condition": names[0], "episodes": 10, "success_rate": 1.0})  # not flown everywhere
    for row in rows:
        row.update(landing_error_mean_cm=1.0, landing_time_mean_s=3.0, collision_rate=0.0)
    write_evaluation(tmp_path / "evaluation.csv", rows)
    seeds, conditions, scores = seed_stats.sweep_scores(tmp_path)
    assert seeds == [0, 1] and conditions == names and scores.shape == (2, 10)
    assert scores[1, 5] == pytest.approx(0.1)
    profile = seed_stats.sweep_profile(tmp_path, points=11)
    assert profile.fraction[5] == pytest.approx(4 / 20)  # above tau = 0.5: the static conditions of both seeds
    png = tmp_path / "profiles.png"
    assert main(["plot", "profiles", str(tmp_path), "--out", str(png)]) == 0 and png.stat().st_size > 0
    with pytest.raises(SystemExit):
        main(["plot", "profiles", str(tmp_path), "--out", str(png)])
    assert "already exists" in capsys.readouterr().err
    with pytest.raises(ValueError, match="allowed: success_rate"):
        seed_stats.sweep_scores(tmp_path, metric="reward")
    with pytest.raises(ValueError, match="No seed"):
        seed_stats.sweep_scores(tmp_path, conditions="quick")


def test_one_seed_has_no_interval() -> None:
    single = seed_stats.estimate([[0.9]])
    assert single.n == 1 and np.isnan(single.low) and "n = 1" in single.percent()


def test_seed_curves_and_summary_of_a_sweep(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    run_sweep(TINY, [0, 1], out, workers=2, report=lambda _: None)
    from marlander_lite.plotting import plot_training_curves

    figure = plot_training_curves([out, seed_folder(out, 0)], ["sweep", "seed 0"], ["reward"])
    legend = [t.get_text() for t in figure.axes[0].get_legend().get_texts()]
    assert legend == ["sweep (mean of 2 seeds)", "seed 0"]
    assert main(["plot", "curves", str(out), "--out", str(tmp_path / "curves.png")]) == 0
    assert (tmp_path / "curves.png").stat().st_size > 1000
    curves = seed_stats.seed_curves([seed_folder(out, 0), seed_folder(out, 1)], "reward", points=5)
    assert curves.per_seed.shape == (2, 5)
    assert np.allclose(curves.centre, curves.per_seed.mean(axis=0))  # two seeds: the mean
    assert np.all(curves.low <= curves.centre + 1e-12) and np.all(curves.centre <= curves.high + 1e-12)
    rows = [
        {
            "seed": s,
            "condition": c,
            "episodes": 10,
            "success_rate": r,
            "landing_error_mean_cm": 2.0 + s,
            "landing_time_mean_s": 3.0,
            "collision_rate": 0.0,
        }
        for s, (c, r) in enumerate([("a", 0.9), ("a", 0.7), ("b", 1.0), ("b", 0.8)])
    ]
    table = seed_stats.summary_rows(rows)
    assert [row["condition"] for row in table] == ["a", "b", "all (stratified)"]
    assert table[0]["success_mean"].value == pytest.approx(0.8)
    assert table[0]["worst_seed_success"] == 0.7
    text = seed_stats.markdown_table(table)
    assert "| a | 2 | 80.0 % [70.0, 90.0]" in text


def test_evaluation_flies_every_finished_seed_once_and_resumes(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    run_sweep(TINY, [0, 1], out, workers=2, report=lambda _: None)
    path = evaluate_sweep(out, "pointmass", episodes=20, report=lambda _: None)
    rows = read_evaluation(path)
    assert sorted((r["seed"], r["condition"]) for r in rows) == [
        (0, "point mass, elevated"),
        (0, "point mass, floor"),
        (1, "point mass, elevated"),
        (1, "point mass, floor"),
    ]
    assert all(r["episodes"] == 20 and 0.0 <= r["success_rate"] <= 1.0 for r in rows)
    # A second call flies nothing: every (seed, condition) is already there, and the file is unchanged.
    before = path.read_bytes()
    flown: list[str] = []
    evaluate_sweep(out, "pointmass", episodes=20, report=flown.append)
    assert flown == [] and path.read_bytes() == before


# ---------------------------------------------------------------- shipped artifacts that reproduce


def _ship(data: Path, name: str, run: Path) -> None:
    """Lay out ``run`` as a shipped artifact: data/policies/NAME.safetensors and data/runs/NAME/config.json."""
    (data / "policies").mkdir(parents=True, exist_ok=True)
    (data / "runs" / name).mkdir(parents=True)
    (data / "policies" / f"{name}.safetensors").write_bytes((run / "policy.safetensors").read_bytes())
    (data / "runs" / name / "config.json").write_text((run / "config.json").read_text())


def test_shipped_artifacts_are_retrained_and_compared(tmp_path: Path) -> None:
    from marlander_lite.training.shipped import check_manifest, check_shipped, shipped_artifacts, write_manifest
    from marlander_lite.training.train import train

    data = tmp_path / "data"
    _ship(data, "tiny", train(TINY, tmp_path / "tiny", preset="quick-cpu").root)
    # A policy that today's code cannot make from its config: trained with another learning rate.
    _ship(data, "edited", train(TINY.replace(learning_rate=3e-3), tmp_path / "edited", preset="quick-cpu").root)
    record = json.loads((data / "runs" / "edited" / "config.json").read_text())
    record["train"]["learning_rate"] = TINY.learning_rate
    (data / "runs" / "edited" / "config.json").write_text(json.dumps(record))
    # A fine-tune whose source stage was not shipped.
    record["train"]["init_from"] = "runs/stage-1"
    (data / "runs" / "edited-finetune").mkdir()
    (data / "runs" / "edited-finetune" / "config.json").write_text(json.dumps(record))
    (data / "policies" / "edited-finetune.safetensors").write_bytes(
        (data / "policies" / "tiny.safetensors").read_bytes()
    )

    # The same weights in a file whose description changed (as when the contract format gains a field).
    from safetensors import safe_open
    from safetensors.numpy import load_file, save_file

    _ship(data, "relabelled", tmp_path / "tiny")
    relabelled = data / "policies" / "relabelled.safetensors"
    with safe_open(str(relabelled), framework="numpy") as handle:
        metadata = {**handle.metadata(), "note": "shipped before the format gained this entry"}
    save_file(load_file(relabelled), relabelled, metadata=metadata)

    assert [a.name for a in shipped_artifacts(data)] == ["edited", "edited-finetune", "relabelled", "tiny"]
    write_manifest(data, shipped_in=lambda _: None)
    assert check_manifest(data) == []
    results = {
        r["name"]: r for r in check_shipped([], tmp_path / "check", data=data, episodes=20, report=lambda _: None)
    }
    assert results["tiny"]["status"] == "identical"
    assert results["relabelled"]["status"] == "identical weights" and "note" in results["relabelled"]["why"]
    assert results["edited"]["status"] in ("differs", "equivalent") and results["edited"]["max_weight_difference"] > 0
    assert results["edited-finetune"]["status"] == "not retrainable"
    assert "runs/stage-1" in results["edited-finetune"]["why"]
    assert json.loads((tmp_path / "check" / "report.json").read_text())[3]["status"] == "identical"

    (data / "policies" / "tiny.safetensors").write_bytes((data / "policies" / "edited.safetensors").read_bytes())
    assert check_manifest(data) == ["tiny"]  # a shipped file changed after the manifest was written
    with pytest.raises(ValueError, match="Unknown shipped artifact"):
        check_shipped(["nope"], tmp_path / "check", data=data)


def test_a_fine_tune_of_a_shipped_policy_file_is_retrained_from_that_file(tmp_path: Path) -> None:
    from marlander_lite.training.shipped import shipped_artifacts
    from marlander_lite.training.train import train

    data = tmp_path / "data"
    _ship(data, "tiny", train(TINY, tmp_path / "tiny", preset="quick-cpu").root)
    record = json.loads((data / "runs" / "tiny" / "config.json").read_text())
    for name, source in (("tuned", "data/policies/tiny.safetensors"), ("orphan", "/elsewhere/gone.safetensors")):
        record["train"]["init_from"] = source
        (data / "runs" / name).mkdir()
        (data / "runs" / name / "config.json").write_text(json.dumps(record))
        (data / "policies" / f"{name}.safetensors").write_bytes((data / "policies" / "tiny.safetensors").read_bytes())
    found = {a.name: a for a in shipped_artifacts(data)}
    assert found["tuned"].problem is None
    assert found["tuned"].config["init_from"] == str(data / "policies" / "tiny.safetensors")
    assert "gone.safetensors, which is not shipped" in found["orphan"].problem
