"""Does the local sweep backend keep every core busy? Four seeds one after another, then side by side.

Trains the same four short ``quick-cpu`` seeds twice with :func:`marlander_lite.training.sweep.run_sweep`:
with ``workers=1`` (one after another, in this process) and with ``workers=2`` (two processes at a time, one
torch thread each). On an idle 2-core machine the second should take about half the wall time of the first.
Prints both wall times and their ratio, and checks that both gave the same policies.

    python benchmarks/bench_sweep.py [--steps 200000]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from marlander_lite.training.presets import get_preset
from marlander_lite.training.provenance import policy_digest
from marlander_lite.training.sweep import run_sweep, seed_folder

SEEDS = (0, 1, 2, 3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200_000, help="environment steps per seed")
    args = parser.parse_args()
    config = get_preset("quick-cpu").replace(total_steps=args.steps, checkpoint_every=0)
    walls, digests = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for workers in (1, 2):
            out = Path(tmp) / f"workers-{workers}"
            started = time.perf_counter()
            run_sweep(config, SEEDS, out, preset="quick-cpu", workers=workers, report=lambda _: None)
            walls[workers] = time.perf_counter() - started
            digests[workers] = [policy_digest(seed_folder(out, s) / "policy.safetensors") for s in SEEDS]
    print(f"4 seeds x {args.steps:,} steps of quick-cpu (torch_threads={config.torch_threads})")
    print(f"one after another (workers=1): {walls[1]:7.1f} s")
    print(f"two at a time     (workers=2): {walls[2]:7.1f} s")
    print(f"ratio: {walls[2] / walls[1]:.2f} (ideal on 2 idle cores: 0.50)")
    print(f"same policies either way: {digests[1] == digests[2]}")


if __name__ == "__main__":
    main()
