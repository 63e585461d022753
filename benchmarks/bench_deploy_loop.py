"""Latency of one deployment-loop tick for N drones: estimate + observation + policy + filter + safety (N = 16 < 2 ms).

Times, per tick, what the control station computes between receiving a motion-capture frame and
sending the setpoints (paper Sec. III-A): the estimator update (finite-difference velocities,
pad goals, data ages), the observation, the exported policy (numpy inference from a safetensors
file), the speed clamp, the safety filter (``swarm/safety_filter.py``, on by default in the lab config) and
the safety rules. Poses are synthetic (N drones circling above a plate
whose pads are the simulators' grid, 1 mm noise, 48 Hz). Policies, at N = 2, 8 and 16:

* ``centralised``: the paper's network (512-512-256-128 ReLU, random weights) on every drone's eq. 2
  observation flattened (``13 N`` in, ``3 N`` out); it is trained for one N, so it is timed with one file
  per N (the paper flies N = 2);
* ``shared``: the shipped ``data/policies/shared-quick-local.safetensors`` (128-128), each drone's eq. 2
  observation plus its 3 nearest neighbours (``marlander_lite.swarm.observation``), one forward pass over
  the ``(N, 34)`` batch;
* ``shared-paper``: the same input through the paper's 512-512-256-128 network (random weights): what a
  shared policy as large as the paper's costs.

It then times whole loop ticks of point-mass rehearsals (physics excluded): the above plus the
simulated mocap, cflib building the ``send_extpose`` and velocity packets and the virtual firmware
decoding them, and the JSON flight-log line, for the 2-drone example with the centralised network and
the 8-drone example with the shared policy.

Run: ``python benchmarks/bench_deploy_loop.py [--ticks 3000] [--repeats 3] [--sizes 2 8 16]``. Prints
medians and 95th percentiles of wall time and of the thread's CPU time; the host's speed varies, so
compare runs side by side.
"""

from __future__ import annotations

import argparse
import itertools
import tempfile
import time
from pathlib import Path

import numpy as np

from marlander_lite.deploy.config import EXAMPLE_CONFIG, EXAMPLE_CONFIG_8, LabConfig, load_lab_config, load_lab_policy
from marlander_lite.deploy.estimation import SwarmEstimator
from marlander_lite.deploy.pose_sources import PoseFrame
from marlander_lite.deploy.rehearsal import rehearse
from marlander_lite.deploy.runner import PolicyRunner
from marlander_lite.deploy.safety import SafetyMonitor
from marlander_lite.deploy.sections import SafetyFilterSection
from marlander_lite.policy_file import NEIGHBOUR_FEATURES, PolicyContract, save_policy
from marlander_lite.task import OBS_PER_DRONE

PAPER_HIDDEN = (512, 512, 256, 128)
SHARED_POLICY = Path(__file__).resolve().parents[1] / "data/policies/shared-quick-local.safetensors"


def paper_policy(
    path: Path, num_drones: int | None, hidden: tuple[int, ...] = PAPER_HIDDEN, seed: int = 0, neighbours: int = 3
) -> Path:
    """A policy file with the paper's architecture and random weights (He initialisation): centralised for
    ``num_drones`` drones, or shared (``num_drones=None``, ``neighbours`` nearest neighbours, 0.2 m range)."""
    rng = np.random.default_rng(seed)
    if num_drones is None:
        sizes = [OBS_PER_DRONE + NEIGHBOUR_FEATURES * neighbours, *hidden, 3]
    else:
        sizes = [13 * num_drones, *hidden, 3 * num_drones]
    tensors = {}
    for i, (n_in, n_out) in enumerate(itertools.pairwise(sizes)):
        tensors[f"actor.{i}.weight"] = rng.normal(0.0, np.sqrt(2.0 / n_in), (n_out, n_in))
        tensors[f"actor.{i}.bias"] = np.zeros(n_out)
    shared = num_drones is None
    contract = PolicyContract(
        num_drones=num_drones,
        max_speed=3.0,
        policy_hz=24.0,
        activation="relu",
        hidden_sizes=hidden,
        normalize_observations=False,
        neighbours=neighbours if shared else None,
        neighbour_radius=0.2 if shared else None,
    )
    return save_policy(path, contract, tensors)


def synthetic_frames(names: list[str], ticks: int, hz: float, seed: int = 0) -> list[PoseFrame]:
    """Drones circling 1 m above a plate at the origin, evenly spaced on a 0.5 m (N <= 8) or 1 m circle;
    1 mm noise."""
    rng = np.random.default_rng(seed)
    drones = [name for name in names if name != "plate"]
    radius = 0.5 if len(drones) <= 8 else 1.0
    frames = []
    for k in range(ticks):
        t = k / hz
        bodies = {"plate": np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])}
        for i, name in enumerate(drones):
            phase = t + 2 * np.pi * i / len(drones)
            pos = np.array([radius * np.cos(phase), radius * np.sin(phase), 1.0]) + rng.normal(0, 0.001, 3)
            bodies[name] = np.concatenate((pos, [0.0, 0.0, np.sin(0.05), np.cos(0.05)]))
        frames.append(PoseFrame(t=t, bodies=bodies))
    return frames


