"""How slow a velocity tracker may be: a policy flown on point masses with ever slower horizontal velocity loops.

The training family (:class:`~marlander_lite.pointmass.family.DynamicsFamily`) draws the horizontal velocity time
constant from 0.08-0.40 s, covering our PyBullet trackers (0.14-0.27 s). PyFlyt's Crazyflie, identified the same way
(``benchmarks/identify_simulators.py``), answers with 0.77 s. This script flies one policy on the nominal point mass
with only that time constant changed (0.2-0.8 s), then with every value of PyFlyt's fit, so that one reads where
landing breaks and whether the time constant alone explains a simulator's result (docs/transfer.md, "PyFlyt").

    python benchmarks/tracker_lag_sweep.py POLICY [--episodes 100] [--row floor] [--seed 0] [--taus 0.2,0.4,0.6,0.8]
        [--safety-filter latency_compensation=0.12,identified_lag_share=0.5]

With ``--safety-filter`` every cell flies through the deployment's safety filter with those settings; with
``identified_lag_share`` the table adds the time constant the filter identified in flight (median over episodes), to
read against the point mass's own.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

from marlander_lite.experiments.transfer import Column, fly_cell
from marlander_lite.swarm.safety_filter import parse_settings

PYFLYT_FIT: dict[str, Any] = {
    "velocity_time_constant": 0.7745,
    "vertical_time_constant": 0.06182,
    "attitude_time_constant": 0.1323,
    "max_tilt_deg": 12.89,
    "max_climb_acceleration": 42.71,
    "max_sink_acceleration": 9.621,
}
"""PyFlyt 0.21.0's cf2x in its velocity mode, as fitted (benchmarks/results/identify_simulators_2026-11-27.txt)."""


def parse_taus(parser: argparse.ArgumentParser, text: str) -> list[float]:
    """The time constants of ``--taus``: positive finite seconds, or the parser stops with what was wrong."""
    try:
        taus = [float(tau) for tau in text.split(",")]
    except ValueError:
        parser.error(f"--taus must be comma-separated numbers of seconds, like 0.2,0.4,0.8; got {text!r}.")
    if not all(math.isfinite(tau) and tau > 0 for tau in taus):
        parser.error(f"--taus must all be finite and above 0 s (a time constant); got {text!r}.")
    return taus


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policy")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--row", default="floor")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--taus", default="0.2,0.4,0.6,0.8", help="comma-separated horizontal time constants (s)")
    parser.add_argument("--safety-filter", default=None, metavar="KEY=VALUE,...", help="fly through the filter")
    args = parser.parse_args()
    taus = parse_taus(parser, args.taus)
    try:
        settings = None if args.safety_filter is None else parse_settings(args.safety_filter)
    except ValueError as error:
        parser.error(f"--safety-filter: {error}")
    variants: dict[str, dict[str, Any]] = {
        f"velocity time constant {tau} s": {"velocity_time_constant": tau} for tau in taus
    }
    variants["PyFlyt's fit (all six values)"] = PYFLYT_FIT
    through = "" if settings is None else f", through the safety filter ({args.safety_filter})"
    print(f"{args.policy}, row {args.row}, {args.episodes} episodes a cell, seed {args.seed}, Vicon sensing{through}")
    identified = bool(settings and settings.get("identified_lag_share"))
    extra = " identified lag s |" if identified else ""
    print("| point mass with | success % [95 % Wilson] | landing error cm | touchdown m/s "
          f"| collision / too fast / off pad / out / timeout |{extra}")  # fmt: skip
    print("|---|---|---|---|---|" + ("---|" if identified else ""))
    for name, dynamics in variants.items():
        column = Column(name, "pointmass", {"dynamics": dynamics})
        c = fly_cell(args.policy, column, args.row, args.episodes, args.seed, "vicon", settings)
        causes = ("collisions", "crashes_too_fast", "crashes_off_pad", "out_of_arena", "timeouts")
        failures = " / ".join(str(getattr(c, cause)) for cause in causes)
        lag = f" {c.identified_lag_s:.2f} |" if identified and c.identified_lag_s is not None else ""
        print(
            f"| {name} | {100 * c.success_rate:.1f} [{100 * c.wilson_low:.0f}, {100 * c.wilson_high:.0f}] "
            f"| {c.landing_error_cm:.2f} | {c.touchdown_speed:.2f} | {failures} |{lag}"
        )


if __name__ == "__main__":
    main()
