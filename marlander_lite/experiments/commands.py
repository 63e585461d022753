"""``marlander reproduce``: fly the paper's experiments and write Tables I and II, Fig. 7 and the speed figure.

Examples::

    marlander reproduce --quick --controllers baseline            # a few trials, < 3 min on 2 cores
    marlander reproduce --simulator pointmass                     # 100 trials per controller and condition
    marlander reproduce --simulator crazyflie --trials paper      # the paper's counts, PyBullet
    marlander reproduce --update-shipped --simulator pointmass    # full run: replace the shipped results
    marlander reproduce --report-only --simulator pointmass       # rebuild tables/figures/docs from trials.csv

Results go to ``runs/reproduce/<simulator>[-quick]-<time>/`` or ``--out``: ``trials.csv``,
``summary_by_condition.csv``, ``summary_by_group.csv``, ``table_static.md``, ``table_moving.md``,
``table_conditions.md``, ``table_per_drone.md``, ``gains_baseline.md``, ``fig7_<controller>.png``,
``trajectories_<controller>.csv``, ``fig_speed.png`` and ``run.json``.

The shipped results (``data/results/``) and ``docs/reproduction.md`` change only with
``--update-shipped``, which also requires a full run: every condition, at least 100 trials per
cell and every controller of the shipped run (all five by default). A lock file with the PID
(``.reproduce.lock``) keeps two runs out of one folder; a lock left by a dead process is taken over.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from marlander_lite.cli import non_negative_int, positive_int
from marlander_lite.config_cli import ConfigOptions, FieldOption, changed_options
from marlander_lite.distributed import BACKENDS
from marlander_lite.experiments import figures, includes, tables
from marlander_lite.experiments.controllers import CONTROLLERS, PAPER_CONTROLLERS
from marlander_lite.experiments.protocol import (
    CONDITION_NAMES,
    ProtocolConfig,
    TrialRecord,
    check_policies,
    condition,
    record_trajectory,
    run_protocol,
)
from marlander_lite.pad_frame_lead import lead_argument
from marlander_lite.training.provenance import file_sha256

RESULTS_ROOT = Path("data/results")
"""The shipped results: written only by a full run with ``--update-shipped``."""
RUNS_ROOT = Path("runs/reproduce")
"""Where other runs go by default, one timestamped folder each."""
DEFAULT_DOC = Path("docs/reproduction.md")
QUICK_TRIALS = 3
"""Trials per controller and condition with ``--quick``."""
FULL_TRIALS = 100
"""Trials per controller and condition of the full protocol (the shipped results)."""
LOCK_NAME = ".reproduce.lock"
"""Lock file in the results folder while a run writes there; it holds the writer's PID."""


def _choices(allowed: tuple[str, ...], what: str) -> Any:
    """An argparse type: a comma-separated list of names from ``allowed`` ("all" for every one)."""

    def parse(text: str) -> tuple[str, ...]:
        names = tuple(dict.fromkeys(n.strip() for n in text.split(",") if n.strip()))
        if names == ("all",):
            return allowed
        bad = [n for n in names if n not in allowed]
        if bad or not names:
            raise argparse.ArgumentTypeError(
                f"unknown {what} {', '.join(map(repr, bad)) or repr(text)}; allowed: {', '.join(allowed)} (or all)"
            )
        return names

    return parse


def _trials(text: str) -> int | str:
    if text == "paper":
        return "paper"
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"trials must be a positive integer or 'paper', got {text!r}")
    return value


