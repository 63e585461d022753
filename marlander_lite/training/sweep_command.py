"""``marlander sweep`` (several seeds of a preset, here or on a Ray cluster) and ``marlander shipped``
(retrain the shipped policies and say which today's code still reproduces).

Examples::

    marlander sweep --preset quick-cpu --seeds 0-4 --out runs/sweeps/quick-cpu
    marlander sweep --preset quick-cpu --seeds 0-2 --learning-rate 1e-4 --task.landing-tolerance 0.02
    marlander sweep --preset paper --seeds 0-2 --backend ray --address auto
    marlander sweep --preset quick-cpu --seeds 3 --out runs/sweeps/quick-cpu   # rerun one failed seed

Running the same command again continues an interrupted sweep; seeds already trained are skipped.
``marlander shipped list`` lists the shipped policies against ``data/shipped.json``;
``marlander shipped check quick-cpu`` retrains one and compares it (:mod:`marlander_lite.training.shipped`).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from marlander_lite.cli import positive_int
from marlander_lite.config_cli import ConfigOptions
from marlander_lite.distributed import BACKENDS
from marlander_lite.experiments.commands import acquire_lock, release_lock
from marlander_lite.pointmass.simulator import PointMassParams
from marlander_lite.task import TaskConfig
from marlander_lite.training.commands import DEFAULT_PRESET, TRAIN_FIELDS
from marlander_lite.training.presets import FINETUNE_PRESETS, PRESETS, TrainConfig, get_preset
from marlander_lite.training.sweep import SWEEP_CONDITIONS, evaluate_sweep, parse_seeds, run_sweep


def register(subparsers: argparse._SubParsersAction) -> None:
    sweep = subparsers.add_parser("sweep", help="train a preset with several seeds, evaluate each, report intervals")
    sweep.add_argument("--preset", default="quick-cpu", help=f"one of: {', '.join(PRESETS)} (default quick-cpu)")
    sweep.add_argument("--seeds", required=True, help="seeds to train, e.g. 0-4, 0,2,7 or 0-2,5")
    sweep.add_argument("--out", type=Path, help="sweep folder (default: runs/sweeps/PRESET-TIME)")
    sweep.add_argument("--backend", choices=BACKENDS, default="local", help="local processes (default) or ray")
    sweep.add_argument(
        "--address", help="ray: 'auto' (this machine's cluster) or HEAD_HOST:PORT; default: a private one"
    )
    sweep.add_argument(
        "--workers", type=positive_int, help="local: runs at a time (default: CPU cores / the preset's torch threads)"
    )
    sweep.add_argument(
        "--evaluate",
        choices=(*SWEEP_CONDITIONS, "none"),
        default="quick",
        help="conditions each seed is flown on afterwards (default quick: point mass and PyBullet firmware tracker)",
    )
    options = ConfigOptions(
        sweep,
        TrainConfig,
        get_preset(DEFAULT_PRESET),
        mappings={"task": TaskConfig, "dynamics": PointMassParams},
        skip=("init_from", "task.num_drones", "seed"),  # each seed comes from --seeds
        fields={k: v for k, v in TRAIN_FIELDS.items() if k != "seed"},
        title="TrainConfig fields, as for 'marlander train' (default: the preset's value)",
    )
    sweep.set_defaults(func=run, config_options=options)

    shipped = subparsers.add_parser(
        "shipped", help="list the shipped policies, or retrain them and say which today's code still reproduces"
    )
    shipped.add_argument("action", choices=("list", "check"), help="list: the manifest; check: retrain and compare")
    shipped.add_argument("names", nargs="*", help="artifacts to check (default: all), e.g. quick-cpu v0.1/quick-cpu")
    shipped.add_argument("--out", type=Path, default=Path("runs/shipped-check"), help="where the retrained runs go")
    shipped.add_argument("--data", type=Path, default=Path("data"), help="the shipped data folder")
    shipped.add_argument("--backend", choices=BACKENDS, default="local", help="local processes (default) or ray")
    shipped.add_argument("--address", help="ray: 'auto' or HEAD_HOST:PORT; default: a private one")
    shipped.add_argument("--workers", type=positive_int, default=1, help="local: runs at a time (default 1)")
    shipped.add_argument("--episodes", type=positive_int, default=200, help="evaluation episodes when weights differ")
    shipped.set_defaults(func=run_shipped)


def run(args: argparse.Namespace) -> int:
    from marlander_lite.experiments.seed_stats import summarise_sweep

    if args.preset in FINETUNE_PRESETS:
        raise ValueError(f"--preset {args.preset} fine-tunes a trained run; a sweep trains presets from scratch.")
    if args.address is not None and args.backend != "ray":
        raise ValueError("--address applies to --backend ray only.")
    seeds = parse_seeds(args.seeds)
    config = args.config_options.apply(get_preset(args.preset), args)
    out = args.out or Path("runs") / "sweeps" / f"{args.preset}-{time.strftime('%Y%m%d-%H%M%S')}"
    lock = acquire_lock(out)
    try:
        outcomes = run_sweep(
            config, seeds, out, preset=args.preset, backend=args.backend, workers=args.workers, address=args.address
        )
        if args.evaluate != "none" and evaluate_sweep(out, args.evaluate).is_file():
            print(summarise_sweep(out, args.evaluate))
    finally:
        release_lock(lock)
    unfinished = [o for o in outcomes if o.status != "done"]
    for outcome in unfinished:
        how = "resume it" if outcome.status == "interrupted" else "train it again"
        print(
            f"seed {outcome.seed} {outcome.status}; to {how}: marlander sweep --preset {args.preset} "
            f"--seeds {outcome.seed} --out {out}"
        )
    return 1 if unfinished else 0


def run_shipped(args: argparse.Namespace) -> int:
    from marlander_lite.training.shipped import (
        MANIFEST,
        check_manifest,
        check_shipped,
        markdown_report,
        shipped_artifacts,
    )

    if args.address is not None and args.backend != "ray":
        raise ValueError("--address applies to --backend ray only.")
    if args.action == "list":
        changed = set(check_manifest(args.data)) if (args.data / MANIFEST).is_file() else set()
        for a in shipped_artifacts(args.data):
            state = "retrainable" if a.problem is None else f"not retrainable: {a.problem}"
            flag = "  CHANGED since the manifest" if a.name in changed else ""
            print(f"{a.name:<34} {a.preset or '':<26} {state}{flag}")
        return 1 if changed else 0
    lock = acquire_lock(args.out)
    try:
        results = check_shipped(
            args.names,
            args.out,
            data=args.data,
            backend=args.backend,
            workers=args.workers,
            address=args.address,
            episodes=args.episodes,
        )
    finally:
        release_lock(lock)
    print(markdown_report(results))
    accepted = ("identical", "identical weights", "equivalent", "not retrainable")
    return 0 if all(r["status"] in accepted for r in results) else 1
