"""End-to-end PPO training throughput: environment steps per second, PPO updates included.

Runs the ``paper`` preset's PPO (its 512-512-256-128 policy network, its batch sizes) for a few
rollouts on the point-mass simulator and on the PyBullet Crazyflie simulator, through the same
``marlander_lite.training.train`` code path as ``marlander train``, and prints steps per second
(median of ``--repeats`` runs measured in this one process) and what the 20 M steps of the
paper's training would take at that rate. The ``quick-cpu`` preset is timed too.

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
from pathlib import Path

import torch

from marlander_lite.training.presets import get_preset
from marlander_lite.training.train import train

REFERENCE_STEPS_PER_S = 350.0


def steps_per_second(preset: str, simulator: str, rollouts: int, **changes: object) -> float:
    config = get_preset(preset).replace(simulator=simulator, checkpoint_every=0, **changes)
    config = config.replace(total_steps=rollouts * config.num_envs * config.n_steps)
    with tempfile.TemporaryDirectory() as folder:
        files = train(config, Path(folder) / "run")
        finished = json.loads(files.config.read_text())["finished"]
    return finished["steps"] / finished["seconds"]


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
    print(f"{'preset':<10} {'simulator':<10} {'steps/s':>9} {'x 350':>7} {'20 M steps take':>16}")
    for preset, simulator, rollouts, changes in cases:
        runs = [steps_per_second(preset, simulator, rollouts, **changes) for _ in range(args.repeats)]
        rate = statistics.median(runs)
        hours = 20e6 / rate / 3600
        print(f"{preset:<10} {simulator:<10} {rate:>9.0f} {rate / REFERENCE_STEPS_PER_S:>7.1f} {hours:>14.1f} h")
    print("Target: paper preset on the point-mass >= 7,000 steps/s (20x the reference).")


if __name__ == "__main__":
    main()
