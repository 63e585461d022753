"""Two checkouts of marlander_lite, the point-mass VecEnv step of each, taking turns: which is faster, and by how much.

``bench_pointmass.py`` compares the two engines of one checkout. A code change is judged against the code before it,
on the same machine at the same time: this script runs the same measurement for ``--base`` and ``--new`` (two
directories holding the repository, e.g. ``git worktree add /tmp/base HEAD~1``) in alternating subprocesses, so that a
background load hits both alike, and prints the median million drone-steps per CPU second of each and their ratio.
Random actions with automatic resets, the numba engine, 4096 envs x 2 drones and 1024 x 16.

    python benchmarks/bench_pointmass_ab.py --base /tmp/base --new . [--rounds 5]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
from pathlib import Path

SIZES = ((4096, 2), (1024, 16))
MEASURE = r"""
import sys, time
import numpy as np
sys.path.insert(0, sys.argv[1])
import marlander_lite
assert marlander_lite.__file__.startswith(sys.argv[1]), marlander_lite.__file__
envs, drones = int(sys.argv[2]), int(sys.argv[3])
env = marlander_lite.make_vec_env("pointmass", num_envs=envs, num_drones=drones, seed=0, engine="numba")
env.reset()
actions = np.random.default_rng(0).uniform(-1, 1, (16, envs, 3 * drones)).astype(np.float32)
for i in range(10):
    env.step(actions[i % 16])
runs = []
for _ in range(5):
    start = time.process_time()
    for i in range(60):
        env.step(actions[i % 16])
    runs.append((time.process_time() - start) / 60)
print(envs * drones / sorted(runs)[2] / 1e6)
"""


def run_measurement(checkout: Path, code: str, *args: str) -> str:
    """What ``code`` prints (``python -c code CHECKOUT ARGS...``), run in a fresh process for ``checkout``."""
    done = subprocess.run(
        [sys.executable, "-c", code, str(checkout), *args], capture_output=True, text=True, cwd="/", check=False
    )
    if done.returncode:
        raise SystemExit(f"measuring {checkout} failed:\n{done.stderr[-2000:]}")
    return done.stdout


def parse_checkouts(description: str, rounds: int) -> tuple[dict[str, Path], int]:
    """The command line of an A/B script: ``{"base": path, "new": path}`` (each holding the package) and the rounds."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--base", type=Path, required=True, help="the checkout before the change")
    parser.add_argument("--new", type=Path, default=Path("."), help="the checkout with the change (default: here)")
    parser.add_argument("--rounds", type=int, default=rounds)
    args = parser.parse_args()
    checkouts = {"base": args.base.resolve(), "new": args.new.resolve()}
    for path in checkouts.values():
        if not (path / "marlander_lite" / "__init__.py").is_file():
            parser.error(f"{path} holds no marlander_lite package")
    return checkouts, args.rounds


def drone_steps_per_second(checkout: Path, envs: int, drones: int) -> float:
    """Million drone-steps per CPU second of ``checkout``'s VecEnv (median of 5 x 60 steps), in a fresh process."""
    return float(run_measurement(checkout, MEASURE, str(envs), str(drones)))


def main() -> None:
    checkouts, rounds = parse_checkouts(__doc__.splitlines()[0], rounds=5)
    for envs, drones in SIZES:
        rates: dict[str, list[float]] = {name: [] for name in checkouts}
        for _ in range(rounds):
            for name, path in checkouts.items():
                rates[name].append(drone_steps_per_second(path, envs, drones))
        base, new = (statistics.median(rates[name]) for name in checkouts)
        print(
            f"{envs} x {drones}: base {base:.2f}, new {new:.2f} M drone-steps per CPU second (medians of "
            f"{rounds}), new / base {new / base:.2f}"
        )


if __name__ == "__main__":
    main()
