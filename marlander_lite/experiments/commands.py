"""``marlander reproduce``: fly the paper's experiments and write Tables I and II, Fig. 7 and the speed figure.

Examples::

    marlander reproduce --quick --controllers baseline            # a few trials, < 3 min on 2 cores
    marlander reproduce --simulator pointmass                     # 100 trials per controller and condition
    marlander reproduce --simulator crazyflie --trials paper      # the paper's counts, PyBullet
    marlander reproduce --report-only --simulator pointmass       # rebuild tables/figures/docs from trials.csv

Results go to ``data/results/<simulator>/`` (``<simulator>-quick`` with ``--quick``): ``trials.csv``,
``summary_by_condition.csv``, ``summary_by_group.csv``, ``table_static.md``, ``table_moving.md``,
``table_conditions.md``, ``table_per_drone.md``, ``gains_baseline.md``, ``fig7_<controller>.png``,
``trajectories_<controller>.csv``, ``fig_speed.png`` and ``run.json``. A full (not ``--quick``) run
then refreshes the include blocks of ``docs/reproduction.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from marlander_lite.experiments import figures, includes, tables
from marlander_lite.experiments.controllers import CONTROLLERS, PAPER_CONTROLLERS
from marlander_lite.experiments.protocol import (
    CONDITION_NAMES,
    SENSING_NAMES,
    ProtocolConfig,
    TrialRecord,
    condition,
    record_trajectory,
    run_protocol,
)
from marlander_lite.make import SIMULATORS

RESULTS_ROOT = Path("data/results")
DEFAULT_DOC = Path("docs/reproduction.md")
QUICK_TRIALS = 3
"""Trials per controller and condition with ``--quick``."""


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


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``reproduce`` to the ``marlander`` command line."""
    p = subparsers.add_parser(
        "reproduce",
        help="fly the paper's experiments (Tables I, II, Fig. 7) and write data/results",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--simulator", choices=SIMULATORS, default="pointmass", help="physics back end (default pointmass)")
    p.add_argument(
        "--controllers",
        type=_choices(CONTROLLERS, "controller(s)"),
        default=PAPER_CONTROLLERS,
        help=f"comma-separated, from {', '.join(CONTROLLERS)} (default: the paper's {', '.join(PAPER_CONTROLLERS)})",
    )
    p.add_argument(
        "--conditions",
        type=_choices(CONDITION_NAMES, "condition(s)"),
        default=CONDITION_NAMES,
        help=f"comma-separated, from {', '.join(CONDITION_NAMES)} (default all)",
    )
    p.add_argument("--trials", type=_trials, default=100, help="trials per controller and condition, or 'paper'")
    p.add_argument("--quick", action="store_true", help=f"{QUICK_TRIALS} trials per cell, results in <simulator>-quick")
    p.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    p.add_argument("--seed", type=int, default=0, help="base seed of the trials (default 0)")
    p.add_argument("--sensing", choices=SENSING_NAMES, default="vicon", help="observation model (default vicon)")
    p.add_argument("--time-limit", type=float, default=30.0, help="seconds before a trial times out (default 30)")
    p.add_argument("--marlander-policy", type=Path, help="centralised policy file (default: the shipped one)")
    p.add_argument("--single-agent-policy", type=Path, help="1-drone policy file (default: the shipped one)")
    p.add_argument("--marlander-plus-policy", type=Path, help="policy that observes the platform velocity")
    p.add_argument("--out", type=Path, help="results folder (default data/results/<simulator>[-quick])")
    p.add_argument("--doc", type=Path, help="document whose include blocks to refresh (default docs/reproduction.md)")
    p.add_argument("--no-doc", action="store_true", help="do not touch the document")
    p.add_argument("--report-only", action="store_true", help="rebuild tables, figures and doc from trials.csv")
    p.add_argument("--no-figures", action="store_true", help="skip Fig. 7 and the speed figure")
    p.set_defaults(func=run)


def config_from_args(args: argparse.Namespace) -> ProtocolConfig:
    """The :class:`ProtocolConfig` the command line asks for."""
    policies = {}
    if args.marlander_policy is not None:
        policies["marlander"] = args.marlander_policy
    if args.single_agent_policy is not None:
        policies["single-agent-apf"] = args.single_agent_policy
    if args.marlander_plus_policy is not None:
        policies["marlander-plus"] = args.marlander_plus_policy
    config = ProtocolConfig(
        simulator=args.simulator,
        controllers=args.controllers,
        conditions=args.conditions,
        trials=QUICK_TRIALS if args.quick else args.trials,
        seed=args.seed,
        sensing=args.sensing,
        time_limit_s=args.time_limit,
        policy_paths=policies,
        workers=args.workers,
    )
    return config


def run(args: argparse.Namespace) -> int:
    config = config_from_args(args)
    out = args.out or RESULTS_ROOT / (config.simulator + ("-quick" if args.quick else ""))
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
        records = run_protocol(config, progress=_progress)
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
            "command": command_line(config, out),
        }
        (out / "run.json").write_text(json.dumps(run_record, indent=2) + "\n")
        written.append(tables.write_markdown(tables.run_table(run_record), out / "run.md"))
    elif (out / "run.json").is_file():  # keep the record of the run that flew the trials
        run_record = json.loads((out / "run.json").read_text())
        written.append(tables.write_markdown(tables.run_table(run_record), out / "run.md"))
    doc = args.doc or (None if args.quick else DEFAULT_DOC)
    if doc is not None and not args.no_doc and doc.is_file():
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


def command_line(config: ProtocolConfig, out: Path) -> str:
    """The ``marlander reproduce`` command that repeats ``config`` into ``out``."""
    parts = ["marlander reproduce", f"--simulator {config.simulator}"]
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
    return " ".join([*parts, f"--out {out}"])


def _describe(config: ProtocolConfig) -> str:
    return (
        f"{config.simulator}, controllers {','.join(config.controllers)}, {len(config.conditions)} conditions, "
        f"trials {config.trials}, sensing {config.sensing}, {config.workers} worker(s)"
    )


def _progress(done: int, total: int) -> None:
    print(f"\r  {done}/{total} trials", end="", file=sys.stderr, flush=True)
