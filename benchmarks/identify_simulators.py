"""Each simulator's velocity tracker, identified as the training family's bounds were: the point mass fitted to it.

The training family (:class:`~marlander_lite.pointmass.family.DynamicsFamily`) covers the point-mass fits of our two
PyBullet trackers with a margin (``crazyflie/fit.py``, ``identify_trackers``). This script runs the same fit on every
simulator named: the same go-and-brake commands (``fit_commands``: 0.5 s at 0.5, 1.5 and 3 m/s along ten directions
and their mirror images, then 0.5 s at rest, from hover 2 m up), recorded by ``simulator_response`` and fitted by
``fit_point_mass`` (Gauss-Newton on the six ``FITTED`` values). It prints one row per simulator and the family's
ranges beside them, so that one reads which simulators lie inside the family a policy was trained on and which do
not (docs/transfer.md, "PyFlyt").

    python benchmarks/identify_simulators.py [--simulators crazyflie-pid,crazyflie-firmware,rotorpy,pyflyt,pyflyt-0.21]
"""

from __future__ import annotations

import argparse
import time

from marlander_lite.crazyflie.fit import FITTED, fit_commands, fit_point_mass, fits_table, simulator_response
from marlander_lite.pointmass.family import DynamicsFamily
from marlander_lite.task import TaskConfig

SIMULATORS = {
    "crazyflie-pid": ("crazyflie", {"controller": "pid"}),
    "crazyflie-firmware": ("crazyflie", {"controller": "firmware"}),
    "rotorpy": ("rotorpy", {}),
    "pyflyt": ("pyflyt", {"read_state": "after_physics"}),
    "pyflyt-0.21": ("pyflyt", {"read_state": "before_physics"}),
}
"""Name -> (simulator, its options). ``pyflyt`` steps PyFlyt as releases since 0.22 do, ``pyflyt-0.21`` as the pinned
0.21.0 does (its controllers read the state before the physics step: ``pyflyt_sim.simulator.aviary_class``)."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--simulators", default=",".join(SIMULATORS), help=f"comma-separated, from {list(SIMULATORS)}")
    parser.add_argument("--iterations", type=int, default=15, help="Gauss-Newton iterations per fit")
    args = parser.parse_args()
    task, commands = TaskConfig(num_drones=1), fit_commands()
    fits = {}
    for name in args.simulators.split(","):
        simulator, options = SIMULATORS[name]
        started = time.perf_counter()
        target = simulator_response(commands, task, simulator, **options)
        fits[name] = fit_point_mass(commands, target, task, iterations=args.iterations)
        seconds = time.perf_counter() - started
        print(f"{name}: {len(commands)} go-and-brake commands flown and fitted in {seconds:.0f} s")
    print()
    print(fits_table(fits))
    family = DynamicsFamily()
    print("| training family (DynamicsFamily) | " + " | ".join(f"{lo:g}-{hi:g}" for lo, hi in
                                                           (getattr(family, f) for f in FITTED)) + " | |")  # fmt: skip
    print()
    print("Units: time constants s, tilt degrees, accelerations m/s^2 (climb above hover, sink below g).")


if __name__ == "__main__":
    main()