PROTOCOL_FIELDS = {
    "pad_frame_lead": FieldOption(parse=lead_argument, metavar="S|auto"),
    "controllers": FieldOption(
        parse=_choices(CONTROLLERS, "controller(s)"),
        metavar="NAMES",
        note=f"Comma-separated, from {', '.join(CONTROLLERS)} (or all); with --update-shipped, those of the "
        "shipped run.",
        show=",".join,
    ),
    "conditions": FieldOption(
        parse=_choices(CONDITION_NAMES, "condition(s)"),
        metavar="NAMES",
        note=f"Comma-separated, from {', '.join(CONDITION_NAMES)} (or all).",
        show=lambda names: "all" if tuple(names) == CONDITION_NAMES else ",".join(names),
    ),
    "trials": FieldOption(parse=_trials, metavar="N|paper", note=f"--quick: {QUICK_TRIALS}."),
    "seed": FieldOption(parse=non_negative_int, metavar="S"),
    "time_limit_s": FieldOption(flags=("--time-limit", "--time-limit-s"), metavar="SECONDS"),
    **{name: FieldOption(parse=positive_int, metavar="N") for name in ("num_drones", "workers", "block_size")},
}
"""How ProtocolConfig fields depart from the generated options (comma-separated lists, the old spellings)."""
COMMAND_LINE_FIELDS = (
    *("simulator", "controllers", "conditions", "trials", "seed", "sensing", "time_limit_s", "workers"),
    "policy_paths",
)
"""Fields :func:`command_line` always writes; the others only when they differ from the defaults."""
POLICY_DESTS = {
    "marlander": "marlander_policy",
    "single-agent-apf": "single_agent_policy",
    "marlander-plus": "marlander_plus_policy",
}
"""``ProtocolConfig.policy_paths``: controller -> the option (``--marlander-policy``...) that sets its file."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``reproduce`` to the ``marlander`` command line."""
    p = subparsers.add_parser(
        "reproduce",
        help="fly the paper's experiments (Tables I, II, Fig. 7) and write data/results",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        usage="marlander reproduce [--quick] [--FIELD VALUE ...] [--apf.KEY VALUE ...] [--out DIR] "
        "[--update-shipped | --report-only] ...",
    )
    p.add_argument("--quick", action="store_true", help=f"{QUICK_TRIALS} trials per cell, results in <simulator>-quick")
    p.add_argument(
        "--marlander-policy", type=Path, metavar="FILE", help="centralised policy file (default: the shipped one)"
    )
    p.add_argument(
        "--single-agent-policy", type=Path, metavar="FILE", help="1-drone policy file (default: the shipped one)"
    )
    p.add_argument(
        "--marlander-plus-policy", type=Path, metavar="FILE", help="policy that observes the platform velocity"
    )
    p.add_argument("--out", type=Path, help="results folder (default runs/reproduce/<simulator>[-quick]-<time>)")
    p.add_argument(
        "--update-shipped",
        action="store_true",
        help="a full run that replaces data/results/<simulator> and refreshes docs/reproduction.md",
    )
    p.add_argument("--doc", type=Path, help="document whose include blocks to refresh (default: none)")
    p.add_argument("--no-doc", action="store_true", help="do not touch the document")
    p.add_argument("--report-only", action="store_true", help="rebuild tables, figures and doc from trials.csv")
    p.add_argument("--no-figures", action="store_true", help="skip Fig. 7 and the speed figure")
    p.add_argument(
        "--backend",
        choices=BACKENDS,
        default="local",
        help="local: --workers processes here (default); ray: one Ray task per block of trials (same results)",
    )
    p.add_argument("--address", help="ray: 'auto' (this machine's cluster) or HEAD_HOST:PORT; default: a private one")
    options = ConfigOptions(p, ProtocolConfig, ProtocolConfig(), skip=("policy_paths",), fields=PROTOCOL_FIELDS)
    p.set_defaults(func=run, config_options=options)


def config_from_args(args: argparse.Namespace) -> ProtocolConfig:
    """The :class:`ProtocolConfig` the command line asks for: the defaults, then the options given."""
    config = args.config_options.apply(ProtocolConfig(), args)
    policies = {name: getattr(args, dest) for name, dest in POLICY_DESTS.items() if getattr(args, dest) is not None}
    return replace(config, policy_paths=policies, trials=QUICK_TRIALS if args.quick else config.trials)


