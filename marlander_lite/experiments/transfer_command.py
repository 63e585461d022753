"""``marlander transfer POLICY``: fly one policy on every simulator and tracker of the transfer matrix.

Examples::

    marlander transfer data/policies/quick-cpu.safetensors                  # 200 episodes a cell, 28 cells
    marlander transfer P --episodes 20 --rows floor,UR10 --out runs/t      # a quick look
    marlander transfer P --columns "point mass,PyBullet firmware"
    marlander transfer P --safety-filter cone_radius=0.04,reaction_time=0.35  # as deployed, moving pads
    marlander transfer data/policies/moving-slow-trackers.safetensors --safety-filter pad-frame  # named settings
    marlander transfer data/policies/shared-quick-paired.safetensors --num-drones 8  # a shared policy, 8 drones
    marlander transfer P --rows "arc 0.2-0.5 m/s" --command-frame pad  # a static policy carried by the pad
    marlander transfer P --variants 40 --episodes 25 --rows floor,UR10   # 40 random Crazyflies instead of columns
    marlander transfer P --variants 40 --episodes 25 --variant-simulator pyflyt  # the same draw, in PyFlyt
    marlander transfer P --variants 40 --episodes 25 --variant-simulator rotorpy  # and in RotorPy
    marlander transfer P --columns all --targets paper   # and check the matrix against the paper policy's targets

Writes ``transfer.csv``, ``transfer.json`` and ``transfer.md`` to ``--out`` (default
``runs/transfer-<policy name>``) and prints the table; with ``--variants``, ``variants.csv``, ``.json`` and ``.md``
(default ``runs/variants-<policy name>``). Existing files are kept unless ``--force``.

Each finished cell is kept in ``--out`` as it is flown (``transfer.partial.jsonl``, ``variants.partial.jsonl``): run
an interrupted command again, as it was, and it flies only the cells still missing (``--force`` flies them all again).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

from marlander_lite.experiments import targets as transfer_targets
from marlander_lite.experiments import variants as random_variants
from marlander_lite.experiments.cell_journal import CellJournal, matrix_fingerprint
from marlander_lite.experiments.commands import _choices
from marlander_lite.experiments.transfer import (
    COLUMNS,
    EXTRA_COLUMNS,
    ROWS,
    Column,
    TransferConfig,
    format_flight_table,
    format_table,
    transfer_matrix,
    write_results,
)
from marlander_lite.pad_frame_lead import lead_argument
from marlander_lite.swarm.safety_filter import parse_settings
from marlander_lite.task import COMMAND_FRAMES

OUTPUT_NAMES = ("transfer.csv", "transfer.json", "transfer.md")
JOURNAL_NAME = "transfer.partial.jsonl"
VARIANTS_JOURNAL_NAME = "variants.partial.jsonl"


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``transfer`` to the ``marlander`` command line."""
    p = subparsers.add_parser(
        "transfer",
        help="fly a policy on every simulator and tracker (the transfer matrix)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("policy", type=Path, help="policy file (.safetensors)")
    p.add_argument("--episodes", type=int, default=200, help="episodes per cell (default 200)")
    p.add_argument("--seed", type=int, default=0, help="base seed of the episodes (default 0)")
    columns = tuple(c.name for c in COLUMNS)
    extra = tuple(c.name for c in EXTRA_COLUMNS)
    rows = tuple(r.name for r in ROWS)
    column_help = f"comma-separated, from: {', '.join(columns)} (the default), {', '.join(extra)} (or all)"
    p.add_argument(
        "--columns",
        type=_choices(columns + extra, "column(s)"),
        default=None,
        help=column_help.replace("%", "%%"),  # argparse formats help
    )
    p.add_argument(
        "--rows", type=_choices(rows, "row(s)"), default=rows, help=f"comma-separated, from: {', '.join(rows)} (or all)"
    )
    p.add_argument("--sensing", choices=("vicon", "perfect"), default="vicon", help="observation model (default vicon)")
    p.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    p.add_argument(
        "--num-drones",
        type=int,
        default=None,
        help="swarm size a shared policy flies (default 2); a centralised policy flies its own",
    )
    p.add_argument(
        "--safety-filter",
        nargs="?",
        const={},
        type=_filter_settings,
        metavar="KEY=VALUE,...",
        help="fly every command through the safety filter `marlander deploy` puts after the policy, with its "
        "defaults or these changes to them (e.g. cone_radius=0.04, or a named set: moving-pads, pad-frame)",
    )
    p.add_argument(
        "--command-frame",
        choices=COMMAND_FRAMES,
        default=None,
        help="fly the commands in this frame instead of the policy's own: 'pad' adds each pad's velocity to its "
        "drone's command (TaskConfig.command_frame)",
    )
    p.add_argument(
        "--pad-frame-lead",
        type=lead_argument,
        default=None,
        metavar="S|auto",
        help="with the pad frame, lead the pad velocity a command carries by S seconds of the pad's acceleration "
        "(TaskConfig.pad_frame_lead; default: the policy's own), or 'auto': by 0.6 times the velocity tracker's lag "
        "identified in flight (marlander_lite.pad_frame_lead)",
    )
    p.add_argument(
        "--episode-seconds",
        type=float,
        default=None,
        metavar="S",
        help="each episode's time limit (default: the policy's training episode, 10 s; the paper protocol's is 30 s)",
    )
    p.add_argument(
        "--vertical-bias",
        action="store_true",
        help="identify each drone's steady vertical velocity bias in flight (the climb or sink a tracker without "
        "integral action adds when the drone's mass is not the one it assumes) and take it off the vertical commands "
        "(marlander_lite.swarm.vertical_bias)",
    )
    p.add_argument(
        "--variants",
        type=int,
        default=None,
        metavar="N",
        help="instead of the columns, fly N Crazyflies drawn at random (tracker, physics, mass, latency, gains, tilt "
        "clamp; marlander_lite.experiments.variants)",
    )
    p.add_argument("--variant-seed", type=int, default=0, help="seed of the --variants draw (default 0)")
    p.add_argument(
        "--variant-simulator",
        choices=random_variants.VARIANT_SIMULATORS,
        default=None,
        help="where the --variants fly: crazyflie (our PyBullet swarm, the default), pyflyt (PyFlyt's own "
        "controller with the drawn mass, latency, gains and tilt clamp; the optional extra pyflyt) or rotorpy "
        "(RotorPy's own controller with the drawn mass, latency and gains; the optional extra rotorpy)",
    )
    p.add_argument(
        "--variant-ranges",
        type=_variant_ranges,
        default=None,
        metavar="JSON",
        help='changes to the ranges the variants are drawn from, e.g. \'{"latency_s": [0, 0.1], "firmware_share": 1}\'',
    )
    p.add_argument(
        "--targets",
        choices=tuple(transfer_targets.TARGETS),
        default=None,
        help="after the matrix, check it against the issue's targets for this kind of policy (quick-cpu: static "
        "pads; paper, moving: static and moving pads; marlander_lite.experiments.targets)",
    )
    p.add_argument(
        "--out", type=Path, help="results folder (default runs/transfer-<policy name>, runs/variants-<policy name>)"
    )
    p.add_argument("--force", action="store_true", help="overwrite transfer.* (or variants.*) files already in --out")
    p.set_defaults(func=run)


def _filter_settings(text: str) -> dict[str, float]:
    """``--safety-filter``'s value, as :func:`~marlander_lite.swarm.safety_filter.parse_settings` reads it."""
    try:
        return parse_settings(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _variant_ranges(text: str) -> random_variants.VariantRanges:
    """``--variant-ranges``' JSON object as :class:`~marlander_lite.experiments.variants.VariantRanges`."""
    try:
        values = json.loads(text)
        if not isinstance(values, dict):
            raise ValueError(f"give a JSON object of field -> [low, high] or share, got {text!r}")
        return random_variants.VariantRanges.from_mapping(values)
    except (ValueError, TypeError) as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def open_journal(config: TransferConfig, path: Path, force: bool, columns: list[Column] | None = None) -> CellJournal:
    """The journal of this matrix at ``path``: an interrupted run's cells are resumed (``--force``: dropped)."""
    digest = hashlib.sha256(Path(config.policy).read_bytes()).hexdigest()
    journal = CellJournal(path, matrix_fingerprint(config, digest, columns), discard=force)
    if journal.done:
        total = len(config.rows) * (len(config.columns) if columns is None else len(columns))
        print(f"Resuming: {len(journal.done)} of {total} cells read back from {path} (an interrupted run's)")
    return journal


def run(args: argparse.Namespace) -> int:
    if not args.policy.is_file():
        raise FileNotFoundError(f"--policy: no file {args.policy}")
    if args.variants is None and (
        args.variant_ranges is not None or args.variant_seed != 0 or args.variant_simulator is not None
    ):
        raise ValueError("--variant-seed, --variant-ranges and --variant-simulator need --variants N")
    if args.variants is not None and args.columns is not None:
        raise ValueError("--variants flies random Crazyflies instead of the columns: leave --columns out")
    if args.variants is not None and args.targets is not None:
        raise ValueError("--targets checks the columns' matrix, not random Crazyflies: drop --targets or --variants")
    config = TransferConfig(
        policy=str(args.policy),
        episodes=args.episodes,
        seed=args.seed,
        columns=args.columns or tuple(c.name for c in COLUMNS),
        rows=args.rows,
        sensing=args.sensing,
        workers=args.workers,
        safety_filter=args.safety_filter,
        num_drones=args.num_drones,
        command_frame=args.command_frame,
        pad_frame_lead=args.pad_frame_lead,
        episode_seconds=args.episode_seconds,
        vertical_bias=args.vertical_bias,
    )
    if args.variants is not None:
        return run_variants(args, config)
    out = args.out or Path("runs") / f"transfer-{args.policy.stem}"
    existing = [out / name for name in OUTPUT_NAMES if (out / name).exists()]
    if existing and not args.force:
        raise ValueError(f"--out: {', '.join(map(str, existing))} already exist; choose another --out or add --force")
    journal = open_journal(config, out / JOURNAL_NAME, args.force)
    cells = len(config.rows) * len(config.columns)
    print(f"Flying {args.policy} on {cells} cells x {config.episodes} episodes ({config.workers} workers) ...")
    started = time.perf_counter()
    try:
        results = transfer_matrix(config, journal=journal)
    except KeyboardInterrupt:
        raise journal.interrupted() from None
    wall = journal.earlier_wall_s + time.perf_counter() - started
    paths = write_results(config, results, out, wall)
    journal.remove()
    print(format_table(results))
    print()
    print(format_flight_table(results))
    if args.targets is not None:
        print()
        print(transfer_targets.format_targets(results, transfer_targets.TARGETS[args.targets]))
    print(f"\n{wall:.0f} s; wrote {', '.join(map(str, paths))}", file=sys.stderr)
    return 0


def run_variants(args: argparse.Namespace, config: TransferConfig) -> int:
    """``--variants N``: draw N Crazyflies, fly the policy on each, write ``variants.*`` and print the summary."""
    ranges = args.variant_ranges or random_variants.VariantRanges()
    simulator = args.variant_simulator or "crazyflie"
    drawn = random_variants.draw_variants(args.variants, args.variant_seed, ranges, simulator)
    out = args.out or Path("runs") / f"variants-{args.policy.stem}"
    existing = [out / name for name in random_variants.OUTPUT_NAMES if (out / name).exists()]
    if existing and not args.force:
        raise ValueError(f"--out: {', '.join(map(str, existing))} already exist; choose another --out or add --force")
    journal = open_journal(config, out / VARIANTS_JOURNAL_NAME, args.force, [v.column() for v in drawn])
    print(f"Flying {args.policy} on {len(drawn)} random Crazyflies in {simulator}, {len(config.rows)} rows")
    started = time.perf_counter()
    try:
        results = random_variants.fly_variants(config, drawn, journal)
    except KeyboardInterrupt:
        raise journal.interrupted() from None
    wall = journal.earlier_wall_s + time.perf_counter() - started
    paths = random_variants.write_variants(config, ranges, args.variant_seed, drawn, results, out, wall)
    journal.remove()
    print(random_variants.format_summary(results, drawn))
    print(f"\n{wall:.0f} s; wrote {', '.join(map(str, paths))}", file=sys.stderr)
    return 0
