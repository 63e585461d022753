"""Two checkouts of marlander_lite, the 16-drone PyBullet swarm step of each, taking turns: which is faster, how much.

``bench_crazyflie.py`` measures one checkout. A code change is judged against the code before it, on the same machine
at the same time: this script times the same hovering 16-drone swarms for ``--base`` and ``--new`` (two directories
holding the repository, e.g. ``git worktree add /tmp/base HEAD~1``) in alternating subprocesses, so that a background
load hits both alike. Each measurement takes turns within its process between the simulator step (numba engine, one
policy period at 24 Hz) and a bare ``stepSimulation`` loop over the same bodies (gravity off, the same number of calls,
as ``marlander_lite.crazyflie.timing.bare_step_loop``; written out here, since the base checkout may predate it), 5
rounds of about 1 s each, and reports the medians of the step's time and of its
ratio to the loop. Printed: per setting (tracker / physics), the medians over ``--rounds`` processes of each checkout.

    python benchmarks/bench_crazyflie_ab.py --base /tmp/base --new . [--rounds 3]
"""

from __future__ import annotations

import json
import statistics
from pathlib import Path

from bench_pointmass_ab import parse_checkouts, run_measurement  # the A/B plumbing both scripts share

SETTINGS = (("pid", "bare"), ("pid", "aero"), ("firmware", "bare"))
MEASURE = r"""
import json, statistics, sys, time
import numpy as np
import pybullet as p
sys.path.insert(0, sys.argv[1])
import marlander_lite
from marlander_lite.crazyflie import CrazyflieSwarm, PhysicsConfig
from marlander_lite.platforms import PlatformConfig
from marlander_lite.task import TaskConfig
assert marlander_lite.__file__.startswith(sys.argv[1]), marlander_lite.__file__
controller, physics, n = sys.argv[2], sys.argv[3], 16
config = PhysicsConfig.preset(physics, control_hz=48.0)
sim = CrazyflieSwarm(TaskConfig(num_drones=n), PlatformConfig(), physics=config, controller=controller, engine="numba")
grid = np.array([(0.5 * (i % 4) - 0.75, 0.5 * (i // 4) - 0.25, 1.5) for i in range(n)])
hover, ticks, cid = np.zeros((1, n, 3)), round(sim.physics.control_hz / sim.task.policy_hz), sim.client
def step():
    sim.step(hover)
def bare():
    p.setGravity(0, 0, 0, physicsClientId=cid)
    for _ in range(ticks):
        p.stepSimulation(cid)
    p.setGravity(0, 0, -9.81, physicsClientId=cid)
times = {"step": [], "bare": []}
for fn in (step, bare):
    sim.place(0, grid); fn()
calls = 200
for _ in range(5):
    for name, fn in (("step", step), ("bare", bare)):
        sim.place(0, grid)
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        times[name].append((time.perf_counter() - start) / calls)
ratio = statistics.median(a / b for a, b in zip(times["step"], times["bare"]))
print(json.dumps({"step_us": 1e6 * statistics.median(times["step"]), "bare_x": ratio}))
"""


def measure(checkout: Path, controller: str, physics: str) -> dict[str, float]:
    """Step time (us) and step / bare loop of ``checkout``'s 16-drone swarm, in a fresh process."""
    return json.loads(run_measurement(checkout, MEASURE, controller, physics).strip().splitlines()[-1])


def main() -> None:
    checkouts, rounds = parse_checkouts(__doc__.splitlines()[0], rounds=3)
    for controller, physics in SETTINGS:
        runs: dict[str, list[dict[str, float]]] = {name: [] for name in checkouts}
        for _ in range(rounds):
            for name, path in checkouts.items():
                runs[name].append(measure(path, controller, physics))
        step = {name: statistics.median(r["step_us"] for r in runs[name]) for name in checkouts}
        bare_x = {name: statistics.median(r["bare_x"] for r in runs[name]) for name in checkouts}
        print(
            f"16 drones, {controller} / {physics}: base {step['base']:.0f} us ({bare_x['base']:.2f} x bare), "
            f"new {step['new']:.0f} us ({bare_x['new']:.2f} x bare); base / new {step['base'] / step['new']:.2f} "
            f"(medians of {rounds} processes each)",
            flush=True,
        )


if __name__ == "__main__":
    main()
