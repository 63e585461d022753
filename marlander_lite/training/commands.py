"""``marlander train | evaluate | export | plot | quickstart``."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from marlander_lite.make import SIMULATORS
from marlander_lite.platforms import PLATFORM_KINDS
from marlander_lite.training.presets import FINETUNE_PRESETS, PRESETS, describe_presets, get_preset


def register(subparsers: argparse._SubParsersAction) -> None:
    train = subparsers.add_parser("train", help="train a policy with a preset (PPO)")
    train.add_argument("--preset", default="quick-cpu", help=f"one of: {', '.join(PRESETS)} (default quick-cpu)")
    train.add_argument("--env", choices=SIMULATORS, help="simulator (default: the preset's)")
    train.add_argument("--seed", type=int, help="random seed (default: the preset's)")
    train.add_argument("--steps", type=int, help="environment steps (default: the preset's)")
    train.add_argument("--out", type=Path, help="run directory (default: runs/PRESET-seedS-TIME)")
    train.add_argument("--init-from", type=Path, help="a run directory to fine-tune from")
    train.add_argument("--no-progress", action="store_true", help="no progress bar")
    train.add_argument("--list", action="store_true", help="list the presets and exit")
    train.set_defaults(func=run_train)

    evaluate = subparsers.add_parser("evaluate", help="run a policy file and report success and landing error")
    _add_evaluation_arguments(evaluate)
    evaluate.add_argument("policy", type=Path, help="a policy file (.safetensors) or a run directory")
    evaluate.add_argument("--json", type=Path, help="also write the summary to this JSON file")
    evaluate.set_defaults(func=run_evaluate)

    export = subparsers.add_parser("export", help="write a run's (or checkpoint's) policy as a pickle-free file")
    export.add_argument("run", type=Path, help="a training run directory")
    export.add_argument("--checkpoint", type=int, help="export the checkpoint saved at this step instead")
    export.add_argument("--out", type=Path, help="output file (default: RUN/policy.safetensors)")
    export.set_defaults(func=run_export)

    plot = subparsers.add_parser("plot", help="figures")
    plot_sub = plot.add_subparsers(dest="figure", metavar="FIGURE", required=True)
    curves = plot_sub.add_parser("curves", help="training curves like the paper's Fig. 5 and Fig. 6")
    curves.add_argument("runs", nargs="+", type=Path, help="run directories or progress.csv files")
    curves.add_argument("--labels", nargs="+", help="one label per run")
    curves.add_argument("--curves", nargs="+", default=["reward", "length"], help="reward, length, success, error")
    curves.add_argument("--out", type=Path, default=Path("training_curves.png"), help="image file")
    curves.set_defaults(func=run_plot_curves)

    quick = subparsers.add_parser("quickstart", help="train quick-cpu, evaluate it and plot its curves")
    quick.add_argument("--out", type=Path, default=Path("runs/quickstart"), help="run directory")
    quick.add_argument("--seed", type=int, default=0)
    quick.add_argument("--episodes", type=int, default=500, help="evaluation episodes")
    quick.set_defaults(func=run_quickstart)


def _add_evaluation_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--env", choices=SIMULATORS, default="pointmass", help="simulator")
    parser.add_argument("--platform", choices=PLATFORM_KINDS, default="static-floor")
    parser.add_argument("--platform-speed", type=float, help="m/s, moving platforms")
    parser.add_argument("--sensing", choices=("perfect", "vicon"), default="perfect")
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--eval-seed", type=int, default=12345, help="seed of the evaluation episodes")


def run_train(args: argparse.Namespace) -> int:
    from marlander_lite.training.train import continue_from, train

    if args.list:
        print(describe_presets())
        return 0
    config = get_preset(args.preset)
    changes = {"simulator": args.env, "seed": args.seed, "total_steps": args.steps}
    config = config.replace(**{k: v for k, v in changes.items() if v is not None})
    if args.init_from:
        config = continue_from(config, args.init_from)
    elif args.preset in FINETUNE_PRESETS:
        raise ValueError(
            f"Preset {args.preset!r} continues a trained run: pass --init-from RUN_DIR "
            "(a directory written by 'marlander train', e.g. data/runs/quick-cpu)."
        )
    out = args.out or Path("runs") / f"{args.preset}-seed{config.seed}-{time.strftime('%Y%m%d-%H%M%S')}"
    print(f"Training preset {args.preset!r} on {config.simulator} for {config.total_steps:,} steps -> {out}")
    files = train(config, out, preset=args.preset, progress_bar=not args.no_progress)
    print(f"Done. Policy: {files.policy}")
    return 0


def _policy_path(path: Path) -> Path:
    return path / "policy.safetensors" if path.is_dir() else path


def run_evaluate(args: argparse.Namespace) -> int:
    from marlander_lite.training.evaluation import evaluate_policy_file

    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}.")
    summary = evaluate_policy_file(
        _policy_path(args.policy),
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
    return 0


def run_export(args: argparse.Namespace) -> int:
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from marlander_lite.training.export import export_policy
    from marlander_lite.training.presets import TrainConfig
    from marlander_lite.training.train import RunFiles, make_training_env, task_config_of

    files = RunFiles(args.run)
    if not files.config.is_file():
        raise FileNotFoundError(f"{args.run} is not a training run directory (no config.json).")
    record = json.loads(files.config.read_text())
    config = TrainConfig.from_dict(record["train"])
    model_path, norm_path = files.model, files.normalizer
    if args.checkpoint is not None:
        model_path = files.checkpoints / f"model_{args.checkpoint}.zip"
        norm_path = files.checkpoints / f"vecnormalize_{args.checkpoint}.pkl"
    if not model_path.is_file():
        raise FileNotFoundError(f"No model at {model_path}.")
    model = PPO.load(model_path, device="cpu")
    normalizer = (
        VecNormalize.load(str(norm_path), make_training_env(config, num_envs=1)) if norm_path.is_file() else None
    )
    out = args.out or files.policy
    extra = {"preset": record.get("preset"), "simulator": config.simulator, "steps": int(model.num_timesteps)}
    export_policy(model, out, task_config_of(config), normalizer, extra=extra)
    print(f"Wrote {out}")
    return 0


def run_plot_curves(args: argparse.Namespace) -> int:
    from marlander_lite.plotting import plot_training_curves

    plot_training_curves(args.runs, args.labels, args.curves, out=args.out)
    print(f"Wrote {args.out}")
    return 0


def run_quickstart(args: argparse.Namespace) -> int:
    """The README's main job: quick training, evaluation on the paper's random starts, figure."""
    from marlander_lite.budget import scaled
    from marlander_lite.plotting import plot_training_curves
    from marlander_lite.training.evaluation import evaluate_policy_file
    from marlander_lite.training.train import train

    config = get_preset("quick-cpu").replace(
        seed=args.seed, total_steps=scaled(get_preset("quick-cpu").total_steps, 20_000)
    )
    started = time.perf_counter()
    files = train(config, args.out, preset="quick-cpu", progress_bar=sys.stdout.isatty())
    minutes = (time.perf_counter() - started) / 60
    print(f"Trained {config.total_steps:,} steps in {minutes:.1f} min -> {files.policy}")
    episodes = scaled(args.episodes, 20)
    for platform in ("static-floor", "static-elevated"):
        summary = evaluate_policy_file(files.policy, episodes=episodes, platform=platform)
        print(f"{platform}: {summary}")
        (files.root / f"evaluation-{platform}.json").write_text(json.dumps(summary.to_dict(), indent=2))
    figure = files.root / "training_curves.png"
    plot_training_curves([files.root], ["quick-cpu"], ("reward", "length", "success", "error"), out=figure)
    print(f"Training curves (paper Fig. 5 and 6): {figure}")
    return 0