def partial_reasons(config: ProtocolConfig, quick: bool, controllers: tuple[str, ...]) -> list[str]:
    """Why ``config`` is not the full protocol over ``controllers`` (empty: it is)."""
    reasons = ["--quick"] if quick else []
    missing_conditions = [c for c in CONDITION_NAMES if c not in config.conditions]
    if missing_conditions:
        reasons.append(f"--conditions leaves out {', '.join(missing_conditions)}")
    if config.trials == "paper" or int(config.trials) < FULL_TRIALS:
        reasons.append(f"--trials {config.trials} (the full protocol flies {FULL_TRIALS} per cell)")
    missing_controllers = [c for c in controllers if c not in config.controllers]
    if missing_controllers:
        reasons.append(f"--controllers leaves out {', '.join(missing_controllers)}")
    return reasons


def _inside(path: Path, folder: Path) -> bool:
    return path.resolve().is_relative_to(folder.resolve())


def _shipped_controllers(out: Path) -> tuple[str, ...]:
    """The controllers of the run recorded in ``out/run.json``, or all of them."""
    try:
        return tuple(json.loads((out / "run.json").read_text())["config"]["controllers"])
    except (OSError, ValueError, KeyError, TypeError):
        return CONTROLLERS


def plan_output(args: argparse.Namespace) -> tuple[ProtocolConfig, Path, Path | None]:
    """The config, results folder and document of the run ``args`` ask for; refuses what would hurt shipped data.

    Raises ``ValueError`` naming the option before anything is written.
    """
    if args.update_shipped and args.quick:
        raise ValueError("--update-shipped needs a full run; drop --quick.")
    config = config_from_args(args)
    shipped_folder = RESULTS_ROOT / config.simulator
    if args.update_shipped:
        out = args.out or shipped_folder
        if "controllers" not in args.config_options.given(args) and not args.report_only:
            config = replace(config, controllers=_shipped_controllers(out))  # type: ignore[arg-type]
    if args.update_shipped:
        reasons = [] if args.report_only else partial_reasons(config, args.quick, _shipped_controllers(out))
        if reasons:
            raise ValueError(
                f"--update-shipped replaces {out} only with a full run, but: {'; '.join(reasons)}. "
                "Drop --update-shipped to write a partial run to runs/reproduce/."
            )
    elif args.report_only:
        out = args.out or shipped_folder  # rebuilding from the shipped trials.csv changes no measurement
    else:
        out = args.out or _new_run_folder(f"{config.simulator}{'-quick' if args.quick else ''}")
        if _inside(out, RESULTS_ROOT):
            raise ValueError(
                f"--out {out} is under {RESULTS_ROOT}, which holds the shipped results; only a full run with "
                "--update-shipped writes there. Choose another --out (default runs/reproduce/...)."
            )
    may_refresh_doc = args.update_shipped or (args.report_only and _inside(out, RESULTS_ROOT))
    doc = args.doc or (DEFAULT_DOC if may_refresh_doc else None)
    if args.no_doc:
        doc = None
    if doc is not None and doc.resolve() == DEFAULT_DOC.resolve() and not may_refresh_doc:
        raise ValueError(f"--doc {doc} is refreshed only from the shipped results (--update-shipped).")
    if args.report_only and not (out / "trials.csv").is_file():
        raise FileNotFoundError(f"--report-only: no trials.csv in {out}; pass the --out of an earlier run.")
    return config, out, doc


def _new_run_folder(name: str) -> Path:
    """``runs/reproduce/NAME-<time>``, with ``-2``, ``-3``... when a run started in the same second."""
    base = RUNS_ROOT / f"{name}-{time.strftime('%Y%m%d-%H%M%S')}"
    folder, count = base, 1
    while folder.exists():
        count += 1
        folder = base.with_name(f"{base.name}-{count}")
    return folder


