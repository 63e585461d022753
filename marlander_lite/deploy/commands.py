"""``marlander deploy``: fly the policy on Crazyflies, or rehearse the same code path in simulation.

Hardware::

    marlander deploy --config lab.yaml --policy policy.safetensors

Rehearsal (the same loop, cflib packets decoded by virtual Crazyflies, PyBullet physics)::

    marlander deploy --sim --config lab.yaml --policy policy.safetensors [--inject FAULT]

Exit code 0: every drone landed on its pad (with ``--inject``: the fault was injected and the
rehearsal ended safely, every drone down or hovering inside the fence); 1: the flight ended
otherwise; 2: bad arguments or config, or a hardware run without a terminal to confirm on and
without ``--yes``; 128 + N: signal N (Ctrl-C 130, SIGTERM 143, SIGHUP 129) ended the flight, after
every drone was landed, the log summary written and temporary folders removed.

A flight log never overwrites the policy or the config file; an existing log is refused unless
``--force`` (rehearsals only: a hardware log is never overwritten).
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import select
import sys
import threading
from pathlib import Path
from typing import Any, TextIO

from marlander_lite.deploy.config import SIMULATOR_KINDS, LabConfig, current_simulator_name, load_lab_config
from marlander_lite.deploy.interrupts import FLIGHT_SIGNALS, exit_code, terminate_as_interrupt
from marlander_lite.deploy.link import LinkError
from marlander_lite.deploy.pairing import PairingError
from marlander_lite.deploy.rehearsal.faults import FAULT_KINDS, FaultSpec
from marlander_lite.deploy.rehearsal.world import SimulatorUnavailable


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
    parser.add_argument(
        "--simulator",
        type=lambda name: current_simulator_name(name, "--simulator", stacklevel=1),  # the old name, with a warning
        choices=SIMULATOR_KINDS,
        help="physics of the rehearsal (default: config's)",
    )
    parser.add_argument(
        "--inject",
        choices=FAULT_KINDS,
        metavar="FAULT",
        help=f"fault to rehearse (with --sim), one of: {', '.join(FAULT_KINDS)}",
    )
    parser.add_argument(
        "--fault-at",
        type=_seconds(0.0, "a finite number >= 0"),
        default=1.0,
        help="seconds after the policy starts (default 1)",
    )
    parser.add_argument(
        "--fault-duration",
        type=_seconds(None, "a finite number > 0"),
        help="seconds the fault lasts (default: per fault)",
    )
    parser.add_argument(
        "--fault-drone", type=_drone_index, default=0, help="index of the drone a fault hits, from 0 (default 0)"
    )
    parser.add_argument("--seed", type=int, help="seed of the simulated lab (default: config's)")
    parser.add_argument("--log", type=Path, help="flight log path (default: LOG_DIR/<kind>-<time>.jsonl)")
    parser.add_argument("--plot", type=Path, help="save the trajectories (paper Fig. 7) to this image")
    parser.add_argument("--force", action="store_true", help="rehearsal: overwrite an existing --log file")
    parser.add_argument("--yes", action="store_true", help="hardware: do not ask for confirmation before flying")
    parser.set_defaults(func=run_deploy)


def _seconds(minimum: float | None, what: str) -> Any:
    """An argparse type: a finite number of seconds, ``>= minimum`` (None: ``> 0``); NaN and inf refused."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        ok = math.isfinite(value) and (value > 0 if minimum is None else value >= minimum)
        if not ok:
            raise argparse.ArgumentTypeError(f"{text!r} is not {what} (seconds)")
        return value

    return parse


