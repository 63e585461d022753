"""Rehearsal campaign: one lab config and one policy rehearsed over many seeds, landings and safety counted.

``marlander deploy --sim`` rehearses one flight; the tables of docs/lab_guide.md ("Which policy to fly",
"Flying N drones") need many. For each seed this runs :func:`~marlander_lite.deploy.rehearsal.rehearse`
(no fault; the seed moves the start positions and the sensor noise) and prints one line per seed, then:

* drones on their pads (touched down on their own pad under the policy) and rehearsals with all of them;
* the landing error of those drones (cm from the pad centre), mean and range;
* the closest two drones came at any physics step (simulator truth, m);
* safe rehearsals: every drone inside the fence and down at rest or hovering at the end.

Run::

    python benchmarks/rehearsal_campaign.py --config marlander_lite/deploy/example_lab_8.yaml \\
        --policy data/policies/shared-quick-local.safetensors --seeds 0-19 [--simulator rotorpy] [--controller pid]

``--drones 16`` flies 16 drones on a 4 x 4 grid of pads 0.25 m apart instead of the config's
(:meth:`~marlander_lite.deploy.config.LabConfig.with_drones`; the rest of the config as it is).

``--pad-assignment shortest`` hands the pads out at take-off by the shortest pairing (the config's
``pad_assignment``), as a policy trained so (``shared-quick-paired``) expects.

The config's simulation platform (its motion, speed and inclination), its take-off height and its safety filter can be
changed on the command line, e.g. the 8-drone lab's plate tilted 15 degrees: ``--inclination 15``; or
the plate shuttling along a line at 0.4 m/s with the lab guide's moving-pad settings::

    python benchmarks/rehearsal_campaign.py --config marlander_lite/deploy/example_lab.yaml \\
        --policy data/policies/moving-smooth-16m.safetensors --seeds 0-9 --platform moving-linear \\
        --platform-speed 0.4 --takeoff-height 1.4 --filter-settings cone_radius=0.04,reaction_time=0.35,pad_lead=0.2

``--pad-frame-lead 0.3`` flies a pad-frame policy with that lead instead of its file's (the config's
``limits.pad_frame_lead``); ``--pad-frame-lead auto`` with the lead set in flight from the identified tracker.
"""

from __future__ import annotations

import argparse
import dataclasses
import math

import numpy as np

from marlander_lite.deploy.config import load_lab_config
from marlander_lite.deploy.rehearsal.run import rehearse
from marlander_lite.pad_assignment import PAD_ASSIGNMENTS
from marlander_lite.pad_frame_lead import lead_argument
from marlander_lite.simulators import SIMULATORS
from marlander_lite.swarm.safety_filter import parse_settings


