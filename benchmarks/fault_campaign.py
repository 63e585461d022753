"""Fault campaign: every documented fault on every kind of platform, many seeds, at the fastest allowed speed.

A rehearsal shows that one fault ends safely once; a campaign shows that it does so however the
dice fall. For every fault of :mod:`marlander_lite.deploy.rehearsal.faults` (and a SIGTERM sent to this very
process in the middle of the flight), on each platform the paper flies (the floor, the UR10 holding
the plate still, the UR10 moving it along an arc), for ``--seeds`` seeds (the seed moves the drones'
start positions, the platform, the sensor noise and the moment the fault strikes), it rehearses the
example lab with ``limits.max_speed`` raised to the largest value the lab config accepts, and counts
what must never happen:

==================  ===================================================================
fly-aways           a drone still flying and moving at the end (motors on, faster than 0.2 m/s), or
                    ending more than 0.5 m outside the hard geofence
fence exits         a drone outside the hard geofence at any physics step (simulator truth; sinking
                    into the floor on impact does not count)
drones not landed   a drone not down at the end: motors running, or motors off but still faster than
                    0.2 m/s (falling, tumbling off a plate) and not riding its pad
faults not injected the flight ended (or never started) before the fault or the SIGTERM was due:
                    nothing was rehearsed
ticks missing       tick indices absent from a flight log (0 .. ticks - 1 expected)
duplicate ticks     tick indices logged more than once
logs without summary a flight log not closed by its summary record
==================  ===================================================================

Every total must be 0. Run: ``python benchmarks/fault_campaign.py [--seeds N] [--simulator crazyflie]``
(exit status 1 if any total is not 0). ``tests/test_deploy_campaign.py`` runs it in-process with 3 seeds.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import signal
import sys
import tempfile
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from marlander_lite.deploy.config import EXAMPLE_CONFIG, SIMULATOR_KINDS, LabConfig, load_lab_config
from marlander_lite.deploy.flight_log import read_flight_log
from marlander_lite.deploy.rehearsal import FAULT_KINDS, FaultSpec, RehearsalResult, rehearse
from marlander_lite.policy_file import load_policy
from marlander_lite.swarm.safety_filter import parse_settings

ROOT = Path(__file__).resolve().parents[1]
PLATFORMS = {"floor": "static-floor", "UR10": "static-elevated", "moving arc": "moving-arc"}
"""Campaign name -> ``simulation.platform``."""
POLICIES = {
    "static": ROOT / "data" / "policies" / "crazyflie-finetune.safetensors",
    "moving": ROOT / "data" / "policies" / "moving-crazyflie-finetune.safetensors",
}
"""The shipped PyBullet policies the lab guide recommends: static pads, moving pads (observes their velocity)."""
CASES: tuple[str, ...] = (*FAULT_KINDS, "SIGTERM")
ELEVATED_TAKEOFF_HEIGHT = 1.5
"""Take-off height over the UR10's plate (m)."""
DOWN_SPEED = 0.2
"""A drone with its motors off slower than this is down (m/s): a drone dropped by its firmware may lie
spinning slowly on its back in PyBullet, which :attr:`RehearsalResult.at_rest` (< 0.05 m/s) does not call rest."""
FAR_OUTSIDE_M = 0.5
"""A drone this far outside the hard fence has flown away (m)."""
TOTALS = (
    "rehearsals",
    "fly-aways",
    "fence exits",
    "drones not landed",
    "faults not injected",
    "ticks missing",
    "duplicate ticks",
    "logs without summary",
)


def largest_max_speed(lab: LabConfig, hi: float = 10.0) -> float:
    """The largest ``limits.max_speed`` (to 0.01 m/s) the lab config accepts, found by bisection."""

    def allowed(v: float) -> bool:
        try:
            lab.replace(limits=dataclasses.replace(lab.limits, max_speed=v))
        except ValueError:  # ConfigError is a ValueError
            return False
        return True

    lo = 0.0
    if allowed(hi):
        return hi
    for _ in range(40):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if allowed(mid) else (lo, mid)
    return float(np.floor(lo * 100) / 100)


