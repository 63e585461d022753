"""How hard a shared policy's drones touch down, on point masses that differ from the nominal in one property each.

A touchdown on the own pad counts as a landing only below ``touchdown_speed_max`` (0.5 m/s). This script flies lone
drones (N = 1, the paper's random starts, Vicon sensing) of a shared policy on the nominal point mass and on members
of the training family that change one property (latency, vertical loop, sink limit, command gain, drag, ground
cushion), then on the whole family; every touchdown is recorded, however fast, so one reads the distribution, not
only the failures. Each row: the median, 90th percentile and largest touchdown speed (m/s), and how many of the
drones touched down faster than the limit. With ``--safety-filter`` the same rows fly through the deployment's
safety filter (its defaults, or the settings given).

    python benchmarks/touchdown_speeds.py POLICY [--episodes 200] [--seed 0] [--safety-filter ""]

docs/scaling.md ("Why the touchdowns are not soft") quotes its output.
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from marlander_lite.pointmass.family import NOMINAL, DynamicsFamily
from marlander_lite.swarm.safety_filter import parse_settings
from marlander_lite.swarm.touchdowns import touchdown_speeds

MEMBERS: dict[str, dict[str, float] | None] = {
    "nominal": {},
    "latency 0.02 s": {"latency_s": 0.02},
    "latency 0.04 s": {"latency_s": 0.04},
    "latency 0.06 s": {"latency_s": 0.06},
    "vertical tau 0.2 s": {"vertical_time_constant": 0.2},
    "sink limit 3 m/s^2": {"max_sink_acceleration": 3.0},
    "command gain 1.1": {"command_gain": 1.1},
    "drag 0.3 /s": {"drag": 0.3},
    "ground cushion 0.25 g": {"ground_cushion": 0.25},
    "training family": None,
}
"""Row label -> the properties changed from the nominal point mass (:data:`NOMINAL`); None: the whole family."""


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policy", help="a shared policy file (.safetensors)")
    parser.add_argument("--episodes", type=int, default=200, help="lone drones per row")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--safety-filter", default=None, metavar="KEY=VALUE,...", help='fly through the filter ("" for its defaults)'
    )
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    try:
        settings: dict[str, Any] | None = None if args.safety_filter is None else parse_settings(args.safety_filter)
    except ValueError as error:
        parser.error(f"--safety-filter: {error}")
    limit = 0.5
    print(f"{args.policy}, lone drones, {args.episodes} a row, seed {args.seed}, filter {args.safety_filter!r}")
    print(f"{'point mass':24s} {'median':>7s} {'p90':>7s} {'max':>7s}  above {limit} m/s")
    for label, changes in MEMBERS.items():
        family = DynamicsFamily() if changes is None else DynamicsFamily.fixed(**{**NOMINAL, **changes})
        speeds = touchdown_speeds(args.policy, family, args.episodes, args.seed, settings)
        touched = speeds[np.isfinite(speeds)]
        median, p90, top = (np.percentile(touched, q) for q in (50, 90, 100))
        print(
            f"{label:24s} {median:7.3f} {p90:7.3f} {top:7.3f}  {int((touched > limit).sum()):3d} of {touched.size}",
            flush=True,
        )


if __name__ == "__main__":
    main()
