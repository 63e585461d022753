"""A quick preset end to end: wall time to train, then how well the policy lands.

Target (issue 4): a policy that lands 2 drones on a static pad in the point-mass env with at least
95 % success and at most 2.26 cm mean landing error (the paper's Table I precision), in at most
10 minutes of wall time on 2 cores; faster is better (2 minutes is the aspiration). Issue 10 asks the
same of every column of the transfer matrix: fly the kept run with ``marlander transfer``.

Training is deterministic with a seed, so every run of this script trains the same policy; the
wall time is what varies with the machine. Evaluation: 1000 episodes per platform on the paper's
uniform random starts (training aids off), with and without the motion-capture noise model.

    python benchmarks/bench_quick_cpu.py [--preset quick-cpu-smooth|quick-cpu-slow-trackers|quick-cpu] [--seed 0]
        [--episodes 1000] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from marlander_lite.training.commands import QUICKSTART_PRESETS
from marlander_lite.training.evaluation import evaluate_policy_file
from marlander_lite.training.presets import get_preset
from marlander_lite.training.train import train

TARGET_SUCCESS, TARGET_ERROR_CM, TARGET_MINUTES = 0.95, 2.26, 10.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", choices=QUICKSTART_PRESETS, default=QUICKSTART_PRESETS[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--keep", type=Path, default=None, help="train into this new run folder and keep it")
    args = parser.parse_args()
    config = get_preset(args.preset).replace(seed=args.seed)
    with tempfile.TemporaryDirectory() as folder:
        started = time.perf_counter()
        files = train(config, args.keep or Path(folder) / args.preset, preset=args.preset)
        minutes = (time.perf_counter() - started) / 60
        steps = json.loads(files.config.read_text())["finished"]["steps"]
        rate = steps / minutes / 60
        print(
            f"{args.preset}, seed {args.seed}, {config.torch_threads} torch thread(s): {steps:,} steps in "
            f"{minutes:.2f} min ({rate:,.0f} steps/s)"
        )
        floor = None
        for platform in ("static-floor", "static-elevated"):
            for sensing in ("perfect", "vicon"):
                summary = evaluate_policy_file(files.policy, episodes=args.episodes, platform=platform, sensing=sensing)
                print(f"  {platform:16} {sensing:8} {summary}")
                if (platform, sensing) == ("static-floor", "perfect"):
                    floor = summary
    assert floor is not None
    met = (
        floor.success_rate >= TARGET_SUCCESS
        and floor.landing_error_mean_cm <= TARGET_ERROR_CM
        and minutes <= TARGET_MINUTES
    )
    print(
        f"Target (floor): success >= {100 * TARGET_SUCCESS:.0f} %, error <= {TARGET_ERROR_CM} cm, "
        f"<= {TARGET_MINUTES:.0f} min: {'met' if met else 'NOT met'}"
    )


if __name__ == "__main__":
    main()
