"""``marlander train | evaluate | export | plot | quickstart``.

Every option is checked before any work starts: a bad value, a run directory already in use or
an output file that exists (without ``--force``) ends the command with one line naming the
option (see :mod:`marlander_lite.cli`).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from marlander_lite.cli import check_output_file, non_negative_int, positive_int
from marlander_lite.make import SIMULATORS
from marlander_lite.platforms import PLATFORM_KINDS
from marlander_lite.training.presets import FINETUNE_PRESETS, PRESETS, describe_presets, get_preset

IMAGE_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")
"""File types ``plot --out`` can write (matplotlib would silently append .png to a name without one)."""


def register(subparsers: argparse._SubParsersAction) -> None:
    train = subparsers.add_parser("train", help="train a policy with a preset (PPO)")
    train.add_argument("--preset", help=f"one of: {', '.join(PRESETS)} (default quick-cpu)")
    train.add_argument("--env", choices=SIMULATORS, help="simulator (default: the preset's)")
    train.add_argument("--seed", type=non_negative_int, help="random seed (default: the preset's)")
    train.add_argument("--steps", type=positive_int, help="environment steps (default: the preset's)")
    train.add_argument("--out", type=Path, help="run directory (default: runs/PRESET-seedS-TIME)")
    train.add_argument("--init-from", type=Path, help="a run directory to fine-tune from")
    train.add_argument(
        "--resume", type=Path, metavar="RUN", help="finish a run stopped with Ctrl-C, to its configured steps"
    )
    train.add_argument("--no-progress", action="store_true", help="no progress bar")
    train.add_argument("--list", action="store_true", help="list the presets and exit")
    train.set_defaults(func=run_train)

    evaluate = subparsers.add_parser("evaluate", help="run a policy file and report success and landing error")
    _add_evaluation_arguments(evaluate)
    evaluate.add_argument("policy", type=Path, help="a policy file (.safetensors) or a run directory")
    evaluate.add_argument("--json", type=Path, help="also write the summary to this JSON file")
    evaluate.add_argument("--force", action="store_true", help="overwrite an existing --json file")
    evaluate.set_defaults(func=run_evaluate)

    export = subparsers.add_parser("export", help="write a run's (or checkpoint's) policy as a pickle-free file")
    export.add_argument("run", type=Path, help="a training run directory")
    export.add_argument("--checkpoint", type=non_negative_int, help="export the checkpoint saved at this step instead")
    export.add_argument(
        "--out",
        type=Path,
        help="output file (default: RUN/policy.safetensors, or RUN/checkpoints/policy_STEP.safetensors)",
    )
    export.add_argument("--force", action="store_true", help="overwrite an existing output file")
    export.set_defaults(func=run_export)

    plot = subparsers.add_parser("plot", help="figures")
    plot_sub = plot.add_subparsers(dest="figure", metavar="FIGURE", required=True)
    curves = plot_sub.add_parser("curves", help="training curves like the paper's Fig. 5 and Fig. 6")
    curves.add_argument("runs", nargs="+", type=Path, help="run directories or progress.csv files")
    curves.add_argument("--labels", nargs="+", help="one label per run")
    curves.add_argument("--curves", nargs="+", default=["reward", "length"], help="reward, length, success, error")
    curves.add_argument(
        "--out", type=Path, default=Path("training_curves.png"), help=f"image file ({', '.join(IMAGE_SUFFIXES)})"
    )
    curves.add_argument("--force", action="store_true", help="overwrite an existing image")
    curves.set_defaults(func=run_plot_curves)

    quick = subparsers.add_parser("quickstart", help="train quick-cpu, evaluate it and plot its curves")
    quick.add_argument("--out", type=Path, default=Path("runs/quickstart"), help="run directory")
    quick.add_argument("--seed", type=non_negative_int, default=0)
    quick.add_argument("--episodes", type=positive_int, default=500, help="evaluation episodes")
    quick.add_argument(
        "--firmware-episodes",
        type=positive_int,
        default=50,
        help="episodes flown in PyBullet through the Crazyflie firmware's velocity tracker (default 50)",
    )
    quick.set_defaults(func=run_quickstart)


def _add_evaluation_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--env", choices=SIMULATORS, default="pointmass", help="simulator")
    parser.add_argument("--platform", choices=PLATFORM_KINDS, default="static-floor")
    parser.add_argument("--platform-speed", type=float, help="m/s, moving platforms")
    parser.add_argument("--sensing", choices=("perfect", "vicon"), default="perfect")
    parser.add_argument("--episodes", type=positive_int, default=200)
    parser.add_argument("--eval-seed", type=non_negative_int, default=12345, help="seed of the evaluation episodes")


def run_train(args: argparse.Namespace) -> int:
    from marlander_lite.training.train import check_new_run, continue_from, resume, train

    if args.list:
        print(describe_presets())
        return 0
    if args.resume is not None:
        given = {"--preset": args.preset, "--env": args.env, "--seed": args.seed, "--steps": args.steps}
        given.update({"--out": args.out, "--init-from": args.init_from})
        extra = [flag for flag, value in given.items() if value is not None]
        if extra:
            raise ValueError(f"--resume continues RUN with its own config.json; drop {', '.join(extra)}.")
        files = resume(args.resume, progress_bar=not args.no_progress)
        print(f"Done. Policy: {files.policy}")
        return 0
    preset = args.preset or "quick-cpu"
    config = get_preset(preset)
    changes = {"simulator": args.env, "seed": args.seed, "total_steps": args.steps}
    config = config.replace(**{k: v for k, v in changes.items() if v is not None})
    if args.init_from:
        config = continue_from(config, args.init_from)
    elif preset in FINETUNE_PRESETS:
        raise ValueError(
            f"--preset {preset} continues a trained run: pass --init-from RUN_DIR "
            "(a directory written by 'marlander train', e.g. data/runs/quick-cpu)."
        )
    out = args.out or Path("runs") / f"{preset}-seed{config.seed}-{time.strftime('%Y%m%d-%H%M%S')}"
    check_new_run(config, out)
    print(f"Training preset {preset!r} on {config.simulator} for {config.total_steps:,} steps -> {out}")
    files = train(config, out, preset=preset, progress_bar=not args.no_progress)
    print(f"Done. Policy: {files.policy}")
    return 0


def _policy_path(path: Path) -> Path:
    return path / "policy.safetensors" if path.is_dir() else path


def run_evaluate(args: argparse.Namespace) -> int:
    from marlander_lite.training.evaluation import evaluate_policy_file

    policy = _policy_path(args.policy)
    if args.json is not None:
        check_output_file(args.json, "--json", args.force, reading=[policy])
    summary = evaluate_policy_file(
        policy,
        simulator=args.env,
        episodes=args.episodes,
        seed=args.eval_seed,
        platform=args.platform,
        platform_speed=args.platform_speed,
        sensing=args.sensing,
    )
    print(f"{args.env}, {args.platform}, sensing {args.sensing}: {summary}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(summary.to_dict(), indent=2))
        print(f"Wrote {args.json}")
    return 0


def run_export(args: argparse.Namespace) -> int:
    from marlander_lite.training.train import RunFiles, read_run_record

    files = RunFiles(args.run)
    record = read_run_record(files, "export RUN")
    model_path, norm_path = files.model, files.normalizer
    out = args.out or files.policy
    if args.checkpoint is not None:
        model_path = files.checkpoints / f"model_{args.checkpoint}.zip"
        norm_path = files.checkpoints / f"vecnormalize_{args.checkpoint}.pkl"
        out = args.out or files.checkpoints / f"policy_{args.checkpoint}.safetensors"
    if not model_path.is_file():
        saved = sorted(int(p.stem.split("_")[1]) for p in files.checkpoints.glob("model_*.zip"))
        hint = f" Saved checkpoints: {', '.join(map(str, saved))}." if saved else ""
        raise FileNotFoundError(f"No model at {model_path}.{hint}")
    check_output_file(out, "--out", args.force, reading=[files.config, model_path, norm_path])

    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from marlander_lite.training.export import export_policy
    from marlander_lite.training.presets import TrainConfig
    from marlander_lite.training.train import make_training_env, task_config_of

    config = TrainConfig.from_dict(record["train"])
    model = PPO.load(model_path, device="cpu")
    normalizer = (
        VecNormalize.load(str(norm_path), make_training_env(config, num_envs=1)) if norm_path.is_file() else None
    )
    extra = {"preset": record.get("preset"), "simulator": config.simulator, "steps": int(model.num_timesteps)}
    export_policy(model, out, task_config_of(config), normalizer, extra=extra)
    print(f"Wrote {out}")
    return 0


def run_plot_curves(args: argparse.Namespace) -> int:
    from marlander_lite.plotting import plot_training_curves, progress_path

    logs = [progress_path(run) for run in args.runs]
    check_output_file(args.out, "--out", args.force, reading=logs, suffixes=IMAGE_SUFFIXES)
    plot_training_curves(args.runs, args.labels, args.curves, out=args.out)
    print(f"Wrote {args.out}")
    return 0


def run_quickstart(args: argparse.Namespace) -> int:
    """The README's main job: quick training, evaluation on the paper's random starts, figure."""
    from marlander_lite.budget import scaled
    from marlander_lite.plotting import plot_training_curves
    from marlander_lite.training.evaluation import evaluate_policy_file
    from marlander_lite.training.train import check_new_run, train

    config = get_preset("quick-cpu").replace(
        seed=args.seed, total_steps=scaled(get_preset("quick-cpu").total_steps, 20_000)
    )
    episodes = scaled(args.episodes, 20)
    firmware_episodes = scaled(args.firmware_episodes, 4)
    check_new_run(config, args.out)  # before three minutes of training, not after
    started = time.perf_counter()
    files = train(config, args.out, preset="quick-cpu", progress_bar=sys.stdout.isatty())
    minutes = (time.perf_counter() - started) / 60
    print(f"Trained {config.total_steps:,} steps in {minutes:.1f} min -> {files.policy}")
    for platform in ("static-floor", "static-elevated"):
        summary = evaluate_policy_file(files.policy, episodes=episodes, platform=platform)
        print(f"{platform}: {summary}")
        (files.root / f"evaluation-{platform}.json").write_text(json.dumps(summary.to_dict(), indent=2))
    # Judged where it will fly: the same policy, untouched, in PyBullet through the firmware's own tracker.
    summary = evaluate_policy_file(
        files.policy, simulator="crazyflie", episodes=firmware_episodes, platform="static-floor", controller="firmware"
    )
    print(f"static-floor, PyBullet Crazyflie with the firmware tracker (never trained there): {summary}")
    (files.root / "evaluation-crazyflie-firmware.json").write_text(json.dumps(summary.to_dict(), indent=2))
    figure = files.root / "training_curves.png"
    plot_training_curves([files.root], ["quick-cpu"], ("reward", "length", "success", "error"), out=figure)
    print(f"Training curves (paper Fig. 5 and 6): {figure}")
    return 0