def _drone_index(text: str) -> int:
    """An argparse type: a drone index, an integer >= 0 (-1 does not mean the last drone)."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not a drone index (an integer from 0)")
    return value


def safety_filter_line(lab: LabConfig) -> str:
    """One line saying whether the in-flight safety filter is on, and its main settings."""
    sf = lab.safety_filter
    if not sf.enabled:
        return "Safety filter: OFF (safety_filter.enabled: false): nothing keeps the drones apart in flight."
    named = "" if sf.settings is None else f"settings {sf.settings}: "
    return (
        f"Safety filter: on ({named}drones kept {sf.min_distance:g} m apart, descent braked to "
        f"{sf.touchdown_speed:g} m/s, "
        f"approach cone slope {sf.cone_slope:g} "
        f"and radius {sf.cone_radius:g} m, centring {sf.centring_gain:g}/s; "
        "docs/lab_guide.md, 'The safety filter')."
    )


def run_deploy(args: argparse.Namespace) -> int:
    """Run ``marlander deploy``; returns the exit code."""
    lab = load_lab_config(args.config)
    if args.inject and not args.sim:
        raise ValueError("--inject only works in a rehearsal: add --sim.")
    fault = _fault(lab, args)
    if not args.sim and not args.yes and not _interactive(sys.stdin):
        print(
            "marlander deploy: error: refusing to fly without a terminal to confirm on (stdin is not a "
            "terminal); run it from a terminal, or add --yes to fly without confirmation.",
            file=sys.stderr,
        )
        return 2
    log_path = args.log or _default_log_path(lab, "rehearsal" if args.sim else "flight")
    _check_outputs(args, log_path)
    print(safety_filter_line(lab))
    with terminate_as_interrupt():  # outside the flight, SIGTERM/SIGHUP unwind like Ctrl-C: links closed, temp removed
        try:
            ok, interrupted = _rehearse(lab, args, log_path, fault) if args.sim else _fly(lab, args, log_path)
        except (TimeoutError, ConnectionError, LinkError, SimulatorUnavailable, PairingError) as error:
            print(f"marlander deploy: error: {error}", file=sys.stderr)
            return 2
        except KeyboardInterrupt as stop:  # a signal outside the flight (connecting, settling, closing)
            name = stop.args[0] if stop.args and stop.args[0] in FLIGHT_SIGNALS else "SIGINT"
            _say(f"marlander deploy: stopped by {name} (no drone was flying).", sys.stderr)
            return exit_code(name)
        _say(f"Flight log: {log_path}")
        if args.plot and not interrupted:
            _plot(log_path, args.plot)
            _say(f"Trajectories: {args.plot}")
    if interrupted:
        _say(f"marlander deploy: the flight was ended by {interrupted}; every drone was landed.", sys.stderr)
        return exit_code(interrupted)
    return 0 if ok else 1


def _interactive(stream: TextIO | None) -> bool:
    """Whether ``stream`` is a terminal someone can answer on."""
    try:
        return stream is not None and stream.isatty()
    except (ValueError, OSError):  # closed or detached
        return False


def _fault(lab: LabConfig, args: argparse.Namespace) -> FaultSpec | None:
    """The fault asked for, checked against the lab before anything starts."""
    if not args.inject:
        return None
    from marlander_lite.deploy.rehearsal import fault_time_limit

    fault = FaultSpec(args.inject, start_s=args.fault_at, duration_s=args.fault_duration, drone=args.fault_drone)
    try:
        fault.check(lab.num_drones, fault_time_limit(lab))
    except ValueError as error:
        raise ValueError(f"--inject {args.inject}: {error}") from None
    return fault


def _default_log_path(lab: LabConfig, kind: str) -> Path:
    """``LOG_DIR/<kind>-<time>.jsonl``, with ``-2``, ``-3``, ... if two runs start in the same second."""
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    path, n = Path(lab.log_dir) / f"{kind}-{stamp}.jsonl", 1
    while path.exists():
        n += 1
        path = Path(lab.log_dir) / f"{kind}-{stamp}-{n}.jsonl"
    return path


def _same_file(a: Path, b: Path) -> bool:
    """Whether two paths name the same file (resolved paths, or the same inode: links)."""
    if a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist
        return False


def _check_outputs(args: argparse.Namespace, log_path: Path) -> None:
    """Refuse output paths that would destroy something: the policy or config in use (never, even with
    ``--force``), an existing log (unless ``--force``, and never on hardware)."""
    inputs = {"--policy": args.policy, "--config": args.config}
    outputs = {"--log": log_path, **({"--plot": args.plot} if args.plot else {})}
    for out_flag, out in outputs.items():
        for in_flag, used in inputs.items():
            if _same_file(out, used):
                raise ValueError(f"{out_flag} {out} is the {in_flag} file in use; it is never overwritten.")
    if args.plot and _same_file(args.plot, log_path):
        raise ValueError(f"--plot {args.plot} is the flight log; choose another image path.")
    if log_path.exists() or log_path.is_symlink():
        if not args.sim:
            raise ValueError(f"The flight log {log_path} exists already; choose another --log path.")
        if not args.force:
            raise ValueError(f"The flight log {log_path} exists already; choose another --log path or add --force.")
        if not log_path.is_file():
            raise ValueError(f"--log {log_path} is not a regular file; it is not overwritten, even with --force.")


def _say(text: str, stream: TextIO | None = None) -> None:
    """Print, surviving a terminal that went away (SIGHUP: writes then fail): output goes to /dev/null."""
    stream = stream or sys.stdout
    try:
        print(text, file=stream, flush=True)
    except OSError:
        devnull = open(os.devnull, "w")  # lives as long as the process
        if stream is sys.stderr:
            sys.stderr = devnull
        else:
            sys.stdout = devnull


def _rehearse(
    lab: LabConfig, args: argparse.Namespace, log_path: Path, fault: FaultSpec | None
) -> tuple[bool, str | None]:
    from marlander_lite.deploy.rehearsal import rehearse

    result = rehearse(
        lab,
        args.policy,
        simulator=args.simulator,
        fault=fault,
        seed=args.seed,
        log_path=log_path,
        overwrite_log=args.force,
    )
    if lab.pad_assignment == "shortest":
        from marlander_lite.deploy.pairing import pairing_line

        _say(pairing_line(lab, result.pads))
    _say(result.summary())
    if result.fault_missed:
        _say(
            f"marlander deploy: error: the fault {fault.kind} was never injected: the flight ended before "
            f"{fault.start_s:g} s under the policy; choose an earlier --fault-at.",
            sys.stderr,
        )
    return result.passed, result.mission.interrupted_by


def _fly(lab: LabConfig, args: argparse.Namespace, log_path: Path) -> tuple[bool, str | None]:
    from marlander_lite.deploy.config import load_lab_policy
    from marlander_lite.deploy.flight_log import FlightLogWriter, flight_header
    from marlander_lite.deploy.link import CrazyflieLink
    from marlander_lite.deploy.mission import Mission
    from marlander_lite.deploy.pose_sources import MotionCaptureSource, RealClock

    policy = load_lab_policy(args.policy, lab)
    print(f"Connecting to {lab.mocap.kind} at {lab.mocap.hostname or '(mock)'} ...")
    source = MotionCaptureSource(lab.mocap.kind, lab.mocap.connect_cfg(), lab.mocap.connect_timeout_s)
    link = CrazyflieLink([d.uri for d in lab.drones], lab.crazyflie)
    try:
        print(f"Connecting to {len(lab.drones)} Crazyflies and setting their parameters ...")
        link.open()
        if not args.yes:  # run_deploy refused this without a terminal
            input("Ready. Press Enter to run the pre-flight check and take off (Ctrl-C to cancel). ")
        if lab.pad_assignment == "shortest":  # the drones rest where they will take off: hand the pads out again
            from marlander_lite.deploy.pairing import pair_drones_with_pads, pairing_line, resting_positions

            paired = pair_drones_with_pads(lab, *resting_positions(lab, source, RealClock()))
            print(pairing_line(lab, [d.pad for d in paired.drones]))
            lab = paired
        log = FlightLogWriter(log_path, flight_header(lab, policy, source=lab.mocap.kind))
        mission = Mission(lab, policy, source, link, RealClock(), log=log)
        watcher = KeyWatcher(mission)
        watcher.start()
        print("Flying. Press Enter (or 'l' Enter) to land every drone, 'k' Enter to stop every motor, Ctrl-C to land.")
        try:
            result = mission.run()
        finally:
            watcher.stop()
    finally:
        link.close()
        source.close()
    for e in result.events:
        _say(f"  {e.t:7.2f} s  {e.kind:16s} {e.message}")
    _say(f"On pad: {result.on_pad}; landing error (m): {result.landing_error}")
    return result.success, result.interrupted_by


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
