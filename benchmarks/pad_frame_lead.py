"""Where a pad-frame policy touches down on a moving pad, for each lead its commands are flown with.

A pad-frame policy's command is ``v_pad + T_lead a_pad + a v_max`` (``TaskConfig.command_frame`` ``"pad"``,
``TaskConfig.pad_frame_lead`` ``T_lead``). A tracker that follows a command with velocity time constant ``T`` keeps up
with a pad that accelerates when ``T_lead`` is about ``T``; a longer lead sends its drone ahead of the pad, a shorter
one leaves it behind. For each column and lead this flies ``--episodes`` episodes of one cell of the transfer matrix
(:func:`marlander_lite.experiments.lead_offsets.touchdown_offsets`) and prints the successes, the mean and standard
deviation of each drone's offset from its pad centre at touchdown along the pad's velocity, and the mean across it.

    python benchmarks/pad_frame_lead.py POLICY [--columns "point mass,PyBullet firmware"] [--platform moving-linear]
        [--speed 0.5] [--leads 0 0.15 0.3 0.5] [--episodes 40]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from marlander_lite.experiments.lead_offsets import touchdown_offsets
from marlander_lite.pad_frame_lead import lead_argument


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("policy", help="a pad-frame policy file")
    parser.add_argument("--columns", default="point mass,PyBullet firmware,held-out DSL PID")
    parser.add_argument("--platform", default="moving-linear", choices=("moving-linear", "moving-arc"))
    parser.add_argument("--speed", type=float, default=0.5, help="UR10 tool speed (m/s)")
    parser.add_argument("--leads", type=lead_argument, nargs="+", default=[0.0, 0.15, 0.3, 0.5], help="seconds or auto")
    parser.add_argument("--episodes", type=int, default=40)
    args = parser.parse_args()
    print(f"{args.policy}, {args.platform} {args.speed:g} m/s, {args.episodes} episodes a cell, seed 0, Vicon")
    print(
        "| column | lead s | success | along-track cm (mean, sd; + ahead) | across-track cm (mean) "
        "| lead at touchdown s (median) | s |"
    )
    print("|---|---|---|---|---|---|---|")
    for column in args.columns.split(","):
        for lead in args.leads:
            start = time.perf_counter()
            found = touchdown_offsets(args.policy, column, args.platform, args.speed, lead, args.episodes)
            along, across, seconds = 100 * found.along, 100 * found.across, time.perf_counter() - start
            print(
                f"| {column} | {lead} | {found.successes} / {found.episodes} | {along.mean():+.2f}, "
                f"{along.std():.2f} | {across.mean():+.2f} | {np.median(found.leads):.2f} | {seconds:.0f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
