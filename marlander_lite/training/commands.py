"""``marlander train | evaluate | export | plot | quickstart``.

``marlander train`` takes every :class:`~marlander_lite.training.presets.TrainConfig` field as an option
(``--learning-rate 1e-4``, ``--net-arch 64 64``), the task's and the point-mass dynamics' fields as dotted
keys (``--task.landing-tolerance 0.02``, ``--dynamics.family.max-tilt-deg 15 30``), each with its
docstring as help (:mod:`marlander_lite.config_cli`). The preset is applied first, then the options given;
``marlander train --preset NAME --help`` shows that preset's values. ``marlander evaluate`` takes the
fields of :class:`EvaluateOptions` the same way.

Every option is checked before any work starts: a bad value, a run directory already in use or
an output file that exists (without ``--force``) ends the command with one line naming the
option (see :mod:`marlander_lite.cli`).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from marlander_lite.cli import check_output_file, non_negative_int, positive_int
from marlander_lite.config_cli import ConfigOptions, FieldOption, field_docs, plain
from marlander_lite.make import SIMULATORS, SimulatorName
from marlander_lite.platforms import PLATFORM_KINDS, PlatformKind
from marlander_lite.pointmass.simulator import PointMassParams
from marlander_lite.task import TaskConfig
from marlander_lite.training.presets import FINETUNE_PRESETS, PRESETS, TrainConfig, describe_presets, get_preset

IMAGE_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")
"""File types ``plot --out`` can write (matplotlib would silently append .png to a name without one)."""
DEFAULT_PRESET = "quick-cpu"
QUICKSTART_PRESETS = ("quick-cpu-slow-trackers", "quick-cpu-smooth", "quick-cpu")
"""What ``marlander quickstart`` may train, its default first."""
TRAIN_SENSING = ("perfect", "vicon", "noisy", "robust")
"""The observation models a training run may use (``TrainConfig.sensing``)."""
KEPT_WHEN_FINE_TUNING = (
    "num_drones",
    "net_arch",
    "critic_arch",
    "activation",
    "task.observe_platform_velocity",
    "task.observe_previous_command",
    "task.observe_platform_acceleration",
    "task.observation_history",
)
"""Fields ``--init-from`` takes from the loaded run (its model is loaded whole): setting them is refused."""

TRAIN_FIELDS = {
    "simulator": FieldOption(flags=("--simulator", "--env"), choices=SIMULATORS),
    "platform": FieldOption(choices=PLATFORM_KINDS),
    "sensing": FieldOption(choices=TRAIN_SENSING),
    "seed": FieldOption(parse=non_negative_int, metavar="S"),
    "total_steps": FieldOption(flags=("--total-steps", "--steps"), parse=positive_int, metavar="N"),
    "checkpoint_every": FieldOption(parse=non_negative_int, metavar="N"),
    **{
        name: FieldOption(parse=positive_int, metavar="N")
        for name in ("num_drones", "num_envs", "n_steps", "batch_size", "n_epochs", "torch_threads")
    },
}
"""How TrainConfig fields depart from the generated options: the old spellings ``--env`` and ``--steps``,
the allowed names of ``str`` fields, and integers that must be >= 1 (or >= 0)."""


@dataclass(frozen=True)
class EvaluateOptions:
    """What ``marlander evaluate`` flies: the policy's own task with every training aid off, on the paper's
    random starts, deterministic actions."""

    env: SimulatorName = "pointmass"
    """Simulator: ``pointmass`` or ``crazyflie`` (PyBullet)."""
    platform: PlatformKind = "static-floor"
    """Platform motion (see ``marlander_lite.platforms``)."""
    platform_speed: float | tuple[float, float] | None = None
    """Tool speed of a moving platform (m/s); a (low, high) pair draws it per episode; None: the kind's default."""
    sensing: Literal["perfect", "vicon"] = "perfect"
    """``perfect`` or ``vicon`` (motion-capture noise and latency on the observations)."""
    controller: Literal["pid", "firmware"] | None = None
    """PyBullet only: the velocity tracker, ``pid`` (the cascaded PID) or ``firmware`` (the Crazyflie
    firmware's); None: the simulator's default."""
    episodes: int = 200
    """Episodes to run; the summary counts the first this many begun."""
    eval_seed: int = 12345
    """Seed of the evaluation episodes (their starts and noise)."""
    task: dict[str, Any] = field(default_factory=dict)
    """Overrides of :class:`~marlander_lite.task.TaskConfig` fields, applied after the policy's task with
    every training aid off."""