def bench_core(ticks: int, policy_path: Path, lab: LabConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-tick wall time and CPU time (ms) of estimator + observation + policy + clamp + safety for ``lab``'s
    drones (default: the 2-drone example), exactly as :class:`~marlander_lite.deploy.mission.Mission` calls them.

    On a shared machine the wall time also holds the waits for a free core; the thread's CPU time
    does not.
    """
    lab = lab or load_lab_config(EXAMPLE_CONFIG)
    sf = lab.safety_filter
    policy = load_lab_policy(policy_path, lab)
    runner = PolicyRunner(policy, lab.task_config(), lab.limits.max_speed, sf.filter_config() if sf.enabled else None)
    estimator = SwarmEstimator(lab, landed_height=runner.task.landed_height)
    safety = SafetyMonitor(lab)
    frames = synthetic_frames([*lab.drone_names, "plate"], ticks, lab.rates.loop_hz)
    flying = np.ones(lab.num_drones, dtype=bool)
    times, cpu = np.empty(ticks), np.empty(ticks)
    for k, frame in enumerate(frames):
        start, start_cpu = time.perf_counter(), time.thread_time()
        estimator.ingest([frame])
        est = estimator.estimate(frame.t)
        obs = runner.observe(est)
        _, velocity = runner.act(obs, est.goal)
        velocity, _ = runner.filter_velocity(velocity, est, settled=~flying)
        verdict = safety.flight(frame.t, est, flying, action_ok=True)
        times[k], cpu[k] = time.perf_counter() - start, time.thread_time() - start_cpu
    assert verdict.action == "fly" and np.isfinite(velocity).all()
    return times[50:] * 1000.0, cpu[50:] * 1000.0  # skip the warm-up


def _line(label: str, ms: np.ndarray, cpu: np.ndarray) -> str:
    return (
        f"  {label}: wall median {np.median(ms):.3f} ms, p95 {np.percentile(ms, 95):.3f} ms, max {ms.max():.2f} ms"
        f" | CPU median {np.median(cpu):.3f} ms, p95 {np.percentile(cpu, 95):.3f} ms"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sizes", type=int, nargs="+", default=[2, 8, 16])
    args = parser.parse_args()
    base = load_lab_config(EXAMPLE_CONFIG)
    with tempfile.TemporaryDirectory() as tmp:
        shared_paper = paper_policy(Path(tmp) / "shared-paper.safetensors", num_drones=None)
        print(
            f"Core tick (estimate + observation + policy + clamp + safety filter + safety), {args.ticks} ticks per run:"
        )
        for n in args.sizes:
            lab = base if n == 2 else base.with_drones(n)
            policies = {
                f"centralised {PAPER_HIDDEN}": paper_policy(Path(tmp) / f"paper-{n}.safetensors", num_drones=n),
                "shared (shipped, 128-128)": SHARED_POLICY,
                f"shared-paper {PAPER_HIDDEN}": shared_paper,
            }
            unfiltered = lab.replace(safety_filter=SafetyFilterSection(enabled=False))
            runs = [(name, path, lab) for name, path in policies.items()]
            runs.append(("shared (shipped, 128-128), safety filter off", SHARED_POLICY, unfiltered))
            for name, path, config in runs:
                for r in range(args.repeats):
                    ms, cpu = bench_core(args.ticks, path, config)
                    print(_line(f"N = {n:2d}, {name}, run {r + 1}", ms, cpu))
        print("Whole loop tick in a point-mass rehearsal (+ simulated mocap, cflib packets, virtual firmware, log):")
        rehearsals = {
            "N = 2, centralised paper-sized": (base, paper_policy(Path(tmp) / "paper-2.safetensors", num_drones=2)),
            "N = 8, shared (shipped)": (load_lab_config(EXAMPLE_CONFIG_8), SHARED_POLICY),
        }
        for name, (lab, path) in rehearsals.items():
            for r in range(args.repeats):
                result = rehearse(
                    lab, path, simulator="pointmass", log_path=Path(tmp) / f"log-{lab.num_drones}-{r}.jsonl"
                )
                m = result.mission
                print(
                    f"  {name}, run {r + 1}: median {m.loop_ms_median:.3f} ms, p95 {m.loop_ms_p95:.3f} ms, "
                    f"max {m.loop_ms_max:.2f} ms over {m.ticks} ticks"
                )


if __name__ == "__main__":
    main()
