"""End-to-end PPO training throughput: environment steps per second, PPO updates included.

Runs the ``paper`` preset's PPO (its 512-512-256-128 policy network, its batch sizes) for a few
rollouts on the point-mass simulator and on the PyBullet Crazyflie simulator, through the same
``marlander_lite.training.train`` code path as ``marlander train``, and prints steps per second
(median of ``--repeats`` runs measured in this one process) and what the 20 M steps of the
paper's training would take at that rate. The ``quick-cpu`` preset is timed too. On the point mass it also
prints the share of the training's time spent in the env's step (``LandingVecEnv.step_wait``, resets
included), which says how much a faster simulator could still save.

Reference: SB3 PPO on the nearest toolkit's 2-drone env runs about 350 steps/s on this kind of
2-core machine; the target for the point-mass is at least 20x that (7,000 steps/s), so that the
paper preset's 20 M steps fit in well under 2 hours.

    python benchmarks/bench_training.py [--repeats 3] [--skip-crazyflie]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import torch

from marlander_lite.envs.vec_env import LandingVecEnv
from marlander_lite.training.presets import get_preset
from marlander_lite.training.train import train

REFERENCE_STEPS_PER_S = 350.0


@contextmanager
def timing_env_steps() -> Iterator[list[float]]:
    """Seconds spent in ``LandingVecEnv.step_wait`` (the point-mass env's step, resets included) while inside."""
    spent = [0.0]
    original = LandingVecEnv.step_wait

    def timed(self: LandingVecEnv) -> object:
        start = time.perf_counter()
        try:
            return original(self)
        finally:
            spent[0] += time.perf_counter() - start

    LandingVecEnv.step_wait = timed  # type: ignore[method-assign]
    try:
        yield spent
    finally:
        LandingVecEnv.step_wait = original  # type: ignore[method-assign]


def steps_per_second(preset: str, simulator: str, rollouts: int, **changes: object) -> tuple[float, float]:
    """Training steps per second, and the share of the training's time spent in the env's step (in-process envs)."""
    config = get_preset(preset).replace(simulator=simulator, checkpoint_every=0, **changes)
    config = config.replace(total_steps=rollouts * config.num_envs * config.n_steps)
    with tempfile.TemporaryDirectory() as folder, timing_env_steps() as spent:
        files = train(config, Path(folder) / "run")
        finished = json.loads(files.config.read_text())["finished"]
    return finished["steps"] / finished["seconds"], spent[0] / finished["seconds"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--skip-crazyflie", action="store_true")
    args = parser.parse_args()
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads; medians of {args.repeats} runs")
    cases = [
        ("paper", "pointmass", 4, {}),
        ("quick-cpu", "pointmass", 8, {}),
    ]
    if not args.skip_crazyflie:
        # Two PyBullet worlds in subprocesses; the rollout is kept short so a run takes about a minute.
        cases.append(("paper", "crazyflie", 2, {"num_envs": 2, "n_steps": 1024, "batch_size": 1024, "dynamics": {}}))
    print(f"{'preset':<10} {'simulator':<10} {'steps/s':>9} {'x 350':>7} {'20 M steps take':>16} {'env step':>9}")
    for preset, simulator, rollouts, changes in cases:
        runs = [steps_per_second(preset, simulator, rollouts, **changes) for _ in range(args.repeats)]
        rate = statistics.median(rate for rate, _ in runs)
        share = statistics.median(share for _, share in runs)
        hours = 20e6 / rate / 3600
        shown = f"{100 * share:>8.1f}%" if simulator == "pointmass" else f"{'-':>9}"  # PyBullet's run in subprocesses
        print(
            f"{preset:<10} {simulator:<10} {rate:>9.0f} {rate / REFERENCE_STEPS_PER_S:>7.1f} {hours:>14.1f} h {shown}"
        )
    print("Target: paper preset on the point-mass >= 7,000 steps/s (20x the reference).")
    print("env step: share of the training's time in the point-mass VecEnv's step (resets included); PPO is the rest.")


if __name__ == "__main__":
    main()