EVALUATE_FIELDS = {
    "env": FieldOption(flags=("--env",)),
    "episodes": FieldOption(parse=positive_int, metavar="N"),
    "eval_seed": FieldOption(parse=non_negative_int, metavar="S"),
}


def add_train_config_options(parser: argparse.ArgumentParser) -> ConfigOptions:
    """Every :class:`TrainConfig` field (but ``init_from``) as an option of ``parser``; also for other commands."""
    return ConfigOptions(
        parser,
        TrainConfig,
        get_preset(DEFAULT_PRESET),
        mappings={"task": TaskConfig, "dynamics": PointMassParams},
        skip=("init_from", "task.num_drones"),
        fields=TRAIN_FIELDS,
        title=f"TrainConfig fields (default: the preset's value; {DEFAULT_PRESET} unless --preset)",
    )


def register(subparsers: argparse._SubParsersAction) -> None:
    train = subparsers.add_parser(
        "train",
        help="train a policy with a preset (PPO); any TrainConfig field can be changed",
        description="Train a policy with PPO: the preset's TrainConfig, then the options given. "
        "The resolved config is saved in OUT/config.json.",
        usage="marlander train [--preset NAME] [--FIELD VALUE ...] [--task.KEY VALUE ...] [--out DIR] [--init-from RUN]"
        "\n       marlander train --resume RUN | --list | [--preset NAME] --help",
        add_help=False,
    )
    train.add_argument(
        "-h", "--help", action="store_true", help="show this help (with the values of --preset, if given) and exit"
    )
    train.add_argument("--preset", help=f"one of: {', '.join(PRESETS)} (default {DEFAULT_PRESET})")
    train.add_argument("--out", type=Path, help="run directory (default: runs/PRESET-seedS-TIME)")
    init_doc = plain(field_docs(TrainConfig)["init_from"])
    train.add_argument(
        "--init-from",
        type=Path,
        metavar="RUN",
        help=f"{init_doc} Its drone count, observation layout and networks are kept.",
    )
    train.add_argument(
        "--resume", type=Path, metavar="RUN", help="finish a run stopped with Ctrl-C, to its configured steps"
    )
    train.add_argument("--no-progress", action="store_true", help="no progress bar")
    train.add_argument("--list", action="store_true", help="list the presets and exit")
    train.set_defaults(func=run_train, config_options=add_train_config_options(train))

    evaluate = subparsers.add_parser(
        "evaluate",
        help="run a policy file and report success and landing error",
        usage="marlander evaluate POLICY [--FIELD VALUE ...] [--task.KEY VALUE ...] [--json FILE [--force]]",
    )
    evaluate.add_argument("policy", type=Path, help="a policy file (.safetensors) or a run directory")
    evaluate.add_argument("--json", type=Path, help="also write the summary to this JSON file")
    evaluate.add_argument("--force", action="store_true", help="overwrite an existing --json file")
    options = ConfigOptions(
        evaluate,
        EvaluateOptions,
        EvaluateOptions(),
        mappings={"task": TaskConfig},
        skip=("task.num_drones",),
        fields=EVALUATE_FIELDS,
        title="evaluation options",
        shown={"task": "the policy's, training aids off"},
    )
    evaluate.set_defaults(func=run_evaluate, config_options=options)

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
    curves.add_argument(
        "runs",
        nargs="+",
        type=Path,
        help="run directories, progress.csv files or sweep folders (one line per sweep: IQM over seeds, 95%% band)",
    )
    curves.add_argument("--labels", nargs="+", help="one label per run")
    curves.add_argument("--curves", nargs="+", default=["reward", "length"], help="reward, length, success, error")
    curves.add_argument(
        "--out", type=Path, default=Path("training_curves.png"), help=f"image file ({', '.join(IMAGE_SUFFIXES)})"
    )
    curves.add_argument("--force", action="store_true", help="overwrite an existing image")
    curves.set_defaults(func=run_plot_curves)
    profiles = plot_sub.add_parser(
        "profiles", help="performance profiles of sweeps over the conditions of the paper's Tables I and II"
    )
    profiles.add_argument("sweeps", nargs="+", type=Path, help="sweep folders flown with --evaluate protocol")
    profiles.add_argument("--labels", nargs="+", help="one label per sweep")
    profiles.add_argument("--conditions", default="protocol", help="evaluation set (default protocol)")
    profiles.add_argument(
        "--out", type=Path, default=Path("performance_profiles.png"), help=f"image file ({', '.join(IMAGE_SUFFIXES)})"
    )
    profiles.add_argument("--force", action="store_true", help="overwrite an existing image")
    profiles.set_defaults(func=run_plot_profiles)

    quick = subparsers.add_parser("quickstart", help="train quick-cpu-slow-trackers, evaluate it and plot its curves")
    quick.add_argument("--out", type=Path, default=Path("runs/quickstart"), help="run directory")
    quick.add_argument(
        "--preset",
        choices=QUICKSTART_PRESETS,
        default=QUICKSTART_PRESETS[0],
        help="quick-cpu-slow-trackers (default: 20 M steps, 7-10 min on 2 cores; lands in every static column of the "
        "transfer matrix, within 2.26 cm in all but PyFlyt's 0.21.0 order), quick-cpu-smooth (12 M steps, 4-13 min; "
        "lands in every column but PyFlyt's) or quick-cpu (6.5 min, floor pad, 2.7 cm from the pad centre)",
    )
    quick.add_argument("--seed", type=non_negative_int, default=0)
    quick.add_argument("--episodes", type=positive_int, default=500, help="evaluation episodes")
    quick.add_argument(
        "--firmware-episodes",
        type=positive_int,
        default=50,
        help="episodes flown in PyBullet through the Crazyflie firmware's velocity tracker (default 50)",
    )
    quick.set_defaults(func=run_quickstart)


