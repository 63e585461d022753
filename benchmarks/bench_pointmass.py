"""Point-mass swarm throughput: drone-steps per second of the batched SB3 VecEnv.

For num_envs in {1, 256, 4096} and num_drones in {2, 8} it times ``PointMassVecEnv.step`` with
random actions (so episodes end and auto-reset as in training) and compares it with a bare numpy
loop doing only the integration (first-order lag, acceleration cap, position update) on arrays
of the same size. Target: at least 5 million drone-steps/s with 4096 envs x 2 drones on 2 cores.

Each figure is the median of ``--repeats`` timed runs measured in this one process; the machine
may be shared, so compare numbers from one run with each other, not across runs.

Observations come back as a row-major ``(num_envs, 13 N)`` float32 array (the simulator computes in Fortran
order internally and converts once); the ``+C copy`` column adds ``np.ascontiguousarray``, which is now free.

    python benchmarks/bench_pointmass.py [--repeats 5] [--steps-scale 1.0]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import marlander_lite


def time_env(num_envs: int, num_drones: int, steps: int, contiguous: bool, hover: bool = False) -> tuple[float, float]:
    """Seconds per ``VecEnv.step`` and episodes ended per step; ``hover`` sends zero velocities (no resets)."""
    env = marlander_lite.make_vec_env("pointmass", num_envs=num_envs, num_drones=num_drones, seed=0)
    env.reset()
    actions = np.random.default_rng(0).uniform(-1, 1, (16, num_envs, 3 * num_drones)).astype(np.float32)
    if hover:
        actions[:] = 0.0
    for i in range(5):
        env.step(actions[i])
    ended = 0
    start = time.perf_counter()
    for i in range(steps):
        obs, _, done, _ = env.step(actions[i % 16])
        if contiguous:
            obs = np.ascontiguousarray(obs)
        ended += int(done.sum())
    seconds = time.perf_counter() - start
    return seconds / steps, ended / steps


def time_bare_integration(num_envs: int, num_drones: int, steps: int) -> float:
    """Only the point-mass update, on preallocated arrays: the floor any batched env sits on."""
    vel = np.zeros((num_envs, num_drones, 3), order="F")
    pos = np.zeros_like(vel)
    cmd = np.asfortranarray(np.random.default_rng(0).uniform(-3, 3, vel.shape))
    blend, max_dv, dt = 0.56, 4.07 / 24, 1 / 24
    start = time.perf_counter()
    for _ in range(steps):
        dv = (cmd - vel) * blend
        norm = np.sqrt(dv[..., 0] ** 2 + dv[..., 1] ** 2 + dv[..., 2] ** 2)
        dv *= np.minimum(1.0, max_dv / np.maximum(norm, 1e-12))[..., None]
        pos += (vel + 0.5 * dv) * dt
        vel += dv
    return (time.perf_counter() - start) / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--steps-scale", type=float, default=1.0, help="scale the number of timed steps")
    args = parser.parse_args()
    print(f"marlander_lite {marlander_lite.__version__}, numpy {np.__version__}; medians of {args.repeats} runs")
    header = (
        f"{'envs':>5} {'drones':>6} {'step ms':>8} {'M drone-steps/s':>16} {'+C copy':>8} "
        f"{'bare ms':>8} {'env/bare':>8} {'resets/step':>11} {'hover M/s':>9}"
    )
    print(header)
    for num_envs in (1, 256, 4096):
        for num_drones in (2, 8):
            steps = max(30, int(args.steps_scale * 40_000 / num_envs))
            env_runs = [time_env(num_envs, num_drones, steps, False) for _ in range(args.repeats)]
            copy_runs = [time_env(num_envs, num_drones, steps, True)[0] for _ in range(args.repeats)]
            bare_runs = [time_bare_integration(num_envs, num_drones, steps) for _ in range(args.repeats)]
            hover_runs = [time_env(num_envs, num_drones, steps, False, hover=True)[0] for _ in range(args.repeats)]
            step = statistics.median(r[0] for r in env_runs)
            resets = statistics.median(r[1] for r in env_runs)
            with_copy = statistics.median(copy_runs)
            bare = statistics.median(bare_runs)
            rate = num_envs * num_drones / step / 1e6
            copy_rate = num_envs * num_drones / with_copy / 1e6
            hover_rate = num_envs * num_drones / statistics.median(hover_runs) / 1e6
            print(
                f"{num_envs:>5} {num_drones:>6} {1e3 * step:>8.3f} {rate:>16.2f} "
                f"{copy_rate:>8.2f} {1e3 * bare:>8.3f} {step / bare:>8.1f} {resets:>11.1f} {hover_rate:>9.2f}"
            )
    print("Random actions in [-1, 1] crash drones often, so episodes end and reset every step (resets/step);")
    print("'hover M/s' sends zero velocities: no episode ends before the time limit, the simulator's own cost.")
    print("Target: >= 5 M drone-steps/s at 4096 envs x 2 drones.")


if __name__ == "__main__":
    main()
