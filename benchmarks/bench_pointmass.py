"""Point-mass swarm throughput: drone-steps per second of the batched SB3 VecEnv, numpy vs numba engine.

For 4096 envs x 2 drones and 1024 envs x 16 drones it times ``PointMassVecEnv.step`` with random
actions (so episodes end and auto-reset as in training) on both engines of
:mod:`marlander_lite.pointmass.kernels`: ``numpy`` (the reference: simulator and ``task.min_separation``
in plain numpy) and ``numba`` (the compiled kernels, the same results bit for bit). Target (issue 13):
at least 5 million drone-steps/s at both sizes.

Each figure is the median of ``--repeats`` timed runs, the engines taking turns within this one process,
so that a background load hits both alike. Two clocks: wall time (``perf_counter``), what training sees,
and CPU time of this process (``process_time``), far less sensitive to other processes on a shared machine.
The ratio column is numba over numpy, measured in this run. The first line reports what the first numba
step costs in this process: the compile on a machine's first run, loading numba's disk cache afterwards.
The last lines time the starting-position sampler alone (``task.sample_spawn_positions`` for as many swarms as
a step resets): the numpy reference's rejection loop against the compiled one, which draws the same numbers.

    python benchmarks/bench_pointmass.py [--repeats 5] [--steps-scale 1.0]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
import timeit

import numpy as np

import marlander_lite
from marlander_lite.pointmass import kernels
from marlander_lite.task import TaskConfig, sample_spawn_positions

SIZES = ((4096, 2), (1024, 16))


def make_env(num_envs: int, num_drones: int, engine: str):
    # min_separation (called by the MDP, not the simulator) follows the environment variable.
    os.environ[kernels.ENGINE_VARIABLE] = engine
    env = marlander_lite.make_vec_env("pointmass", num_envs=num_envs, num_drones=num_drones, seed=0, engine=engine)
    env.reset()
    return env


def time_env(num_envs: int, num_drones: int, steps: int, engine: str) -> tuple[float, float, float]:
    """Wall and CPU seconds per ``VecEnv.step`` and episodes ended per step."""
    env = make_env(num_envs, num_drones, engine)
    actions = np.random.default_rng(0).uniform(-1, 1, (16, num_envs, 3 * num_drones)).astype(np.float32)
    for i in range(5):
        env.step(actions[i])
    ended = 0
    wall, cpu = time.perf_counter(), time.process_time()
    for i in range(steps):
        _, _, done, _ = env.step(actions[i % 16])
        ended += int(done.sum())
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return wall / steps, cpu / steps, ended / steps


def first_step_seconds() -> float:
    """Seconds of the first reset + step with numba in this process (compile, or cache load)."""
    start = time.perf_counter()
    for num_envs, num_drones in SIZES:
        make_env(num_envs, num_drones, "numba").step(np.zeros((num_envs, 3 * num_drones), np.float32))
    return time.perf_counter() - start


def spawn_milliseconds(num_drones: int, swarms: int, engine: str, repeats: int) -> float:
    """Best of ``repeats`` mean times (ms) of one ``sample_spawn_positions`` call for ``swarms`` swarms."""
    os.environ[kernels.ENGINE_VARIABLE] = engine
    config, plate_top, rng = TaskConfig(num_drones=num_drones), np.zeros(swarms), np.random.default_rng(0)
    sample_spawn_positions(rng, plate_top, config)  # compile or load the cache first
    runs = timeit.repeat(lambda: sample_spawn_positions(rng, plate_top, config), number=20, repeat=repeats)
    return 1e3 * min(runs) / 20


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--steps-scale", type=float, default=1.0, help="scale the number of timed steps")
    args = parser.parse_args()
    engines = ["numpy", "numba"] if kernels.numba_available() else ["numpy"]
    print(
        f"marlander_lite {marlander_lite.__version__}, numpy {np.__version__}, numba "
        f"{kernels.numba.__version__ if kernels.numba else 'not installed'}; medians of {args.repeats} runs"
    )
    if kernels.numba_available():
        print(f"first numba reset + step in this process (compile or cache load): {first_step_seconds():.2f} s")
    print(
        f"{'envs':>5} {'drones':>6} {'engine':>6} {'wall ms':>8} {'wall M/s':>9} {'CPU ms':>7} {'CPU M/s':>8} "
        f"{'resets/step':>11}"
    )
    for num_envs, num_drones in SIZES:
        steps = max(30, int(args.steps_scale * 100_000 / num_envs))
        runs: dict[str, list[tuple[float, float, float]]] = {engine: [] for engine in engines}
        for _ in range(args.repeats):
            for engine in engines:
                runs[engine].append(time_env(num_envs, num_drones, steps, engine))
        rates = {}
        for engine in engines:
            wall, cpu, resets = (statistics.median(r[i] for r in runs[engine]) for i in range(3))
            drone_steps = num_envs * num_drones
            rates[engine] = (drone_steps / wall / 1e6, drone_steps / cpu / 1e6)
            print(
                f"{num_envs:>5} {num_drones:>6} {engine:>6} {1e3 * wall:>8.3f} {rates[engine][0]:>9.2f} "
                f"{1e3 * cpu:>7.3f} {rates[engine][1]:>8.2f} {resets:>11.1f}"
            )
        if len(engines) == 2:
            wall_ratio, cpu_ratio = (rates["numba"][i] / rates["numpy"][i] for i in range(2))
            print(f"{'':>13}numba / numpy: {wall_ratio:.2f}x wall, {cpu_ratio:.2f}x CPU")
    print("M/s: million drone-steps per second (envs x drones / step time). Target: >= 5 at both sizes.")
    if len(engines) == 2:
        print("starting positions for 100 swarms (one step's resets), best of the runs, ms per call:")
        for num_drones in (2, 8, 16):
            times = {engine: spawn_milliseconds(num_drones, 100, engine, args.repeats) for engine in engines}
            print(
                f"  {num_drones:>2} drones: numpy {times['numpy']:.3f}, numba {times['numba']:.3f} "
                f"({times['numpy'] / times['numba']:.1f}x)"
            )


if __name__ == "__main__":
    main()