def campaign_lab(platform: str, max_time_s: float, base: LabConfig | None = None) -> LabConfig:
    """The example lab on ``platform`` at its fastest allowed speed, the simulation cut to ``max_time_s``.

    Over a plate the UR10 holds (up to about 1 m high, depending on the seed) the drones take off to
    :data:`ELEVATED_TAKEOFF_HEIGHT`, since arming demands a take-off height 0.3 m above the pads.
    """
    lab = base or load_lab_config(EXAMPLE_CONFIG)
    sim = dataclasses.replace(lab.simulation, platform=platform, max_time_s=max_time_s)
    limits = lab.limits
    if platform != "static-floor":
        limits = dataclasses.replace(limits, takeoff_height=max(limits.takeoff_height, ELEVATED_TAKEOFF_HEIGHT))
    lab = lab.replace(simulation=sim, limits=limits)
    return lab.replace(limits=dataclasses.replace(lab.limits, max_speed=largest_max_speed(lab)))


class SignalAt:
    """Mission hook: sends ``signum`` to this process ``delay_s`` after the policy took over."""

    def __init__(self, delay_s: float, signum: int = signal.SIGTERM) -> None:
        self.delay_s, self.signum, self.sent = delay_s, signum, False

    def __call__(self, mission, t: float) -> None:
        if not self.sent and mission.policy_start is not None and t >= mission.policy_start + self.delay_s:
            self.sent = True
            os.kill(os.getpid(), self.signum)


@dataclass
class Campaign:
    """Totals of a campaign, and one line per rehearsal that went wrong."""

    totals: dict[str, int] = field(default_factory=lambda: dict.fromkeys(TOTALS, 0))
    failures: list[str] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return all(v == 0 for k, v in self.totals.items() if k != "rehearsals") and self.totals["rehearsals"] > 0

    def add(self, name: str, result: RehearsalResult, log_path: Path, interrupted: str | None = None) -> None:
        """Count what went wrong in one rehearsal."""
        counts = dict.fromkeys(TOTALS, 0)
        counts["rehearsals"] = 1
        moving = result.motors_on & (result.final_speeds >= 0.2)
        counts["fly-aways"] = int((moving | (result.fence_excess > FAR_OUTSIDE_M)).sum())
        counts["fence exits"] = int((result.fence_excess > 0).sum())
        down = ~result.motors_on & ((result.final_speeds < DOWN_SPEED) | result.riding)
        counts["drones not landed"] = int((~down).sum())
        counts["faults not injected"] = int(result.fault_missed)
        log = read_flight_log(log_path)
        ticks = [t["tick"] for t in log.ticks]
        counts["ticks missing"] = len(set(range(result.mission.ticks)) - set(ticks))
        counts["duplicate ticks"] = len(ticks) - len(set(ticks))
        counts["logs without summary"] = int(log.summary is None)
        if interrupted is not None and result.mission.interrupted_by != interrupted:
            counts["faults not injected"] += 1
            self.failures.append(f"{name}: {interrupted} did not end the flight ({result.mission.interrupted_by})")
        for key, value in counts.items():
            self.totals[key] += value
        bad = {k: v for k, v in counts.items() if k != "rehearsals" and v}
        if bad:
            first = result.summary().splitlines()[0]
            self.failures.append(f"{name}: {bad}; fence excess {np.round(result.fence_excess, 3).tolist()} m; {first}")

    def report(self) -> str:
        lines = [f"{key:22s} {value}" for key, value in self.totals.items()]
        lines += [f"all zero: {self.ok}   ({self.seconds:.1f} s)"]
        return "\n".join(lines + (["failures:"] + [f"  {f}" for f in self.failures] if self.failures else []))


