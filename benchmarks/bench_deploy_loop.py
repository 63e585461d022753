"""Latency of one deployment-loop tick for 2 drones: observation + policy + safety (target: under 1 ms).

Times, per tick, what the control station computes between receiving a motion-capture frame and
sending the setpoints (paper Sec. III-A): the estimator update (finite-difference velocities,
pad goals, data ages), the eq. 2 observation, the exported policy with the paper's network
(512-512-256-128 ReLU, numpy inference from a safetensors file), the speed clamp and the safety
rules. Poses are synthetic (two drones circling above a plate, 1 mm noise, 48 Hz).

It then times whole loop ticks of a rehearsal (point-mass physics excluded): the above plus the
simulated mocap, cflib building the ``send_extpose`` and velocity packets and the virtual firmware
decoding them, and the JSON flight-log line.

Run: ``python benchmarks/bench_deploy_loop.py [--ticks 5000] [--repeats 3]``. Prints medians and
95th percentiles; the host's speed varies, so compare runs side by side.
"""

from __future__ import annotations

import argparse
import itertools
import tempfile
import time
from pathlib import Path

import numpy as np

from marlander_lite.deploy.config import EXAMPLE_CONFIG, load_lab_config
from marlander_lite.deploy.estimation import SwarmEstimator
from marlander_lite.deploy.pose_sources import PoseFrame
from marlander_lite.deploy.rehearsal import rehearse
from marlander_lite.deploy.runner import PolicyRunner
from marlander_lite.deploy.safety import SafetyMonitor
from marlander_lite.policy_file import PolicyContract, load_policy, save_policy

PAPER_HIDDEN = (512, 512, 256, 128)


def paper_policy(path: Path, num_drones: int, hidden: tuple[int, ...] = PAPER_HIDDEN, seed: int = 0) -> Path:
    """A policy file with the paper's architecture and random weights (He initialisation)."""
    rng = np.random.default_rng(seed)
    sizes = [13 * num_drones, *hidden, 3 * num_drones]
    tensors = {}
    for i, (n_in, n_out) in enumerate(itertools.pairwise(sizes)):
        tensors[f"actor.{i}.weight"] = rng.normal(0.0, np.sqrt(2.0 / n_in), (n_out, n_in))
        tensors[f"actor.{i}.bias"] = np.zeros(n_out)
    contract = PolicyContract(
        num_drones=num_drones,
        max_speed=3.0,
        policy_hz=24.0,
        activation="relu",
        hidden_sizes=hidden,
        normalize_observations=False,
    )
    return save_policy(path, contract, tensors)


def synthetic_frames(names: list[str], ticks: int, hz: float, seed: int = 0) -> list[PoseFrame]:
    """Drones circling 1 m above a plate at the origin; 1 mm position noise."""
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(ticks):
        t = k / hz
        bodies = {"plate": np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])}
        for i, name in enumerate(names[:-1] if names[-1] == "plate" else names):
            phase = t + i * np.pi
            pos = np.array([0.5 * np.cos(phase), 0.5 * np.sin(phase), 1.0]) + rng.normal(0, 0.001, 3)
            bodies[name] = np.concatenate((pos, [0.0, 0.0, np.sin(0.05), np.cos(0.05)]))
        frames.append(PoseFrame(t=t, bodies=bodies))
    return frames


def bench_core(ticks: int, policy_path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Per-tick wall time and CPU time (ms) of estimator + observation + policy + clamp + safety.

    On a shared machine the wall time also holds the waits for a free core; the thread's CPU time
    does not.
    """
    lab = load_lab_config(EXAMPLE_CONFIG)
    task = lab.task_config()
    runner = PolicyRunner(load_policy(policy_path, task), task, lab.limits.max_speed)
    estimator = SwarmEstimator(lab, landed_height=task.landed_height)
    safety = SafetyMonitor(lab)
    frames = synthetic_frames([*lab.drone_names, "plate"], ticks, lab.rates.loop_hz)
    flying = np.ones(lab.num_drones, dtype=bool)
    times, cpu = np.empty(ticks), np.empty(ticks)
    for k, frame in enumerate(frames):
        start, start_cpu = time.perf_counter(), time.thread_time()
        estimator.ingest([frame])
        est = estimator.estimate(frame.t)
        obs = runner.observe(est)
        _, velocity = runner.act(obs)
        verdict = safety.flight(frame.t, est, flying, action_ok=True)
        times[k], cpu[k] = time.perf_counter() - start, time.thread_time() - start_cpu
    assert verdict.action == "fly" and np.isfinite(velocity).all()
    return times[50:] * 1000.0, cpu[50:] * 1000.0  # skip the warm-up


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=5000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        policy_path = paper_policy(Path(tmp) / "paper.safetensors", num_drones=2)
        print(f"Core tick (estimate + observation + policy {PAPER_HIDDEN} + safety), 2 drones, {args.ticks} ticks:")
        for r in range(args.repeats):
            ms, cpu = bench_core(args.ticks, policy_path)
            print(
                f"  run {r + 1}: wall median {np.median(ms) * 1000:.0f} us, p95 {np.percentile(ms, 95) * 1000:.0f} us, "
                f"max {ms.max():.2f} ms | CPU median {np.median(cpu) * 1000:.0f} us, "
                f"p95 {np.percentile(cpu, 95) * 1000:.0f} us"
            )
        lab = load_lab_config(EXAMPLE_CONFIG)
        print("Whole loop tick in a point-mass rehearsal (+ simulated mocap, cflib packets, virtual firmware, log):")
        for r in range(args.repeats):
            result = rehearse(lab, policy_path, simulator="pointmass", log_path=Path(tmp) / f"log{r}.jsonl")
            m = result.mission
            print(
                f"  run {r + 1}: median {m.loop_ms_median * 1000:.0f} us, p95 {m.loop_ms_p95 * 1000:.0f} us, "
                f"max {m.loop_ms_max:.2f} ms over {m.ticks} ticks"
            )


if __name__ == "__main__":
    main()
