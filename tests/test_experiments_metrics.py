"""Metrics of the experiments: Wilson and bootstrap intervals, trial metrics of a known touchdown, cell summaries.

scipy is only an independent check here; the library computes everything in numpy.
"""

import math

import numpy as np
import pytest
from scipy import stats

from marlander_lite.episodes import LandingEpisodes
from marlander_lite.experiments.metrics import TrialMetrics, bootstrap_ci, summarise, wilson_interval
from marlander_lite.platforms import PlatformConfig
from marlander_lite.pointmass import PointMassSwarm
from marlander_lite.task import TaskConfig

# ---------------------------------------------------------------------------- Wilson


def test_wilson_interval_matches_hand_computed_values():
    # 11 of 12 (the paper's static MARLander trials), z = 1.959964, z^2 = 3.841459:
    # centre = (11/12 + z^2/24) / (1 + z^2/12) = 1.076728 / 1.320122 = 0.815628
    # half = z / 1.320122 * sqrt((11/12)(1/12)/12 + z^2/576) = 1.484684 * 0.114171 = 0.169508
    low, high = wilson_interval(11, 12)
    assert low == pytest.approx(0.815628 - 0.169508, abs=2e-6)
    assert high == pytest.approx(0.815628 + 0.169508, abs=2e-6)
    # 0 of 10: centre = half = (z^2/20) / (1 + z^2/10) = 0.138766, so (0, 0.277533)
    assert wilson_interval(0, 10) == pytest.approx((0.0, 0.277533), abs=2e-6)
    # 10 of 10 mirrors it
    assert wilson_interval(10, 10) == pytest.approx((1 - 0.277533, 1.0), abs=2e-6)


@pytest.mark.parametrize(("k", "n"), [(0, 1), (1, 1), (8, 10), (6, 10), (11, 12), (6, 8), (37, 100), (99, 100)])
def test_wilson_interval_agrees_with_scipy(k, n):
    expected = stats.binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    assert wilson_interval(k, n) == pytest.approx((expected.low, expected.high), abs=1e-12)
    expected90 = stats.binomtest(k, n).proportion_ci(confidence_level=0.9, method="wilson")
    assert wilson_interval(k, n, 0.9) == pytest.approx((expected90.low, expected90.high), abs=1e-12)


def test_wilson_interval_rejects_impossible_counts():
    with pytest.raises(ValueError, match="0 <= successes <= trials"):
        wilson_interval(5, 3)
    assert all(math.isnan(x) for x in wilson_interval(0, 0))


# ---------------------------------------------------------------------------- bootstrap


def test_bootstrap_of_a_constant_sample_is_that_constant():
    assert bootstrap_ci(np.full(20, 2.5)) == (2.5, 2.5)
    assert bootstrap_ci(np.full(20, 2.5), "median") == (2.5, 2.5)


def test_bootstrap_of_two_values_spans_the_hand_computed_quantiles():
    # A sample (0, 1): each resample's mean is 0, 0.5 or 1 with probability 1/4, 1/2, 1/4, so the
    # 2.5 % and 97.5 % quantiles of many resamples are 0 and 1.
    assert bootstrap_ci(np.array([0.0, 1.0]), n_resamples=4000, seed=1) == (0.0, 1.0)


@pytest.mark.parametrize("statistic", ["mean", "median"])
def test_bootstrap_agrees_with_scipy_percentile_bootstrap(statistic):
    sample = np.random.default_rng(3).gamma(2.0, 1.5, size=120)  # skewed, like landing errors
    ours = bootstrap_ci(sample, statistic, n_resamples=20000, seed=0)
    theirs = stats.bootstrap(
        (sample,),
        np.mean if statistic == "mean" else np.median,
        n_resamples=20000,
        method="percentile",
        random_state=np.random.default_rng(1),
    ).confidence_interval
    # Different resampling draws: agreement to a few hundredths of the sample's spread.
    tolerance = 0.03 * sample.std()
    assert ours[0] == pytest.approx(theirs.low, abs=tolerance)
    assert ours[1] == pytest.approx(theirs.high, abs=tolerance)


