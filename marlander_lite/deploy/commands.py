"""``marlander deploy``: fly the policy on Crazyflies, or rehearse the same code path in simulation.

Hardware::

    marlander deploy --config lab.yaml --policy policy.safetensors

Rehearsal (the same loop, cflib packets decoded by virtual Crazyflies, PyBullet physics)::

    marlander deploy --sim --config lab.yaml --policy policy.safetensors [--inject FAULT]

Exit code 0: every drone landed on its pad (with ``--inject``: the rehearsal ended safely, every
drone down or hovering inside the fence); 1: the flight ended otherwise; 2: bad arguments or config.
"""

from __future__ import annotations

import argparse
import datetime
import select
import sys
import threading
from pathlib import Path
from typing import Any

from marlander_lite.deploy.config import SIMULATOR_KINDS, LabConfig, load_lab_config
from marlander_lite.deploy.faults import FAULT_KINDS, FaultSpec
from marlander_lite.deploy.link import LinkError
from marlander_lite.deploy.sim_world import SimulatorUnavailable


def register(subparsers: Any) -> None:
    """Add the ``deploy`` subcommand."""
    parser = subparsers.add_parser(
        "deploy",
        help="fly a policy on Crazyflies with motion capture, or rehearse it in simulation (--sim)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--config", required=True, type=Path, help="lab config YAML (see example_lab.yaml)")
    parser.add_argument("--policy", required=True, type=Path, help="exported policy file (.safetensors)")
    parser.add_argument("--sim", action="store_true", help="rehearse in simulation instead of flying")
    parser.add_argument("--simulator", choices=SIMULATOR_KINDS, help="physics of the rehearsal (default: config's)")
    parser.add_argument(
        "--inject",
        choices=FAULT_KINDS,
        metavar="FAULT",
        help=f"fault to rehearse (with --sim), one of: {', '.join(FAULT_KINDS)}",
    )
    parser.add_argument("--fault-at", type=float, default=1.0, help="seconds after the policy starts (default 1)")
    parser.add_argument("--fault-duration", type=float, help="seconds the fault lasts (default: per fault)")
    parser.add_argument("--fault-drone", type=int, default=0, help="index of the drone a fault hits (default 0)")
    parser.add_argument("--seed", type=int, help="seed of the simulated lab (default: config's)")
    parser.add_argument("--log", type=Path, help="flight log path (default: LOG_DIR/<kind>-<time>.jsonl)")
    parser.add_argument("--plot", type=Path, help="save the trajectories (paper Fig. 7) to this image")
    parser.add_argument("--yes", action="store_true", help="hardware: do not ask for confirmation before flying")
    parser.set_defaults(func=run_deploy)


def run_deploy(args: argparse.Namespace) -> int:
    """Run ``marlander deploy``; returns the exit code."""
    lab = load_lab_config(args.config)
    if args.inject and not args.sim:
        raise ValueError("--inject only works in a rehearsal: add --sim.")
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    log_path = args.log or Path(lab.log_dir) / f"{'rehearsal' if args.sim else 'flight'}-{stamp}.jsonl"
    if log_path.exists() and not args.sim:
        raise ValueError(f"The flight log {log_path} exists already; choose another --log path.")
    try:
        ok = _rehearse(lab, args, log_path) if args.sim else _fly(lab, args, log_path)
    except (TimeoutError, ConnectionError, LinkError, SimulatorUnavailable) as error:
        print(f"marlander deploy: error: {error}", file=sys.stderr)
        return 2
    print(f"Flight log: {log_path}")
    if args.plot:
        _plot(log_path, args.plot)
        print(f"Trajectories: {args.plot}")
    return 0 if ok else 1


def _rehearse(lab: LabConfig, args: argparse.Namespace, log_path: Path) -> bool:
    from marlander_lite.deploy.rehearsal import rehearse

    fault = None
    if args.inject:
        fault = FaultSpec(args.inject, start_s=args.fault_at, duration_s=args.fault_duration, drone=args.fault_drone)
    result = rehearse(lab, args.policy, simulator=args.simulator, fault=fault, seed=args.seed, log_path=log_path)
    print(result.summary())
    return result.safe and (fault is not None or result.mission.success)


def _fly(lab: LabConfig, args: argparse.Namespace, log_path: Path) -> bool:
    from marlander_lite.deploy.config import load_lab_policy
    from marlander_lite.deploy.link import CrazyflieLink
    from marlander_lite.deploy.mission import Mission
    from marlander_lite.deploy.pose_sources import MotionCaptureSource, RealClock
    from marlander_lite.deploy.rehearsal import flight_header

    policy = load_lab_policy(args.policy, lab)
    print(f"Connecting to {lab.mocap.kind} at {lab.mocap.hostname or '(mock)'} ...")
    source = MotionCaptureSource(lab.mocap.kind, lab.mocap.connect_cfg(), lab.mocap.connect_timeout_s)
    link = CrazyflieLink([d.uri for d in lab.drones], lab.crazyflie)
    try:
        print(f"Connecting to {len(lab.drones)} Crazyflies and setting their parameters ...")
        link.open()
        if not args.yes and sys.stdin.isatty():
            input("Ready. Press Enter to run the pre-flight check and take off (Ctrl-C to cancel). ")
        from marlander_lite.deploy.flight_log import FlightLogWriter

        log = FlightLogWriter(log_path, flight_header(lab, policy, source=lab.mocap.kind))
        mission = Mission(lab, policy, source, link, RealClock(), log=log)
        watcher = KeyWatcher(mission)
        watcher.start()
        print("Flying. Press Enter (or 'l' Enter) to land every drone, 'k' Enter to stop every motor, Ctrl-C to land.")
        result = mission.run()
        watcher.stop()
    finally:
        link.close()
        source.close()
    for e in result.events:
        print(f"  {e.t:7.2f} s  {e.kind:16s} {e.message}")
    print(f"On pad: {result.on_pad}; landing error (m): {result.landing_error}")
    return result.success


class KeyWatcher:
    """Reads the terminal during a flight: a line ``k`` stops every motor, any other line lands every drone."""

    def __init__(self, mission: Any) -> None:
        self.mission = mission
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="emergency-keys", daemon=True)

    def start(self) -> None:
        if sys.stdin.isatty():
            self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([sys.stdin], [], [], 0.1)
            if ready:
                line = sys.stdin.readline().strip().lower()
                if line == "k":
                    self.mission.request_kill("emergency key 'k'")
                else:
                    self.mission.request_land("emergency key")


def _plot(log_path: Path, image: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from marlander_lite.deploy.flight_log import read_flight_log
    from marlander_lite.deploy.plots import plot_trajectories

    ax = plot_trajectories(read_flight_log(log_path))
    image.parent.mkdir(parents=True, exist_ok=True)
    ax.figure.savefig(image, dpi=120, bbox_inches="tight")
    plt.close(ax.figure)