def acquire_lock(folder: Path) -> Path:
    """Create ``folder/.reproduce.lock`` holding this PID; refuse a folder another live run holds.

    A lock whose PID is no longer running (a run that was killed) is taken over with a message.
    """
    folder.mkdir(parents=True, exist_ok=True)
    lock = folder / LOCK_NAME
    for _ in range(3):
        try:
            descriptor = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            pid = _lock_pid(lock)
            if pid is not None and _running(pid):
                raise FileExistsError(
                    f"--out {folder} is in use by another marlander command (PID {pid}, lock file {lock}); "
                    "wait for it to finish or choose another --out."
                ) from None
            print(f"Taking over the stale lock {lock} (PID {pid} is not running).", file=sys.stderr)
            lock.unlink(missing_ok=True)
            continue
        with os.fdopen(descriptor, "w") as handle:
            handle.write(f"{os.getpid()}\n")
        return lock
    raise FileExistsError(f"Could not take the lock {lock}; another run keeps creating it.")


def release_lock(lock: Path) -> None:
    """Remove ``lock`` if it is still ours."""
    if _lock_pid(lock) == os.getpid():
        lock.unlink(missing_ok=True)


def _lock_pid(lock: Path) -> int | None:
    try:
        return int(lock.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    return True


def run(args: argparse.Namespace) -> int:
    if args.address is not None and args.backend != "ray":
        raise ValueError("--address applies to --backend ray only.")
    config, out, doc = plan_output(args)
    if not args.report_only:
        check_policies(config)  # a missing policy file stops the run before any folder is made
    lock = acquire_lock(out)
    try:
        return _run_locked(args, config, out, doc)
    finally:
        release_lock(lock)


def _run_locked(args: argparse.Namespace, config: ProtocolConfig, out: Path, doc: Path | None) -> int:
    started = time.perf_counter()
    if args.report_only:
        records = tables.read_trials_csv(out / "trials.csv")
        config = replace(
            config,
            controllers=tuple(dict.fromkeys(r.controller for r in records)),  # type: ignore[arg-type]
            conditions=tuple(dict.fromkeys(r.condition for r in records)),  # type: ignore[arg-type]
        )
        flight_s = None
    else:
        print(f"marlander reproduce: {_describe(config)} -> {out}", file=sys.stderr)
        records = run_protocol(config, progress=_progress, backend=args.backend, address=args.address)
        flight_s = time.perf_counter() - started
        print(file=sys.stderr)
        # Tables come from the CSV as written (4-decimal cm), so --report-only rebuilds them exactly.
        records = tables.read_trials_csv(tables.write_trials_csv(records, out / "trials.csv"))
    written = write_report(records, config, out, figures_too=not args.no_figures)
    total_s = time.perf_counter() - started
    if not args.report_only:
        run_record = {
            "config": tables.record_json(config),
            "trials": len(records),
            "flight_seconds": round(flight_s or 0.0, 1),
            "total_seconds": round(total_s, 1),
            "command": command_line(config, out, update_shipped=args.update_shipped),
            "policies": flown_policies(config),
        }
        (out / "run.json").write_text(json.dumps(run_record, indent=2) + "\n")
        written.append(tables.write_markdown(tables.run_table(run_record), out / "run.md"))
    elif (out / "run.json").is_file():  # keep the record of the run that flew the trials
        run_record = json.loads((out / "run.json").read_text())
        written.append(tables.write_markdown(tables.run_table(run_record), out / "run.md"))
    if doc is not None and doc.is_file():
        includes.update_includes(doc)
        written.append(doc)
    print(f"{len(records)} trials; {total_s:.1f} s. Wrote:", *(f"  {p}" for p in written), sep="\n")
    return 0


def write_report(records: list[TrialRecord], config: ProtocolConfig, out: Path, figures_too: bool = True) -> list[Path]:
    """Summaries, tables and figures of ``records`` into ``out``; returns the files written."""
    sim = f"{config.simulator} simulator"
    by_condition = tables.summarise_records(records, "condition")
    by_group = tables.summarise_records(records, "group")
    written = [
        tables.write_summary_csv(by_condition, out / "summary_by_condition.csv"),
        tables.write_summary_csv(by_group, out / "summary_by_group.csv"),
        tables.write_markdown(tables.paper_table(by_group, "static", sim), out / "table_static.md"),
        tables.write_markdown(tables.paper_table(by_group, "moving", sim), out / "table_moving.md"),
        tables.write_markdown(tables.conditions_table(by_condition, sim), out / "table_conditions.md"),
        tables.write_markdown(tables.per_drone_table(by_group, sim), out / "table_per_drone.md"),
        tables.write_markdown(tables.gains_table(config.apf), out / "gains_baseline.md"),
        tables.write_markdown(tables.paper_intervals_table(), out / "paper_intervals.md"),
    ]
    if not figures_too:
        return written
    flown = {r.condition for r in records}
    panels = figures.fig7_conditions([c for c in CONDITION_NAMES if c in flown])
    figure_lines = []
    for name in dict.fromkeys(r.controller for r in records):
        if not panels:
            break
        trajectories = {letter: record_trajectory(config, name, cond, trial=0) for letter, cond in panels.items()}
        written.append(figures.write_trajectories_csv(trajectories, out / f"trajectories_{name}.csv"))
        title = f"Fig. 7 reproduced: {figures.CONTROLLER_LABELS[name]}, {sim}, trial 0 of each condition"
        png = figures.save(figures.plot_trajectories(trajectories, title), out / f"fig7_{name}.png")
        written.append(png)
        figure_lines.append(f"![{title}]({png.name})\n")
    moving = [r for r in by_condition if condition(r.cell).group == "moving"]
    if moving:
        png = figures.save(
            figures.plot_speed(by_condition, f"Success and error versus platform speed, {sim}"),
            out / "fig_speed.png",
        )
        written.append(png)
        figure_lines.append(f"![Success and landing error versus platform speed]({png.name})\n")
    written.append(tables.write_markdown("\n".join(figure_lines), out / "figures.md"))
    return written


def command_line(config: ProtocolConfig, out: Path, update_shipped: bool = False) -> str:
    """The ``marlander reproduce`` command that repeats ``config`` into ``out``."""
    parts = ["marlander reproduce", f"--simulator {config.simulator}"]
    if update_shipped:
        parts.append("--update-shipped")
    if config.controllers != PAPER_CONTROLLERS:
        parts.append("--controllers " + ",".join(config.controllers))
    if config.conditions != CONDITION_NAMES:
        parts.append("--conditions " + ",".join(config.conditions))
    parts += [f"--trials {config.trials}", f"--seed {config.seed}", f"--sensing {config.sensing}"]
    parts += [f"--time-limit {config.time_limit_s:g}", f"--workers {config.workers}"]
    flags = (
        ("--marlander-policy", "marlander"),
        ("--single-agent-policy", "single-agent-apf"),
        ("--marlander-plus-policy", "marlander-plus"),
    )
    for flag, name in flags:
        if name in config.policy_paths:
            parts.append(f"{flag} {config.policy_paths[name]}")
    parts += changed_options(config, ProtocolConfig(), skip=COMMAND_LINE_FIELDS)  # --num-drones, --apf.*, ...
    return " ".join([*parts, f"--out {out}"])


def _describe(config: ProtocolConfig) -> str:
    return (
        f"{config.simulator}, controllers {','.join(config.controllers)}, {len(config.conditions)} conditions, "
        f"trials {config.trials}, sensing {config.sensing}, {config.workers} worker(s)"
    )


def flown_policies(config: ProtocolConfig) -> dict[str, dict[str, str]]:
    """Per policy controller of ``config``: the policy file it flew and the file's sha256, for ``run.json``
    (the default files change between releases; the record says which ones these trials used)."""
    flown = {}
    for name in config.controllers:
        path = config.spec(name).resolved_policy_path
        if path is not None:
            flown[name] = {"file": str(path), "sha256": file_sha256(path)}
    return flown


def _progress(done: int, total: int) -> None:
    print(f"\r  {done}/{total} trials", end="", file=sys.stderr, flush=True)