def test_bootstrap_is_seeded_and_resamples_trials_as_clusters():
    rng = np.random.default_rng(0)
    errors = rng.uniform(0, 5, size=(40, 2))
    errors[rng.random((40, 2)) < 0.1] = np.nan  # drones that did not land
    assert bootstrap_ci(errors, seed=5) == bootstrap_ci(errors, seed=5)
    assert bootstrap_ci(errors, seed=5) != bootstrap_ci(errors, seed=6)
    # Two identical drones per trial: a cluster bootstrap gives the interval of the per-trial
    # values, not a narrower one as if 2n independent values had been measured.
    per_trial = rng.uniform(0, 5, size=60)
    twins = np.stack([per_trial, per_trial], axis=1)
    assert bootstrap_ci(twins, seed=2) == pytest.approx(bootstrap_ci(per_trial, seed=2))
    with pytest.raises(ValueError, match="allowed: mean, median"):
        bootstrap_ci(per_trial, "mode")  # type: ignore[arg-type]


# ---------------------------------------------------------------------------- trial metrics


def test_landing_error_of_a_known_touchdown():
    """Drones released 3, 4 cm (-> 5 cm) and -6 cm (-> 6 cm) off their pad centres descend straight down."""
    task = TaskConfig(num_drones=2)
    sim = PointMassSwarm(task, PlatformConfig(kind="static-elevated"), 1)
    episodes = LandingEpisodes(sim, seed=0)
    episodes.reset()
    pads = sim.state().pad_pos[0]
    lift = task.landed_height + 0.05
    sim.place(0, pads + np.array([[0.03, 0.04, lift], [-0.06, 0.0, lift]]))
    down = np.array([[0.0, 0.0, -0.1, 0.0, 0.0, -0.1]])  # 0.3 m/s, well under the 0.5 m/s touchdown limit
    for _ in range(50):
        outcome = episodes.step(down)
        if outcome.done[0]:
            break
    metrics = TrialMetrics.from_outcome(outcome, task.dt)
    assert metrics.success and metrics.outcome == "success"
    assert metrics.landing_error_cm == pytest.approx((5.0, 6.0), abs=1e-9)
    assert metrics.landing_time_s == pytest.approx(outcome.episode_length[0] * task.dt)
    assert metrics.min_separation_m == pytest.approx(math.hypot(0.25 - 0.09, 0.04), abs=1e-9)


def test_metrics_refuse_an_unfinished_episode_and_name_failures():
    task = TaskConfig(num_drones=1)
    sim = PointMassSwarm(task, PlatformConfig(), 1)
    episodes = LandingEpisodes(sim, seed=0)
    episodes.reset()
    sim.place(0, np.array([[1.9, 1.9, 2.0]]))
    outcome = episodes.step(np.zeros((1, 3)))
    with pytest.raises(ValueError, match="not ended"):
        TrialMetrics.from_outcome(outcome, task.dt)
    for _ in range(30):  # straight out of the arena
        outcome = episodes.step(np.array([[1.0, 0.0, 0.0]]))
        if outcome.done[0]:
            break
    metrics = TrialMetrics.from_outcome(outcome, task.dt)
    assert metrics.outcome == "out-of-arena" and not metrics.success
    assert math.isnan(metrics.landing_error_cm[0]) and math.isnan(metrics.landing_time_s)


def _trial(outcome, errors, time_s=math.nan, separation=0.3):
    landed = tuple(not math.isnan(e) for e in errors)
    return TrialMetrics(outcome, landed, tuple(errors), time_s, separation, 10.0)


def test_cell_summary_by_hand():
    trials = [
        _trial("success", (1.0, 3.0), 10.0),
        _trial("success", (2.0, 4.0), 14.0, separation=0.2),
        _trial("crash", (5.0, math.nan)),
        _trial("collision", (math.nan, math.nan), separation=0.1),
    ]
    s = summarise(trials, seed=0)
    assert (s.trials, s.successes, s.success_rate) == (4, 2, 0.5)
    assert (s.success_low, s.success_high) == pytest.approx(wilson_interval(2, 4))
    assert s.landed_drones == 5
    assert s.error_mean_cm == pytest.approx((1 + 3 + 2 + 4 + 5) / 5)
    assert s.error_median_cm == pytest.approx(3.0)
    assert s.error_per_drone_cm == pytest.approx(((1 + 2 + 5) / 3, (3 + 4) / 2))
    assert s.time_mean_s == pytest.approx(12.0)  # successful trials only
    assert s.min_separation_m == pytest.approx(0.1)
    assert s.outcome_counts == {"success": 2, "collision": 1, "crash": 1, "out-of-arena": 0, "timeout": 0}
    assert s.error_mean_low <= s.error_mean_cm <= s.error_mean_high
    assert summarise(trials, seed=0) == s