def seed_range(text: str) -> list[int]:
    """``"0-19"`` or ``"3"`` -> the seeds."""
    first, _, last = text.partition("-")
    return list(range(int(first), int(last or first) + 1))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", required=True, help="lab config YAML")
    parser.add_argument("--policy", required=True, help="policy file (.safetensors)")
    parser.add_argument("--seeds", default="0-19", help="seed range, e.g. 0-19")
    parser.add_argument("--simulator", default=None, choices=SIMULATORS, help="default: the lab's")
    parser.add_argument("--controller", default=None, help="PyBullet tracker (firmware, pid); default: firmware")
    parser.add_argument("--platform", default=None, help="simulation.platform instead of the config's")
    parser.add_argument("--platform-speed", type=float, default=None, help="simulation.platform_speed (m/s)")
    parser.add_argument(
        "--inclination", type=float, default=None, help="simulation.inclination_deg: the plate tilts this (degrees)"
    )
    parser.add_argument("--tilt-axis", type=float, default=None, help="simulation.tilt_axis_deg (degrees from +x)")
    parser.add_argument(
        "--mocap-latency", type=float, default=None, help="simulation.latency_s: how late poses arrive (s)"
    )
    parser.add_argument("--takeoff-height", type=float, default=None, help="limits.takeoff_height (m)")
    parser.add_argument(
        "--pad-frame-lead",
        type=lead_argument,
        default=None,
        help="limits.pad_frame_lead (s, or auto) for a pad-frame policy",
    )
    parser.add_argument(
        "--drones",
        type=int,
        default=None,
        help="fly this many drones instead of the config's, on the simulators' 0.25 m grid (LabConfig.with_drones)",
    )
    parser.add_argument("--no-filter", action="store_true", help="fly without the safety filter (the policy alone)")
    parser.add_argument(
        "--pad-assignment", default=None, choices=PAD_ASSIGNMENTS, help="pad_assignment instead of the config's"
    )
    parser.add_argument(
        "--filter-settings",
        default="",
        metavar="KEY=VALUE,...",
        help="safety_filter keys instead of the config's (or a named set: moving-pads, pad-frame)",
    )
    args = parser.parse_args(argv)
    if args.mocap_latency is not None and not 0.0 <= args.mocap_latency <= 1.0:
        parser.error(f"--mocap-latency must be from 0 to 1 s, got {args.mocap_latency}")
    lab = load_lab_config(args.config)
    if args.drones is not None:
        try:
            lab = lab.with_drones(args.drones)
        except ValueError as error:
            parser.error(f"--drones: {error}")
    simulation = {
        "platform": args.platform,
        "platform_speed": args.platform_speed,
        "latency_s": args.mocap_latency,
        "inclination_deg": args.inclination,
        "tilt_axis_deg": args.tilt_axis,
    }
    try:
        safety_filter = lab.safety_filter.with_settings(parse_settings(args.filter_settings))
        changed = {k: v for k, v in simulation.items() if v is not None}
        lab = lab.replace(simulation=dataclasses.replace(lab.simulation, **changed), safety_filter=safety_filter)
    except ValueError as error:  # ConfigError is one
        parser.error(str(error))
    if args.no_filter:
        lab = lab.replace(safety_filter=dataclasses.replace(lab.safety_filter, enabled=False))
    if args.pad_assignment is not None:
        lab = lab.replace(pad_assignment=args.pad_assignment)
    if args.takeoff_height is not None:
        lab = lab.replace(limits=dataclasses.replace(lab.limits, takeoff_height=args.takeoff_height))
    if args.pad_frame_lead is not None:
        try:
            lab = lab.replace(limits=dataclasses.replace(lab.limits, pad_frame_lead=args.pad_frame_lead))
        except ValueError as error:
            parser.error(f"--pad-frame-lead: {error}")
    on_pad = all_down = safe = 0
    drones, errors, closest = 0, [], math.inf
    for seed in seed_range(args.seeds):
        result = rehearse(lab, args.policy, simulator=args.simulator, seed=seed, controller=args.controller)
        mission = result.mission
        landed = int(np.sum(mission.on_pad))
        drones += len(mission.on_pad)
        on_pad += landed
        all_down += bool(mission.success)
        safe += result.safe
        closest = min(closest, result.min_separation)
        seed_errors = [100 * e for e in mission.landing_error if not math.isnan(e)]
        errors += seed_errors
        shown = ", ".join(f"{e:.1f}" for e in seed_errors)
        print(
            f"seed {seed:3d}: {landed}/{len(mission.on_pad)} on their pads ({shown} cm), phases {mission.phases}, "
            f"closest {result.min_separation:.3f} m, safe {result.safe}",
            flush=True,
        )
    runs = len(seed_range(args.seeds))
    print(
        f"drones on their pads: {on_pad} / {drones} ({100 * on_pad / drones:.1f} %); all landed in {all_down} of {runs}"
    )
    if errors:
        print(f"landing error: mean {np.mean(errors):.2f} cm, {min(errors):.1f}-{max(errors):.1f} cm")
    print(f"closest two drones: {closest:.3f} m; safe: {safe} of {runs}")


if __name__ == "__main__":
    main()