def run_train(args: argparse.Namespace) -> int:
    from marlander_lite.training.train import check_new_run, continue_from, resume, train

    options: ConfigOptions = args.config_options
    preset = args.preset or DEFAULT_PRESET
    if args.help:
        options.show_values(get_preset(preset))
        options.parser.print_help()
        return 0
    if args.list:
        print(describe_presets())
        return 0
    given = options.given(args)
    if args.resume is not None:
        named = {"--preset": args.preset, "--out": args.out, "--init-from": args.init_from}
        extra = [flag for flag, value in named.items() if value is not None] + list(given.values())
        if extra:
            raise ValueError(f"--resume continues RUN with its own config.json; drop {', '.join(extra)}.")
        files = resume(args.resume, progress_bar=not args.no_progress)
        print(f"Done. Policy: {files.policy}")
        return 0
    try:
        config = options.apply(get_preset(preset), args)
    except ValueError as error:
        if "dynamics options apply" in str(error) and "dynamics" not in given:
            hint = f"Add --dynamics '{{}}' to leave out the point-mass dynamics of --preset {preset}."
            raise ValueError(f"{error} {hint}") from None
        raise
    if args.init_from:
        kept = [given[name] for name in KEPT_WHEN_FINE_TUNING if name in given]
        if kept:
            raise ValueError(
                f"--init-from keeps the loaded run's drone count, observation and networks; drop {', '.join(kept)}."
            )
        config = continue_from(config, args.init_from)
    elif preset in FINETUNE_PRESETS:
        raise ValueError(
            f"--preset {preset} continues a trained run: pass --init-from RUN_DIR "
            "(a directory written by 'marlander train', e.g. data/runs/quick-cpu)."
        )
    check_nested_configs(config)
    out = args.out or Path("runs") / f"{preset}-seed{config.seed}-{time.strftime('%Y%m%d-%H%M%S')}"
    check_new_run(config, out)
    print(f"Training preset {preset!r} on {config.simulator} for {config.total_steps:,} steps -> {out}")
    files = train(config, out, preset=preset, progress_bar=not args.no_progress)
    print(f"Done. Policy: {files.policy}")
    return 0