def run_campaign(
    seeds: Iterable[int],
    *,
    simulator: str = "crazyflie",
    max_time_s: float = 12.0,
    cases: Iterable[str] = CASES,
    platforms: dict[str, str] = PLATFORMS,
    progress: Callable[[str], None] | None = None,
    moving_filter: dict[str, float] | None = None,
) -> Campaign:
    """Rehearse every case on every platform for every seed; returns the totals (see the module docstring).

    The fault strikes (or the SIGTERM is sent) between 0.1 and 0.6 s after the policy took over, drawn
    from the seed: at the fastest speed the drones may be down a second after the policy starts.
    ``moving_filter``: changes to the lab's safety filter on the moving platforms (e.g. the lab guide's moving-pad
    settings); None: the example lab's filter everywhere.
    """
    campaign, start = Campaign(), time.perf_counter()
    seeds, cases = list(seeds), list(cases)
    policies = {}
    with tempfile.TemporaryDirectory(prefix="marlander-campaign-") as tmp:
        for name, platform in platforms.items():
            lab = campaign_lab(platform, max_time_s)
            kind = "moving" if platform.startswith("moving") else "static"
            if kind == "moving" and moving_filter:
                lab = lab.replace(safety_filter=lab.safety_filter.with_settings(moving_filter))
            if kind not in policies:
                policies[kind] = load_policy(POLICIES[kind], lab.task_config(kind == "moving"))
            for seed in seeds:
                rng = np.random.default_rng([seed, len(name)])
                for case in cases:
                    at = float(rng.uniform(0.1, 0.6))
                    drone = int(rng.integers(lab.num_drones))
                    label = f"{name} seed {seed} {case} at {at:.2f} s"
                    log_path = Path(tmp) / f"{platform}-{seed}-{case}.jsonl"
                    fault, hooks, interrupted = None, [], None
                    if case == "SIGTERM":
                        hooks, interrupted = [SignalAt(at)], "SIGTERM"
                    else:
                        fault = FaultSpec(case, start_s=at, drone=drone)
                    result = rehearse(
                        lab, policies[kind], simulator=simulator, fault=fault, seed=seed, log_path=log_path, hooks=hooks
                    )
                    campaign.add(label, result, log_path, interrupted)
                    log_path.unlink()
                if progress is not None:
                    progress(f"{name} seed {seed}: {campaign.totals}")
    campaign.seconds = time.perf_counter() - start
    return campaign


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=20, help="seeds per fault and platform (default 20)")
    parser.add_argument("--simulator", choices=SIMULATOR_KINDS, default="crazyflie")
    parser.add_argument("--max-time", type=float, default=12.0, help="simulated seconds per rehearsal (default 12)")
    parser.add_argument(
        "--platforms", default=",".join(PLATFORMS), help=f"comma-separated, from: {', '.join(PLATFORMS)} (default all)"
    )
    parser.add_argument(
        "--moving-filter",
        default="",
        metavar="KEY=VALUE,...",
        help="safety filter changes on the moving platforms, e.g. cone_radius=0.04,reaction_time=0.35,pad_lead=0.2",
    )
    args = parser.parse_args(argv)
    names = [name.strip() for name in args.platforms.split(",")]
    unknown = sorted(set(names) - set(PLATFORMS))
    if unknown:
        parser.error(f"unknown platform(s) {unknown}; allowed: {', '.join(PLATFORMS)}")
    try:
        moving_filter = parse_settings(args.moving_filter)
        campaign_lab("moving-arc", args.max_time).safety_filter.with_settings(
            moving_filter
        )  # refused before any flight
    except ValueError as error:  # ConfigError is one
        parser.error(f"--moving-filter: {error}")
    lab = campaign_lab("static-floor", args.max_time)
    print(
        f"fault campaign: {len(CASES)} cases ({', '.join(CASES)}) x {len(names)} platforms "
        f"({', '.join(names)}) x {args.seeds} seeds, {args.simulator}, max_speed {lab.limits.max_speed} m/s"
        + (f", moving-platform filter {args.moving_filter}" if moving_filter else ""),
        flush=True,
    )
    campaign = run_campaign(
        range(args.seeds),
        simulator=args.simulator,
        max_time_s=args.max_time,
        platforms={name: PLATFORMS[name] for name in names},
        progress=lambda s: print(s, flush=True),
        moving_filter=moving_filter,
    )
    print(campaign.report())
    return 0 if campaign.ok else 1


if __name__ == "__main__":
    sys.exit(main())