def check_nested_configs(config: TrainConfig) -> None:
    """Build the task and the point-mass dynamics ``config`` asks for, so a bad value stops before any work."""
    from marlander_lite.training.train import task_config_of

    task_config_of(config)
    try:
        PointMassParams(**config.dynamics)
    except TypeError as error:  # an unknown key or a family that is not a mapping
        raise ValueError(f"--dynamics: {error}") from None


def _policy_path(path: Path) -> Path:
    return path / "policy.safetensors" if path.is_dir() else path


def run_evaluate(args: argparse.Namespace) -> int:
    from marlander_lite.training.evaluation import evaluate_policy_file

    options: EvaluateOptions = args.config_options.apply(EvaluateOptions(), args)
    policy = _policy_path(args.policy)
    if args.json is not None:
        check_output_file(args.json, "--json", args.force, reading=[policy])
    env_options: dict[str, Any] = {}
    if options.controller is not None:
        if options.env != "crazyflie":
            raise ValueError("--controller chooses the PyBullet tracker; add --env crazyflie or drop it.")
        env_options["controller"] = options.controller
    if options.task:
        env_options["task"] = dict(options.task)
    summary = evaluate_policy_file(
        policy,
        simulator=options.env,
        episodes=options.episodes,
        seed=options.eval_seed,
        platform=options.platform,
        platform_speed=options.platform_speed,
        sensing=options.sensing,
        **env_options,
    )
    print(f"{options.env}, {options.platform}, sensing {options.sensing}: {summary}")
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
    from marlander_lite.training.sweep import sweep_runs

    logs = [progress_path(log) for run in args.runs for log in (sweep_runs(run) or [run])]
    check_output_file(args.out, "--out", args.force, reading=logs, suffixes=IMAGE_SUFFIXES)
    plot_training_curves(args.runs, args.labels, args.curves, out=args.out)
    print(f"Wrote {args.out}")
    return 0


def run_plot_profiles(args: argparse.Namespace) -> int:
    from marlander_lite.plotting import plot_performance_profiles
    from marlander_lite.training.sweep import EVALUATION_FILE

    evaluations = [Path(sweep) / EVALUATION_FILE for sweep in args.sweeps]
    check_output_file(args.out, "--out", args.force, reading=evaluations, suffixes=IMAGE_SUFFIXES)
    plot_performance_profiles(args.sweeps, args.labels, args.conditions, out=args.out)
    print(f"Wrote {args.out}")
    return 0


def run_quickstart(args: argparse.Namespace) -> int:
    """The README's main job: quick training, evaluation on the paper's random starts, figure."""
    from marlander_lite.budget import scaled
    from marlander_lite.plotting import plot_training_curves
    from marlander_lite.training.evaluation import evaluate_policy_file
    from marlander_lite.training.train import check_new_run, train

    preset = get_preset(args.preset)
    config = preset.replace(seed=args.seed, total_steps=scaled(preset.total_steps, 20_000))
    episodes = scaled(args.episodes, 20)
    firmware_episodes = scaled(args.firmware_episodes, 4)
    check_new_run(config, args.out)  # before three minutes of training, not after
    started = time.perf_counter()
    files = train(config, args.out, preset=args.preset, progress_bar=sys.stdout.isatty())
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
    plot_training_curves([files.root], [args.preset], ("reward", "length", "success", "error"), out=figure)
    print(f"Training curves (paper Fig. 5 and 6): {figure}")
    return 0
